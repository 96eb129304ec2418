// Stein's unbiased risk estimate of a denoised image's per-pixel squared error (Stein 1981;
// Firmino et al. 2022; docs/pipeline.md, "Stages and choices"):
// SURE_p = (y_p - x_p)^2 - var_p + 2 div_p, with div_p = dy_p/dx_p * var_p. The divergence comes
// from the denoiser's Jacobian diagonal when it offers one (free), else from Monte-Carlo probes
// (K extra denoiser runs: div_p ~ 1/(eps K) sum_k b_kp (F(x + eps b_k)_p - F(x)_p), b ~ N(0, var)).
#pragma once

#include <cstdint>

#include "proden/denoise/denoiser.hpp"

namespace proden {

struct MonteCarloProbes {
  int count = 4;          // K (the authors use 4)
  float epsilon = 1e-3f;  // step relative to b ~ N(0, var) (the authors use 1e-4, see README)
  std::uint64_t seed = 0x5eed;
};

// Deterministic N(0, 1) draw for (probe, pixel, channel): tiled and whole runs see the same noise.
float probe_normal(std::uint64_t seed, int probe, int x, int y, int c);

// div = dydx * var over `region` (buffers cover it).
void divergence_from_derivative(const View& variance, const Buffer& dydx, const Rect& region,
                                Buffer& div);

// Monte-Carlo divergence of a black-box denoiser over `region`; `y` = F(x) there. With half
// buffers in `in` it perturbs them too, consistently with x (a denoiser may read x only through
// its halves, like NFOR: docs/nfor.md).
void divergence_monte_carlo(const Denoiser& denoiser, const DenoiseInputs& in, const Rect& region,
                            const Buffer& y, const MonteCarloProbes& probes, Buffer& div);

// SURE over `region` from x, var, y and div.
void sure(const View& x, const View& variance, const Buffer& y, const Buffer& div,
          const Rect& region, Buffer& out);

}  // namespace proden

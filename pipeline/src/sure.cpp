#include "proden/sure.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include "proden/hash.hpp"

namespace proden {

float probe_normal(std::uint64_t seed, int probe, int x, int y, int c) {
  const std::int32_t key[4] = {probe, x, y, c};
  const std::uint64_t h = hash_span(std::span<const std::int32_t>(key), seed);
  // Box-Muller from two 24-bit uniforms in (0, 1].
  const double u1 = (static_cast<double>(h >> 40) + 1.0) / 16777216.0;
  const double u2 = static_cast<double>((h >> 16) & 0xFFFFFF) / 16777216.0;
  return static_cast<float>(std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2));
}

void divergence_from_derivative(const View& variance, const Buffer& dydx, const Rect& region,
                                Buffer& div) {
  const int n = region.width();
  for (int c = 0; c < 3; ++c) {
    for (int y = region.y0; y < region.y1; ++y) {
      const float* d = dydx.ptr(region.x0, y, c);
      const float* v = variance.ptr(region.x0, y, c);
      float* out = div.ptr(region.x0, y, c);
      for (int i = 0; i < n; ++i) out[i] = d[i] * v[i];
    }
  }
}

void divergence_monte_carlo(const Denoiser& denoiser, const DenoiseInputs& in, const Rect& region,
                            const Buffer& y, const MonteCarloProbes& probes, Buffer& div) {
  const Rect src = region.expanded(denoiser.radius()).intersect({0, 0, in.width, in.height});
  // With half buffers (which a denoiser such as NFOR reads instead of x), the probe perturbs
  // them, x_h + eps b_h with b_h ~ N(0, Var[x_h]), and x by the same amount, b = a b_A +
  // (1 - a) b_B, a = Var[x] / Var[x_A] (x = a x_A + (1 - a) x_B): then Var[b] = Var[x] and the
  // estimate is cov(y, x) / Var[x]-weighted as SURE needs. Without halves, b ~ N(0, Var[x]).
  const bool halves = in.half_colour[0].valid() && in.half_colour[1].valid() &&
                      in.half_variance[0].valid() && in.half_variance[1].valid();
  Buffer perturbed(src, 3), b(src, 3);
  std::array<Buffer, 2> perturbed_half;
  if (halves) perturbed_half = {Buffer(src, 3), Buffer(src, 3)};
  Buffer yk(region, 3);
  for (int c = 0; c < 3; ++c) {
    for (int py = region.y0; py < region.y1; ++py) {
      for (int px = region.x0; px < region.x1; ++px) div.at(px, py, c) = 0.0f;
    }
  }
  const int K = probes.count > 0 ? probes.count : 1;
  for (int k = 0; k < K; ++k) {
    for (int c = 0; c < 3; ++c) {
      for (int py = src.y0; py < src.y1; ++py) {
        for (int px = src.x0; px < src.x1; ++px) {
          float bp = 0.0f;
          if (halves) {
            const float va = in.half_variance[0].at(px, py, c);
            const float vb = in.half_variance[1].at(px, py, c);
            const float v = in.variance.at(px, py, c);
            const float a = va > 0.0f ? std::clamp(v / va, 0.0f, 1.0f) : 0.5f;
            const float ba = std::sqrt(va) * probe_normal(probes.seed + 1, k, px, py, c);
            const float bb = std::sqrt(vb) * probe_normal(probes.seed + 2, k, px, py, c);
            perturbed_half[0].at(px, py, c) = in.half_colour[0].at(px, py, c) + probes.epsilon * ba;
            perturbed_half[1].at(px, py, c) = in.half_colour[1].at(px, py, c) + probes.epsilon * bb;
            bp = a * ba + (1.0f - a) * bb;
          } else {
            bp = std::sqrt(in.variance.at(px, py, c)) * probe_normal(probes.seed, k, px, py, c);
          }
          b.at(px, py, c) = bp;
          perturbed.at(px, py, c) = in.colour.at(px, py, c) + probes.epsilon * bp;
        }
      }
    }
    DenoiseInputs pin = in;
    pin.colour = perturbed.view();
    if (halves) {
      pin.half_colour[0] = perturbed_half[0].view();
      pin.half_colour[1] = perturbed_half[1].view();
    }
    denoiser.denoise(pin, region, yk, nullptr);
    for (int c = 0; c < 3; ++c) {
      for (int py = region.y0; py < region.y1; ++py) {
        for (int px = region.x0; px < region.x1; ++px) {
          div.at(px, py, c) += b.at(px, py, c) * (yk.at(px, py, c) - y.at(px, py, c));
        }
      }
    }
  }
  const float scale = 1.0f / (probes.epsilon * static_cast<float>(K));
  for (int c = 0; c < 3; ++c) {
    for (int py = region.y0; py < region.y1; ++py) {
      for (int px = region.x0; px < region.x1; ++px) div.at(px, py, c) *= scale;
    }
  }
}

void sure(const View& x, const View& variance, const Buffer& y, const Buffer& div,
          const Rect& region, Buffer& out) {
  const int n = region.width();
  for (int c = 0; c < 3; ++c) {
    for (int py = region.y0; py < region.y1; ++py) {
      const float* yr = y.ptr(region.x0, py, c);
      const float* xr = x.ptr(region.x0, py, c);
      const float* vr = variance.ptr(region.x0, py, c);
      const float* dr = div.ptr(region.x0, py, c);
      float* o = out.ptr(region.x0, py, c);
      for (int i = 0; i < n; ++i) {
        const float d = yr[i] - xr[i];
        o[i] = d * d - vr[i] + 2.0f * dr[i];
      }
    }
  }
}

}  // namespace proden

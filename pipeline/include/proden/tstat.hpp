// The t-statistic rescale of the mixing weight (design.md §2.4, the authors' values): where the
// mixed image drifts from the render by more than the samples' noise explains, alpha shrinks, so
// the output converges to the unbiased render as samples grow.
#pragma once

#include "proden/region.hpp"

namespace proden {

struct TTestParams {
  int radius = 5;              // 11x11 window
  float sigma_scale = 100.0f;  // s = sigma_scale * sqrt(clamp(mean_c var, 0, 1))
  float sigma_floor = 1e-3f;
  float t0 = 4.2f;  // alpha' = alpha (1 - Phi(slope (t - t0)))
  float slope = 2.0f;
  // Var[xbar] comes from K passes, so t is Student-t with about K - 1 degrees of freedom, not
  // normal: with few passes the authors' t0 (a normal quantile) rejects good mixes wherever the
  // heavy-tailed variance estimate came out low. When on and the pass count is known, t0 becomes
  // the Student-t quantile of the same tail probability (Cornish-Fisher); as K grows it tends to
  // the authors' t0. Off = exactly the authors' test.
  bool dof_correction = true;
};

// The threshold used for a pixel whose variance came from `passes` passes.
double t_threshold(const TTestParams& params, double passes);

// Reads x, var, z (= x + alpha (y - x) with the un-rescaled alpha) and alpha over
// out.expanded(radius) ∩ image; writes alpha' over `out`. Neighbours outside the image are
// skipped. The three channels are summed into one statistic per pixel (the same factor scales
// all channels), and the window's highest-variance pixel M is added to both sums.
// `passes` (1 channel, passes per pixel) enables the degrees-of-freedom correction; an invalid view
// (unknown pass counts) keeps the authors' t0.
void t_rescale(const View& x, const View& variance, const View& z, const View& alpha, int width,
               int height, const Rect& out, const TTestParams& params, Buffer& rescaled,
               const View& passes = {});

// The statistic itself at one pixel (exposed for tests and diagnostics).
double t_statistic(const View& x, const View& variance, const View& z, int width, int height,
                   int px, int py, const TTestParams& params);

}  // namespace proden

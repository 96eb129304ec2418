// The cascade (issue 10): an ensemble of the two built-in denoisers, NL-means and NFOR, weighted
// per pixel by their window-smoothed errors; the pipeline then mixes it with the render as usual.
#pragma once

#include <memory>
#include <string>

#include "proden/denoise/denoiser.hpp"
#include "proden/denoise/nfor.hpp"
#include "proden/denoise/nlmeans.hpp"
#include "proden/mixer.hpp"

namespace proden {

struct CascadeParams {
  // Window radius of the smoothed errors that weight NFOR against NL-means (docs/cascade.md).
  int radius = 12;
};

// y = y1 + b (y2 - y1) with y1 = NL-means(x), y2 = NFOR(x) and
// b = clamp(S(max(SURE(y1), 0)) / S((y2 - y1)^2), 0, 1), S a window sum weighted by relMSE's
// 1 / (3x3 mean of y1)^2 + 0.01): the MSE-optimal blend of y1 towards y2 when their errors are
// uncorrelated, E[(y2 - y1)^2] = MSE(y1) + MSE(y2). Only NL-means' error estimate is needed, the
// one that measures best (NFOR's under-estimates and fails at caustics: docs/nfor.md); where NFOR
// departs from NL-means by more than NL-means' own error explains, b falls towards NL-means.
// The window sum is the closed-form Stein mixer run on (y1, y2) with SURE(y1) as the variance.
// Whole-frame (NFOR is); dy/dx = (1 - b) dy1/dx + b dy2/dx with b held fixed.
class CascadeDenoiser final : public Denoiser {
 public:
  CascadeDenoiser(NlMeansParams nlmeans, NforParams nfor, CascadeParams params = {});
  std::string name() const override { return "cascade"; }
  int radius() const override { return 0; }
  bool has_derivative() const override { return true; }
  bool whole_frame() const override { return true; }
  void denoise(const DenoiseInputs& in, const Rect& out, Buffer& y, Buffer* dydx) const override;

  // The weight b of NFOR per pixel and channel over the full frame, with y (tests, diagnostics).
  void denoise_with_weight(const DenoiseInputs& in, Buffer& y, Buffer* dydx, Buffer& b) const;

 private:
  NlMeansDenoiser nlmeans_;
  NforDenoiser nfor_;
  ClosedFormMixer blend_;
};

}  // namespace proden

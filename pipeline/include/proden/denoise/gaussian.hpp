// A plain Gaussian blur as a denoiser: linear in x with fixed weights (so its Jacobian diagonal is
// simply the centre weight), fast, and strongly biased at edges and detail. It is the reference
// "denoiser that stalls": the progressive pipeline must converge to the render where it blurs.
#pragma once

#include "proden/denoise/denoiser.hpp"

namespace proden {

class GaussianDenoiser final : public Denoiser {
 public:
  explicit GaussianDenoiser(float sigma = 2.0f);
  std::string name() const override { return "gaussian"; }
  int radius() const override { return radius_; }
  bool has_derivative() const override { return true; }
  bool linear() const override { return true; }
  void denoise(const DenoiseInputs& in, const Rect& out, Buffer& y, Buffer* dydx) const override;

 private:
  float sigma_;
  int radius_;
};

}  // namespace proden

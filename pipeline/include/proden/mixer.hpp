// Per-pixel mixing weight alpha of z = x + alpha (y - x): the interface the learned network and
// the closed-form baseline share, and the closed-form mixer itself.
#pragma once

#include <algorithm>
#include <string>

#include "proden/region.hpp"
#include "proden/tstat.hpp"

namespace proden {

// Everything a mixer may read, as views covering at least out.expanded(radius()) ∩ image.
struct MixInputs {
  int width = 0, height = 0;
  View x, y, variance, sure, divergence;  // 3 channels each
  // Where `variance` came from (its degrees of freedom): the closed-form mixer weighs how well
  // its window sums pin alpha down. Default: treated as exact.
  VarianceOrigin origin{};
};

class Mixer {
 public:
  virtual ~Mixer() = default;
  virtual std::string name() const = 0;
  virtual int radius() const = 0;
  // alpha in [0, 1] per pixel and channel over `out` (a 3-channel buffer covering it).
  virtual void mix(const MixInputs& in, const Rect& out, Buffer& alpha) const = 0;
};

enum class ClosedFormRule {
  // alpha = S(var - div) / S((y - x)^2): the MSE-optimal blend when y depends on x, by Stein's
  // lemma (E[(x - mu)(y - x)] = div - var); reduces to inverse-error weighting when y is
  // independent of x. S is a weighted window sum (see WindowWeight).
  stein,
  // alpha = S(var) / (S(var) + max(S(SURE), 0)): inverse-error weighting (Firmino et al. 2022's
  // closed-form baseline; docs/pipeline.md).
  inverse_error,
};

// How the window sums weight their pixels.
enum class WindowWeight {
  uniform,   // plain sums
  variance,  // 1 / (3x3 mean of var + floor): the window's variance-normalised error
  relative,  // 1 / ((3x3 mean of x)^2 + 0.01): the window's relMSE (default; docs/pipeline.md)
};

struct ClosedFormParams {
  ClosedFormRule rule = ClosedFormRule::stein;
  WindowWeight weight = WindowWeight::relative;
  float variance_floor = 1e-4f;  // variance weights: floor = variance_floor * (mean x^2 + 0.01)
  int radius = 12;               // box window (2r+1)^2 that smooths the noisy per-pixel estimates
  // Two scales (stein rule; docs/pipeline.md, "The mixer's two scales"): alpha from the radius
  // window is shrunk toward alpha from a wide_radius window unless the two differ by more than
  // `garrote` standard errors of their difference (a non-negative garrote). wide_radius <= radius:
  // one window.
  int wide_radius = 24;
  float garrote = 2.0f;
};

class ClosedFormMixer final : public Mixer {
 public:
  explicit ClosedFormMixer(ClosedFormParams p = {}) : params_(p) {}
  std::string name() const override;
  int radius() const override {  // + the weights' 3x3
    return std::max(params_.radius, params_.wide_radius) + 1;
  }
  void mix(const MixInputs& in, const Rect& out, Buffer& alpha) const override;

 private:
  ClosedFormParams params_;
};

}  // namespace proden

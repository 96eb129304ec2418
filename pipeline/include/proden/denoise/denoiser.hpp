// The denoiser interface: y = F(x, features) over a region, reading inputs within radius() of it.
// Built-in filters and adapters (external programs, the renderer's own) implement it; the
// progressive pipeline treats them uniformly and uses the Jacobian diagonal when one is offered.
#pragma once

#include <array>
#include <string>

#include "proden/region.hpp"

namespace proden {

// Full-frame inputs (views over the whole image, or over a region that covers every pixel the
// denoiser reads). Feature views are invalid when the frame has no such feature.
struct DenoiseInputs {
  int width = 0, height = 0;  // of the full image
  View colour;                // x, 3 channels
  View variance;              // Var[x], 3 channels
  View albedo, normal, depth;
  View albedo_variance, normal_variance, depth_variance;
  // Half buffers A and B (passes alternate between them; docs/nfor.md): colour x_A, x_B and
  // Var[x_A], Var[x_B] are valid when both halves hold passes (2 passes or more); the feature
  // means per half are valid when, in addition, the frame carries that feature and its state
  // kept feature halves (a state restored from format v1 did not).
  std::array<View, 2> half_colour, half_variance;
  std::array<View, 2> half_albedo, half_normal, half_depth;
};

class Denoiser {
 public:
  virtual ~Denoiser() = default;
  virtual std::string name() const = 0;
  // How far outside the output region inputs are read (the tile halo it needs).
  virtual int radius() const = 0;
  // True if denoise() can fill dydx with the Jacobian diagonal dy_p/dx_p per channel.
  virtual bool has_derivative() const = 0;
  // True for a denoiser that must see the whole frame at once (a global solve): the pipeline runs
  // it once over the full image before the tiled stages, and the tiles read y from that run.
  virtual bool whole_frame() const { return false; }
  // True for a linear filter whose weights do not depend on the data (y = K x, a fixed K): the
  // error estimate then splits its error into bias and variance exactly from the two halves' runs
  // (docs/error_estimate.md, "A linear denoiser").
  virtual bool linear() const { return false; }
  // Computes y (and dydx when non-null and supported) over `out`, which must lie in the image.
  // y and dydx must be 3-channel buffers covering `out`.
  virtual void denoise(const DenoiseInputs& in, const Rect& out, Buffer& y, Buffer* dydx) const = 0;
};

}  // namespace proden

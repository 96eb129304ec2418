// One pass: an independent render of a frame (n samples per pixel), as planar float buffers,
// and the layout of optional features it carries (the paper's Table 1 input combinations).
#pragma once

#include <string>

#include "proden/image.hpp"

namespace proden {

// Which optional inputs a pass (and so a frame) carries besides its colour.
struct Layout {
  bool albedo = false;
  bool normal = false;
  bool depth = false;
  bool variance = false;  // renderer-provided variance of the pass's pixel estimate

  bool operator==(const Layout&) const = default;
  // "HDR", "HDR+VAR", "HDR+ALB+NRM", "HDR+ALB+NRM+VAR" (+DEP when depth is present).
  std::string to_string() const;
};

struct Pass {
  Image colour;    // 3 channels, linear RGB: the pass's per-pixel mean of its samples
  Image albedo;    // empty, or 3 channels
  Image normal;    // empty, or 3 channels
  Image depth;     // empty, or 1 channel
  Image variance;  // empty, or 3 channels: variance of this pass's pixel mean
  double spp = 1.0;

  int width() const { return colour.width(); }
  int height() const { return colour.height(); }
  Layout layout() const {
    return {!albedo.empty(), !normal.empty(), !depth.empty(), !variance.empty()};
  }
};

}  // namespace proden

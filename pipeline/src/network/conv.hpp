// Direct convolution over channel-interleaved (HWC) activations with a zero border: the learned
// mixer's hot loop. Vectorised over output channels (16 per vector), register-blocked over pixels;
// AVX-512, AVX2+FMA and baseline builds are chosen at run time (no -march=native).
#pragma once

#include <cstddef>
#include <vector>

#include "proden/network/pdnet.hpp"

namespace proden::network::detail {

// An activation map of h x w pixels, `cs` floats per pixel, with a zero border of kBorder pixels
// so 3x3 and 5x5 convolutions read without bounds checks.
struct Activation {
  static constexpr int kBorder = 2;
  int h = 0, w = 0, cs = 0;
  std::vector<float> data;

  Activation(int h_, int w_, int cs_)
      : h(h_),
        w(w_),
        cs(cs_),
        data(static_cast<std::size_t>(h_ + 2 * kBorder) *
             static_cast<std::size_t>(w_ + 2 * kBorder) * static_cast<std::size_t>(cs_)) {}
  std::ptrdiff_t row_stride() const { return static_cast<std::ptrdiff_t>(w + 2 * kBorder) * cs; }
  float* px(int y, int x) {
    return data.data() + (y + kBorder) * row_stride() +
           static_cast<std::ptrdiff_t>(x + kBorder) * cs;
  }
  const float* px(int y, int x) const {
    return data.data() + (y + kBorder) * row_stride() +
           static_cast<std::ptrdiff_t>(x + kBorder) * cs;
  }
};

// out = [relu](conv(in) + bias [+ residual]) over the interior; `in` holds layer.cin channels
// (stride in.cs), out and residual have stride layer.cout_pad.
void conv_forward(const ConvLayer& layer, const Activation& in, Activation& out,
                  const Activation* residual, bool relu);

// Which kernel build conv_forward uses on this CPU ("avx512", "avx2" or "baseline").
const char* conv_isa();

}  // namespace proden::network::detail

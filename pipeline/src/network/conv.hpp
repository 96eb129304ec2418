// Direct convolution over channel-interleaved (HWC) activations with a zero border: the learned
// mixer's hot loop. Vectorised over output channels (16 per vector), register-blocked over pixels;
// AVX-512, AVX2+FMA and baseline builds are chosen at run time (no -march=native).
#pragma once

#include <cstddef>
#include <string>
#include <vector>

#include "proden/network/pdnet.hpp"

namespace proden::network::detail {

// An activation map of h x w pixels, `cs` floats per pixel, with a zero border of kBorder pixels
// so 3x3 and 5x5 convolutions read without bounds checks. It views storage owned elsewhere
// (reused between tiles): bind() sizes the storage and zeroes only the border, because every
// convolution and the input builder overwrite the whole interior.
struct Activation {
  static constexpr int kBorder = 2;
  int h = 0, w = 0, cs = 0;
  float* data = nullptr;

  static Activation bind(std::vector<float>& storage, int h, int w, int cs);
  std::ptrdiff_t row_stride() const { return static_cast<std::ptrdiff_t>(w + 2 * kBorder) * cs; }
  float* px(int y, int x) const {
    return data + (y + kBorder) * row_stride() + static_cast<std::ptrdiff_t>(x + kBorder) * cs;
  }
};

// out = [relu](conv(in) + bias [+ residual]) over the interior; `in` holds layer.cin channels
// (stride in.cs), out and residual have stride layer.cout_pad.
void conv_forward(const ConvLayer& layer, const Activation& in, Activation& out,
                  const Activation* residual, bool relu);

// Which kernel build conv_forward uses on this CPU ("avx512", "avx2" or "baseline").
const char* conv_isa();

// For tests: the builds this CPU can run, and conv_forward with a given one.
std::vector<std::string> conv_isas_available();
void conv_forward_with(const std::string& isa, const ConvLayer& layer, const Activation& in,
                       Activation& out, const Activation* residual, bool relu);

}  // namespace proden::network::detail

// Branch-free float helpers that GCC auto-vectorises (internal to the pipeline).
#pragma once

#include <bit>
#include <cstdint>

namespace proden::detail {

#include "exp_neg.inc"

struct ScalarOps {
  using F = float;
  static std::int32_t to_int(float v) { return static_cast<std::int32_t>(v); }
  static float to_float(std::int32_t v) { return static_cast<float>(v); }
  static float from_bits(std::int32_t v) { return std::bit_cast<float>(v); }
  static float select(bool m, float a, float b) { return m ? a : b; }
};

inline float exp_neg(float x) { return exp_neg_with<ScalarOps>(x); }

}  // namespace proden::detail

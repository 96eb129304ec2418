// Branch-free float helpers that GCC auto-vectorises (internal to the pipeline).
#pragma once

#include <bit>
#include <cstdint>

namespace proden::detail {

// exp(x) for x <= 0 (positive x is treated as 0), relative error ~2e-7, 0 below -87 (no
// denormals). Branch-free, so loops calling it vectorise; deterministic, so tiled and
// whole-image runs agree bit for bit. 2^t = 2^i * 2^f with i = round(t), |f| <= 0.5, and a
// degree-6 Taylor polynomial of 2^f.
inline float exp_neg(float x) {
  float t = x * 1.4426950408889634f;  // log2(e)
  t = t < -126.0f ? -126.0f : t;
  t = t > 0.0f ? 0.0f : t;
  const float shifted = t - 0.5f;  // in [-126.5, -0.5]: truncation rounds towards zero
  const int ti = static_cast<int>(shifted);
  const float tf = static_cast<float>(ti);
  const float fi = tf - (shifted < tf ? 1.0f : 0.0f) + 1.0f;  // floor(t - 0.5) + 1 = round(t)
  const float f = t - fi;                                     // [-0.5, 0.5]
  float p = 1.5403530393381606e-4f;                           // ln2^6 / 720
  p = p * f + 1.3333558146428443e-3f;                         // ln2^5 / 120
  p = p * f + 9.6181291076284772e-3f;                         // ln2^4 / 24
  p = p * f + 5.5504108664821580e-2f;                         // ln2^3 / 6
  p = p * f + 2.4022650695910071e-1f;                         // ln2^2 / 2
  p = p * f + 6.9314718055994531e-1f;                         // ln2
  p = p * f + 1.0f;
  const std::int32_t bits = (static_cast<std::int32_t>(fi) + 127) << 23;
  return x < -87.0f ? 0.0f : p * std::bit_cast<float>(bits);
}

}  // namespace proden::detail

// Shared by the benchmark tools: synthetic Cycles-like passes (colour + albedo + normal + depth:
// a smooth signal with a step, per-pass Gaussian noise, piecewise-constant features) and a
// denoiser run alone over a frame in parallel tiles ("one denoiser run").
#pragma once

#include <tbb/blocked_range2d.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "proden/denoise/denoiser.hpp"
#include "proden/pass.hpp"

namespace proden::bench {

// The upper median of repeated timings (0 for none).
inline double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

inline Pass synthetic_pass(int w, int h, int k, double spp) {
  std::mt19937 rng(static_cast<unsigned>(1000 + k));
  std::normal_distribution<float> n(0.0f, 1.0f);
  Pass p;
  p.spp = spp;
  p.colour = Image(w, h, 3);
  p.albedo = Image(w, h, 3);
  p.normal = Image(w, h, 3);
  p.depth = Image(w, h, 1);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const bool right = x > w / 2;
      const float base = 0.3f + 0.2f * std::sin(0.05f * static_cast<float>(x)) +
                         0.1f * std::cos(0.03f * static_cast<float>(y)) + (right ? 0.3f : 0.0f);
      const float sd = std::sqrt(0.08f * base);
      for (int c = 0; c < 3; ++c) {
        p.colour.at(x, y, c) = std::max(0.0f, base + sd * n(rng));
        p.albedo.at(x, y, c) = right ? 0.8f : 0.4f;
        p.normal.at(x, y, c) = c == 2 ? -1.0f : 0.0f;
      }
      p.depth.at(x, y, 0) = right ? 2.0f : 5.0f;
    }
  }
  return p;
}

// y = F(x) over the whole frame in tiles of `tile` pixels (one call for a whole-frame denoiser),
// no Jacobian, parallel like the pipeline.
inline Image tiled_denoise(const Denoiser& den, const DenoiseInputs& din, int tile) {
  Image y(din.width, din.height, 3);
  const int t = den.whole_frame() ? std::max(din.width, din.height) : std::max(1, tile);
  tbb::parallel_for(
      tbb::blocked_range2d<int>(0, (din.height + t - 1) / t, 1, 0, (din.width + t - 1) / t, 1),
      [&](const tbb::blocked_range2d<int>& r) {
        for (int ty = r.rows().begin(); ty < r.rows().end(); ++ty) {
          for (int tx = r.cols().begin(); tx < r.cols().end(); ++tx) {
            const Rect rect{tx * t, ty * t, std::min(din.width, (tx + 1) * t),
                            std::min(din.height, (ty + 1) * t)};
            Buffer b(rect, 3);
            den.denoise(din, rect, b, nullptr);
            store(b, rect, y);
          }
        }
      });
  return y;
}

}  // namespace proden::bench

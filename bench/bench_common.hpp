// Shared by the benchmark tools: synthetic Cycles-like passes (colour + albedo + normal + depth:
// a smooth signal with a step, per-pass Gaussian noise, piecewise-constant features), a
// denoiser run alone over a frame in parallel tiles ("one denoiser run"), and the Jacobian's cost
// against it, timed in pairs.
#pragma once

#include <tbb/blocked_range2d.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <ctime>
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

// CPU seconds of the calling thread.
inline double thread_cpu_seconds() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

// Every pixel of the frame once on the calling thread, in `tile`-pixel tiles, with or without
// the denoiser's Jacobian diagonal (the divergence SURE needs).
inline void serial_denoise(const Denoiser& den, const DenoiseInputs& din, int tile, bool jacobian) {
  for (int y0 = 0; y0 < din.height; y0 += tile) {
    for (int x0 = 0; x0 < din.width; x0 += tile) {
      const Rect t{x0, y0, std::min(x0 + tile, din.width), std::min(y0 + tile, din.height)};
      Buffer y(t, 3), d(t, 3);
      den.denoise(din, t, y, jacobian ? &d : nullptr);
    }
  }
}

// One pair of serial_denoise runs back to back, without and with the Jacobian (`jacobian_first`
// says which runs first), in thread CPU seconds: {without, with}. Issue 12's "divergence <= 0.25x
// the denoiser alone" is the median over many pairs, alternating the order, of with / without - 1,
// so that the VM's slow minutes weigh on both halves of every ratio.
struct JacobianPair {
  double without = 0, with = 0;
  double cost() const { return with / without - 1.0; }  // the Jacobian's, over the denoiser's
};
inline JacobianPair jacobian_pair(const Denoiser& den, const DenoiseInputs& din, int tile,
                                  bool jacobian_first) {
  JacobianPair p;
  for (int i = 0; i < 2; ++i) {
    const bool jac = (i == 0) == jacobian_first;
    const double t0 = thread_cpu_seconds();
    serial_denoise(den, din, tile, jac);
    (jac ? p.with : p.without) = thread_cpu_seconds() - t0;
  }
  return p;
}

}  // namespace proden::bench

// NFOR §5.3: per-pixel selection between the first pass's NL-means bandwidths, driven by MSE
// estimates from the half buffers (each half's filter output against the other, independent,
// half), smoothed because a single pixel's estimate is far too noisy to choose by.
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "nfor_internal.hpp"

namespace proden::nfor {
namespace {

constexpr float kMaxEstimate = 1e30f;  // keeps squared 1e18 values (and their sums) finite

}  // namespace

void select_bandwidths(const Geometry& g, const std::vector<Planes>& fa,
                       const std::vector<Planes>& fb, const Planes& xa, const Planes& xb,
                       const Planes& va, const Planes& vb, const WeightSpec& smoothing,
                       Planes& out_a, Planes& out_b, Planes& share) {
  const int n = static_cast<int>(fa.size());
  Planes mse(g, n), smoothed(g, n);
  tbb::parallel_for(0, g.height, [&](int y) {
    const std::ptrdiff_t row = g.offset(0, y);
    for (int i = 0; i < n; ++i) {
      float* e = mse.origin(i) + row;
      for (int x = 0; x < g.width; ++x) {
        double s = 0.0;
        for (int c = 0; c < 3; ++c) {
          const double a = fa[static_cast<std::size_t>(i)].origin(c)[row + x];
          const double b = fb[static_cast<std::size_t>(i)].origin(c)[row + x];
          const double ya = xa.origin(c)[row + x], yb = xb.origin(c)[row + x];
          s += (a - yb) * (a - yb) - vb.origin(c)[row + x] + (b - ya) * (b - ya) -
               va.origin(c)[row + x];
        }
        e[x] = static_cast<float>(std::clamp(s / 6.0, -double{kMaxEstimate}, double{kMaxEstimate}));
      }
    }
  });
  replicate_border(g, mse);
  nlmeans_filter(g, smoothing, mse, smoothed);
  // Winner map (1 where bandwidth i has the lowest smoothed estimate; ties go to the first).
  Planes win(g, n);
  tbb::parallel_for(0, g.height, [&](int y) {
    const std::ptrdiff_t row = g.offset(0, y);
    for (int x = 0; x < g.width; ++x) {
      int best = 0;
      for (int i = 1; i < n; ++i) {
        if (smoothed.origin(i)[row + x] < smoothed.origin(best)[row + x]) best = i;
      }
      for (int i = 0; i < n; ++i) win.origin(i)[row + x] = i == best ? 1.0f : 0.0f;
    }
  });
  replicate_border(g, win);
  nlmeans_filter(g, smoothing, win, share);
  tbb::parallel_for(0, g.height, [&](int y) {
    const std::ptrdiff_t row = g.offset(0, y);
    for (int c = 0; c < 3; ++c) {
      float* oa = out_a.origin(c) + row;
      float* ob = out_b.origin(c) + row;
      for (int x = 0; x < g.width; ++x) {
        float sa = 0.0f, sb = 0.0f;
        for (int i = 0; i < n; ++i) {
          const float s = share.origin(i)[row + x];
          sa += s * fa[static_cast<std::size_t>(i)].origin(c)[row + x];
          sb += s * fb[static_cast<std::size_t>(i)].origin(c)[row + x];
        }
        oa[x] = sa;
        ob[x] = sb;
      }
    }
  });
  replicate_border(g, out_a);
  replicate_border(g, out_b);
}

}  // namespace proden::nfor

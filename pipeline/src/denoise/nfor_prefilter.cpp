// NFOR §5.1: feature prefiltering. Features such as depth and normals are noisy under depth of
// field, motion blur or glossy paths; filtering each half with NL-means weights computed on the
// *other* half keeps the filter's weights independent of the noise of the data it averages.
#include <tbb/parallel_for.h>

#include "nfor_internal.hpp"

namespace proden::nfor {
namespace {

constexpr int kFeatureVarianceRadius = 1;  // box smoothing of the halves' squared difference

}  // namespace

Planes prefilter_features(const Geometry& g, const Planes& half_a, const Planes& half_b,
                          const std::array<bool, 3>& present, const PrefilterSpec& spec) {
  constexpr int kFirst[3] = {0, 3, 6};
  constexpr int kCount[3] = {3, 3, 1};
  Planes out(g, kFeatures);
  for (int group = 0; group < 3; ++group) {
    if (!present[static_cast<std::size_t>(group)]) continue;
    const int c0 = kFirst[group], n = kCount[group];
    // Var of one half: E[(A - B)^2] = Var[A] + Var[B] = 2 Var[half]; 3x3 box (more dof).
    Planes diff(g, n);
    tbb::parallel_for(0, g.height, [&](int y) {
      for (int c = 0; c < n; ++c) {
        const float* a = half_a.origin(c0 + c) + g.offset(0, y);
        const float* b = half_b.origin(c0 + c) + g.offset(0, y);
        float* d = diff.origin(c) + g.offset(0, y);
        for (int x = 0; x < g.width; ++x) d[x] = 0.5f * (a[x] - b[x]) * (a[x] - b[x]);
      }
    });
    const Planes var = box_mean(g, diff, kFeatureVarianceRadius);
    Planes data_a(g, n), data_b(g, n), fa(g, n), fb(g, n);
    for (int c = 0; c < n; ++c) {
      std::copy(half_a.plane(c0 + c), half_a.plane(c0 + c) + g.plane_size(), data_a.plane(c));
      std::copy(half_b.plane(c0 + c), half_b.plane(c0 + c) + g.plane_size(), data_b.plane(c));
    }
    WeightSpec from_b, from_a;
    from_b.channels = from_a.channels = n;
    from_b.radius = from_a.radius = spec.radius;
    from_b.patch = from_a.patch = spec.patch;
    from_b.k = from_a.k = spec.k;
    from_b.kernels = from_a.kernels = spec.kernels;
    for (int c = 0; c < n; ++c) {
      from_b.guide[c] = data_b.origin(c);
      from_a.guide[c] = data_a.origin(c);
      from_b.variance[c] = from_a.variance[c] = var.origin(c);
    }
    nlmeans_filter(g, from_b, data_a, fa);  // A filtered with B's weights
    nlmeans_filter(g, from_a, data_b, fb);  // B filtered with A's weights
    for (int c = 0; c < n; ++c) {
      const float* a = fa.plane(c);
      const float* b = fb.plane(c);
      float* o = out.plane(c0 + c);
      for (std::size_t i = 0; i < g.plane_size(); ++i) o[i] = 0.5f * (a[i] + b[i]);
    }
  }
  return out;
}

}  // namespace proden::nfor

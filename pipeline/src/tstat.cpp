#include "proden/tstat.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

namespace proden {
namespace {

constexpr double kSqrt2Pi = 2.5066282746310002;

// Per-pixel channel sums of x, z and var over a region (what every window tap needs).
struct ChannelSums {
  Rect rect;
  std::vector<double> x, z, v;
  ChannelSums(const View& xv, const View& vv, const View& zv, const Rect& r)
      : rect(r), x(r.area()), z(r.area()), v(r.area()) {
    std::size_t i = 0;
    for (int py = r.y0; py < r.y1; ++py) {
      for (int px = r.x0; px < r.x1; ++px, ++i) {
        double sx = 0, sz = 0, sv = 0;
        for (int c = 0; c < 3; ++c) {
          sx += xv.at(px, py, c);
          sz += zv.at(px, py, c);
          sv += vv.at(px, py, c);
        }
        x[i] = sx;
        z[i] = sz;
        v[i] = sv;
      }
    }
  }
  std::size_t index(int px, int py) const {
    return static_cast<std::size_t>(py - rect.y0) * static_cast<std::size_t>(rect.width()) +
           static_cast<std::size_t>(px - rect.x0);
  }
};

double statistic(const ChannelSums& s, int width, int height, int px, int py,
                 const TTestParams& p) {
  const double mean_var = s.v[s.index(px, py)] / 3.0;
  const double sigma =
      std::max(static_cast<double>(p.sigma_scale) * std::sqrt(std::clamp(mean_var, 0.0, 1.0)),
               static_cast<double>(p.sigma_floor));
  const double norm = 1.0 / (sigma * kSqrt2Pi);
  // k(dx, dy) = norm g(dx) g(dy): the Gaussian is separable, so 2r+1 exponentials suffice.
  double g[64];
  const int r = std::min(p.radius, 31);
  for (int d = 0; d <= r; ++d) g[d] = std::exp(-static_cast<double>(d * d) / (2.0 * sigma * sigma));
  const Rect win = Rect{px, py, px + 1, py + 1}.expanded(r).intersect({0, 0, width, height});
  double xbar = 0, zbar = 0, vbar = 0, best = -1.0;
  std::size_t m = s.index(px, py);
  for (int qy = win.y0; qy < win.y1; ++qy) {
    const double gy = norm * g[std::abs(qy - py)];
    for (int qx = win.x0; qx < win.x1; ++qx) {
      const double k = gy * g[std::abs(qx - px)];
      const std::size_t i = s.index(qx, qy);
      xbar += k * s.x[i];
      zbar += k * s.z[i];
      vbar += k * k * s.v[i];
      if (s.v[i] > best) {
        best = s.v[i];
        m = i;
      }
    }
  }
  // The window's highest-variance pixel M, its three channels read from their own planes.
  xbar += s.x[m] / 3.0;
  zbar += s.z[m] / 3.0;
  vbar += s.v[m] / 9.0;
  return std::abs(zbar - xbar) / (std::sqrt(std::max(vbar, 0.0)) + 1e-6);
}

}  // namespace

double t_statistic(const View& x, const View& variance, const View& z, int width, int height,
                   int px, int py, const TTestParams& params) {
  const Rect r =
      Rect{px, py, px + 1, py + 1}.expanded(params.radius).intersect({0, 0, width, height});
  return statistic(ChannelSums(x, variance, z, r), width, height, px, py, params);
}

double t_threshold(const TTestParams& p, double passes) {
  const double z = p.t0;
  const double nu = passes - 1.0;
  if (!p.dof_correction || nu < 1.0) return z;  // one pass: variance is a spatial guess
  // Cornish-Fisher expansion of the Student-t quantile around the normal one.
  const double z3 = z * z * z, z5 = z3 * z * z;
  return z + (z3 + z) / (4.0 * nu) + (5.0 * z5 + 16.0 * z3 + 3.0 * z) / (96.0 * nu * nu);
}

void t_rescale(const View& x, const View& variance, const View& z, const View& alpha, int width,
               int height, const Rect& out, const TTestParams& p, Buffer& rescaled,
               const View& passes) {
  const ChannelSums sums(x, variance, z, out.expanded(p.radius).intersect({0, 0, width, height}));
  for (int py = out.y0; py < out.y1; ++py) {
    for (int px = out.x0; px < out.x1; ++px) {
      const double t = statistic(sums, width, height, px, py, p);
      // 1 - Phi(u) = erfc(u / sqrt(2)) / 2
      const double t0 = passes.valid() ? t_threshold(p, passes.at(px, py, 0)) : p.t0;
      const double keep = 0.5 * std::erfc(p.slope * (t - t0) / std::sqrt(2.0));
      for (int c = 0; c < 3; ++c) {
        rescaled.at(px, py, c) = static_cast<float>(alpha.at(px, py, c) * keep);
      }
    }
  }
}

}  // namespace proden

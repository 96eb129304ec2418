#include "proden/tstat.hpp"

#include <algorithm>
#include <cmath>

namespace proden {

double t_statistic(const View& x, const View& variance, const View& z, int width, int height,
                   int px, int py, const TTestParams& p) {
  const double mean_var = (static_cast<double>(variance.at(px, py, 0)) + variance.at(px, py, 1) +
                           variance.at(px, py, 2)) /
                          3.0;
  const double s =
      std::max(static_cast<double>(p.sigma_scale) * std::sqrt(std::clamp(mean_var, 0.0, 1.0)),
               static_cast<double>(p.sigma_floor));
  const double norm = 1.0 / (s * std::sqrt(2.0 * 3.141592653589793));
  const Rect win = Rect{px, py, px + 1, py + 1}.expanded(p.radius).intersect({0, 0, width, height});
  double xbar = 0, zbar = 0, vbar = 0, best = -1.0;
  int mx = px, my = py;
  for (int qy = win.y0; qy < win.y1; ++qy) {
    for (int qx = win.x0; qx < win.x1; ++qx) {
      const double d2 = static_cast<double>((qx - px) * (qx - px) + (qy - py) * (qy - py));
      const double k = norm * std::exp(-d2 / (2.0 * s * s));
      double xs = 0, zs = 0, vs = 0;
      for (int c = 0; c < 3; ++c) {
        xs += x.at(qx, qy, c);
        zs += z.at(qx, qy, c);
        vs += variance.at(qx, qy, c);
      }
      xbar += k * xs;
      zbar += k * zs;
      vbar += k * k * vs;
      if (vs > best) {
        best = vs;
        mx = qx;
        my = qy;
      }
    }
  }
  // The highest-variance pixel of the window, all three channels read from their own planes.
  double xm = 0, zm = 0, vm = 0;
  for (int c = 0; c < 3; ++c) {
    xm += x.at(mx, my, c);
    zm += z.at(mx, my, c);
    vm += variance.at(mx, my, c);
  }
  xbar += xm / 3.0;
  zbar += zm / 3.0;
  vbar += vm / 9.0;
  return std::abs(zbar - xbar) / (std::sqrt(std::max(vbar, 0.0)) + 1e-6);
}

void t_rescale(const View& x, const View& variance, const View& z, const View& alpha, int width,
               int height, const Rect& out, const TTestParams& p, Buffer& rescaled) {
  for (int py = out.y0; py < out.y1; ++py) {
    for (int px = out.x0; px < out.x1; ++px) {
      const double t = t_statistic(x, variance, z, width, height, px, py, p);
      // 1 - Phi(u) = erfc(u / sqrt(2)) / 2
      const double keep = 0.5 * std::erfc(p.slope * (t - p.t0) / std::sqrt(2.0));
      for (int c = 0; c < 3; ++c) {
        rescaled.at(px, py, c) = static_cast<float>(alpha.at(px, py, c) * keep);
      }
    }
  }
}

}  // namespace proden

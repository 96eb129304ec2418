#include "proden/denoise/gaussian.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace proden {

GaussianDenoiser::GaussianDenoiser(float sigma)
    : sigma_(sigma), radius_(static_cast<int>(std::ceil(3.0f * sigma))) {
  if (!(sigma > 0.0f) || radius_ > 64) {
    throw std::invalid_argument("GaussianDenoiser: sigma must be in (0, 21]");
  }
}

void GaussianDenoiser::denoise(const DenoiseInputs& in, const Rect& out, Buffer& y,
                               Buffer* dydx) const {
  const int r = radius_;
  std::vector<double> g(static_cast<std::size_t>(2 * r + 1));
  for (int d = -r; d <= r; ++d) {
    g[static_cast<std::size_t>(d + r)] = std::exp(-0.5 * d * d / (sigma_ * sigma_));
  }
  // Window clipped to the image, renormalised: weights fixed, independent of x.
  const Rect rows{out.x0, std::max(out.y0 - r, 0), out.x1, std::min(out.y1 + r, in.height)};
  std::vector<double> h(rows.area()), hw(rows.area());
  for (int c = 0; c < 3; ++c) {
    std::size_t i = 0;
    for (int py = rows.y0; py < rows.y1; ++py) {
      for (int px = rows.x0; px < rows.x1; ++px, ++i) {
        double s = 0, sw = 0;
        for (int qx = std::max(px - r, 0); qx < std::min(px + r + 1, in.width); ++qx) {
          const double w = g[static_cast<std::size_t>(qx - px + r)];
          s += w * in.colour.at(qx, py, c);
          sw += w;
        }
        h[i] = s;
        hw[i] = sw;
      }
    }
    for (int py = out.y0; py < out.y1; ++py) {
      for (int px = out.x0; px < out.x1; ++px) {
        double s = 0, sw = 0;
        for (int qy = std::max(py - r, 0); qy < std::min(py + r + 1, in.height); ++qy) {
          const std::size_t j =
              static_cast<std::size_t>(qy - rows.y0) * static_cast<std::size_t>(rows.width()) +
              static_cast<std::size_t>(px - rows.x0);
          const double w = g[static_cast<std::size_t>(qy - py + r)];
          s += w * h[j];
          sw += w * hw[j];
        }
        y.at(px, py, c) = static_cast<float>(s / sw);
        if (dydx)
          dydx->at(px, py, c) = static_cast<float>(g[static_cast<std::size_t>(r)] *
                                                   g[static_cast<std::size_t>(r)] / sw);
      }
    }
  }
}

}  // namespace proden

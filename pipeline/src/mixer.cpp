#include "proden/mixer.hpp"

#include <algorithm>
#include <cmath>

namespace proden {
namespace {

constexpr double kTinyVariance = 1e-30;  // keeps 1 / var finite where a pixel is exact

}  // namespace

std::string ClosedFormMixer::name() const {
  return params_.rule == ClosedFormRule::stein ? "closed-form-stein" : "closed-form-inverse-error";
}

void ClosedFormMixer::mix(const MixInputs& in, const Rect& out, Buffer& alpha) const {
  const int r = params_.radius;
  const Rect image{0, 0, in.width, in.height};
  // Weights 1 / (3x3 mean of var): smoothing gives the weight many more degrees of freedom than
  // the pixel's own estimate, whose noise would otherwise bias alpha low (E[1/s^2] > 1/sigma^2).
  const Rect wrect = out.expanded(r).intersect(image);
  Buffer weight(wrect, 3);
  for (int c = 0; c < 3; ++c) {
    for (int py = wrect.y0; py < wrect.y1; ++py) {
      for (int px = wrect.x0; px < wrect.x1; ++px) {
        const Rect nb = Rect{px, py, px + 1, py + 1}.expanded(1).intersect(image);
        double s = 0;
        for (int qy = nb.y0; qy < nb.y1; ++qy) {
          for (int qx = nb.x0; qx < nb.x1; ++qx) s += in.variance.at(qx, qy, c);
        }
        weight.at(px, py, c) =
            static_cast<float>(1.0 / (s / static_cast<double>(nb.area()) + kTinyVariance));
      }
    }
  }
  for (int c = 0; c < 3; ++c) {
    for (int py = out.y0; py < out.y1; ++py) {
      for (int px = out.x0; px < out.x1; ++px) {
        const Rect win = Rect{px, py, px + 1, py + 1}.expanded(r).intersect(image);
        double s_var = 0, s_div = 0, s_d2 = 0, s_sure = 0;
        for (int qy = win.y0; qy < win.y1; ++qy) {
          for (int qx = win.x0; qx < win.x1; ++qx) {
            // Terms weighted by 1/var: alpha minimises the window's variance-normalised error,
            // so a firefly's huge variance cannot make its neighbours trust a y it smeared into
            // them (a plain sum would be dominated by it).
            const double w = weight.at(qx, qy, c);
            const double d = static_cast<double>(in.y.at(qx, qy, c)) - in.x.at(qx, qy, c);
            s_var += w * in.variance.at(qx, qy, c);
            s_div += w * in.divergence.at(qx, qy, c);
            s_d2 += w * d * d;
            s_sure += w * in.sure.at(qx, qy, c);
          }
        }
        double a = 0.0;
        if (params_.rule == ClosedFormRule::stein) {
          if (s_d2 > 0.0) a = (s_var - s_div) / s_d2;
        } else {
          const double ex = s_var, ey = std::max(s_sure, 0.0);
          if (ex + ey > 0.0) a = ex / (ex + ey);
        }
        alpha.at(px, py, c) = static_cast<float>(std::clamp(std::isfinite(a) ? a : 0.0, 0.0, 1.0));
      }
    }
  }
}

}  // namespace proden

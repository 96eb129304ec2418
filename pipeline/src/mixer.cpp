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

namespace {

// Sums of `src` (a buffer covering at least out ⊕ r ∩ image) over each pixel's (2r+1)^2 window
// clipped to the image, for every pixel of `out`. Separable: rows, then columns.
void box_sums(const Buffer& src, int c, const Rect& out, int r, const Rect& image, Buffer& dst,
              int dst_c) {
  const Rect rows{out.x0, std::max(out.y0 - r, image.y0), out.x1, std::min(out.y1 + r, image.y1)};
  Buffer h(rows, 1);
  for (int y = rows.y0; y < rows.y1; ++y) {
    for (int x = rows.x0; x < rows.x1; ++x) {
      const int a = std::max(x - r, image.x0), b = std::min(x + r + 1, image.x1);
      double s = 0;
      for (int q = a; q < b; ++q) s += src.at(q, y, c);
      h.at(x, y, 0) = static_cast<float>(s);
    }
  }
  for (int y = out.y0; y < out.y1; ++y) {
    const int a = std::max(y - r, image.y0), b = std::min(y + r + 1, image.y1);
    for (int x = out.x0; x < out.x1; ++x) {
      double s = 0;
      for (int q = a; q < b; ++q) s += h.at(x, q, 0);
      dst.at(x, y, dst_c) = static_cast<float>(s);
    }
  }
}

}  // namespace

void ClosedFormMixer::mix(const MixInputs& in, const Rect& out, Buffer& alpha) const {
  const int r = params_.radius;
  const Rect image{0, 0, in.width, in.height};
  const Rect wrect = out.expanded(r).intersect(image);
  const Rect vrect = wrect.expanded(1).intersect(image);
  Buffer planes(vrect, 2), terms(wrect, 4), sums(out, 4), local(wrect, 2);
  const bool relative = params_.weight == WindowWeight::relative;
  for (int c = 0; c < 3; ++c) {
    for (int y = vrect.y0; y < vrect.y1; ++y) {
      for (int x = vrect.x0; x < vrect.x1; ++x) {
        planes.at(x, y, 0) = in.variance.at(x, y, c);
        planes.at(x, y, 1) = in.x.at(x, y, c);
      }
    }
    // Weights 1 / (3x3 mean of var): smoothing gives the weight many more degrees of freedom
    // than the pixel's own estimate, whose noise would otherwise bias alpha low
    // (E[1/s^2] > 1/sigma^2). Weighting by 1/var makes alpha minimise the window's
    // variance-normalised error, so a firefly's huge variance cannot make its neighbours trust
    // a y it smeared into them (a plain sum would be dominated by it).
    // The variance floor (1 % relative standard deviation of the local mean, or of 0.1 where it
    // is black) stops a pixel whose few passes happened to agree exactly (var = 0 in a dark,
    // undersampled region) from taking over its whole window with an infinite weight.
    box_sums(planes, 0, wrect, 1, image, local, 0);
    box_sums(planes, 1, wrect, 1, image, local, 1);
    for (int y = wrect.y0; y < wrect.y1; ++y) {
      const int ny = std::min(y + 2, image.y1) - std::max(y - 1, image.y0);
      for (int x = wrect.x0; x < wrect.x1; ++x) {
        const int nx = std::min(x + 2, image.x1) - std::max(x - 1, image.x0);
        const double mv = static_cast<double>(local.at(x, y, 0)) / (nx * ny);
        const double mx = static_cast<double>(local.at(x, y, 1)) / (nx * ny);
        const double w =
            params_.weight == WindowWeight::uniform ? 1.0
            : relative                              ? 1.0 / (mx * mx + 0.01)
                       : 1.0 / (mv + params_.variance_floor * (mx * mx + 0.01) + kTinyVariance);
        const double v = in.variance.at(x, y, c);
        const double d = static_cast<double>(in.y.at(x, y, c)) - in.x.at(x, y, c);
        terms.at(x, y, 0) = static_cast<float>(w * v);
        terms.at(x, y, 1) = static_cast<float>(w * in.divergence.at(x, y, c));
        terms.at(x, y, 2) = static_cast<float>(w * d * d);
        terms.at(x, y, 3) = static_cast<float>(w * in.sure.at(x, y, c));
      }
    }
    for (int t = 0; t < 4; ++t) box_sums(terms, t, out, r, image, sums, t);
    for (int y = out.y0; y < out.y1; ++y) {
      for (int x = out.x0; x < out.x1; ++x) {
        const double s_var = sums.at(x, y, 0), s_div = sums.at(x, y, 1);
        const double s_d2 = sums.at(x, y, 2), s_sure = sums.at(x, y, 3);
        double a = 0.0;
        if (params_.rule == ClosedFormRule::stein) {
          if (s_d2 > 0.0) a = (s_var - s_div) / s_d2;
        } else {
          const double ex = s_var, ey = std::max(s_sure, 0.0);
          if (ex + ey > 0.0) a = ex / (ex + ey);
        }
        alpha.at(x, y, c) = static_cast<float>(std::clamp(std::isfinite(a) ? a : 0.0, 0.0, 1.0));
      }
    }
  }
}

}  // namespace proden

// The cascade of NL-means and NFOR (docs/cascade.md).
#include "proden/denoise/cascade.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "proden/sure.hpp"

namespace proden {
namespace {

// Rows per parallel band of the tiled stages (NL-means, the blend's window sums).
constexpr int kBand = 32;

template <class F>
void for_bands(int width, int height, F&& f) {
  tbb::parallel_for(0, (height + kBand - 1) / kBand, [&](int b) {
    f(Rect{0, b * kBand, width, std::min(height, (b + 1) * kBand)});
  });
}

ClosedFormParams blend_params(const CascadeParams& p) {
  ClosedFormParams c;
  c.rule = ClosedFormRule::stein;  // alpha = S(var - div) / S((y - x)^2), here div = 0
  c.weight = WindowWeight::relative;
  c.radius = p.radius;
  return c;
}

}  // namespace

CascadeDenoiser::CascadeDenoiser(NlMeansParams nlmeans, NforParams nfor, CascadeParams params)
    : nlmeans_(nlmeans), nfor_(nfor), blend_(blend_params(params)) {
  if (params.radius < 0) throw std::invalid_argument("cascade: the window radius must be >= 0");
}

void CascadeDenoiser::denoise_with_weight(const DenoiseInputs& in, Buffer& y, Buffer* dydx,
                                          Buffer& b) const {
  const int W = in.width, H = in.height;
  const Rect image{0, 0, W, H};
  // y1 = NL-means with its exact Jacobian diagonal (SURE needs it), in parallel bands.
  Buffer y1(image, 3), d1(image, 3), div1(image, 3), sure1(image, 3);
  for_bands(W, H, [&](const Rect& r) {
    nlmeans_.denoise(in, r, y1, &d1);
    divergence_from_derivative(in.variance, d1, r, div1);
    sure(in.colour, in.variance, y1, div1, r, sure1);
    // The blend reads SURE(y1) as its "variance": negative estimates (noisy features correlated
    // with x's noise, docs/nfor.md) count as no error, so they cannot push b below 0 alone.
    for (int c = 0; c < 3; ++c) {
      for (int py = r.y0; py < r.y1; ++py) {
        for (int px = r.x0; px < r.x1; ++px) {
          const float s = sure1.at(px, py, c);
          sure1.at(px, py, c) = std::isfinite(s) ? std::max(s, 0.0f) : 0.0f;
        }
      }
    }
  });
  // y2 = NFOR (whole frame, parallel inside), with its hat diagonal when dy/dx is asked for.
  Buffer y2(image, 3), d2(dydx ? image : Rect{}, 3);
  nfor_.denoise(in, image, y2, dydx ? &d2 : nullptr);

  // b = S(SURE(y1)) / S((y2 - y1)^2): the closed-form Stein mixer on x := y1, y := y2, with
  // SURE(y1) as the variance and no divergence (y2 is treated as independent of y1's error).
  const Buffer zero(image, 3, 0.0f);
  const MixInputs mi{W, H, y1.view(), y2.view(), sure1.view(), zero.view(), zero.view()};
  b.reset(image, 3);
  for_bands(W, H, [&](const Rect& r) {
    Buffer part(r, 3);
    blend_.mix(mi, r, part);
    for (int c = 0; c < 3; ++c) {
      for (int py = r.y0; py < r.y1; ++py) {
        for (int px = r.x0; px < r.x1; ++px) {
          const float w = part.at(px, py, c);
          const float a = y1.at(px, py, c), v = y2.at(px, py, c);
          b.at(px, py, c) = w;
          // A convex combination: y stays between the two denoisers' outputs.
          y.at(px, py, c) = std::clamp((1.0f - w) * a + w * v, std::min(a, v), std::max(a, v));
          if (dydx) dydx->at(px, py, c) = (1.0f - w) * d1.at(px, py, c) + w * d2.at(px, py, c);
        }
      }
    }
  });
}

void CascadeDenoiser::denoise(const DenoiseInputs& in, const Rect& out, Buffer& y,
                              Buffer* dydx) const {
  if (out.empty()) return;
  const Rect image{0, 0, in.width, in.height};
  Buffer full_y(image, 3), full_d(dydx ? image : Rect{}, 3), b;
  denoise_with_weight(in, full_y, dydx ? &full_d : nullptr, b);
  for (int c = 0; c < 3; ++c) {
    for (int py = out.y0; py < out.y1; ++py) {
      for (int px = out.x0; px < out.x1; ++px) {
        y.at(px, py, c) = full_y.at(px, py, c);
        if (dydx) dydx->at(px, py, c) = full_d.at(px, py, c);
      }
    }
  }
}

}  // namespace proden

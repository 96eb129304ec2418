#include "proden/error_estimate.hpp"

#include <boost/math/distributions/chi_squared.hpp>
#include <boost/math/distributions/normal.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <stdexcept>

namespace proden {
namespace {

constexpr double kInfinity = std::numeric_limits<double>::infinity();
constexpr double kRelEps = 0.01;        // relMSE's denominator z^2 + 0.01 (README "eval")
constexpr double kPixelsPerDraw = 4.0;  // Cycles' 1.5 px filter: ~2x2 pixels share samples

// Frame sums of one quantity split as in docs/error_estimate.md: the part proportional to the
// variance scale (v), the part that is not (d), and the floor (f, proportional to it).
struct Sums {
  double v = 0, d = 0, f = 0;
  // value at variance scale lambda (lambda = inf: +inf unless both scaled parts vanish)
  double at(double lambda) const {
    if (std::isinf(lambda)) return (v > 0 || f > 0) ? kInfinity : std::max(d, 0.0);
    return std::max(lambda * v + d, lambda * f);
  }
  // min and max over lambda in [lo, hi]: the function is convex (a max of two lines), so the max
  // is at an end and the min at an end or at the kink.
  std::pair<double, double> range(double lo, double hi) const {
    double mn = std::min(at(lo), at(hi)), mx = std::max(at(lo), at(hi));
    if (f > v) {
      const double kink = d / (f - v);
      if (kink > lo && kink < hi) mn = std::min(mn, at(kink));
    }
    return {mn, mx};
  }
};

// Standard error of the frame mean of per-element terms t_j: their average noise variance from
// horizontally adjacent pixels, sum (t_{i+1} - t_i)^2 / (2 pairs) (differences of neighbours
// ignore smooth spatial trends of the error itself), times kPixelsPerDraw for the correlation of
// neighbouring pixels, over the element count. Absolute, so a mean clamped at 0 (a negative SURE)
// still gets the spread of its terms.
struct DiffVar {
  double ss = 0;
  std::size_t pairs = 0;
  void add(double a, double b) {
    ss += (b - a) * (b - a);
    ++pairs;
  }
  double se(double elements) const {
    if (pairs == 0) return 0.0;
    return std::sqrt(kPixelsPerDraw * ss / (2.0 * static_cast<double>(pairs)) / elements);
  }
};

// The relMSE denominator's stand-in for the reference (docs/error_estimate.md, "The relMSE
// denominator"). The result itself is a noisy stand-in: a firefly (z far above the reference) gets
// a tiny weight 1/(z^2 + 0.01) where the true weight 1/(ref^2 + 0.01) is large, which biased
// relMSE low, 1.3-35x at 2-8 spp and up to 1000x on the glass scene (bench/RESULTS.md,
// "Calibration"). Instead: the local mean of z over a (2 kStandInRadius + 1)^2 window, whose
// square is unbiased for ref^2 up to its own noise, minus that noise (the window mean of the
// per-element error e, over the window's independent draws), floored at 0. Edges blur a little;
// fireflies are diluted instead of hiding the error they cause.
constexpr int kStandInRadius = 3;

// A render-only frame (no denoiser) floors that stand-in at the square of the window's mean
// without its largest value (docs/error_estimate.md, "The relMSE denominator"). Where one or two
// fireflies dominate a window, its noise estimate is theirs too, the correction overshoots, the
// stand-in falls to 0 and the weight to 100 on pixels whose reference is bright (a caustic): on
// the glass scene at 8 spp, 1 % of the pixels made three quarters of an estimate 4.7x the truth.
// Leaving out the window's largest value gives a level that one firefly cannot raise, and that
// sits below the mean for the right-skewed noise of a render (the weight errs high, toward "not
// done"). Not for denoised results: their windows hold a firefly spread over many pixels, which
// leaving out one value does not remove (measured: it took glass's 128-spp NL-means cell from
// 0.65 to 0.36 of the truth).

// A frame-sized plane of doubles, left uninitialised: estimate_error writes every element before
// reading it. Value-initialised vectors zero-filled ~1 GB per call on a 4-megapixel frame (five
// per-element planes and four filter planes, per channel): 45 % of the daemon's samples on a
// 2048x2048 update with no denoiser (bench/results/daemon.md).
using Plane = std::unique_ptr<double[]>;
Plane plane(std::size_t n) {
  return std::make_unique_for_overwrite<double[]>(n);
}

// Maximum over the clamped (2r+1)^2 window of each element (separable; `t` is scratch).
void box_max(const double* a, double* t, double* out, int W, int H, int r) {
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      double m = -kInfinity;
      for (int d = -r; d <= r; ++d)
        m = std::max(m, a[static_cast<std::size_t>(y) * W + std::clamp(x + d, 0, W - 1)]);
      t[static_cast<std::size_t>(y) * W + x] = m;
    }
  }
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      double m = -kInfinity;
      for (int d = -r; d <= r; ++d)
        m = std::max(m, t[static_cast<std::size_t>(std::clamp(y + d, 0, H - 1)) * W + x]);
      out[static_cast<std::size_t>(y) * W + x] = m;
    }
  }
}

// Mean over the clamped (2r+1)^2 window of each element (separable; `t` is scratch).
void box_mean(const double* a, double* t, double* out, int W, int H, int r) {
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      double s = 0;
      for (int d = -r; d <= r; ++d)
        s += a[static_cast<std::size_t>(y) * W + std::clamp(x + d, 0, W - 1)];
      t[static_cast<std::size_t>(y) * W + x] = s;
    }
  }
  const double k = 1.0 / ((2.0 * r + 1) * (2.0 * r + 1));
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      double s = 0;
      for (int d = -r; d <= r; ++d)
        s += t[static_cast<std::size_t>(std::clamp(y + d, 0, H - 1)) * W + x];
      out[static_cast<std::size_t>(y) * W + x] = s * k;
    }
  }
}

void check(const Image* img, const Image& like, const char* what) {
  if (!img || img->channels() != 3 || !img->same_size(like)) {
    throw std::invalid_argument(std::string("estimate_error: ") + what +
                                " must be an RGB image of the render's size");
  }
}

double finite_or_zero(double v) {
  return std::isfinite(v) ? v : 0.0;
}

}  // namespace

ElementError render_error(double v) {
  v = std::max(0.0, finite_or_zero(v));
  return {v, 0.0, v};
}

ElementError sure_error(double v, double a, double d, double sure) {
  // SURE of z = x + a (y - x) with alpha held fixed: e = (1-a) v + a SURE - a (1-a) d^2 (it keeps
  // the x-y covariance that (1-a)^2 v + a^2 SURE drops) = scaled + measured with
  // scaled = (1-a) v + a (SURE - d^2) proportional to the variance scale (SURE - d^2 = -v + 2 v
  // div), measured = a^2 d^2.
  v = std::max(0.0, finite_or_zero(v));
  a = finite_or_zero(a);
  d = finite_or_zero(d);
  return {(1.0 - a) * v + a * (finite_or_zero(sure) - d * d), a * a * d * d,
          (1.0 - a) * (1.0 - a) * v};
}

ElementError cv_error(double v, double a, double d, double cv_square, double cv_variance,
                      std::optional<double> cv_spread) {
  // The same e with m = (cv_square - cv_variance) kHalfToFullMse, or for a linear denoiser
  // m = cv_square - cv_variance - cv_spread (its bias and its variance at the full frame's samples,
  // docs/error_estimate.md): the variance part scales with the variance estimate, the squares and
  // d^2 are measured.
  v = std::max(0.0, finite_or_zero(v));
  a = finite_or_zero(a);
  d = finite_or_zero(d);
  const double vh = std::max(0.0, finite_or_zero(cv_variance));
  const double q = finite_or_zero(cv_square);
  const double c = cv_spread ? 1.0 : kHalfToFullMse;
  const double measured = cv_spread ? q - std::max(0.0, finite_or_zero(*cv_spread)) : c * q;
  return {(1.0 - a) * v - a * c * vh, a * measured - a * (1.0 - a) * d * d,
          (1.0 - a) * (1.0 - a) * v};
}

std::string_view to_string(NoiseScope s) {
  return s == NoiseScope::pixel ? "pixel" : "frame";
}

EstimatedError estimate_error(const ErrorInputs& in, const ErrorContext& ctx) {
  if (!in.render || in.render->channels() != 3 || in.render->empty()) {
    throw std::invalid_argument("estimate_error: the render must be a non-empty RGB image");
  }
  const Image& x = *in.render;
  check(in.variance, x, "the variance");
  check(in.result, x, "the result");
  const bool denoised = in.denoised != nullptr;
  if (denoised) {
    check(in.denoised, x, "the denoised image");
    check(in.alpha, x, "alpha");
    check(in.sure, x, "SURE");
  }
  const bool cv = denoised && in.cv_square != nullptr;
  if (cv) {
    check(in.cv_square, x, "the cross-validation square");
    check(in.cv_variance, x, "the cross-validation variance");
    if (in.cv_spread) check(in.cv_spread, x, "the cross-validation spread");
  }
  const bool spread = cv && in.cv_spread != nullptr;
  if (!(ctx.confidence > 0.0 && ctx.confidence < 1.0)) {
    throw std::invalid_argument("estimate_error: confidence must be in (0, 1)");
  }
  const int W = x.width(), H = x.height();
  const std::size_t n = x.pixels();

  Sums m, r;       // MSE and relMSE sums
  double q = 0;    // sum of w v: the render's own relMSE
  DiffVar dm, dr;  // neighbour differences of the MSE and relMSE terms
  // Per element, reused by each channel: the error terms (below), the stand-in's inputs, their
  // window means and maximum, and the filters' scratch.
  const Plane EV = plane(n), ED = plane(n), F = plane(n), Z = plane(n), Epos = plane(n);
  const Plane zbar = plane(n), ebar = plane(n), tmp = plane(n);
  const Plane zmax = denoised ? Plane() : plane(n);
  for (int c = 0; c < 3; ++c) {
    const auto xv = x.plane(c), vv = in.variance->plane(c), zv = in.result->plane(c);
    std::span<const float> yv, av, sv, qv, bv, pv;
    if (denoised) {
      yv = in.denoised->plane(c);
      av = in.alpha->plane(c);
      sv = in.sure->plane(c);
    }
    if (cv) {
      qv = in.cv_square->plane(c);
      bv = in.cv_variance->plane(c);
      if (spread) pv = in.cv_spread->plane(c);
    }
    // Per element: the error terms (below), then the relMSE weights from the stand-in.
    for (std::size_t i = 0; i < n; ++i) {
      // The terms of docs/error_estimate.md, "The model" (non-finite values count as 0). The
      // frame mean is taken without per-element clamping (that would bias it up, 4-5x on
      // interior) and floored at mean (1-a)^2 v: MSE(z) >= that when div >= 0, and SURE biased
      // low (noisy features correlated with x's noise) can take the mean below it.
      const double a = denoised ? av[i] : 0.0;
      const double d = denoised ? static_cast<double>(yv[i]) - xv[i] : 0.0;
      const std::optional<double> p = spread ? std::optional<double>(pv[i]) : std::nullopt;
      const ElementError el = !denoised ? render_error(vv[i])
                              : cv      ? cv_error(vv[i], a, d, qv[i], bv[i], p)
                                        : sure_error(vv[i], a, d, sv[i]);
      const double ev = el.scaled, ed = el.measured, f = el.floor;
      EV[i] = ev;
      ED[i] = ed;
      F[i] = f;
      Z[i] = std::isfinite(zv[i]) ? zv[i] : 0.0;
      Epos[i] = std::max({ev + ed, f, 0.0});
    }
    box_mean(Z.get(), tmp.get(), zbar.get(), W, H, kStandInRadius);
    box_mean(Epos.get(), tmp.get(), ebar.get(), W, H, kStandInRadius);
    const double window = (2.0 * kStandInRadius + 1) * (2.0 * kStandInRadius + 1);
    const double draws_per_window = std::max(1.0, window / kPixelsPerDraw);
    if (!denoised) box_max(Z.get(), tmp.get(), zmax.get(), W, H, kStandInRadius);
    for (int py = 0; py < H; ++py) {
      double prev[2] = {0, 0};
      for (int px = 0; px < W; ++px) {
        const std::size_t i = static_cast<std::size_t>(py) * W + px;
        const double v = std::isfinite(vv[i]) ? std::max(0.0, static_cast<double>(vv[i])) : 0.0;
        const double ev = EV[i], ed = ED[i], f = F[i];
        double ref2 = std::max(0.0, zbar[i] * zbar[i] - ebar[i] / draws_per_window);
        if (!denoised) {
          // The window's sum is window * zbar (edges replicated, as box_mean counts them).
          const double trimmed = std::max(0.0, (window * zbar[i] - zmax[i]) / (window - 1.0));
          ref2 = std::max(ref2, trimmed * trimmed);
        }
        const double w = std::isfinite(zv[i]) ? 1.0 / (ref2 + kRelEps) : 0.0;
        m.v += ev;
        m.d += ed;
        m.f += f;
        r.v += w * ev;
        r.d += w * ed;
        r.f += w * f;
        q += w * v;
        const double cur[2] = {ev + ed, w * (ev + ed)};
        if (px > 0) {
          dm.add(prev[0], cur[0]);
          dr.add(prev[1], cur[1]);
        }
        std::copy(cur, cur + 2, prev);
      }
    }
  }
  const double N = 3.0 * static_cast<double>(n);
  for (Sums* s : {&m, &r}) {
    s->v /= N;
    s->d /= N;
    s->f /= N;
  }
  q /= N;

  EstimatedError e;
  e.spp = ctx.spp;
  e.confidence = ctx.confidence;
  e.noise_scope = ctx.noise_scope;
  e.source = cv ? "variance+cross-validation" : denoised ? "variance+sure" : "variance";
  e.mse = m.at(1.0);
  e.relmse = r.at(1.0);
  e.render_relmse = q;

  // Sampling error of the pixel averages (absolute).
  const double se_m = dm.se(N), se_r = dr.se(N);
  e.sampling_rse = se_m == 0.0 ? 0.0 : e.mse > 0 ? se_m / e.mse : kInfinity;

  // Effective degrees of freedom of the variance scale.
  double dof_pixel = 0.0;
  if (ctx.variance_source == VarianceSource::renderer) {
    dof_pixel = std::max({ctx.spp - ctx.passes, static_cast<double>(ctx.passes - 1), 1.0});
  } else if (ctx.variance_source == VarianceSource::between_passes && ctx.passes >= 2) {
    dof_pixel = ctx.passes - 1;
  }
  const double draws = ctx.noise_scope == NoiseScope::pixel
                           ? std::max(1.0, static_cast<double>(n) / kPixelsPerDraw)
                           : 1.0;
  const double dof = dof_pixel * draws;
  const double alpha = 1.0 - ctx.confidence;
  double lo = 0.0, hi = kInfinity;
  if (dof > 0) {
    namespace bm_ = boost::math;
    const bm_::chi_squared_distribution<double> chi(dof);
    lo = dof / bm_::quantile(bm_::complement(chi, alpha / 2));
    hi = dof / bm_::quantile(chi, alpha / 2);
    e.dof = dof;
  }
  const double zq = boost::math::quantile(
      boost::math::complement(boost::math::normal_distribution<double>(), alpha / 2));

  // The interval: the variance scale's range, widened by z standard errors of the pixel average
  // (scaled with the variance at each end).
  auto bounds = [&](const Sums& s, double se, double& low, std::optional<double>& high) {
    const auto [mn, mx] = s.range(lo, hi);
    low = std::max(0.0, mn - zq * se * lo);
    if (std::isfinite(mx)) {
      high = mx + zq * se * (std::isfinite(hi) ? hi : 1.0);
    } else {
      high.reset();
    }
  };
  bounds(m, se_m, e.mse_low, e.mse_high);
  bounds(r, se_r, e.relmse_low, e.relmse_high);
  // A negative mean of the error terms (SURE biased far below zero: issue 13's HDR-only POV-Ray
  // frames) is no estimate of a squared error at all: the point value stays (the floor), but
  // nothing bounds it from above.
  e.consistent = m.v + m.d >= 0 && r.v + r.d >= 0;
  // A SURE known to be biased low (ErrorInputs::sure_unbounded) bounds nothing from above either.
  const bool unbounded = denoised && !cv && in.sure_unbounded;
  if (m.v + m.d < 0 || unbounded) e.mse_high.reset();
  if (r.v + r.d < 0 || unbounded) e.relmse_high.reset();

  // Equivalent spp: plain MC's relMSE falls as 1/spp, so spp' = spp * q / relmse. At variance
  // scale lambda, q and the scaled part of relmse grow with lambda, and an error x on the pixel
  // average adds to relmse: eq(lambda, x) = spp * q / max(r.v + (r.d + x) / lambda, r.f + x /
  // lambda), non-decreasing in lambda; a non-positive denominator is unbounded.
  auto eq = [&](double lambda, double err) {
    if (!(q > 0)) return kInfinity;  // a noise-free frame: plain MC is exact already
    double denom;
    if (lambda <= 0) {
      denom = (r.d + err > 0 || err > 0) ? kInfinity : std::max(r.v, r.f);
    } else if (std::isinf(lambda)) {
      denom = std::max(r.v, r.f);
    } else {
      denom = std::max(r.v + (r.d + err) / lambda, r.f + err / lambda);
    }
    return denom > 0 ? ctx.spp * q / denom : kInfinity;
  };
  e.equivalent_spp = e.relmse > 0 ? ctx.spp * q / e.relmse : eq(1.0, 0.0);
  e.equivalent_spp_low =
      r.v + r.d < 0 || unbounded
          ? 0.0
          : std::min(eq(lo, zq * se_r * lo), eq(hi, std::isfinite(hi) ? zq * se_r * hi : 0.0));
  const double top =
      std::max(eq(lo, -zq * se_r * lo), eq(hi, std::isfinite(hi) ? -zq * se_r * hi : 0.0));
  if (std::isfinite(top)) e.equivalent_spp_high = top;

  // The model's own error (kModelBand), beyond the statistics above.
  e.model_band = kModelBand;
  e.mse_low /= kModelBand;
  e.relmse_low /= kModelBand;
  e.equivalent_spp_low /= kModelBand;
  for (std::optional<double>* h : {&e.mse_high, &e.relmse_high, &e.equivalent_spp_high}) {
    if (*h) **h *= kModelBand;
  }
  return e;
}

bool meets_relmse(const EstimatedError& e, double target) {
  return e.relmse_high && *e.relmse_high <= target;
}

bool meets_equivalent_spp(const EstimatedError& e, double target) {
  return e.equivalent_spp_low >= target;
}

bool misses_relmse(const EstimatedError& e, double target) {
  return e.relmse_low > target;
}

bool misses_equivalent_spp(const EstimatedError& e, double target) {
  return e.equivalent_spp_high && *e.equivalent_spp_high < target;
}

}  // namespace proden

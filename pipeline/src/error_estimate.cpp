#include "proden/error_estimate.hpp"

#include <boost/math/distributions/chi_squared.hpp>
#include <boost/math/distributions/normal.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

namespace proden {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kRelEps = 0.01;        // relMSE's denominator z^2 + 0.01 (README "eval")
constexpr double kPixelsPerDraw = 4.0;  // Cycles' 1.5 px filter: ~2x2 pixels share samples

// Frame sums of one quantity split as in docs/error_estimate.md: the part proportional to the
// variance scale (v), the part that is not (d), and the floor (f, proportional to it).
struct Sums {
  double v = 0, d = 0, f = 0;
  // value at variance scale lambda (lambda = inf: +inf unless both scaled parts vanish)
  double at(double lambda) const {
    if (std::isinf(lambda)) return (v > 0 || f > 0) ? kInf : std::max(d, 0.0);
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

// Relative standard error of the frame mean of per-element terms t_j: their average noise
// variance from horizontally adjacent pixels, sum (t_{i+1} - t_i)^2 / (2 pairs) (differences of
// neighbours ignore smooth spatial trends of the error itself), times kPixelsPerDraw for the
// correlation of neighbouring pixels, over the element count.
struct DiffVar {
  double ss = 0;
  std::size_t pairs = 0;
  void add(double a, double b) {
    ss += (b - a) * (b - a);
    ++pairs;
  }
  double rse(double mean, double elements) const {
    if (pairs == 0) return 0.0;
    const double var = ss / (2.0 * static_cast<double>(pairs));
    if (var == 0.0) return 0.0;
    if (!(std::abs(mean) > 0)) return kInf;
    return std::sqrt(kPixelsPerDraw * var / elements) / std::abs(mean);
  }
};

void check(const Image* img, const Image& like, const char* what) {
  if (!img || img->channels() != 3 || !img->same_size(like)) {
    throw std::invalid_argument(std::string("estimate_error: ") + what +
                                " must be an RGB image of the render's size");
  }
}

}  // namespace

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
  if (!(ctx.confidence > 0.0 && ctx.confidence < 1.0)) {
    throw std::invalid_argument("estimate_error: confidence must be in (0, 1)");
  }
  const int W = x.width(), H = x.height();
  const std::size_t n = x.pixels();

  Sums m, r;                 // MSE and relMSE sums
  double q = 0;              // sum of w v: the render's own relMSE
  DiffVar dm, dmf, dr, drf;  // neighbour differences of the MSE and relMSE terms (and floors)
  for (int c = 0; c < 3; ++c) {
    const auto xv = x.plane(c), vv = in.variance->plane(c), zv = in.result->plane(c);
    std::span<const float> yv, av, sv;
    if (denoised) {
      yv = in.denoised->plane(c);
      av = in.alpha->plane(c);
      sv = in.sure->plane(c);
    }
    for (int py = 0; py < H; ++py) {
      double prev[4] = {0, 0, 0, 0};
      for (int px = 0; px < W; ++px) {
        const std::size_t i = static_cast<std::size_t>(py) * W + px;
        const double v = std::max(0.0, static_cast<double>(vv[i]));
        const double z = zv[i];
        const double w = 1.0 / (z * z + kRelEps);
        double ev = v, ed = 0.0, f = v;
        if (denoised) {
          const double a = av[i], d = static_cast<double>(yv[i]) - xv[i];
          // e = (1-a) v + a SURE - a (1-a) d^2 (estimated_result_mse) = e_v + e_d with
          // e_v = (1-a) v + a (SURE - d^2) proportional to the variance scale, e_d = a^2 d^2.
          ev = (1.0 - a) * v + a * (sv[i] - d * d);
          ed = a * a * d * d;
          f = (1.0 - a) * (1.0 - a) * v;
        }
        m.v += ev;
        m.d += ed;
        m.f += f;
        r.v += w * ev;
        r.d += w * ed;
        r.f += w * f;
        q += w * v;
        const double cur[4] = {ev + ed, f, w * (ev + ed), w * f};
        if (px > 0) {
          dm.add(prev[0], cur[0]);
          dmf.add(prev[1], cur[1]);
          dr.add(prev[2], cur[2]);
          drf.add(prev[3], cur[3]);
        }
        std::copy(cur, cur + 4, prev);
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
  e.source = denoised ? "variance+sure" : "variance";
  e.mse = m.at(1.0);
  e.relmse = r.at(1.0);
  e.render_relmse = q;

  // Sampling error of the pixel average, for the branch (estimate or floor) in use.
  const bool m_floor = m.v + m.d < m.f, r_floor = r.v + r.d < r.f;
  e.sampling_rse = (m_floor ? dmf : dm).rse(e.mse, N);
  const double rse_r = (r_floor ? drf : dr).rse(e.relmse, N);

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
  double lo = 0.0, hi = kInf;
  if (dof > 0) {
    namespace bm_ = boost::math;
    const bm_::chi_squared_distribution<double> chi(dof);
    lo = dof / bm_::quantile(bm_::complement(chi, alpha / 2));
    hi = dof / bm_::quantile(chi, alpha / 2);
    e.dof = dof;
  }
  const double zq = boost::math::quantile(
      boost::math::complement(boost::math::normal_distribution<double>(), alpha / 2));

  auto bounds = [&](const Sums& s, double rse, double& low, std::optional<double>& high) {
    const auto [mn, mx] = s.range(lo, hi);
    low = mn * std::max(0.0, 1.0 - zq * rse);
    if (std::isfinite(mx) && std::isfinite(rse)) {
      high = mx * (1.0 + zq * rse);
    } else {
      high.reset();
    }
  };
  bounds(m, e.sampling_rse, e.mse_low, e.mse_high);
  bounds(r, rse_r, e.relmse_low, e.relmse_high);

  // Equivalent spp: plain MC's relMSE falls as 1/spp, so spp' = spp * q / relmse. At variance
  // scale lambda both q and the scaled part of relmse grow with lambda: eq(lambda) =
  // spp * q / max(r.v + r.d / lambda, r.f), non-decreasing in lambda.
  auto eq = [&](double lambda) {
    if (!(q > 0)) return kInf;  // a noise-free frame: plain MC is exact already
    double denom;
    if (lambda <= 0) {
      denom = r.d > 0 ? kInf : std::max(r.v, r.f);
    } else if (std::isinf(lambda)) {
      denom = std::max(r.v, r.f);
    } else {
      denom = std::max(r.v + r.d / lambda, r.f);
    }
    return denom > 0 ? ctx.spp * q / denom : kInf;
  };
  e.equivalent_spp = e.relmse > 0 ? ctx.spp * q / e.relmse : eq(1.0);
  e.equivalent_spp_low = eq(lo) / (1.0 + zq * rse_r);
  const double top = eq(hi);
  if (std::isfinite(top) && std::isfinite(rse_r) && zq * rse_r < 1.0) {
    e.equivalent_spp_high = top / (1.0 - zq * rse_r);
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

#include "proden/tstat.hpp"

#include <tbb/parallel_for.h>
#include <boost/math/distributions/normal.hpp>
#include <boost/math/distributions/students_t.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <utility>

#include "simd.hpp"

namespace proden {
namespace {

constexpr double kSqrt2Pi = 2.5066282746310002;
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr int kMaxLanes = 8;  // output pixels per kernel call, at most (one AVX-512 register)
constexpr int kMaxRadius = kTTestMaxRadius;  // window and pooling radii the lane arrays hold
constexpr int kMaxSpan = 2 * (2 * kMaxRadius) + 1;

double upper_normal_tail(double u) {
  return 0.5 * std::erfc(u / std::sqrt(2.0));
}

// Local copies of what the kernel reads over g = out ⊕ (radius + pool), in double, zero outside
// the image (taps there add exact zeros) with vsum = -1 there (never a window's maximum):
//   d_c = z_c - x_c and the pooled variance v_c (read by the statistic, within out ⊕ radius),
//   pbar = mean_c of the raw per-pixel estimates and q = pbar^2 / (dof + 2) (read by the degrees
//   of freedom; without raw estimates the pooled ones and q = pbar^2 / dof).
struct Planes {
  Rect rect;
  std::size_t w = 0;
  std::vector<double> d[3], v[3], vsum, pbar, q;
  std::vector<double> cx, cy;  // 1 / (pooling box width) per column / row, 0 outside the image
  bool raw = false;            // pbar and q come from the raw (unpooled) estimates
  std::size_t at(int x, int y) const {
    return static_cast<std::size_t>(y - rect.y0) * w + static_cast<std::size_t>(x - rect.x0);
  }
};

// Per-call constants of the kernel.
struct Setup {
  int radius = 5, pool = 0, width = 0, height = 0;
  bool proden = true;  // per-channel consistent statistic (else the authors' summed one)
  bool dof = false;    // compute Welch-Satterthwaite degrees of freedom (else exact variance)
  double sigma_scale = 100.0, sigma_floor = 1e-3;
  // A pixel whose three statistics are all at or below this needs its dof only as "finite" (the
  // rejection curve's RejectionCurve::dof_free_t: any finite dof gives a keep factor within
  // kDofFreeKeepTolerance of any other): the kernel then skips the scalar part of the sum over
  // the highest-variance pixel's box, and reports dof 1 when it is finite. -1 (never):
  // t_statistic, which reports the dof itself.
  double dof_free_t = -1.0;
};

// Statistics of up to kMaxLanes consecutive pixels of one row.
struct LaneStats {
  double t[3][kMaxLanes];
  double dof[kMaxLanes];
};

// Width of the pooling box around coordinate c in [0, n): (2r+1) clipped to the image.
inline int box_width(int c, int r, int n) {
  return std::min(c + r, n - 1) - std::max(c - r, 0) + 1;
}

// Kernel builds (no -march=native; chosen at run time): one register of doubles per Lane, so the
// window loop's ten accumulators stay in registers. A fixed 8-double Lane was two registers each
// on AVX2, where the accumulators spilled and (with the loads tstat_kernel.inc now avoids) the
// t-test cost 4-6x the AVX-512 build's (bench/RESULTS.md, "The t-test on AVX2").
using KernelFn = void (*)(const Planes&, const Setup&, int px0, int py, int n, LaneStats& out);

namespace portable {
constexpr int kLanes = 2;
#include "tstat_kernel.inc"
}  // namespace portable

#ifdef PRODEN_KERNEL_BUILDS_X86
#pragma GCC push_options
#pragma GCC target("avx2")
namespace avx2 {
constexpr int kLanes = 4;
#include "tstat_kernel.inc"
}  // namespace avx2
#pragma GCC pop_options

#pragma GCC push_options
#pragma GCC target("avx512f")
namespace avx512 {
constexpr int kLanes = 8;
#include "tstat_kernel.inc"
}  // namespace avx512
#pragma GCC pop_options
#endif

struct KernelBuild {
  std::string name;
  int lanes;
  KernelFn fn;
};

// The builds this CPU runs, best last.
const std::vector<KernelBuild>& kernel_builds() {
  static const std::vector<KernelBuild> builds = [] {
    std::vector<KernelBuild> b;
    for (const auto& name : cpu_kernel_builds()) {
#ifdef PRODEN_KERNEL_BUILDS_X86
      if (name == "avx512") b.push_back({name, avx512::kLanes, avx512::lane_kernel});
      if (name == "avx2") b.push_back({name, avx2::kLanes, avx2::lane_kernel});
#endif
      if (name == "baseline") b.push_back({name, portable::kLanes, portable::lane_kernel});
    }
    return b;
  }();
  return builds;
}

const KernelBuild& kernel_build(const std::string& isa) {
  const auto& builds = kernel_builds();
  if (isa.empty()) return builds.back();
  for (const auto& b : builds) {
    if (b.name == isa) return b;
  }
  throw std::invalid_argument("t-test: kernel build '" + isa + "' is not available on this CPU");
}

Planes make_planes(const View& x, const View& variance, const View& z, const Rect& out,
                   const Setup& s, const VarianceOrigin& origin) {
  Planes pl;
  const Rect image{0, 0, s.width, s.height};
  // kMaxLanes - 1 more columns on the right: the kernel always computes whole lane blocks.
  pl.rect = out.expanded(s.radius + s.pool);
  pl.rect.x1 += kMaxLanes - 1;
  pl.w = static_cast<std::size_t>(pl.rect.width());
  const std::size_t n = pl.rect.area();
  for (int c = 0; c < 3; ++c) {
    pl.d[c].assign(n, 0.0);
    pl.v[c].assign(n, 0.0);
  }
  pl.vsum.assign(n, -1.0);
  const Rect stat = out.expanded(s.radius).intersect(image);
  for (int py = stat.y0; py < stat.y1; ++py) {
    for (int px = stat.x0; px < stat.x1; ++px) {
      const std::size_t i = pl.at(px, py);
      double sum = 0.0;
      for (int c = 0; c < 3; ++c) {
        pl.d[c][i] = static_cast<double>(z.at(px, py, c)) - x.at(px, py, c);
        pl.v[c][i] = variance.at(px, py, c);
        sum += pl.v[c][i];
      }
      pl.vsum[i] = sum;
    }
  }
  if (!s.dof) return pl;
  pl.cx.assign(pl.w, 0.0);
  pl.cy.assign(static_cast<std::size_t>(pl.rect.height()), 0.0);
  for (int px = std::max(pl.rect.x0, 0); px < std::min(pl.rect.x1, s.width); ++px) {
    pl.cx[static_cast<std::size_t>(px - pl.rect.x0)] = 1.0 / box_width(px, s.pool, s.width);
  }
  for (int py = std::max(pl.rect.y0, 0); py < std::min(pl.rect.y1, s.height); ++py) {
    pl.cy[static_cast<std::size_t>(py - pl.rect.y0)] = 1.0 / box_width(py, s.pool, s.height);
  }
  pl.pbar.assign(n, 0.0);
  pl.q.assign(n, 0.0);
  pl.raw = origin.raw.valid();
  const Rect all = pl.rect.intersect(image);
  for (int py = all.y0; py < all.y1; ++py) {
    for (int px = all.x0; px < all.x1; ++px) {
      const std::size_t i = pl.at(px, py);
      const View& v = pl.raw ? origin.raw : variance;
      double sum = 0.0;
      for (int c = 0; c < 3; ++c) sum += v.at(px, py, c);
      pl.pbar[i] = sum / 3.0;
      // sigma^4 / nu, estimated without bias from a raw chi-square estimate
      // (E[vhat^2] = (1 + 2 / nu) sigma^4), or plugged in from the pooled one.
      const double nu = pixel_dof(origin.passes.at(px, py, 0));
      pl.q[i] = pl.pbar[i] * pl.pbar[i] / (pl.raw ? nu + 2.0 : nu);
    }
  }
  return pl;
}

Setup make_setup(const TTestParams& p, const VarianceOrigin& origin, int width, int height) {
  if (p.radius < 0 || p.radius > kMaxRadius) {
    throw std::invalid_argument("t-test radius must be in [0, " + std::to_string(kMaxRadius) +
                                "], got " + std::to_string(p.radius));
  }
  if (origin.pool_radius < 0 || origin.pool_radius > kMaxRadius) {
    throw std::invalid_argument("t-test: variance pool radius must be in [0, " +
                                std::to_string(kMaxRadius) + "], got " +
                                std::to_string(origin.pool_radius));
  }
  Setup s;
  s.radius = p.radius;
  s.pool = origin.pool_radius;
  s.width = width;
  s.height = height;
  s.proden = p.dof_correction;
  // The variance counts as exact (infinite degrees of freedom) when it is the renderer's or its
  // pass counts are unknown.
  s.dof = p.dof_correction && !origin.renderer && origin.passes.valid();
  s.sigma_scale = p.sigma_scale;
  s.sigma_floor = p.sigma_floor;
  return s;
}

}  // namespace

void pool_variance(const Image& img, int r, Image& tmp, Image& out) {
  if (r <= 0) {
    out = img;
    return;
  }
  const int W = img.width(), H = img.height();
  if (!tmp.same_size(img) || tmp.channels() != img.channels()) tmp = Image(W, H, img.channels());
  if (!out.same_size(img) || out.channels() != img.channels()) out = Image(W, H, img.channels());
  // Rows in parallel, each output written by one task: the same sums as one serial loop.
  const int rows = H * img.channels();
  tbb::parallel_for(0, rows, [&](int row) {
    const int c = row / H, y = row % H;
    for (int x = 0; x < W; ++x) {
      double s = 0;
      const int a = std::max(x - r, 0), b = std::min(x + r + 1, W);
      for (int q = a; q < b; ++q) s += img.at(q, y, c);
      tmp.at(x, y, c) = static_cast<float>(s / (b - a));
    }
  });
  tbb::parallel_for(0, rows, [&](int row) {
    const int c = row / H, y = row % H;
    const int a = std::max(y - r, 0), b = std::min(y + r + 1, H);
    for (int x = 0; x < W; ++x) {
      double s = 0;
      for (int q = a; q < b; ++q) s += tmp.at(x, q, c);
      out.at(x, y, c) = static_cast<float>(s / (b - a));
    }
  });
}

Image pool_variance(const Image& img, int r) {
  Image tmp, out;
  pool_variance(img, r, tmp, out);
  return out;
}

double student_t_quantile(double dof, double upper_tail) {
  namespace bm = boost::math;
  if (!(upper_tail > 0.0 && upper_tail < 1.0) || !(dof > 0.0)) {
    throw std::invalid_argument("student_t_quantile: need dof > 0 and a tail in (0, 1)");
  }
  if (std::isinf(dof))
    return bm::quantile(bm::complement(bm::normal_distribution<double>(), upper_tail));
  return bm::quantile(bm::complement(bm::students_t_distribution<double>(dof), upper_tail));
}

double t_threshold(const TTestParams& p, double dof) {
  if (!p.dof_correction) return p.t0;
  return student_t_quantile(dof, upper_normal_tail(p.t0));
}

RejectionCurve::RejectionCurve(double t0, double slope) : t0_(t0), slope_(slope) {
  if (!(slope > 0.0) || !std::isfinite(slope) || !std::isfinite(t0)) {
    throw std::invalid_argument("t-test: slope must be positive and t0 finite");
  }
  constexpr int kRows = 129;
  constexpr double kStep = 0.1;
  const double half = 6.0 / slope;  // keep = 1 - Phi(slope (u - t0)) within 1e-9 of 1 or 0 beyond
  u_lo_ = std::max(0.0, t0 - half);
  du_ = kStep;
  u_cols_ = static_cast<int>(std::ceil((t0 + half - u_lo_) / kStep)) + 1;
  nu_rows_ = kRows;
  table_.resize(static_cast<std::size_t>(nu_rows_) * static_cast<std::size_t>(u_cols_));
  for (int i = 0; i < nu_rows_; ++i) {
    const double sq = static_cast<double>(i) / (nu_rows_ - 1);  // sqrt(1 / dof)
    const double dof = i == 0 ? kInf : 1.0 / (sq * sq);
    for (int j = 0; j < u_cols_; ++j) {
      const double u = u_lo_ + du_ * j;
      const double t = u > 0.0 ? student_t_quantile(dof, upper_normal_tail(u)) : 0.0;
      table_[static_cast<std::size_t>(i) * static_cast<std::size_t>(u_cols_) +
             static_cast<std::size_t>(j)] = std::asinh(t);
    }
    first_t_.push_back(
        std::sinh(table_[static_cast<std::size_t>(i) * static_cast<std::size_t>(u_cols_)]));
    last_t_.push_back(
        std::sinh(table_[static_cast<std::size_t>(i + 1) * static_cast<std::size_t>(u_cols_) - 1]));
  }
  keep_lo_ = upper_normal_tail(slope_ * (u_lo_ - t0_));
  keep_hi_ = upper_normal_tail(slope_ * (u_lo_ + du_ * (u_cols_ - 1) - t0_));
  // The largest t whose infinite-dof keep, 1 - Phi(slope (t - t0)), is within the tolerance of
  // keep_lo_ (the curve falls with t), and never below the first node's exact bound.
  namespace bm = boost::math;
  const double tail = std::min(1.0 - keep_lo_ + kDofFreeKeepTolerance, 0.5);
  dof_free_t_ = std::max(first_t_.front(),
                         t0_ + bm::quantile(bm::normal_distribution<double>(), tail) / slope_);
}

const RejectionCurve& RejectionCurve::shared(double t0, double slope) {
  static std::mutex mutex;
  static std::map<std::pair<double, double>, std::unique_ptr<RejectionCurve>> curves;
  const std::lock_guard<std::mutex> lock(mutex);
  auto& slot = curves[{t0, slope}];
  if (!slot) slot = std::make_unique<RejectionCurve>(t0, slope);
  return *slot;
}

RejectionCurve::Row RejectionCurve::row(double dof) const {
  // Rows sit at 1/dof = (i / (rows - 1))^2; between two rows the quantile is close to linear in
  // 1/dof (its Cornish-Fisher series), so interpolate in 1/dof itself.
  const double inv = 1.0 / std::max(dof, 1.0), n = nu_rows_ - 1;
  const int i = std::min(static_cast<int>(std::sqrt(inv) * n), nu_rows_ - 2);
  const double x0 = (i / n) * (i / n), x1 = ((i + 1) / n) * ((i + 1) / n);
  Row r;
  r.lo = table_.data() + static_cast<std::size_t>(i) * static_cast<std::size_t>(u_cols_);
  r.hi = r.lo + u_cols_;
  r.f = (inv - x0) / (x1 - x0);
  // The table grows with 1/dof, so the interpolated row lies between rows i and i + 1.
  r.t_lo = first_t_[static_cast<std::size_t>(i)];
  r.t_hi = last_t_[static_cast<std::size_t>(i) + 1];
  return r;
}

double RejectionCurve::normal_score(const Row& r, double t) const {
  const double u_hi = u_lo_ + du_ * (u_cols_ - 1);
  if (t <= r.t_lo) return u_lo_;
  if (t >= r.t_hi) return u_hi;
  auto at = [&](int j) { return (1.0 - r.f) * r.lo[j] + r.f * r.hi[j]; };
  const double a = std::asinh(t);
  if (a <= at(0)) return u_lo_;
  if (a >= at(u_cols_ - 1)) return u_hi;
  int j0 = 0, j1 = u_cols_ - 1;  // at(j0) < a < at(j1); the row increases with u
  while (j1 - j0 > 1) {
    // Bisection by selects, not branches: which half holds a is a coin flip per probe.
    const int mid = (j0 + j1) / 2;
    const bool below = at(mid) <= a;
    j0 = below ? mid : j0;
    j1 = below ? j1 : mid;
  }
  const double r0 = at(j0), r1 = at(j1);
  return u_lo_ + du_ * (j0 + std::clamp((a - r0) / (r1 - r0), 0.0, 1.0));
}

double RejectionCurve::normal_score(double t, double dof) const {
  if (std::isinf(dof)) return t;
  return normal_score(row(dof), t);
}

double RejectionCurve::keep(double t, double dof) const {
  return upper_normal_tail(slope_ * (normal_score(t, dof) - t0_));
}

void RejectionCurve::keep(const double* t, int n, double dof, double* out) const {
  if (std::isinf(dof)) {
    for (int i = 0; i < n; ++i) out[i] = upper_normal_tail(slope_ * (t[i] - t0_));
    return;
  }
  // Every row starts at or above the normal row's first t (a quantile grows as dof falls), so
  // statistics at or below it keep keep_lo_ whatever the dof: most pixels, without a row.
  bool low = true;
  for (int i = 0; i < n; ++i) low = low && t[i] <= first_t_.front();
  if (low) {
    for (int i = 0; i < n; ++i) out[i] = keep_lo_;
    return;
  }
  const Row r = row(dof);
  for (int i = 0; i < n; ++i) {
    out[i] = t[i] <= r.t_lo   ? keep_lo_
             : t[i] >= r.t_hi ? keep_hi_
                              : upper_normal_tail(slope_ * (normal_score(r, t[i]) - t0_));
  }
}

double RejectionCurve::exact_normal_score(double t, double dof) {
  namespace bm = boost::math;
  if (std::isinf(dof)) return t;
  const double tail = bm::cdf(bm::complement(bm::students_t_distribution<double>(dof), t));
  return bm::quantile(bm::complement(bm::normal_distribution<double>(), tail));
}

void t_rescale(const View& x, const View& variance, const View& z, const View& alpha, int width,
               int height, const Rect& out, const TTestParams& p, Buffer& rescaled,
               const VarianceOrigin& origin) {
  if (out.empty()) return;
  Setup s = make_setup(p, origin, width, height);
  const Planes pl = make_planes(x, variance, z, out, s, origin);
  const RejectionCurve* curve = s.proden ? &RejectionCurve::shared(p.t0, p.slope) : nullptr;
  if (curve) s.dof_free_t = curve->dof_free_t();
  const KernelBuild& kb = kernel_build(p.isa);
  LaneStats st;
  for (int py = out.y0; py < out.y1; ++py) {
    for (int px0 = out.x0; px0 < out.x1; px0 += kb.lanes) {
      const int n = std::min(kb.lanes, out.x1 - px0);
      kb.fn(pl, s, px0, py, n, st);
      for (int l = 0; l < n; ++l) {
        double t[3] = {st.t[0][l], st.t[1][l], st.t[2][l]}, keep[3];
        if (curve) {
          curve->keep(t, 3, st.dof[l], keep);
        } else {
          for (int c = 0; c < 3; ++c) keep[c] = upper_normal_tail(p.slope * (t[c] - p.t0));
        }
        for (int c = 0; c < 3; ++c) {
          rescaled.at(px0 + l, py, c) = static_cast<float>(alpha.at(px0 + l, py, c) * keep[c]);
        }
      }
    }
  }
}

TStatistic t_statistic(const View& x, const View& variance, const View& z, int width, int height,
                       int px, int py, const TTestParams& params, const VarianceOrigin& origin) {
  const Setup s = make_setup(params, origin, width, height);
  const Rect out{px, py, px + 1, py + 1};
  const Planes pl = make_planes(x, variance, z, out, s, origin);
  LaneStats st;
  kernel_build(params.isa).fn(pl, s, px, py, 1, st);
  TStatistic r;
  for (int c = 0; c < 3; ++c) r.t[c] = st.t[c][0];
  r.dof = st.dof[0];
  return r;
}

std::vector<std::string> t_test_builds() {
  std::vector<std::string> out;
  for (const auto& b : kernel_builds()) out.push_back(b.name);
  return out;
}

}  // namespace proden

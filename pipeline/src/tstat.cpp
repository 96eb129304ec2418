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
constexpr int kLanes = 8;  // output pixels per kernel call: one AVX-512 register of doubles
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
};

// Statistics of up to kLanes consecutive pixels of one row.
struct LaneStats {
  double t[3][kLanes];
  double dof[kLanes];
};

// Width of the pooling box around coordinate c in [0, n): (2r+1) clipped to the image.
inline int box_width(int c, int r, int n) {
  return std::min(c + r, n - 1) - std::max(c - r, 0) + 1;
}

// kLanes doubles: one AVX-512 register, two AVX2 ones, four SSE2 ones (GCC vector extension;
// element-wise arithmetic, so every build rounds alike and tiles equal the whole image).
using Lane = double __attribute__((vector_size(kLanes * sizeof(double))));
using LaneMask = long long __attribute__((vector_size(kLanes * sizeof(long long))));

// Unaligned loads through memcpy (no vector-returning helper: that would change the ABI between
// the multiversioned builds).
#define PRODEN_LOAD(v, p) std::memcpy(&(v), (p), sizeof(Lane))

PRODEN_MULTIVERSION void lane_kernel(const Planes& pl, const Setup& s, int px0, int py, int n,
                                     LaneStats& out) {
  const int R = s.radius, P = s.pool, S = R + P;
  double norm_a[kLanes], g_a[kMaxRadius + 1][kLanes];
  double last_sigma = -1.0;  // the fine test's sigma is the same for every pixel: one exp
  for (int l = 0; l < kLanes; ++l) {
    const double mean_var = pl.vsum[pl.at(px0 + l, py)] / 3.0;
    const double sigma =
        std::max(s.sigma_scale * std::sqrt(std::clamp(mean_var, 0.0, 1.0)), s.sigma_floor);
    norm_a[l] = 1.0 / (sigma * kSqrt2Pi);
    if (sigma == last_sigma) {
      for (int d = 0; d <= R; ++d) g_a[d][l] = g_a[d][l - 1];
      continue;
    }
    last_sigma = sigma;
    // k(dx, dy) = norm g(dx) g(dy) is separable, and g(d) = q^(d^2) with q = exp(-1 / 2 sigma^2)
    // follows from g(d) = g(d - 1) q^(2d - 1): one exponential per pixel.
    const double q = std::exp(-1.0 / (2.0 * sigma * sigma)), q2 = q * q;
    double step = q;
    g_a[0][l] = 1.0;
    for (int d = 1; d <= R; ++d) {
      g_a[d][l] = g_a[d - 1][l] * step;
      step *= q2;
    }
  }
  Lane norm, g[kMaxRadius + 1];
  PRODEN_LOAD(norm, norm_a);
  for (int d = 0; d <= R; ++d) PRODEN_LOAD(g[d], g_a[d]);

  // The window sums: D_c = sum k (z - x), V_c = sum k^2 var, and the highest-variance pixel M
  // (the first maximum in raster order).
  Lane D0{}, D1{}, D2{}, V0{}, V1{}, V2{}, mx{}, my{}, km{}, best = Lane{} - 2.0;
  for (int dy = -R; dy <= R; ++dy) {
    const Lane ky = norm * g[std::abs(dy)];
    const Lane fdy = Lane{} + dy;
    for (int dx = -R; dx <= R; ++dx) {
      const std::size_t b = pl.at(px0 + dx, py + dy);
      const Lane k = ky * g[std::abs(dx)], k2 = k * k;
      Lane d[3], v[3], sv;
      for (int c = 0; c < 3; ++c) {
        PRODEN_LOAD(d[c], pl.d[c].data() + b);
        PRODEN_LOAD(v[c], pl.v[c].data() + b);
      }
      PRODEN_LOAD(sv, pl.vsum.data() + b);
      D0 += k * d[0];
      D1 += k * d[1];
      D2 += k * d[2];
      V0 += k2 * v[0];
      V1 += k2 * v[1];
      V2 += k2 * v[2];
      const LaneMask gt = sv > best;
      best = gt ? sv : best;
      mx = gt ? Lane{} + dx : mx;
      my = gt ? fdy : my;
      km = gt ? k : km;
    }
  }

  // Welch-Satterthwaite: Var-hat = sum_r b_r vhat_r over the raw per-pixel estimates, with
  // b_r = sum_q w_q^2 [r in box(q)] / |box(q)|; dof = (sum b sigma^2)^2 / sum (b sigma^2)^2 /
  // dof_r, sigma_r^2 plugged in as the pooled estimate (docs/pipeline.md). The Gaussian part of w^2
  // and the clipped box are separable: b_r = hx(rx) hy(ry) (hy holding norm^2), plus M's extra
  // weight.
  Lane hx[kMaxSpan], hy[kMaxSpan], a1{}, a2{};
  if (s.dof) {
    // hx(o) = sum over window columns d with |o - d| <= P of g(d)^2 / |box|, |box| and the
    // window clipped to the image (cx, cy: 1 / box width inside the image, 0 outside).
    for (int o = -S; o <= S; ++o) {
      Lane sx{}, sy{};
      for (int d = std::max(-R, o - P); d <= std::min(R, o + P); ++d) {
        const Lane g2 = g[std::abs(d)] * g[std::abs(d)];
        Lane cx;
        PRODEN_LOAD(cx, pl.cx.data() + (px0 + d - pl.rect.x0));
        sx += g2 * cx;
        sy += g2 * pl.cy[static_cast<std::size_t>(py + d - pl.rect.y0)];
      }
      hx[o + S] = sx;
      hy[o + S] = sy * (norm * norm);  // k^2 = norm^2 g^2 g^2
    }
    // b_r = hy(ry) hx(rx): both sums by rows, sum_y hy (sum_x hx pbar) and the same in squares.
    Lane hx2[kMaxSpan];
    for (int o = 0; o <= 2 * S; ++o) hx2[o] = hx[o] * hx[o];
    for (int oy = -S; oy <= S; ++oy) {
      Lane r1{}, r2{};
      const std::size_t row = pl.at(px0 - S, py + oy);
      for (int o = 0; o <= 2 * S; ++o) {
        Lane pb, q;
        PRODEN_LOAD(pb, pl.pbar.data() + row + o);
        PRODEN_LOAD(q, pl.q.data() + row + o);
        r1 += hx[o] * pb;
        r2 += hx2[o] * q;
      }
      const Lane wy = hy[oy + S];
      a1 += wy * r1;
      a2 += wy * wy * r2;
    }
  }

  for (int l = 0; l < n; ++l) {
    const int px = px0 + l;
    const int qx = px + static_cast<int>(mx[l]), qy = py + static_cast<int>(my[l]);
    const std::size_t m = pl.at(qx, qy);
    const double Dl[3] = {D0[l], D1[l], D2[l]}, Vl[3] = {V0[l], V1[l], V2[l]};
    if (!s.proden) {
      // The authors' statistic: channels summed, M's three channels added to both sums with
      // weight 1/3 and its variance with 1/9 (as if M were an independent extra pixel).
      double num = 0.0, var = 0.0;
      for (int c = 0; c < 3; ++c) {
        num += Dl[c] + pl.d[c][m] / 3.0;
        var += Vl[c] + pl.v[c][m] / 9.0;
      }
      const double t = std::abs(num) / (std::sqrt(std::max(var, 0.0)) + 1e-6);
      for (int c = 0; c < 3; ++c) out.t[c][l] = t;
      out.dof[l] = kInf;
      continue;
    }
    // M's weight becomes k_M + 1/3, so its variance weight grows by (k_M + 1/3)^2 - k_M^2.
    const double cm = 2.0 * km[l] / 3.0 + 1.0 / 9.0;
    for (int c = 0; c < 3; ++c) {
      const double num = Dl[c] + pl.d[c][m] / 3.0;
      const double var = Vl[c] + cm * pl.v[c][m];
      out.t[c][l] = std::abs(num) / (std::sqrt(std::max(var, 0.0)) + 1e-6);
    }
    double dof = kInf;
    if (s.dof) {
      double n1 = a1[l], n2 = a2[l];
      const double mw = cm / (box_width(qx, P, s.width) * box_width(qy, P, s.height));
      for (int ry = std::max(qy - P, 0); ry <= std::min(qy + P, s.height - 1); ++ry) {
        for (int rx = std::max(qx - P, 0); rx <= std::min(qx + P, s.width - 1); ++rx) {
          const std::size_t r = pl.at(rx, ry);
          const double sr = hy[ry - py + S][l] * hx[rx - px + S][l];
          n1 += mw * pl.pbar[r];
          n2 += (2.0 * sr * mw + mw * mw) * pl.q[r];
        }
      }
      // With the raw estimates plugged in, (sum b vhat)^2 overstates (sum b sigma^2)^2 by
      // Var[sum b vhat] = 2 sum b^2 sigma^4 / nu, i.e. the ratio by 2.
      if (n2 > 0.0 && n1 > 0.0) dof = std::max(n1 * n1 / n2 - (pl.raw ? 2.0 : 0.0), 1.0);
    }
    out.dof[l] = dof;
  }
}

Planes make_planes(const View& x, const View& variance, const View& z, const Rect& out,
                   const Setup& s, const VarianceOrigin& origin) {
  Planes pl;
  const Rect image{0, 0, s.width, s.height};
  // kLanes - 1 more columns on the right: the kernel always computes whole lane blocks.
  pl.rect = out.expanded(s.radius + s.pool);
  pl.rect.x1 += kLanes - 1;
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
  const Setup s = make_setup(p, origin, width, height);
  const Planes pl = make_planes(x, variance, z, out, s, origin);
  const RejectionCurve* curve = s.proden ? &RejectionCurve::shared(p.t0, p.slope) : nullptr;
  LaneStats st;
  for (int py = out.y0; py < out.y1; ++py) {
    for (int px0 = out.x0; px0 < out.x1; px0 += kLanes) {
      const int n = std::min(kLanes, out.x1 - px0);
      lane_kernel(pl, s, px0, py, n, st);
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
  lane_kernel(pl, s, px, py, 1, st);
  TStatistic r;
  for (int c = 0; c < 3; ++c) r.t[c] = st.t[c][0];
  r.dof = st.dof[0];
  return r;
}

}  // namespace proden

// The t-test's statistics (docs/pipeline.md, "The t-test's statistics"): exact Student-t
// quantiles against published table values, the tabulated rejection curve against Boost.Math,
// the statistic and its Welch-Satterthwaite degrees of freedom against a brute-force evaluation
// of their definitions, and the calibration: an unbiased mix of frames made of K passes is
// rejected at the nominal rate, a biased one is rejected.
#include <tbb/global_control.h>
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "proden/accumulator.hpp"
#include "proden/progressive.hpp"
#include "proden/tstat.hpp"

using namespace proden;

namespace {

constexpr double kPi = 3.14159265358979323846;

double upper_tail(double u) {
  return 0.5 * std::erfc(u / std::sqrt(2.0));
}

}  // namespace

TEST_CASE("Student-t quantiles match published table values", "[ttest][quantile]") {
  // Two-sided 95 %, 99 %, 99.8 % columns of the usual t table.
  CHECK(student_t_quantile(1, 0.025) == Approx(12.706).margin(5e-4));
  CHECK(student_t_quantile(2, 0.025) == Approx(4.303).margin(5e-4));
  CHECK(student_t_quantile(3, 0.005) == Approx(5.841).margin(5e-4));
  CHECK(student_t_quantile(7, 0.005) == Approx(3.499).margin(5e-4));
  CHECK(student_t_quantile(10, 0.05) == Approx(1.812).margin(5e-4));
  CHECK(student_t_quantile(30, 0.025) == Approx(2.042).margin(5e-4));
  CHECK(student_t_quantile(4, 0.001) == Approx(7.173).margin(5e-4));
  CHECK(student_t_quantile(INFINITY, 0.025) == Approx(1.960).margin(5e-4));
  CHECK(student_t_quantile(INFINITY, 0.005) == Approx(2.576).margin(5e-4));

  // The authors' tail 1 - Phi(4.2) = 1.3346e-5: closed forms for 1 dof (Cauchy,
  // t = tan(pi (1/2 - p))) and 2 dof (t = (1 - 2p) / sqrt(2 p (1 - p))).
  const TTestParams params;
  const double p = upper_tail(params.t0);  // t0 is a float: 4.19999981
  CHECK(p == Approx(1.3346e-5).epsilon(1e-3));
  CHECK(t_threshold(params, 1) == Approx(std::tan(kPi * (0.5 - p))).epsilon(1e-9));
  CHECK(t_threshold(params, 1) == Approx(23851).margin(1.0));
  CHECK(t_threshold(params, 2) == Approx((1 - 2 * p) / std::sqrt(2 * p * (1 - p))).epsilon(1e-9));
  CHECK(t_threshold(params, 2) == Approx(193.5).margin(0.1));
  // Many degrees of freedom: the authors' normal threshold.
  CHECK(t_threshold(params, 1e7) == Approx(4.2).epsilon(1e-5));
  CHECK(t_threshold(params, INFINITY) == Approx(params.t0).epsilon(1e-12));
  CHECK(t_threshold(params, 25) > t_threshold(params, 50));
  TTestParams authors;
  authors.dof_correction = false;
  CHECK(t_threshold(authors, 1) == Approx(4.2));
  CHECK_THROWS_AS(student_t_quantile(0, 0.1), std::invalid_argument);
  CHECK_THROWS_AS(student_t_quantile(3, 1.5), std::invalid_argument);
}

TEST_CASE("the tabulated rejection curve matches Boost.Math", "[ttest][quantile]") {
  for (const auto& [t0, slope] :
       {std::pair{4.2, 2.0}, std::pair{2.3263, 2.0}, std::pair{3.0, 1.0}}) {
    const RejectionCurve curve(t0, slope);
    std::mt19937_64 rng(7);
    std::uniform_real_distribution<double> logdof(0.0, std::log(1e5)), un(0.0, 1.0);
    double worst_u = 0.0, worst_keep = 0.0;
    for (int i = 0; i < 2000; ++i) {
      const double dof = i < 20 ? 1.0 + i : std::exp(logdof(rng));  // integers and a spread
      // t over the span where the curve moves: normal scores t0 +- 6 / slope.
      const double u =
          std::max(0.0, t0 - 6.0 / slope) + un(rng) * (std::min(t0, 6.0 / slope) + 6.0 / slope);
      const double t = student_t_quantile(dof, upper_tail(u));
      const double exact_u = RejectionCurve::exact_normal_score(t, dof);
      INFO("t0 " << t0 << " dof " << dof << " t " << t << " u " << u);
      REQUIRE(exact_u == Approx(u).margin(1e-7));  // Boost's cdf inverts its quantile
      worst_u = std::max(worst_u, std::abs(curve.normal_score(t, dof) - exact_u));
      worst_keep =
          std::max(worst_keep, std::abs(curve.keep(t, dof) - upper_tail(slope * (exact_u - t0))));
    }
    INFO("t0 " << t0 << " slope " << slope << ": worst |du| " << worst_u << ", |dkeep| "
               << worst_keep);
    CHECK(worst_u < 1e-3);
    CHECK(worst_keep < 5e-4);
    // Infinite degrees of freedom: exactly the authors' curve.
    for (double t : {0.0, 1.0, t0, t0 + 0.3, 10.0}) {
      CHECK(curve.keep(t, INFINITY) == upper_tail(slope * (t - t0)));
    }
    // dof_free_t: up to it every dof's exact keep is within 1e-5 of the first node's, and a
    // little above it the infinite dof's is not.
    const double u_lo = std::max(0.0, t0 - 6.0 / slope), keep_lo = upper_tail(slope * (u_lo - t0));
    CHECK(curve.dof_free_t() >= u_lo);
    for (double f : {0.0, 0.5, 0.9, 1.0}) {
      const double t = f * curve.dof_free_t();
      for (double dof : {1.0, 2.0, 3.0, 30.0, 1e4, double(INFINITY)}) {
        INFO("t0 " << t0 << " t " << t << " dof " << dof);
        const double u = RejectionCurve::exact_normal_score(t, dof);
        CHECK(std::abs(upper_tail(slope * (u - t0)) - keep_lo) <= 1e-5 + 1e-12);
      }
    }
    CHECK(keep_lo - upper_tail(slope * (curve.dof_free_t() + 0.05 - t0)) > 1e-5);
    // Below and beyond the grid: exact at t = 0 (u = 0), flat within 1e-9 past t0 + 6 / slope.
    CHECK(curve.keep(0.0, 3.0) == Approx(upper_tail(-slope * t0)).margin(1e-8));
    CHECK(curve.keep(1e300, 1.0) < 1e-8);
  }
  CHECK(&RejectionCurve::shared(4.2, 2.0) == &RejectionCurve::shared(4.2, 2.0));
  CHECK_THROWS_AS(RejectionCurve(4.2, 0.0), std::invalid_argument);
}

namespace {

// The statistic and its degrees of freedom at (px, py) straight from their definitions
// (docs/pipeline.md): weights w_q = k_q + [q = M] / 3 over the clipped window, the raw
// estimates' weights b_r = sum_q w_q^2 [r in box(q)] / |box(q)|, and Welch-Satterthwaite.
TStatistic brute_force(const Image& x, const Image& raw_var, const Image& passes, const Image& z,
                       int pool, int px, int py, const TTestParams& p) {
  const int W = x.width(), H = x.height(), R = p.radius;
  const Image pooled = pool_variance(raw_var, pool);
  auto psum = [&](int qx, int qy) {
    return static_cast<double>(pooled.at(qx, qy, 0)) + pooled.at(qx, qy, 1) + pooled.at(qx, qy, 2);
  };
  const double sigma = std::max(p.sigma_scale * std::sqrt(std::clamp(psum(px, py) / 3.0, 0.0, 1.0)),
                                static_cast<double>(p.sigma_floor));
  auto k = [&](int qx, int qy) {
    const double d2 = (qx - px) * (qx - px) + (qy - py) * (qy - py);
    return std::exp(-d2 / (2 * sigma * sigma)) / (sigma * std::sqrt(2 * kPi));
  };
  int mx = px, my = py;
  double best = -1;
  for (int qy = std::max(py - R, 0); qy <= std::min(py + R, H - 1); ++qy) {
    for (int qx = std::max(px - R, 0); qx <= std::min(px + R, W - 1); ++qx) {
      if (psum(qx, qy) > best) {
        best = psum(qx, qy);
        mx = qx;
        my = qy;
      }
    }
  }
  auto box = [&](int c, int n) { return std::min(c + pool, n - 1) - std::max(c - pool, 0) + 1; };
  TStatistic s;
  std::vector<double> b(static_cast<std::size_t>(W * H), 0.0);
  double D[3] = {}, V[3] = {};
  for (int qy = std::max(py - R, 0); qy <= std::min(py + R, H - 1); ++qy) {
    for (int qx = std::max(px - R, 0); qx <= std::min(px + R, W - 1); ++qx) {
      const double w = k(qx, qy) + (qx == mx && qy == my ? 1.0 / 3.0 : 0.0);
      for (int c = 0; c < 3; ++c) {
        D[c] += w * (static_cast<double>(z.at(qx, qy, c)) - x.at(qx, qy, c));
        V[c] += w * w * pooled.at(qx, qy, c);
      }
      const double area = box(qx, W) * box(qy, H);
      for (int ry = std::max(qy - pool, 0); ry <= std::min(qy + pool, H - 1); ++ry) {
        for (int rx = std::max(qx - pool, 0); rx <= std::min(qx + pool, W - 1); ++rx) {
          b[static_cast<std::size_t>(ry * W + rx)] += w * w / area;
        }
      }
    }
  }
  for (int c = 0; c < 3; ++c) s.t[c] = std::abs(D[c]) / (std::sqrt(V[c]) + 1e-6);
  // Welch-Satterthwaite with the raw estimates: sigma^4 / nu estimated by vhat^2 / (nu + 2), and
  // the squared numerator's own variance (2 sum b^2 sigma^4 / nu) taken off.
  double n1 = 0, n2 = 0;
  for (int ry = 0; ry < H; ++ry) {
    for (int rx = 0; rx < W; ++rx) {
      const double br = b[static_cast<std::size_t>(ry * W + rx)];
      const double v = (static_cast<double>(raw_var.at(rx, ry, 0)) + raw_var.at(rx, ry, 1) +
                        raw_var.at(rx, ry, 2)) /
                       3.0;
      n1 += br * v;
      n2 += br * br * v * v / (pixel_dof(passes.at(rx, ry, 0)) + 2.0);
    }
  }
  s.dof = std::max(n1 * n1 / n2 - 2.0, 1.0);
  return s;
}

}  // namespace

TEST_CASE("pool_variance is the clamped box mean, the same at any thread count", "[ttest][pool]") {
  // Rows run in parallel: every output must be the serial separable mean, bit for bit.
  const int W = 67, H = 41, C = 3, r = 2;
  std::mt19937 rng(5);
  std::exponential_distribution<float> e(1.0f);
  Image v(W, H, C);
  for (float& f : v.data()) f = e(rng);
  const Image many = pool_variance(v, r);
  Image one;
  {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, 1);
    one = pool_variance(v, r);
  }
  std::size_t differ = 0;
  double worst = 0.0;
  for (int c = 0; c < C; ++c) {
    for (int y = 0; y < H; ++y) {
      for (int x = 0; x < W; ++x) {
        differ += many.at(x, y, c) != one.at(x, y, c);
        // The definition: the mean over the window clipped to the frame, rows then columns.
        double col = 0.0;
        const int y0 = std::max(y - r, 0), y1 = std::min(y + r + 1, H);
        const int x0 = std::max(x - r, 0), x1 = std::min(x + r + 1, W);
        for (int q = y0; q < y1; ++q) {
          double row = 0.0;
          for (int p = x0; p < x1; ++p) row += v.at(p, q, c);
          col += static_cast<float>(row / (x1 - x0));
        }
        const double want = col / (y1 - y0);
        worst = std::max(worst, std::abs(many.at(x, y, c) - want) / want);
      }
    }
  }
  CHECK(differ == 0);
  CHECK(worst < 1e-6);
}

TEST_CASE("the statistic and its Welch-Satterthwaite dof equal their definitions", "[ttest][dof]") {
  const int W = 23, H = 19, pool = 2;
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<float> un(0.0f, 1.0f);
  Image x(W, H, 3), z(W, H, 3), var(W, H, 3), passes(W, H, 1);
  for (int y = 0; y < H; ++y) {
    for (int xx = 0; xx < W; ++xx) {
      passes.at(xx, y, 0) = static_cast<float>(1 + (xx * 7 + y * 3) % 5);  // 1..5 passes
      for (int c = 0; c < 3; ++c) {
        x.at(xx, y, c) = un(rng);
        z.at(xx, y, c) = x.at(xx, y, c) + 0.01f * (un(rng) - 0.5f);
        // Heterogeneous: a firefly-like pixel, and widths s from the floor to the clamp.
        var.at(xx, y, c) =
            (xx == 15 && y == 9 ? 40.0f : 1e-6f + 2e-4f * un(rng) * static_cast<float>(xx));
      }
    }
  }
  const Image pooled = pool_variance(var, pool);
  const VarianceOrigin origin{view_of(passes), false, pool, view_of(var)};
  const TTestParams p;
  for (const auto& [px, py] : {std::pair{11, 9}, std::pair{0, 0}, std::pair{22, 18},
                               std::pair{3, 15}, std::pair{14, 8}, std::pair{20, 2}}) {
    const TStatistic got =
        t_statistic(view_of(x), view_of(pooled), view_of(z), W, H, px, py, p, origin);
    const TStatistic want = brute_force(x, var, passes, z, pool, px, py, p);
    INFO("pixel " << px << "," << py << " dof " << got.dof << " vs " << want.dof);
    for (int c = 0; c < 3; ++c) CHECK(got.t[c] == Approx(want.t[c]).epsilon(1e-9));
    CHECK(got.dof == Approx(want.dof).epsilon(1e-9));
    CHECK(got.dof >= 1.0);
  }
  // Homogeneous variance and K passes everywhere: dof = (K - 1) x the effective number of raw
  // estimates, (sum b)^2 / sum b^2, far more than K - 1.
  Image flat(W, H, 3, 1e-4f), two(W, H, 1, 2.0f);
  const TStatistic h = t_statistic(view_of(x), view_of(pool_variance(flat, pool)), view_of(z), W, H,
                                   11, 9, p, {view_of(two), false, pool, view_of(flat)});
  CHECK(h.dof > 10.0);
  const TStatistic h0 = t_statistic(view_of(x), view_of(flat), view_of(z), W, H, 11, 9, p,
                                    {view_of(two), false, 0, view_of(flat)});
  CHECK(h0.dof < h.dof);  // without pooling fewer raw estimates carry the variance
  // Renderer variance or unknown pass counts: the variance counts as exact.
  CHECK(std::isinf(t_statistic(view_of(x), view_of(pooled), view_of(z), W, H, 11, 9, p,
                               {view_of(passes), true, pool, view_of(var)})
                       .dof));
  CHECK(std::isinf(t_statistic(view_of(x), view_of(pooled), view_of(z), W, H, 11, 9, p).dof));
}

TEST_CASE("every t-test kernel build gives the same bits", "[ttest][isa]") {
  // Odd sizes (rows end mid-lane in every build), a firefly, pass counts 1..5, and widths from the
  // floor to the clamp; the three tests the pipeline runs (proden's pooled 11x11, the fine 5x5
  // and the authors' summed statistic).
  const int W = 41, H = 23, pool = 2;
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<float> un(0.0f, 1.0f);
  Image x(W, H, 3), z(W, H, 3), var(W, H, 3), alpha(W, H, 3), passes(W, H, 1);
  for (int y = 0; y < H; ++y) {
    for (int xx = 0; xx < W; ++xx) {
      passes.at(xx, y, 0) = static_cast<float>(1 + (xx * 5 + y * 3) % 5);
      for (int c = 0; c < 3; ++c) {
        x.at(xx, y, c) = un(rng);
        z.at(xx, y, c) = x.at(xx, y, c) + 0.05f * (un(rng) - 0.5f);
        alpha.at(xx, y, c) = un(rng);
        var.at(xx, y, c) =
            xx == 20 && y == 11 ? 40.0f : 1e-6f + 5e-4f * un(rng) * static_cast<float>(xx % 9);
      }
    }
  }
  const Image pooled = pool_variance(var, pool);
  const VarianceOrigin origin{view_of(passes), false, pool, view_of(var)};
  const auto builds = t_test_builds();
  REQUIRE(builds.front() == "baseline");
  INFO("builds on this CPU: " << builds.size());
  TTestParams fine{.radius = 2, .sigma_scale = 0.0f, .sigma_floor = 1.0f};
  TTestParams authors;
  authors.dof_correction = false;
  for (const TTestParams& base : {TTestParams{}, fine, authors}) {
    const Rect whole{0, 0, W, H}, part{3, 2, 30, 19};
    for (const Rect& out : {whole, part}) {
      std::vector<std::vector<float>> got;
      std::vector<TStatistic> stat;
      for (const auto& isa : builds) {
        TTestParams p = base;
        p.isa = isa;
        Buffer r(out, 3);
        t_rescale(view_of(x), view_of(pooled), view_of(z), view_of(alpha), W, H, out, p, r, origin);
        got.emplace_back();
        for (int c = 0; c < 3; ++c) {
          for (int y = out.y0; y < out.y1; ++y) {
            for (int xx = out.x0; xx < out.x1; ++xx) got.back().push_back(r.at(xx, y, c));
          }
        }
        stat.push_back(
            t_statistic(view_of(x), view_of(pooled), view_of(z), W, H, 20, 11, p, origin));
      }
      for (std::size_t b = 1; b < builds.size(); ++b) {
        INFO("build " << builds[b] << " against baseline, radius " << base.radius);
        CHECK(got[b] == got[0]);
        for (int c = 0; c < 3; ++c) CHECK(stat[b].t[c] == stat[0].t[c]);
        CHECK(stat[b].dof == stat[0].dof);
      }
      // The baseline's output is not constant: the comparison above has something to compare.
      CHECK(
          std::any_of(got[0].begin(), got[0].end(), [&](float v) { return v != got[0].front(); }));
    }
  }
  TTestParams bad;
  bad.isa = "sse9";
  Buffer b(Rect{0, 0, 1, 1}, 3);
  CHECK_THROWS_AS(t_rescale(view_of(x), view_of(pooled), view_of(z), view_of(alpha), W, H,
                            Rect{0, 0, 1, 1}, bad, b, origin),
                  std::invalid_argument);
}

TEST_CASE("t_rescale keeps alpha by the curve at each pixel's statistic and dof", "[ttest][dof]") {
  // t_rescale skips the dof's last sum where all three t are too low for it to matter
  // (RejectionCurve::dof_free_t: the keep factor moves by at most 1e-5 there); t_statistic always
  // computes it. Low and high t, few passes (where the dof moves the threshold most), and a region
  // of exactly zero variance. The bound is written out here, not read from
  // kDofFreeKeepTolerance, so that a looser constant fails.
  const int W = 37, H = 21, pool = 2;
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<float> un(0.0f, 1.0f);
  Image x(W, H, 3), z(W, H, 3), var(W, H, 3), alpha(W, H, 3), passes(W, H, 1);
  for (int y = 0; y < H; ++y) {
    for (int xx = 0; xx < W; ++xx) {
      passes.at(xx, y, 0) = static_cast<float>(2 + (xx + y) % 3);  // 2..4 passes
      for (int c = 0; c < 3; ++c) {
        const bool exact = xx<8, biased = xx> 24;
        x.at(xx, y, c) = un(rng);
        const float sd = exact ? 0.0f : 0.02f;
        var.at(xx, y, c) = sd * sd;
        // Unbiased (t mostly below dof_free_t), biased by 0.3 to 30 sd (t high).
        const float shift = biased ? sd * 0.3f * static_cast<float>(1 + (xx * 7 + y) % 100) : 0.0f;
        z.at(xx, y, c) = x.at(xx, y, c) + (exact ? 0.0f : shift + 0.3f * sd * (un(rng) - 0.5f));
        alpha.at(xx, y, c) = 0.25f + 0.75f * un(rng);
      }
    }
  }
  const Image pooled = pool_variance(var, pool);
  const VarianceOrigin origin{view_of(passes), false, pool, view_of(var)};
  const TTestParams fine{.radius = 2, .sigma_scale = 0.0f, .sigma_floor = 1.0f};
  int skipped = 0;  // pixels whose dof only the tolerance lets t_rescale skip (both tests)
  for (const TTestParams& p : {TTestParams{}, fine}) {
    const RejectionCurve& curve = RejectionCurve::shared(p.t0, p.slope);
    const Rect whole{0, 0, W, H};
    Buffer r(whole, 3);
    t_rescale(view_of(x), view_of(pooled), view_of(z), view_of(alpha), W, H, whole, p, r, origin);
    int low = 0, high = 0, rejected = 0;
    for (int y = 0; y < H; ++y) {
      for (int xx = 0; xx < W; ++xx) {
        const TStatistic st =
            t_statistic(view_of(x), view_of(pooled), view_of(z), W, H, xx, y, p, origin);
        double keep[3];
        curve.keep(st.t, 3, st.dof, keep);
        const double tmax = std::max({st.t[0], st.t[1], st.t[2]});
        const bool no_dof = tmax <= curve.dof_free_t();
        (no_dof ? low : high) += 1;
        // Skipped only by the tolerance: above the first node's exact bound.
        // The first node's t at infinite dof is its u, max(0, t0 - 6 / slope) (the curve's grid).
        skipped += no_dof && tmax > std::max(0.0, p.t0 - 6.0 / p.slope) ? 1 : 0;
        for (int c = 0; c < 3; ++c) {
          INFO("pixel " << xx << "," << y << " t " << st.t[c] << " dof " << st.dof);
          const float want = static_cast<float>(alpha.at(xx, y, c) * keep[c]);
          if (no_dof) {
            CHECK(std::abs(r.at(xx, y, c) - want) <= 1e-5f * alpha.at(xx, y, c) + 1e-7f);
          } else {
            CHECK(r.at(xx, y, c) == want);
          }
          rejected += keep[c] < 0.5 ? 1 : 0;
        }
      }
    }
    // Both kinds of pixel were there, and some were rejected.
    CHECK(low > 50);
    CHECK(high > 50);
    CHECK(rejected > 50);
  }
  CHECK(skipped > 10);
}

namespace {

enum class Noise {
  gaussian,    // independent channels
  heavy,       // contaminated normal: variance x10 with probability 0.1 (excess kurtosis 6)
  correlated,  // Gaussian, channels correlated 0.8 (as in Cycles renders, docs/pipeline.md)
};

// splitmix64 uniforms and Box-Muller normals: cheap enough for the sanitizer build's -O0.
struct Rng {
  std::uint64_t state;
  double spare = 0.0;
  bool has_spare = false;
  explicit Rng(std::uint64_t seed) : state(seed) {}
  double uniform() {  // in (0, 1)
    std::uint64_t z = (state += 0x9e3779b97f4a7c15ull);
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
    z ^= z >> 31;
    return (static_cast<double>(z >> 11) + 0.5) * 0x1.0p-53;
  }
  double gauss() {
    if (has_spare) {
      has_spare = false;
      return spare;
    }
    const double r = std::sqrt(-2.0 * std::log(uniform())), phi = 2.0 * kPi * uniform();
    spare = r * std::sin(phi);
    has_spare = true;
    return r * std::cos(phi);
  }
};

// Frames of K passes with known truth mu and known Var[x] per pixel, accumulated by the real
// FrameAccumulator. Passes alternate 4 and 8 spp; a pass's pixel is mu + sd e with sd^2 the
// per-sample variance / spp. Var[x] spans 1e-5..1e-2 over the frame, so the t-test's window
// width s runs from 0.3 to 10.
struct Sim {
  int w = 132, h = 132;
  Image truth, var_x;  // mu and Var[x]
  Sim() : truth(w, h, 3), var_x(w, h, 3) {
    for (int c = 0; c < 3; ++c) {
      for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
          const double fx = static_cast<double>(x) / w, fy = static_cast<double>(y) / h;
          truth.at(x, y, c) =
              static_cast<float>(0.5 + 0.3 * std::sin(0.2 * x + c) * std::cos(0.15 * y));
          var_x.at(x, y, c) = static_cast<float>(
              std::pow(10.0, -5.0 + 3.0 * (0.5 * fx + 0.5 * (0.5 + 0.5 * std::sin(6.0 * fy)))));
        }
      }
    }
  }

  FrameEstimate frame(int passes, Noise noise, std::uint64_t seed, bool renderer_var) const {
    Rng rng(seed);
    const double heavy_lo = std::sqrt(1.0 / 1.9),
                 heavy_hi = std::sqrt(10.0 / 1.9);  // unit variance
    double total_spp = 0;
    for (int k = 0; k < passes; ++k) total_spp += k % 2 ? 8.0 : 4.0;
    FrameAccumulator acc;
    std::vector<double> e(3);
    for (int k = 0; k < passes; ++k) {
      Pass p;
      p.spp = k % 2 ? 8.0 : 4.0;
      p.colour = Image(w, h, 3);
      if (renderer_var) p.variance = Image(w, h, 3);
      const double scale = std::sqrt(total_spp / p.spp);  // sd of the pass / sd of x
      for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) {
          const double common = noise == Noise::correlated ? rng.gauss() : 0.0;
          for (int c = 0; c < 3; ++c) {
            switch (noise) {
              case Noise::gaussian:
                e[c] = rng.gauss();
                break;
              case Noise::heavy:
                e[c] = rng.gauss() * (rng.uniform() < 0.1 ? heavy_hi : heavy_lo);
                break;
              case Noise::correlated:
                e[c] = std::sqrt(0.8) * common + std::sqrt(0.2) * rng.gauss();
                break;
            }
            const double sd = scale * std::sqrt(static_cast<double>(var_x.at(x, y, c)));
            p.colour.at(x, y, c) = static_cast<float>(truth.at(x, y, c) + sd * e[c]);
            if (renderer_var) p.variance.at(x, y, c) = static_cast<float>(sd * sd);
          }
        }
      }
      acc.add(p, "pass" + std::to_string(k));
    }
    return acc.estimate({.halves = false, .features = false});
  }
};

struct Rate {
  long rejected = 0, tests = 0, pixels = 0;
  double value() const { return static_cast<double>(rejected) / static_cast<double>(tests); }
};

// Runs the real pooling and t-test on `frames` simulated frames with z = mu + bias sd(x) (bias 0:
// an unbiased mix, alpha = 1) at test pixels 11 apart, whose 11x11 windows are disjoint, so the
// tests are close to independent. A value is rejected when alpha' < alpha / 2 (u > t0).
Rate rejection_rate(const Sim& sim, int passes, Noise noise, int frames, const TTestParams& p,
                    double bias = 0.0, bool renderer_var = false) {
  const int w = sim.w, h = sim.h, pool = 2;
  Image z = sim.truth;
  for (std::size_t i = 0; i < z.data().size(); ++i) {
    z.data()[i] += static_cast<float>(bias * std::sqrt(static_cast<double>(sim.var_x.data()[i])));
  }
  const Image alpha(w, h, 3, 1.0f);
  Rate r;
  for (int f = 0; f < frames; ++f) {
    const FrameEstimate est =
        sim.frame(passes, noise,
                  7919u * static_cast<std::uint64_t>(passes) +
                      31u * static_cast<std::uint64_t>(noise) + static_cast<std::uint64_t>(f),
                  renderer_var);
    const Image pooled = pool_variance(est.variance, pool);
    const VarianceOrigin origin{view_of(est.passes),
                                est.variance_source == VarianceSource::renderer, pool,
                                view_of(est.variance)};
    for (int py = 5; py < h - 5; py += 11) {
      for (int px = 5; px < w - 5; px += 11) {
        const Rect out{px, py, px + 1, py + 1};
        Buffer a(out, 3);
        t_rescale(view_of(est.mean), view_of(pooled), view_of(z), view_of(alpha), w, h, out, p, a,
                  origin);
        for (int c = 0; c < 3; ++c) r.rejected += a.at(px, py, c) < 0.5f ? 1 : 0;
        r.tests += 3;
        ++r.pixels;
      }
    }
  }
  return r;
}

}  // namespace

namespace {

// Two-sided nominal rate 2 (1 - Phi(t0)) = 2 %, where the rate is measurable with a few thousand
// tests; the binomial tolerance is 4 standard errors of that rate over n independent tests.
struct Nominal {
  TTestParams params;
  double rate;
  Nominal() {
    params.t0 = 2.3263479f;
    rate = 2.0 * upper_tail(params.t0);
  }
  double tolerance(long n) const {
    return 4.0 * std::sqrt(rate * (1 - rate) / static_cast<double>(n));
  }
};

constexpr int kFrames = 10;  // 4320 values per case

}  // namespace

TEST_CASE("t-test calibration: an unbiased mix of K passes is rejected at the nominal rate",
          "[ttest][calibration]") {
  const Sim sim;
  const Nominal nominal;
  REQUIRE(nominal.rate == Approx(0.02).epsilon(1e-5));
  for (int K : {2, 3, 4, 8, 32}) {
    for (Noise noise : {Noise::gaussian, Noise::heavy}) {
      // 32 passes cost 16x 2 passes to simulate: half the frames (the tolerance follows n).
      const Rate r = rejection_rate(sim, K, noise, K >= 32 ? kFrames / 2 : kFrames, nominal.params);
      INFO(K << " passes, " << (noise == Noise::gaussian ? "Gaussian" : "heavy-tailed") << ": "
             << r.rejected << " / " << r.tests << " = " << r.value() << " (nominal " << nominal.rate
             << " +- " << nominal.tolerance(r.tests) << ")");
      CHECK(std::abs(r.value() - nominal.rate) <= nominal.tolerance(r.tests));
    }
  }
}

TEST_CASE("t-test calibration: renderer variance / one pass / correlated channels",
          "[ttest][calibration]") {
  const Sim sim;
  const Nominal nominal;
  // Renderer variance counts as exact (normal quantile).
  const Rate renderer = rejection_rate(sim, 2, Noise::gaussian, kFrames, nominal.params, 0.0, true);
  INFO("renderer variance: " << renderer.value());
  CHECK(std::abs(renderer.value() - nominal.rate) <= nominal.tolerance(renderer.tests));
  // One pass: the spatial variance over-estimates (the truth varies within 3x3): conservative.
  const Rate spatial = rejection_rate(sim, 1, Noise::gaussian, kFrames, nominal.params);
  INFO("spatial variance: " << spatial.value());
  CHECK(spatial.value() <= nominal.rate + nominal.tolerance(spatial.tests));
  // Correlated channels: one statistic per channel stays calibrated. A pixel's three channels
  // now test nearly the same thing, so the tolerance counts pixels, not values.
  const Rate corr = rejection_rate(sim, 4, Noise::correlated, kFrames, nominal.params);
  INFO("per channel, correlated: " << corr.value());
  CHECK(std::abs(corr.value() - nominal.rate) <= nominal.tolerance(corr.pixels));
  // The authors' statistic sums the channels but adds their variances as if independent: with
  // correlation 0.8 the sum's variance is 2.6x that, and unbiased mixes are rejected far too
  // often (even with 8 passes, where its normal threshold is nearly right: nu' ~ 270).
  TTestParams authors = nominal.params;
  authors.dof_correction = false;
  const Rate summed = rejection_rate(sim, 8, Noise::correlated, kFrames / 2, authors);
  INFO("authors' summed statistic, correlated: " << summed.value());
  CHECK(summed.value() > 3.0 * nominal.rate);
}

TEST_CASE("t-test: a biased mix is rejected with few passes too", "[ttest][calibration]") {
  // At the authors' t0 = 4.2 (nominal 2.7e-5) and 2 passes: a mix drifting by 4 standard
  // deviations of x per pixel is rejected almost everywhere (the exact threshold with the pooled
  // degrees of freedom is ~5-6; a threshold from the pass count alone, 23851, would keep it all),
  // an unbiased one almost nowhere.
  const Sim sim;
  const Rate biased = rejection_rate(sim, 2, Noise::gaussian, 2, TTestParams{}, 4.0);
  const Rate unbiased = rejection_rate(sim, 2, Noise::gaussian, 2, TTestParams{}, 0.0);
  INFO("biased " << biased.value() << ", unbiased " << unbiased.value());
  CHECK(biased.value() > 0.95);
  CHECK(unbiased.value() < 0.005);
}

TEST_CASE("Pipeline::commit rejects t-test radii beyond the kernel's", "[ttest][object]") {
  PipelineOptions o;
  o.variance_pool_radius = kTTestMaxRadius + 1;
  Pipeline p(o);
  CHECK_THROWS_AS(p.commit(), PipelineError);
  CHECK_FALSE(p.committed());
  o.variance_pool_radius = 2;
  o.ttest.radius = kTTestMaxRadius + 1;
  p.set_options(o);
  CHECK_THROWS_AS(p.commit(), PipelineError);
  o.ttest.radius = 5;
  p.set_options(o);
  CHECK_NOTHROW(p.commit());
}

// Accumulator statistics against closed forms, and its non-finite and fallback policies.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "proden/accumulator.hpp"
#include "proden/error.hpp"
#include "test_support.hpp"

using namespace proden;
using Catch::Matchers::Contains;

namespace {

Pass constant_pass(int w, int h, double spp, float r, float g, float b) {
  Pass p;
  p.spp = spp;
  p.colour = Image(w, h, 3);
  for (auto& v : p.colour.plane(0)) v = r;
  for (auto& v : p.colour.plane(1)) v = g;
  for (auto& v : p.colour.plane(2)) v = b;
  return p;
}

// Direct two-pass computation of the spp-weighted mean and variance of the mean.
struct Direct {
  double mean, var;
};
Direct direct(const std::vector<double>& x, const std::vector<double>& n) {
  double N = 0, s = 0;
  for (std::size_t k = 0; k < x.size(); ++k) {
    N += n[k];
    s += n[k] * x[k];
  }
  const double mean = s / N;
  double m2 = 0;
  for (std::size_t k = 0; k < x.size(); ++k) m2 += n[k] * (x[k] - mean) * (x[k] - mean);
  return {mean, m2 / static_cast<double>(x.size() - 1) / N};
}

}  // namespace

TEST_CASE("equal spp: mean and unbiased variance of the mean match the closed form",
          "[accumulator]") {
  const std::vector<double> xs = {0.25, 0.5, 1.0, 0.125, 2.0};
  FrameAccumulator f;
  for (std::size_t k = 0; k < xs.size(); ++k) {
    const float v = static_cast<float>(xs[k]);
    f.add(constant_pass(4, 3, 8, v, 2 * v, 3 * v), "p" + std::to_string(k));
  }
  // s^2 / K with the unbiased sample variance s^2.
  double mean = 0;
  for (double x : xs) mean += x;
  mean /= 5;
  double s2 = 0;
  for (double x : xs) s2 += (x - mean) * (x - mean);
  s2 /= 4;
  const FrameEstimate e = f.estimate();
  REQUIRE(e.variance_source == VarianceSource::between_passes);
  REQUIRE_FALSE(e.low_confidence());
  for (int c = 0; c < 3; ++c) {
    const double k = c + 1;
    CHECK(e.mean.at(2, 1, c) == Approx(k * mean).epsilon(1e-6));
    CHECK(e.variance.at(2, 1, c) == Approx(k * k * s2 / 5).epsilon(1e-6));
  }
  CHECK(f.passes() == 5);
  CHECK(f.total_spp() == 40);
  CHECK(e.passes.at(0, 0, 0) == 5.0f);
}

TEST_CASE("unequal spp: spp-weighted mean and variance of the mean", "[accumulator]") {
  const std::vector<double> xs = {0.3, 0.9, 0.5, 0.65};
  const std::vector<double> ns = {1, 2, 4, 8};
  FrameAccumulator f;
  for (std::size_t k = 0; k < xs.size(); ++k) {
    const float v = static_cast<float>(xs[k]);
    f.add(constant_pass(2, 2, ns[k], v, v, v), "p" + std::to_string(k));
  }
  // What float inputs really were.
  std::vector<double> xf;
  for (double x : xs) xf.push_back(static_cast<float>(x));
  const Direct d = direct(xf, ns);
  const FrameEstimate e = f.estimate();
  CHECK(e.mean.at(1, 1, 0) == Approx(d.mean).epsilon(1e-6));
  CHECK(e.variance.at(1, 1, 0) == Approx(d.var).epsilon(1e-6));
}

TEST_CASE("variance of the mean is unbiased for Gaussian passes of unequal spp", "[accumulator]") {
  // Pass k's pixel mean ~ N(mu, sigma^2 / n_k); the estimator's mean over 3*128*128 values must
  // match sigma^2 / N, and so must the squared error of the accumulated mean.
  const int w = 128, h = 128;
  const double sigma = 0.5, mu = 1.0;
  const std::vector<double> ns = {1, 3, 2, 6};
  const double N = 12;
  std::mt19937_64 rng(7);
  FrameAccumulator f;
  for (std::size_t k = 0; k < ns.size(); ++k) {
    std::normal_distribution<double> g(mu, sigma / std::sqrt(ns[k]));
    Pass p;
    p.spp = ns[k];
    p.colour = Image(w, h, 3);
    for (auto& v : p.colour.data()) v = static_cast<float>(g(rng));
    f.add(p, "g" + std::to_string(k));
  }
  const FrameEstimate e = f.estimate();
  double mean_var = 0, mean_se = 0;
  for (int c = 0; c < 3; ++c) {
    for (std::size_t i = 0; i < e.mean.pixels(); ++i) {
      mean_var += e.variance.plane(c)[i];
      const double d = e.mean.plane(c)[i] - mu;
      mean_se += d * d;
    }
  }
  const double count = 3.0 * w * h;
  mean_var /= count;
  mean_se /= count;
  const double truth = sigma * sigma / N;
  // Relative standard errors: ~0.0018 (variance estimator, 3 dof) and ~0.0032 (squared error).
  CHECK(mean_var == Approx(truth).epsilon(0.01));
  CHECK(mean_se == Approx(truth).epsilon(0.015));
}

TEST_CASE("half buffers alternate passes and carry their own statistics", "[accumulator]") {
  FrameAccumulator f;
  const std::vector<float> xs = {1, 2, 3, 4, 5, 7};
  for (std::size_t k = 0; k < xs.size(); ++k) {
    f.add(constant_pass(3, 3, 2, xs[k], xs[k], xs[k]), "p" + std::to_string(k));
  }
  CHECK(f.history()[0].half == 0);
  CHECK(f.history()[1].half == 1);
  CHECK(f.history()[4].half == 0);
  const FrameEstimate e = f.estimate();
  REQUIRE_FALSE(e.half_mean[0].empty());
  CHECK(e.half_mean[0].at(1, 1, 0) == Approx((1 + 3 + 5) / 3.0));
  CHECK(e.half_mean[1].at(1, 1, 0) == Approx((2 + 4 + 7) / 3.0));
  // Var[x_h] = sigma^2 / N_h with the pooled per-sample variance: twice Var[x] for equal halves.
  CHECK(e.half_variance[0].at(1, 1, 0) == Approx(2 * e.variance.at(1, 1, 0)).epsilon(1e-6));
}

TEST_CASE("feature means and renderer variance accumulate with spp weights", "[accumulator]") {
  Layout all{true, true, true, true};
  FrameAccumulator f;
  std::vector<Pass> ps;
  for (int k = 0; k < 3; ++k) ps.push_back(test::make_pass(5, 4, 1 + k, 100 + k, all));
  for (int k = 0; k < 3; ++k) f.add(ps[k], "p" + std::to_string(k));
  const FrameEstimate e = f.estimate();
  REQUIRE(e.variance_source == VarianceSource::renderer);
  const double N = 1 + 2 + 3;
  double alb = 0, var = 0;
  for (int k = 0; k < 3; ++k) {
    alb += ps[k].spp * ps[k].albedo.at(3, 2, 1);
    var += ps[k].spp * ps[k].spp * ps[k].variance.at(3, 2, 1);
  }
  CHECK(e.albedo.at(3, 2, 1) == Approx(alb / N).epsilon(1e-6));
  CHECK(e.variance.at(3, 2, 1) == Approx(var / (N * N)).epsilon(1e-6));
  CHECK_FALSE(e.normal.empty());
  CHECK(e.depth.channels() == 1);
  CHECK(FrameAccumulator::bytes_per_pixel(all) == 312);
  CHECK(FrameAccumulator::bytes_per_pixel(Layout{}) == 120);
}

TEST_CASE("feature halves: per-half means, full mean and spread over all passes", "[accumulator]") {
  Layout feats{true, true, true, false};
  FrameAccumulator f;
  std::vector<Pass> ps;
  for (int k = 0; k < 5; ++k) ps.push_back(test::make_pass(4, 3, 1 + k, 200 + k, feats));
  for (int k = 0; k < 5; ++k) f.add(ps[k], "p" + std::to_string(k));
  const FrameEstimate e = f.estimate();
  REQUIRE_FALSE(e.half_albedo[0].empty());
  REQUIRE_FALSE(e.half_normal[1].empty());
  REQUIRE(e.half_depth[1].channels() == 1);
  // Half A holds passes 0, 2, 4 and half B passes 1, 3 (spp 1..5).
  auto weighted = [&](std::initializer_list<int> ks, auto value) {
    double s = 0, n = 0;
    for (int k : ks) {
      s += ps[k].spp * value(ps[k]);
      n += ps[k].spp;
    }
    return s / n;
  };
  auto alb = [](const Pass& p) { return static_cast<double>(p.albedo.at(2, 1, 2)); };
  auto dep = [](const Pass& p) { return static_cast<double>(p.depth.at(3, 2, 0)); };
  CHECK(e.half_albedo[0].at(2, 1, 2) == Approx(weighted({0, 2, 4}, alb)).epsilon(1e-6));
  CHECK(e.half_albedo[1].at(2, 1, 2) == Approx(weighted({1, 3}, alb)).epsilon(1e-6));
  CHECK(e.half_depth[1].at(3, 2, 0) == Approx(weighted({1, 3}, dep)).epsilon(1e-6));
  CHECK(e.albedo.at(2, 1, 2) == Approx(weighted({0, 1, 2, 3, 4}, alb)).epsilon(1e-6));
  // Variance of the feature mean over all 5 passes (spp-weighted, K - 1 = 4 dof).
  const double m = weighted({0, 1, 2, 3, 4}, dep);
  double m2 = 0, n = 0;
  for (const Pass& p : ps) {
    m2 += p.spp * (dep(p) - m) * (dep(p) - m);
    n += p.spp;
  }
  CHECK(e.depth_variance.at(3, 2, 0) == Approx(m2 / 4 / n).epsilon(1e-5));
  // No halves requested, or one pass only: no feature halves either.
  CHECK(f.estimate({.halves = false}).half_normal[0].empty());
  FrameAccumulator one;
  one.add(ps[0], "only");
  CHECK(one.estimate().half_albedo[0].empty());
}

TEST_CASE("quarters: each half split as a frame of only that half's passes would be",
          "[accumulator][quarters]") {
  Layout feats{true, true, true, false};
  FrameAccumulator f({.quarters = true});
  CHECK(f.quarters());
  std::vector<Pass> ps;
  for (int k = 0; k < 7; ++k) ps.push_back(test::make_pass(4, 3, 1 + k, 300 + k, feats));
  for (int k = 0; k < 3; ++k) f.add(ps[k], "p" + std::to_string(k));
  CHECK(f.estimate({.quarters = true}).quarter_mean[0].empty());  // 3 passes: quarter 3 empty
  for (int k = 3; k < 7; ++k) f.add(ps[k], "p" + std::to_string(k));
  const FrameEstimate e = f.estimate({.quarters = true});
  // Pass k: half k % 2, sub-half (k / 2) % 2; quarter 2 h + s. Half A = 0, 2, 4, 6 -> quarters
  // 0 = {0, 4}, 1 = {2, 6}; half B = 1, 3, 5 -> quarters 2 = {1, 5}, 3 = {3}.
  const std::initializer_list<int> members[4] = {{0, 4}, {2, 6}, {1, 5}, {3}};
  auto weighted = [&](std::initializer_list<int> ks, auto value) {
    double s = 0, n = 0;
    for (int k : ks) {
      s += ps[k].spp * value(ps[k]);
      n += ps[k].spp;
    }
    return std::pair{s / n, n};
  };
  // Per-sample variance pooled over all 7 passes (what Var[x] rests on), over the quarter's spp.
  const double sigma2 = e.variance.at(2, 1, 0) * (1 + 2 + 3 + 4 + 5 + 6 + 7);
  for (std::size_t q = 0; q < 4; ++q) {
    INFO("quarter " << q);
    REQUIRE_FALSE(e.quarter_mean[q].empty());
    const auto [col, n] =
        weighted(members[q], [](const Pass& p) { return double{p.colour.at(2, 1, 0)}; });
    CHECK(e.quarter_mean[q].at(2, 1, 0) == Approx(col).epsilon(1e-6));
    CHECK(e.quarter_variance[q].at(2, 1, 0) == Approx(sigma2 / n).epsilon(1e-5));
    const auto [alb, n2] =
        weighted(members[q], [](const Pass& p) { return double{p.albedo.at(1, 2, 1)}; });
    CHECK(e.quarter_albedo[q].at(1, 2, 1) == Approx(alb).epsilon(1e-6));
    const auto [dep, n3] =
        weighted(members[q], [](const Pass& p) { return double{p.depth.at(3, 0, 0)}; });
    CHECK(e.quarter_depth[q].at(3, 0, 0) == Approx(dep).epsilon(1e-6));
    CHECK_FALSE(e.quarter_normal[q].empty());
  }
  // Not asked for, or not kept: none. Keeping them costs 2 x (1 + 3 + 7) doubles per pixel.
  CHECK(f.estimate().quarter_mean[0].empty());
  FrameAccumulator plain;
  for (int k = 0; k < 7; ++k) plain.add(ps[k], "p" + std::to_string(k));
  CHECK(plain.estimate({.quarters = true}).quarter_mean[0].empty());
  CHECK(FrameAccumulator::bytes_per_pixel(feats, true) ==
        FrameAccumulator::bytes_per_pixel(feats) + 2 * 11 * 8);
  CHECK(f.state_bytes() == FrameAccumulator::bytes_per_pixel(feats, true) * 12);
  // The halves and the full frame are the same with or without quarters.
  const FrameEstimate ep = plain.estimate({.quarters = true});
  for (std::size_t i = 0; i < e.mean.data().size(); ++i) {
    CHECK(e.mean.data()[i] == ep.mean.data()[i]);
    CHECK(e.half_mean[1].data()[i] == ep.half_mean[1].data()[i]);
  }
}

TEST_CASE("a frame larger than add()'s blocks equals its rows accumulated alone, to the bit",
          "[accumulator][blocks]") {
  // add() works in parallel chunks of pixels and, within them, in blocks, one plane at a
  // time. A pixel's statistics depend on its own samples only (holes and
  // single-pass pixels aside, which borrow from neighbours and are kept out of this frame), so
  // every row accumulated as a frame of its own must give the same bits. 131 x 67 = 8777
  // pixels: more than one chunk, and neither a whole number of chunks nor of blocks.
  const int W = 131, H = 67;
  Layout all{true, true, true, true};
  std::vector<Pass> ps;
  for (int k = 0; k < 6; ++k) {
    Pass p = test::make_pass(W, H, 1 + k % 3, 500 + k, all);
    // Drops in some passes (no pixel loses all or all but one: checked below), and features
    // to sanitise.
    for (int i = 0; i < 40; ++i) {
      p.colour.plane(i % 3)[static_cast<std::size_t>((k * 997 + i * 211) % (W * H))] = NAN;
    }
    p.variance.plane(1)[static_cast<std::size_t>(k * 31 + 7)] = -1.0f;
    p.depth.plane(0)[static_cast<std::size_t>(k * 53 + 11)] = INFINITY;
    p.normal.plane(2)[static_cast<std::size_t>(k * 71 + 5)] = NAN;
    ps.push_back(std::move(p));
  }
  auto row_of = [&](const Pass& p, int y) {
    auto slice = [&](const Image& img) {
      if (img.empty()) return Image{};
      Image r(W, 1, img.channels());
      for (int c = 0; c < img.channels(); ++c) {
        for (int x = 0; x < W; ++x) r.plane(c)[static_cast<std::size_t>(x)] = img.at(x, y, c);
      }
      return r;
    };
    Pass r;
    r.spp = p.spp;
    r.colour = slice(p.colour);
    r.albedo = slice(p.albedo);
    r.normal = slice(p.normal);
    r.depth = slice(p.depth);
    r.variance = slice(p.variance);
    return r;
  };
  for (const bool variance : {true, false}) {
    INFO("renderer variance " << variance);
    FrameAccumulator whole({.quarters = true});
    std::size_t dropped = 0, sanitized = 0;
    for (std::size_t k = 0; k < ps.size(); ++k) {
      Pass p = ps[k];
      if (!variance) p.variance = Image{};
      const AddResult r = whole.add(p, std::to_string(k));
      dropped += r.dropped_pixels;
      sanitized += r.sanitized_features;
    }
    CHECK(dropped > 200);
    CHECK(sanitized == 12);
    const EstimateOptions opts{.quarters = true};
    const FrameEstimate e = whole.estimate(opts);
    REQUIRE(e.hole_pixels == 0);
    REQUIRE(e.spatial_pixels == 0);
    REQUIRE_FALSE(e.quarter_mean[3].empty());
    std::size_t compared = 0, row_dropped = 0;
    for (int y = 0; y < H; ++y) {
      FrameAccumulator row({.quarters = true});
      for (std::size_t k = 0; k < ps.size(); ++k) {
        Pass p = row_of(ps[k], y);
        if (!variance) p.variance = Image{};
        row_dropped += row.add(p, std::to_string(k)).dropped_pixels;
      }
      const FrameEstimate r = row.estimate(opts);
      auto same = [&](const Image& a, const Image& b, const char* what) {
        REQUIRE(a.channels() == b.channels());
        for (int c = 0; c < a.channels(); ++c) {
          for (int x = 0; x < W; ++x) {
            const float u = a.at(x, y, c), v = b.at(x, 0, c);
            if (std::memcmp(&u, &v, sizeof u) != 0) {
              FAIL(what << " differs at (" << x << ", " << y << ", " << c << "): " << u << " vs "
                        << v);
            }
            ++compared;
          }
        }
      };
      same(e.mean, r.mean, "mean");
      same(e.variance, r.variance, "variance");
      same(e.passes, r.passes, "passes");
      same(e.albedo, r.albedo, "albedo");
      same(e.normal_variance, r.normal_variance, "normal variance");
      same(e.depth, r.depth, "depth");
      for (std::size_t h = 0; h < 2; ++h) {
        same(e.half_mean[h], r.half_mean[h], "half mean");
        same(e.half_variance[h], r.half_variance[h], "half variance");
        same(e.half_albedo[h], r.half_albedo[h], "half albedo");
      }
      for (std::size_t q = 0; q < 4; ++q) {
        same(e.quarter_mean[q], r.quarter_mean[q], "quarter mean");
        same(e.quarter_normal[q], r.quarter_normal[q], "quarter normal");
      }
    }
    CHECK(row_dropped == dropped);
    CHECK(compared == static_cast<std::size_t>(W) * H * (3 + 3 + 1 + 3 + 3 + 1 + 2 * 9 + 4 * 6));
  }
}

TEST_CASE("NaN/Inf samples are dropped per pixel and counted, never reaching the mean",
          "[accumulator][nonfinite]") {
  FrameAccumulator f;
  Pass a = constant_pass(4, 4, 1, 1, 1, 1);
  Pass b = constant_pass(4, 4, 1, 3, 3, 3);
  Pass c = constant_pass(4, 4, 1, 2, 2, 2);
  c.colour.at(1, 1, 0) = std::numeric_limits<float>::quiet_NaN();
  c.colour.at(2, 3, 2) = std::numeric_limits<float>::infinity();
  f.add(a, "a");
  f.add(b, "b");
  const AddResult r = f.add(c, "c");
  CHECK(r.dropped_pixels == 2);
  CHECK(f.dropped_samples() == 2);
  const FrameEstimate e = f.estimate();
  for (int ch = 0; ch < 3; ++ch) {
    CHECK(e.mean.at(1, 1, ch) == Approx(2.0));  // (1 + 3) / 2: the whole pixel sample dropped
    CHECK(e.mean.at(0, 0, ch) == Approx(2.0));  // (1 + 3 + 2) / 3
    CHECK(std::isfinite(e.variance.at(1, 1, ch)));
  }
  CHECK(e.passes.at(1, 1, 0) == 2.0f);
  CHECK(e.passes.at(2, 3, 0) == 2.0f);
  CHECK(e.passes.at(0, 0, 0) == 3.0f);
  CHECK(e.variance.at(1, 1, 0) == Approx(2.0 / 2));  // s^2 = 2, K = 2
}

TEST_CASE("a pixel every pass dropped is a flagged hole filled from its neighbours",
          "[accumulator][nonfinite]") {
  FrameAccumulator f;
  for (int k = 0; k < 2; ++k) {
    Pass p = constant_pass(3, 3, 1, 1.0f + static_cast<float>(k), 1, 1);
    p.colour.at(1, 1, 1) = std::numeric_limits<float>::quiet_NaN();
    f.add(p, "p" + std::to_string(k));
  }
  const FrameEstimate e = f.estimate();
  CHECK(e.hole_pixels == 1);
  CHECK(e.low_confidence());
  CHECK(e.mean.at(1, 1, 0) == Approx(1.5));
  CHECK(std::isfinite(e.variance.at(1, 1, 0)));
}

TEST_CASE("a half without a sample at a pixel falls back to the frame's estimate there",
          "[accumulator][nonfinite]") {
  // Passes a, c go to half A, b, d to half B. Pixel (1, 1): half B's passes dropped it (A has
  // two samples). Pixel (2, 2): both of half A's dropped it, one sample left: a spatial pixel.
  // Pixel (0, 3): every pass dropped it, a hole.
  FrameAccumulator f;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float value[4] = {1, 3, 2, 5};
  for (int k = 0; k < 4; ++k) {
    Pass p = constant_pass(4, 4, 1, value[k], value[k] + 1, value[k] + 2);
    p.colour.at(1, 1, 0) = p.colour.at(0, 0, 0) + 0.25f * static_cast<float>(k);
    if (k % 2 == 1) p.colour.at(1, 1, 1) = nan;
    if (k % 2 == 0) p.colour.at(2, 2, 2) = nan;
    if (k == 3) p.colour.at(2, 2, 0) = nan;
    p.colour.at(0, 3, 0) = nan;
    f.add(p, "p" + std::to_string(k));
  }
  const FrameEstimate e = f.estimate();
  REQUIRE(!e.half_mean[0].empty());
  CHECK(e.hole_pixels == 1);
  CHECK(e.spatial_pixels == 2);  // the hole and (2, 2)
  for (int c = 0; c < 3; ++c) {
    // (1, 1): half A keeps its own two samples, half B is the frame's (= half A's) estimate.
    CHECK(e.half_mean[0].at(1, 1, c) == e.mean.at(1, 1, c));
    CHECK(e.half_mean[1].at(1, 1, c) == e.mean.at(1, 1, c));
    CHECK(e.half_variance[1].at(1, 1, c) == e.variance.at(1, 1, c));
    CHECK(e.half_variance[0].at(1, 1, c) == Approx(e.variance.at(1, 1, c)));
    // (2, 2): half A has no sample, half B's one sample is the frame's; both carry the
    // spatial variance (half B's as sigma^2 N / N_B with N_B = N).
    CHECK(e.half_mean[0].at(2, 2, c) == e.mean.at(2, 2, c));
    CHECK(e.half_variance[0].at(2, 2, c) == e.variance.at(2, 2, c));
    CHECK(e.half_mean[1].at(2, 2, c) == e.mean.at(2, 2, c));
    CHECK(e.half_variance[1].at(2, 2, c) == Approx(e.variance.at(2, 2, c)));
    CHECK(e.variance.at(2, 2, c) > 0.0f);
    // The hole: both halves are the filled mean and its spatial variance.
    for (int h = 0; h < 2; ++h) {
      CHECK(e.half_mean[h].at(0, 3, c) == e.mean.at(0, 3, c));
      CHECK(e.half_variance[h].at(0, 3, c) == e.variance.at(0, 3, c));
    }
  }
  // A pixel every pass kept: each half's own mean of its two passes, Var = 2 x the frame's.
  CHECK(e.half_mean[0].at(3, 0, 0) == Approx(1.5));
  CHECK(e.half_mean[1].at(3, 0, 0) == Approx(4.0));
  CHECK(e.mean.at(3, 0, 0) == Approx(2.75));
}

TEST_CASE("non-finite feature values are sanitised, colour kept", "[accumulator][nonfinite]") {
  Layout l{false, false, true, false};
  Pass p = test::make_pass(2, 2, 1, 1, l);
  p.depth.at(0, 0, 0) = std::numeric_limits<float>::infinity();
  FrameAccumulator f;
  const AddResult r = f.add(p, "p");
  CHECK(r.dropped_pixels == 0);
  CHECK(r.sanitized_features == 1);
  CHECK(f.estimate().depth.at(0, 0, 0) == Approx(1e10));
}

TEST_CASE("a single pass falls back to a spatial variance and flags low confidence",
          "[accumulator][fallback]") {
  FrameAccumulator f;
  f.add(test::make_pass(16, 16, 4, 3), "only");
  const FrameEstimate e = f.estimate();
  CHECK(e.variance_source == VarianceSource::spatial);
  CHECK(e.low_confidence());
  CHECK(e.spatial_pixels == 256);
  CHECK(e.half_mean[0].empty());
  for (float v : e.variance.data()) {
    CHECK(std::isfinite(v));
    CHECK(v >= 0.0f);
  }
  // 1x1 frame: no neighbours, 100 % relative error is assumed.
  FrameAccumulator one;
  one.add(constant_pass(1, 1, 1, 2, 0, 0.5f), "px");
  const FrameEstimate e1 = one.estimate();
  CHECK(e1.variance.at(0, 0, 0) == Approx(4.0));
  CHECK(e1.variance.at(0, 0, 1) == 0.0f);
}

TEST_CASE("1e6 dynamic range: Welford keeps the variance exact", "[accumulator][range]") {
  // Fireflies of ~1e6 next to values ~1e-2 and ~1e-8.
  const std::vector<double> bright = {1e6, 1e6 + 3, 1e6 - 1, 1e6 + 0.5};
  const std::vector<double> dark = {1e-8, 3e-8, 2e-8, 0.5e-8};
  FrameAccumulator f;
  for (std::size_t k = 0; k < bright.size(); ++k) {
    Pass p = constant_pass(2, 1, 1, 0.01f, 0.01f, 0.01f);
    p.colour.at(0, 0, 0) = static_cast<float>(bright[k]);
    p.colour.at(1, 0, 0) = static_cast<float>(dark[k]);
    p.colour.at(1, 0, 1) = 0.01f * static_cast<float>(k);
    f.add(p, "p" + std::to_string(k));
  }
  std::vector<double> bf, df;
  for (double v : bright) bf.push_back(static_cast<float>(v));
  for (double v : dark) df.push_back(static_cast<float>(v));
  const std::vector<double> ones(4, 1.0);
  const FrameEstimate e = f.estimate();
  CHECK(e.variance.at(0, 0, 0) == Approx(direct(bf, ones).var).epsilon(1e-5));
  CHECK(e.variance.at(1, 0, 0) == Approx(direct(df, ones).var).epsilon(1e-5));
  CHECK(e.mean.at(1, 0, 0) == Approx(direct(df, ones).mean).epsilon(1e-6));
  CHECK(e.variance.at(0, 0, 1) == 0.0f);  // constant 0.01 across passes
}

TEST_CASE("identical passes are refused but constant frames are not", "[accumulator][duplicate]") {
  FrameAccumulator f;
  const Pass p = test::make_pass(8, 8, 4, 11);
  f.add(p, "first.exr");
  f.add(test::make_pass(8, 8, 4, 12), "second.exr");
  const auto before = f.state_digest();
  try {
    f.add(p, "again.exr");
    FAIL("duplicate accepted");
  } catch (const InputError& e) {
    CHECK(e.kind() == InputErrorKind::duplicate);
    CHECK_THAT(e.what(), Contains("again.exr") && Contains("first.exr"));
  }
  CHECK(f.state_digest() == before);
  CHECK(f.passes() == 2);

  FrameAccumulator black;
  black.add(constant_pass(4, 4, 1, 0, 0, 0), "b0");
  black.add(constant_pass(4, 4, 1, 0, 0, 0), "b1");
  const FrameEstimate e = black.estimate();
  CHECK(black.passes() == 2);
  CHECK(e.variance.at(2, 2, 1) == 0.0f);
  CHECK_FALSE(e.low_confidence());
}

TEST_CASE("size, layout and spp mismatches are refused and leave the state unchanged",
          "[accumulator][bad-input]") {
  FrameAccumulator f;
  f.add(test::make_pass(8, 8, 4, 1), "a");
  f.add(test::make_pass(8, 8, 4, 2), "b");
  const auto before = f.state_digest();
  auto expect = [&](const Pass& p, InputErrorKind kind, const char* what) {
    try {
      f.add(p, "bad.exr");
      FAIL("accepted a bad pass: " << what);
    } catch (const InputError& e) {
      CHECK(e.kind() == kind);
      CHECK_THAT(e.what(), Contains("bad.exr") && Contains(what));
    }
    CHECK(f.state_digest() == before);
    CHECK(f.passes() == 2);
  };
  expect(test::make_pass(8, 7, 4, 3), InputErrorKind::size_mismatch, "8x7");
  expect(test::make_pass(8, 8, 4, 4, Layout{true, true, false, false}),
         InputErrorKind::layout_mismatch, "HDR+ALB+NRM");
  expect(test::make_pass(8, 8, 0, 5), InputErrorKind::invalid_value, "samples per pixel");
  Pass nan_spp = test::make_pass(8, 8, 1, 6);
  nan_spp.spp = std::numeric_limits<double>::quiet_NaN();
  expect(nan_spp, InputErrorKind::invalid_value, "samples per pixel");
  Pass two = test::make_pass(8, 8, 1, 7);
  two.colour = Image(8, 8, 2);
  expect(two, InputErrorKind::missing_channels, "RGB");
}

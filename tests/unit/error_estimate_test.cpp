// estimate_error(): the error object's point estimates against known truth, its intervals (they
// cover the truth, widen with fewer passes and with frame-wide noise, are unbounded for one
// pass), the equivalent spp, the target tests, and bad inputs.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>
#include <random>

#include "proden/accumulator.hpp"
#include "proden/error_estimate.hpp"
#include "proden/metrics.hpp"
#include "proden/progressive.hpp"

using namespace proden;

namespace {

Image smooth_truth(int w, int h) {
  Image t(w, h, 3);
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        t.at(x, y, c) = 0.3f + 0.5f * static_cast<float>(x) / static_cast<float>(w) +
                        (y > h / 2 ? 0.4f : 0.0f) + 0.1f * static_cast<float>(c);
      }
    }
  }
  return t;
}

// K passes of truth + N(0, sigma^2) per pixel (independent pixels), accumulated for real.
FrameEstimate accumulate(const Image& truth, int passes, float sigma, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> n(0.0f, sigma);
  FrameAccumulator acc;
  for (int k = 0; k < passes; ++k) {
    Pass p;
    p.spp = 4;
    p.colour = truth;
    for (auto& v : p.colour.data()) v += n(rng);
    acc.add(p, "p" + std::to_string(k));
  }
  return acc.estimate({.halves = false, .features = false});
}

// z = x + a (y - x) with y = the truth (a perfect denoiser that ignores x: div = 0, so
// SURE(y) = (y - x)^2 - Var[x]); a constant alpha.
struct Mixed {
  Image y, alpha, sure, z;
};
Mixed mix_with_truth(const FrameEstimate& f, const Image& truth, float a) {
  Mixed m{truth, Image(truth.width(), truth.height(), 3, a),
          Image(truth.width(), truth.height(), 3), Image(truth.width(), truth.height(), 3)};
  for (std::size_t i = 0; i < truth.data().size(); ++i) {
    const float x = f.mean.data()[i], v = f.variance.data()[i], d = truth.data()[i] - x;
    m.sure.data()[i] = d * d - v;
    m.z.data()[i] = x + a * d;
  }
  return m;
}

// A textured truth (a product of sines) for the cross-validation tests.
Image textured_truth(int w, int h) {
  Image truth(w, h, 3);
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        truth.at(x, y, c) =
            0.5f +
            0.3f * std::sin(0.9f * static_cast<float>(x)) * std::cos(0.7f * static_cast<float>(y)) +
            0.05f * static_cast<float>(c);
  return truth;
}

// A pass of `spp` around the truth with Gaussian noise, whose albedo is its own noisy colour (the
// features carry the colour's noise, as the paths' first hits do).
Pass noisy_pass(const Image& truth, std::mt19937_64& rng, float sigma, double spp) {
  std::normal_distribution<float> n(0.0f, sigma);
  Pass p;
  p.spp = spp;
  p.colour = truth;
  for (auto& v : p.colour.data()) v += n(rng);
  p.albedo = p.colour;
  return p;
}

// The cross-validated estimate of a run brackets the true MSE (from truth / sqrt(2) to 2x), where
// the same terms from SURE fall below it; returns the SURE-only estimate.
EstimatedError check_cross_validated(const PipelineResult& r, const Image& truth,
                                     const ErrorContext& ctx) {
  const double truth_mse = compute_metrics(r.result, truth).mse;
  const EstimatedError sure_only =
      estimate_error({&r.render, &r.variance, &r.result, &r.denoised, &r.alpha, &r.sure}, ctx);
  INFO("true " << truth_mse << " cross-validated " << r.estimated_error.mse << " SURE "
               << sure_only.mse);
  CHECK(r.estimated_error.mse >= truth_mse / std::sqrt(2.0));
  CHECK(r.estimated_error.mse <= truth_mse * 2.0);
  CHECK(sure_only.mse < truth_mse / std::sqrt(2.0));
  return sure_only;
}

}  // namespace

TEST_CASE("estimate_error: the plain render is worth its own spp", "[error_estimate]") {
  const Image truth = smooth_truth(64, 64);
  const FrameEstimate f = accumulate(truth, 8, 0.1f, 1);
  ErrorContext ctx{.spp = 32, .passes = 8, .noise_scope = NoiseScope::pixel};
  const EstimatedError e = estimate_error({&f.mean, &f.variance, &f.mean}, ctx);
  double mean_var = 0;
  for (float v : f.variance.data()) mean_var += v;
  mean_var /= static_cast<double>(f.variance.data().size());
  CHECK(e.mse == Approx(mean_var).epsilon(1e-9));
  CHECK(e.relmse == Approx(e.render_relmse).epsilon(1e-12));
  CHECK(e.equivalent_spp == Approx(32.0).epsilon(1e-12));
  CHECK(e.source == "variance");
  REQUIRE(e.dof);
  CHECK(*e.dof == Approx(7.0 * 64 * 64 / 4.0));
  REQUIRE(e.mse_high);
  CHECK(e.mse_low < e.mse);
  CHECK(*e.mse_high > e.mse);
  // The true MSE of the render (sigma^2 / 8 passes) lies inside the statistical interval (the
  // model band divided out: this frame has no stand-in, no shared part, no bracket).
  const double truth_mse = compute_metrics(f.mean, truth).mse;
  CHECK(e.mse_low * e.model_band <= truth_mse);
  CHECK(*e.mse_high / e.model_band >= truth_mse);
}

TEST_CASE("estimate_error: unbiased against the truth, intervals cover it", "[error_estimate]") {
  const Image truth = smooth_truth(96, 96);
  for (std::uint64_t seed = 1; seed <= 5; ++seed) {
    const FrameEstimate f = accumulate(truth, 6, 0.2f, seed);
    const Mixed m = mix_with_truth(f, truth, 0.6f);
    ErrorContext ctx{.spp = 24, .passes = 6, .noise_scope = NoiseScope::pixel};
    const EstimatedError e =
        estimate_error({&f.mean, &f.variance, &m.z, &m.y, &m.alpha, &m.sure}, ctx);
    const double truth_mse = compute_metrics(m.z, truth).mse;
    INFO("seed " << seed << " est " << e.mse << " true " << truth_mse);
    CHECK(e.source == "variance+sure");
    CHECK(e.mse == Approx(truth_mse).epsilon(0.1));
    REQUIRE(e.mse_high);
    CHECK(e.mse_low * e.model_band <= truth_mse);  // the statistical interval covers it
    CHECK(*e.mse_high / e.model_band >= truth_mse);
    // z's error is (1-a)^2 of the render's: the denoised frame is worth ~1/0.16 the samples.
    CHECK(e.equivalent_spp == Approx(24.0 / (0.4 * 0.4)).epsilon(0.15));
    CHECK(e.equivalent_spp_low <= e.equivalent_spp);
    REQUIRE(e.equivalent_spp_high);
    CHECK(*e.equivalent_spp_high >= e.equivalent_spp);
  }
}

TEST_CASE("estimate_error: the pipeline's result error, SURE of z", "[error_estimate]") {
  const Image truth = smooth_truth(48, 40);
  const FrameEstimate f = accumulate(truth, 4, 0.15f, 9);
  PipelineOptions o;
  o.features = false;
  Pipeline p(o);
  p.commit();
  ErrorContext ctx{.spp = 16, .passes = 4, .noise_scope = NoiseScope::pixel};
  const PipelineResult r = p.execute(f, ctx);
  // The documented formula, computed here independently: mean of
  // (1-a) v + a SURE - a (1-a) (y-x)^2, floored at mean (1-a)^2 v.
  double sum = 0, floor = 0;
  for (std::size_t i = 0; i < f.mean.data().size(); ++i) {
    const double a = r.alpha.data()[i], v = f.variance.data()[i];
    const double d = static_cast<double>(r.denoised.data()[i]) - f.mean.data()[i];
    sum += (1 - a) * v + a * r.sure.data()[i] - a * (1 - a) * d * d;
    floor += (1 - a) * (1 - a) * v;
  }
  const double n = static_cast<double>(f.mean.data().size());
  CHECK(r.estimated_error.mse == Approx(std::max(sum, floor) / n).epsilon(1e-9));
  CHECK(r.estimated_error.spp == 16.0);
  CHECK(r.estimated_error.source == "variance+sure");
  // execute() and a direct call agree.
  const EstimatedError e =
      estimate_error({&f.mean, &f.variance, &r.result, &r.denoised, &r.alpha, &r.sure}, ctx);
  CHECK(e.relmse == Approx(r.estimated_error.relmse).epsilon(1e-12));
  // The same terms from a SURE known to be biased low: the point values stay, the bounds go.
  REQUIRE(e.relmse_high);
  REQUIRE(e.equivalent_spp_low > 0);
  ErrorInputs low{&f.mean, &f.variance, &r.result, &r.denoised, &r.alpha, &r.sure};
  low.sure_unbounded = true;
  const EstimatedError u = estimate_error(low, ctx);
  CHECK(u.relmse == e.relmse);
  CHECK(u.relmse_low == e.relmse_low);
  CHECK_FALSE(u.relmse_high);
  CHECK_FALSE(u.mse_high);
  CHECK(u.equivalent_spp_low == 0);
}

TEST_CASE("estimate_error: fewer passes and frame-wide noise widen the interval",
          "[error_estimate]") {
  const Image truth = smooth_truth(64, 64);
  auto width = [&](int passes, NoiseScope scope) {
    const FrameEstimate f = accumulate(truth, passes, 0.1f, 3);
    const Mixed m = mix_with_truth(f, truth, 0.5f);
    ErrorContext ctx{.spp = 4.0 * passes, .passes = passes, .noise_scope = scope};
    const EstimatedError e =
        estimate_error({&f.mean, &f.variance, &m.z, &m.y, &m.alpha, &m.sure}, ctx);
    REQUIRE(e.relmse_high);
    return *e.relmse_high / e.relmse_low / (e.model_band * e.model_band);  // the statistics'
  };
  const double frame4 = width(4, NoiseScope::frame), frame16 = width(16, NoiseScope::frame);
  const double pixel4 = width(4, NoiseScope::pixel);
  CHECK(frame4 > frame16);
  CHECK(frame16 > pixel4);
  CHECK(frame4 > 10.0);  // 3 dof: the variance scale is known to a factor ~ 14
  CHECK(pixel4 < 1.3);   // 3 x 1024 dof, 12288 pixel terms
}

TEST_CASE("estimate_error: the model band widens both ends of a narrow interval",
          "[error_estimate]") {
  // 16 Cycles-like passes at 64x64: the statistics alone pin relMSE to a few per cent, so the
  // ends sit at least kModelBand from the value only because of the band.
  const Image truth = smooth_truth(64, 64);
  const FrameEstimate f = accumulate(truth, 16, 0.1f, 3);
  const Mixed m = mix_with_truth(f, truth, 0.5f);
  ErrorContext ctx{.spp = 64, .passes = 16, .noise_scope = NoiseScope::pixel};
  const EstimatedError e =
      estimate_error({&f.mean, &f.variance, &m.z, &m.y, &m.alpha, &m.sure}, ctx);
  CHECK(e.model_band == kModelBand);
  REQUIRE(e.relmse_high);
  REQUIRE(e.mse_high);
  REQUIRE(e.equivalent_spp_high);
  INFO("relmse " << e.relmse << " [" << e.relmse_low << ", " << *e.relmse_high << "]");
  CHECK(*e.relmse_high / e.relmse < 1.1 * kModelBand);  // the statistical part is small here
  CHECK(*e.relmse_high >= kModelBand * e.relmse);
  CHECK(e.relmse_low <= e.relmse / kModelBand);
  CHECK(*e.mse_high >= kModelBand * e.mse);
  CHECK(e.mse_low <= e.mse / kModelBand);
  CHECK(e.equivalent_spp_low <= e.equivalent_spp / kModelBand);
  CHECK(*e.equivalent_spp_high >= kModelBand * e.equivalent_spp);
}

TEST_CASE("estimate_error: one pass (spatial variance) has no upper bound", "[error_estimate]") {
  const Image truth = smooth_truth(32, 32);
  const FrameEstimate f = accumulate(truth, 1, 0.1f, 4);
  REQUIRE(f.variance_source == VarianceSource::spatial);
  ErrorContext ctx{.spp = 4,
                   .passes = 1,
                   .variance_source = VarianceSource::spatial,
                   .noise_scope = NoiseScope::pixel};
  const EstimatedError e = estimate_error({&f.mean, &f.variance, &f.mean}, ctx);
  CHECK_FALSE(e.mse_high);
  CHECK_FALSE(e.relmse_high);
  CHECK_FALSE(e.dof);
  CHECK_FALSE(meets_relmse(e, 1e9));  // never "good enough" on a guess
  CHECK(e.relmse_low >= 0.0);
}

TEST_CASE("estimate_error: target tests use the conservative end", "[error_estimate]") {
  EstimatedError e;
  e.relmse = 1e-3;
  e.relmse_low = 0.8e-3;
  e.relmse_high = 1.3e-3;
  e.equivalent_spp = 1000;
  e.equivalent_spp_low = 800;
  e.equivalent_spp_high = 1300;
  CHECK(meets_relmse(e, 1.3e-3));
  CHECK_FALSE(meets_relmse(e, 1.2e-3));  // the point estimate meets it, the bound does not
  CHECK(meets_equivalent_spp(e, 800));
  CHECK_FALSE(meets_equivalent_spp(e, 900));
  CHECK(misses_relmse(e, 0.7e-3));
  CHECK_FALSE(misses_relmse(e, 0.9e-3));  // within the interval: neither
  CHECK(misses_equivalent_spp(e, 1400));
  CHECK_FALSE(misses_equivalent_spp(e, 1200));
}

TEST_CASE("estimate_error: a noise-free frame is exact", "[error_estimate]") {
  const Image flat(16, 16, 3, 0.5f), zero(16, 16, 3, 0.0f);
  ErrorContext ctx{.spp = 8, .passes = 2, .noise_scope = NoiseScope::pixel};
  const EstimatedError e = estimate_error({&flat, &zero, &flat}, ctx);
  CHECK(e.mse == 0.0);
  CHECK(e.relmse == 0.0);
  CHECK(std::isinf(e.equivalent_spp));
  CHECK(meets_equivalent_spp(e, 1e6));
  CHECK(meets_relmse(e, 1e-12));
}

TEST_CASE("estimate_error: refuses missing or mismatched images", "[error_estimate]") {
  const Image a(16, 16, 3), b(8, 8, 3), mono(16, 16, 1);
  ErrorContext ctx{.spp = 4, .passes = 2};
  CHECK_THROWS_AS(estimate_error({&a, &b, &a}, ctx), std::invalid_argument);
  CHECK_THROWS_AS(estimate_error({&a, &mono, &a}, ctx), std::invalid_argument);
  CHECK_THROWS_AS(estimate_error({&a, &a, nullptr}, ctx), std::invalid_argument);
  CHECK_THROWS_AS(estimate_error({&a, &a, &a, &a, nullptr, &a}, ctx), std::invalid_argument);
  ctx.confidence = 1.0;
  CHECK_THROWS_AS(estimate_error({&a, &a, &a}, ctx), std::invalid_argument);
}

TEST_CASE("estimate_error: a negative mean SURE bounds nothing from above", "[error_estimate]") {
  // SURE far below zero (e.g. HDR-only input, issue 13) with alpha ~ 1: the terms average below 0.
  const Image truth = smooth_truth(32, 32);
  const FrameEstimate f = accumulate(truth, 8, 0.1f, 5);
  Mixed m = mix_with_truth(f, truth, 0.98f);
  for (auto& s : m.sure.data()) s = -std::abs(s) - 0.05f;
  ErrorContext ctx{.spp = 32, .passes = 8, .noise_scope = NoiseScope::pixel};
  const EstimatedError e =
      estimate_error({&f.mean, &f.variance, &m.z, &m.y, &m.alpha, &m.sure}, ctx);
  CHECK_FALSE(e.consistent);
  CHECK_FALSE(e.mse_high);
  CHECK_FALSE(e.relmse_high);
  CHECK(e.equivalent_spp_low == 0.0);
  CHECK_FALSE(meets_relmse(e, 1.0));
  CHECK_FALSE(meets_equivalent_spp(e, 1.0));
  CHECK(e.mse > 0.0);  // the floor
}

// Issue 13: relMSE divides by ref^2 + 0.01, and the frame has no reference. With the noisy result
// as the stand-in, a dark frame's noisy pixels (z^2 >> ref^2) got small weights and relMSE came
// out ~0.5x the truth (toward "done"); the local mean less its noise is unbiased up to blur.
TEST_CASE("estimate_error: relMSE of a dark noisy frame is not biased low by its own noise",
          "[error_estimate]") {
  const int W = 96, H = 96;
  const float ref = 0.02f, sigma = 0.1f;  // noise 5x the signal: a dark corner at low spp
  Image x(W, H, 3), v(W, H, 3, sigma * sigma);
  std::mt19937_64 rng(13);
  std::normal_distribution<float> n(0.0f, sigma);
  for (auto& p : x.data()) p = ref + n(rng);
  double truth = 0;
  for (const float p : x.data()) truth += (p - ref) * (p - ref) / (ref * ref + 0.01);
  truth /= static_cast<double>(x.data().size());
  ErrorContext ctx{.spp = 8, .passes = 8, .noise_scope = NoiseScope::pixel};
  const EstimatedError e = estimate_error({&x, &v, &x}, ctx);
  INFO("est " << e.relmse << " true " << truth);
  CHECK(e.relmse / truth > 0.8);
  CHECK(e.relmse / truth < 1.25);
}

// A caustic at low spp: a bright level (ref 1) made of rare large samples (2 % of the samples,
// value 50), 8 passes of 1 spp. A 7x7 window holds ~8 firefly samples, and its noise estimate,
// theirs too, often exceeds its mean's square (more so as these pixels are independent, where
// the correction assumes 4 pixels per draw); the stand-in fell to 0 there (weight 100 for a
// reference of 1), and the estimate came out 7.0x the truth. Floored at the window's mean
// without its largest value it is 1.95x: still high (toward "not done"), never low.
TEST_CASE(
    "estimate_error: fireflies on a bright level do not make a render-only frame's relMSE "
    "explode",
    "[error_estimate]") {
  const int W = 96, H = 96;
  const float F = 50.0f, p = 0.02f;  // ref = p F = 1
  std::mt19937_64 rng(31);
  std::bernoulli_distribution firefly(p);
  FrameAccumulator acc;
  for (int k = 0; k < 8; ++k) {
    Pass pass;
    pass.spp = 1;
    pass.colour = Image(W, H, 3);
    for (auto& v : pass.colour.data()) v = firefly(rng) ? F : 0.0f;
    acc.add(pass, "p" + std::to_string(k));
  }
  const FrameEstimate f = acc.estimate({.halves = false, .features = false});
  double truth = 0;
  for (const float v : f.mean.data()) truth += (v - 1.0) * (v - 1.0) / 1.01;
  truth /= static_cast<double>(f.mean.data().size());
  ErrorContext ctx{.spp = 8, .passes = 8, .noise_scope = NoiseScope::pixel};
  const EstimatedError e = estimate_error({&f.mean, &f.variance, &f.mean}, ctx);
  INFO("est " << e.relmse << " true " << truth);
  CHECK(e.relmse / truth > 0.67);
  CHECK(e.relmse / truth < 3.0);
}

TEST_CASE(
    "estimate_error: cross-validation measures what SURE misses when the features carry "
    "the colour's noise",
    "[error_estimate][cross_validation]") {
  // A textured truth; each pass's albedo is its colour's own noisy sample (the paths the colour
  // took), so NL-means' feature weights follow the colour noise, which SURE's colour-only
  // divergence does not see (here SURE's mean falls to the floor, ~0). The cross-validated
  // estimate must not say the frame is better than it is by more than the kHalfToFullMse
  // bracket (>= truth / sqrt(2)). Above, this extreme case (the albedo *is* the colour) is not
  // bracketed: the half run's feature weights keep the full frame's bandwidth
  // (docs/error_estimate.md) and reject more, so the estimate errs high (1.7x), toward "not
  // done"; it must stay within 2x.
  const int W = 96, H = 96;
  const Image truth = textured_truth(W, H);
  std::mt19937_64 rng(17);
  FrameAccumulator acc;
  for (int k = 0; k < 8; ++k) {
    acc.add(noisy_pass(truth, rng, 0.25f, 2), "p" + std::to_string(k));
  }
  PipelineOptions o;
  Pipeline pipe(o);
  pipe.commit();
  ErrorContext ctx{.spp = 16, .passes = 8, .noise_scope = NoiseScope::pixel};
  const PipelineResult r = pipe.execute(acc.estimate(pipe.estimate_options()), ctx);
  REQUIRE(r.estimated_error.source == "variance+cross-validation");
  REQUIRE_FALSE(r.cv_square.empty());
  const EstimatedError sure_only = check_cross_validated(r, truth, ctx);
}

TEST_CASE("estimate_error: NFOR, which reads the halves, is cross-validated on their quarters",
          "[error_estimate][cross_validation][nfor]") {
  // The same frame as above (the albedo is the colour's own noisy sample), under NFOR: its SURE
  // (the hat diagonal with the weights held fixed) misses the noise the features and the
  // cross-filtered weights carry. Run on one half with that half's sub-halves as its halves
  // (docs/error_estimate.md), NFOR's cross-validated error must bracket the truth as NL-means'
  // does; without quarters (fewer than 4 passes, or a state that keeps none) the estimate says
  // it fell back to SURE.
  const int W = 96, H = 96;
  const Image truth = textured_truth(W, H);
  std::mt19937_64 rng(23);
  PipelineOptions o;
  o.denoiser = "nfor";
  Pipeline pipe(o);
  pipe.commit();
  REQUIRE(pipe.estimate_options().quarters);
  FrameAccumulator acc({.quarters = pipe.estimate_options().quarters}), plain;
  for (int k = 0; k < 8; ++k) {
    const Pass p = noisy_pass(truth, rng, 0.25f, 2);
    acc.add(p, "p" + std::to_string(k));
    plain.add(p, "p" + std::to_string(k));
  }
  ErrorContext ctx{.spp = 16, .passes = 8, .noise_scope = NoiseScope::pixel};
  const FrameEstimate est = acc.estimate(pipe.estimate_options());
  const PipelineResult r = pipe.execute(est, ctx);
  REQUIRE(r.estimated_error.source == "variance+cross-validation");
  const EstimatedError sure_only = check_cross_validated(r, truth, ctx);

  // The half runs read the quarters: with each half's sub-halves replaced by the half itself
  // (no independent split), the cross-validated terms change.
  FrameEstimate flat = acc.estimate(pipe.estimate_options());
  for (std::size_t q = 0; q < 4; ++q) {
    flat.quarter_mean[q] = flat.half_mean[q / 2];
    flat.quarter_albedo[q] = flat.half_albedo[q / 2];
  }
  const PipelineResult rf = pipe.execute(flat, ctx);
  REQUIRE(rf.estimated_error.source == "variance+cross-validation");
  CHECK(rf.estimated_error.mse != r.estimated_error.mse);
  // The published frame does not depend on the error estimate.
  CHECK(rf.result.data()[W * H / 2] == r.result.data()[W * H / 2]);

  // Cross-validated, it is bounded and can meet a target it truly meets.
  REQUIRE(r.estimated_error.relmse_high);
  CHECK(r.estimated_error.equivalent_spp_low > 0);
  CHECK(meets_relmse(r.estimated_error, 10 * *r.estimated_error.relmse_high));
  // No quarters (a state saved without them; fewer than 4 passes): the half runs get no halves
  // and NFOR runs its single-buffer mode, another filter (docs/error_estimate.md), still
  // cross-validated.
  const PipelineResult rp = pipe.execute(plain.estimate(pipe.estimate_options()), ctx);
  CHECK(rp.estimated_error.source == "variance+cross-validation");
  CHECK(rp.estimated_error.mse != r.estimated_error.mse);
  CHECK(rp.result.data()[W * H / 2] == r.result.data()[W * H / 2]);
  // One pass with the renderer's own variance: no halves, so SURE, which for NFOR is known to
  // be biased low: it bounds nothing from above, so no target is ever met on it.
  FrameAccumulator one({.quarters = true});
  Pass p = noisy_pass(truth, rng, 0.25f * 0.25f, 16);
  p.variance = Image(W, H, 3, 0.25f * 0.25f * 0.0625f);
  one.add(p, "one");
  ctx.passes = 1;
  const FrameEstimate e1 = one.estimate(pipe.estimate_options());
  REQUIRE(e1.variance_source == VarianceSource::renderer);
  ctx.variance_source = e1.variance_source;
  const PipelineResult r1 = pipe.execute(e1, ctx);
  CHECK(r1.estimated_error.source == "variance+sure");
  CHECK(r1.estimated_error.dof);  // bounded by the variance's dof, were it not for SURE
  CHECK_FALSE(r1.estimated_error.relmse_high);
  CHECK_FALSE(r1.estimated_error.mse_high);
  CHECK(r1.estimated_error.equivalent_spp_low == 0);
  CHECK_FALSE(meets_relmse(r1.estimated_error, 1e9));
  CHECK_FALSE(meets_equivalent_spp(r1.estimated_error, 1e-9));
}

// A committed pipeline with the Gaussian, the linear denoiser, and a frame of `passes` noisy
// passes of `truth` (spp each) accumulated as it asks.
struct LinearRun {
  Pipeline pipe;
  FrameEstimate frame;
};
LinearRun gaussian_frame(const Image& truth, int passes, std::uint64_t seed, double spp) {
  std::mt19937_64 rng(seed);
  PipelineOptions o;
  o.denoiser = "gaussian";
  LinearRun run{Pipeline(o), {}};
  run.pipe.commit();
  FrameAccumulator acc;
  for (int k = 0; k < passes; ++k)
    acc.add(noisy_pass(truth, rng, 0.25f, spp), "p" + std::to_string(k));
  run.frame = acc.estimate(run.pipe.estimate_options());
  return run;
}

TEST_CASE("estimate_error: a linear denoiser's error is split into bias and variance exactly",
          "[error_estimate][cross_validation]") {
  // A Gaussian blur over a fine texture: its error is nearly all bias, which the full frame's
  // samples do not reduce, so the kHalfToFullMse bracket (1/sqrt(2) of the half run's error)
  // reads ~0.71 of it, and the mix's small difference of large terms magnified that on the
  // evaluation scenes (docs/error_estimate.md, "A linear denoiser"). For a filter whose weights
  // do not depend on the data, the two half runs share their bias and differ only by noise:
  // cvsquare - cvvariance - cvspread measures the full run's error itself.
  const int W = 128, H = 128;
  const Image truth = textured_truth(W, H);
  LinearRun run = gaussian_frame(truth, 8, 41, 2);
  ErrorContext ctx{.spp = 16, .passes = 8, .noise_scope = NoiseScope::pixel};
  const PipelineResult r = run.pipe.execute(run.frame, ctx);
  REQUIRE(r.estimated_error.source == "variance+cross-validation");
  REQUIRE_FALSE(r.cv_spread.empty());
  double m_true = 0, m_split = 0, m_bracket = 0;
  const std::size_t n = truth.data().size();
  for (std::size_t i = 0; i < n; ++i) {
    const double e = r.denoised.data()[i] - truth.data()[i];
    m_true += e * e;
    const double cv = r.cv_square.data()[i] - r.cv_variance.data()[i];
    m_split += cv - r.cv_spread.data()[i];
    m_bracket += kHalfToFullMse * cv;
  }
  INFO("denoiser's MSE, summed: true " << m_true << " split " << m_split << " bracket "
                                       << m_bracket);
  CHECK(m_split / m_true > 0.95);
  CHECK(m_split / m_true < 1.05);
  CHECK(m_bracket / m_true < 0.8);  // what the bracket would have said
  // The published estimate uses the split: the result's error within 20 %.
  const double truth_mse = compute_metrics(r.result, truth).mse;
  INFO("result: true " << truth_mse << " estimated " << r.estimated_error.mse);
  CHECK(r.estimated_error.mse / truth_mse > 0.8);
  CHECK(r.estimated_error.mse / truth_mse < 1.25);
  // The layer is in the published layers; a data-adaptive denoiser gets none.
  bool listed = false;
  for (const auto& [name, img] : r.layers()) listed = listed || name == layer::cv_spread;
  CHECK(listed);
  Pipeline nlm;
  nlm.commit();
  const PipelineResult rn = nlm.execute(run.frame, ctx);
  CHECK_FALSE(rn.cv_square.empty());
  CHECK(rn.cv_spread.empty());
}

TEST_CASE("estimate_error: the spread weighs halves of unequal samples by their shares",
          "[error_estimate][cross_validation]") {
  // 3 passes: half A holds 2 of them, half B one, so the full run keeps w_A w_B = 2/9 of the half
  // runs' summed variance, not 1/4: cvspread = (1/2 - w_A w_B) (y_A - y_B)^2, element by element.
  const int W = 40, H = 24;
  const Image truth = textured_truth(W, H);
  LinearRun run = gaussian_frame(truth, 3, 43, 4);
  const FrameEstimate& f = run.frame;
  const PipelineResult r = run.pipe.execute(f, {.spp = 12, .passes = 3});
  REQUIRE_FALSE(r.cv_spread.empty());
  const GaussianDenoiser blur(run.pipe.options().gaussian_sigma);
  const Rect all{0, 0, W, H};
  std::array<Buffer, 2> y;
  for (std::size_t h = 0; h < 2; ++h) {
    DenoiseInputs in = denoise_inputs(f, f.half_mean[h], f.half_variance[h], false);
    y[h] = Buffer(all, 3);
    blur.denoise(in, all, y[h], nullptr);
  }
  int checked = 0;
  for (int c = 0; c < 3; ++c) {
    for (int py = 0; py < H; ++py) {
      for (int px = 0; px < W; ++px) {
        const double va = f.half_variance[0].at(px, py, c), vb = f.half_variance[1].at(px, py, c);
        REQUIRE(va > 0);
        CHECK(vb / va == Approx(2.0).epsilon(1e-5));  // one per-sample variance, 8 vs 4 samples
        const double d = y[0].at(px, py, c) - y[1].at(px, py, c);
        const double want = (0.5 - va * vb / ((va + vb) * (va + vb))) * d * d;
        CHECK(r.cv_spread.at(px, py, c) == Approx(want).epsilon(1e-4).margin(1e-12));
        ++checked;
      }
    }
  }
  CHECK(checked == 3 * W * H);
}

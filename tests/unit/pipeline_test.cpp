// The progressive pipeline's stages: the denoiser's exact derivative, SURE against known truth,
// the t-test's convergence behaviour, and tiled == whole-image runs.
#include <catch2/catch.hpp>

#include <cmath>
#include <random>

#include "../../pipeline/src/fast_math.hpp"
#include "proden/progressive.hpp"

using namespace proden;

namespace {

// A ground truth with flat regions, a ramp, edges and a bright square.
Image truth_image(int w, int h) {
  Image t(w, h, 3);
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        float v = 0.2f + 0.3f * static_cast<float>(x) / static_cast<float>(w);
        if (x > w / 2) v += 0.4f;
        if (y > h / 3 && y < h / 2 && x > w / 4 && x < w / 3) v = 2.0f;
        t.at(x, y, c) = v * (1.0f + 0.2f * static_cast<float>(c));
      }
    }
  }
  return t;
}

// x = truth + N(0, var) with var proportional to the truth.
FrameEstimate noisy(const Image& truth, float rel_var, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> n(0.0f, 1.0f);
  FrameEstimate f;
  f.mean = truth;
  f.variance = Image(truth.width(), truth.height(), 3);
  for (std::size_t i = 0; i < truth.data().size(); ++i) {
    const float v = rel_var * truth.data()[i];
    f.variance.data()[i] = v;
    f.mean.data()[i] = truth.data()[i] + std::sqrt(v) * n(rng);
  }
  return f;
}

DenoiseInputs inputs_of(const FrameEstimate& f) {
  return denoise_inputs(f, f.mean, f.variance, true);
}

double max_rel_diff(const Image& a, const Image& b) {
  double m = 0;
  for (std::size_t i = 0; i < a.data().size(); ++i) {
    const double x = a.data()[i], y = b.data()[i];
    m = std::max(m, std::abs(x - y) / std::max(std::abs(y), 1e-6));
  }
  return m;
}

}  // namespace

TEST_CASE("exp_neg matches std::exp over the weights' range", "[pipeline][math]") {
  // Relative error < 1e-6 down to -10, growing to ~4e-6 at -87 where float's own rounding of
  // x * log2(e) dominates (such weights are < 1e-37 and irrelevant).
  double worst_near = 0, worst = 0;
  for (float x = -87.0f; x <= 0.0f; x += 0.001f) {
    const double e = std::exp(static_cast<double>(x));
    const double rel = std::abs(detail::exp_neg(x) - e) / e;
    worst = std::max(worst, rel);
    if (x > -10.0f) worst_near = std::max(worst_near, rel);
  }
  CHECK(worst_near < 1e-6);
  CHECK(worst < 1e-5);
  CHECK(detail::exp_neg(0.0f) == 1.0f);
  CHECK(detail::exp_neg(-1000.0f) == 0.0f);
  CHECK(detail::exp_neg(5.0f) == 1.0f);  // positive input is clamped
}

TEST_CASE("NL-means Jacobian diagonal matches finite differences", "[pipeline][denoise]") {
  const FrameEstimate f = noisy(truth_image(32, 32), 0.02f, 3);
  NlMeansParams p;
  p.search_radius = 3;
  p.patch_radius = 1;
  const NlMeansDenoiser den(p);
  const DenoiseInputs in = inputs_of(f);
  const Rect all{0, 0, 32, 32};
  Buffer y(all, 3), dydx(all, 3);
  den.denoise(in, all, y, &dydx);
  int checked = 0;
  for (int py = 6; py < 26; py += 5) {
    for (int px = 6; px < 26; px += 4) {
      for (int c = 0; c < 3; ++c) {
        const double h = 1e-4 * std::max(1.0f, std::abs(f.mean.at(px, py, c)));
        const Rect one{px, py, px + 1, py + 1};
        auto eval = [&](double delta) {
          FrameEstimate g = f;
          g.mean.at(px, py, c) += static_cast<float>(delta);
          DenoiseInputs gi = inputs_of(g);
          Buffer out(one, 3);
          den.denoise(gi, one, out, nullptr);
          return static_cast<double>(out.at(px, py, c));
        };
        const double fd = (eval(h) - eval(-h)) / (2 * h);
        const double an = dydx.at(px, py, c);
        INFO("pixel " << px << "," << py << " ch " << c << ": analytic " << an << " fd " << fd);
        CHECK(an == Approx(fd).margin(2e-3).epsilon(0.03));
        ++checked;
      }
    }
  }
  CHECK(checked == 60);
}

TEST_CASE("analytic and Monte-Carlo divergence agree on the built-in filter", "[pipeline][sure]") {
  const FrameEstimate f = noisy(truth_image(48, 48), 0.02f, 5);
  NlMeansParams p;
  p.search_radius = 3;
  p.patch_radius = 1;
  const NlMeansDenoiser den(p);
  const DenoiseInputs in = inputs_of(f);
  const Rect all{0, 0, 48, 48};
  Buffer y(all, 3), dydx(all, 3), div_a(all, 3), div_mc(all, 3);
  den.denoise(in, all, y, &dydx);
  divergence_from_derivative(in.variance, dydx, all, div_a);
  MonteCarloProbes probes;
  probes.count = 32;
  divergence_monte_carlo(den, in, all, y, probes, div_mc);
  // Compare the means over the interior (MC per-pixel estimates are noisy by construction).
  double sa = 0, sm = 0, sd2 = 0;
  int n = 0;
  for (int c = 0; c < 3; ++c) {
    for (int py = 4; py < 44; ++py) {
      for (int px = 4; px < 44; ++px) {
        sa += div_a.at(px, py, c);
        sm += div_mc.at(px, py, c);
        const double d = div_mc.at(px, py, c) - div_a.at(px, py, c);
        sd2 += d * d;
        ++n;
      }
    }
  }
  const double se = std::sqrt(sd2 / n) / std::sqrt(static_cast<double>(n));
  INFO("mean analytic " << sa / n << ", mean MC " << sm / n << ", standard error " << se);
  CHECK(std::abs(sa - sm) / n < 4 * se + 1e-3 * std::abs(sa / n));
  CHECK(sa > 0);
}

TEST_CASE("mean SURE matches the true MSE of the denoised image", "[pipeline][sure]") {
  const Image truth = truth_image(64, 64);
  for (const auto method : {DivergenceMethod::analytic, DivergenceMethod::monte_carlo}) {
    const FrameEstimate f = noisy(truth, 0.05f, 11);
    PipelineOptions o;
    o.nlmeans.search_radius = 4;
    o.nlmeans.patch_radius = 2;
    o.divergence = method;
    o.probes.count = 8;
    Pipeline pipeline(o);
    pipeline.commit();
    const PipelineResult r = pipeline.execute(f);
    // Interior only: near the border the analytic derivative is approximate by design.
    double s_sure = 0, s_mse = 0, s_d2 = 0;
    int n = 0;
    for (int c = 0; c < 3; ++c) {
      for (int py = 8; py < 56; ++py) {
        for (int px = 8; px < 56; ++px) {
          const double e = r.denoised.at(px, py, c) - truth.at(px, py, c);
          const double s = r.sure.at(px, py, c);
          s_sure += s;
          s_mse += e * e;
          s_d2 += (s - e * e) * (s - e * e);
          ++n;
        }
      }
    }
    const double se = std::sqrt(s_d2 / n / n);
    INFO(r.divergence << ": mean SURE " << s_sure / n << ", true MSE " << s_mse / n
                      << ", standard error " << se);
    CHECK(std::abs(s_sure - s_mse) / n < 4 * se);
    // And the denoiser actually helps on this image: MSE well below the noise variance.
    double s_var = 0;
    for (float v : f.variance.data()) s_var += v;
    CHECK(s_mse / n < 0.5 * s_var / static_cast<double>(f.variance.data().size()));
  }
}

TEST_CASE("tiled runs equal the whole-image run", "[pipeline][tiles]") {
  FrameEstimate f = noisy(truth_image(50, 37), 0.05f, 17);
  f.albedo = Image(50, 37, 3, 0.5f);
  for (int y = 0; y < 37; ++y) {
    for (int x = 25; x < 50; ++x) f.albedo.at(x, y, 1) = 0.9f;
  }
  f.normal = Image(50, 37, 3, 0.0f);
  for (float& v : f.normal.plane(2)) v = 1.0f;
  for (const auto method : {DivergenceMethod::analytic, DivergenceMethod::monte_carlo}) {
    PipelineOptions o;
    o.nlmeans.search_radius = 3;
    o.nlmeans.patch_radius = 2;
    o.divergence = method;
    o.probes.count = 2;
    o.tile = 4096;
    Pipeline pipeline(o);
    pipeline.commit();
    const PipelineResult whole = pipeline.execute(f);
    REQUIRE(whole.inputs.albedo);
    for (int tile : {1, 7, 16, 33}) {  // smaller than the halo, and not dividing 50x37
      o.tile = tile;
      pipeline.set_options(o);
      pipeline.commit();
      const PipelineResult tiled = pipeline.execute(f);
      INFO("tile " << tile << " halo " << tiled.halo << " divergence " << tiled.divergence);
      CHECK(max_rel_diff(tiled.result, whole.result) <= 1e-6);
      CHECK(max_rel_diff(tiled.denoised, whole.denoised) <= 1e-6);
      CHECK(max_rel_diff(tiled.alpha, whole.alpha) <= 1e-6);
      CHECK(max_rel_diff(tiled.sure, whole.sure) <= 1e-6);
    }
  }
}

TEST_CASE("t-test: a biased denoiser is rejected as the variance shrinks", "[pipeline][ttest]") {
  // y = truth + 0.05 (biased), x = truth + noise of shrinking variance.
  const Image truth = truth_image(40, 40);
  double prev_mean_alpha = 2.0;
  for (float var : {1e-2f, 1e-4f, 1e-6f, 1e-8f}) {
    FrameEstimate f;
    f.mean = truth;
    f.variance = Image(40, 40, 3, var);
    std::mt19937 rng(1);
    std::normal_distribution<float> n(0.0f, std::sqrt(var));
    for (float& v : f.mean.data()) v += n(rng);
    Image z(40, 40, 3), alpha(40, 40, 3, 1.0f);  // a mixer that fully trusts y
    for (std::size_t i = 0; i < z.data().size(); ++i) z.data()[i] = truth.data()[i] + 0.05f;
    const Rect all{0, 0, 40, 40};
    Buffer out(all, 3);
    t_rescale(view_of(f.mean), view_of(f.variance), view_of(z), view_of(alpha), 40, 40, all, {},
              out);
    double mean_alpha = 0;
    for (int c = 0; c < 3; ++c) {
      for (int y = 0; y < 40; ++y) {
        for (int x = 0; x < 40; ++x) mean_alpha += out.at(x, y, c);
      }
    }
    mean_alpha /= 3 * 40 * 40;
    INFO("var " << var << ": mean alpha' " << mean_alpha);
    CHECK(mean_alpha <= prev_mean_alpha + 1e-9);
    prev_mean_alpha = mean_alpha;
    if (var <= 1e-6f) CHECK(mean_alpha < 1e-3);
  }
  // The whole pipeline converges to the render: with tiny variance the result equals x.
  FrameEstimate f;
  f.mean = truth;
  f.variance = Image(40, 40, 3, 1e-10f);
  Pipeline pipeline;
  pipeline.commit();
  const PipelineResult r = pipeline.execute(f);
  CHECK(max_rel_diff(r.result, f.mean) < 1e-4);
}

TEST_CASE("t-test: an unbiased mix keeps its alpha", "[pipeline][ttest]") {
  const Image truth = truth_image(40, 40);
  const FrameEstimate f = noisy(truth, 0.01f, 23);
  Image alpha(40, 40, 3, 0.8f);
  Image z(40, 40, 3);
  // z = x + 0.8 (truth - x): an unbiased y (the truth itself).
  for (std::size_t i = 0; i < z.data().size(); ++i) {
    z.data()[i] = f.mean.data()[i] + 0.8f * (truth.data()[i] - f.mean.data()[i]);
  }
  const Rect all{0, 0, 40, 40};
  Buffer out(all, 3);
  t_rescale(view_of(f.mean), view_of(f.variance), view_of(z), view_of(alpha), 40, 40, all, {}, out);
  double mean_alpha = 0;
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < 40; ++y) {
      for (int x = 0; x < 40; ++x) mean_alpha += out.at(x, y, c);
    }
  }
  mean_alpha /= 3 * 40 * 40;
  CHECK(mean_alpha > 0.95 * 0.8);
}

TEST_CASE("the result's estimated MSE matches its true MSE on known truth", "[pipeline][sure]") {
  const Image truth = truth_image(160, 160);  // borders (approximate derivative) stay a small share
  const FrameEstimate f = noisy(truth, 0.05f, 29);
  PipelineOptions o;
  o.nlmeans.search_radius = 4;
  o.nlmeans.patch_radius = 2;
  o.nlmeans.use_features = false;
  Pipeline pipeline(o);
  pipeline.commit();
  const PipelineResult r = pipeline.execute(f);
  double se = 0;
  for (std::size_t i = 0; i < truth.data().size(); ++i) {
    const double e = r.result.data()[i] - truth.data()[i];
    se += e * e;
  }
  const double true_mse = se / static_cast<double>(truth.data().size());
  const double est = r.estimated_error.mse;
  CHECK(r.estimated_error.source == error_source::variance_sure);
  INFO("estimated " << est << " true " << true_mse);
  CHECK(est == Approx(true_mse).epsilon(0.15));
  // The formula it replaced, (1-a)^2 var + a^2 max(SURE, 0), misses the x-y covariance.
  double old = 0;
  for (std::size_t i = 0; i < truth.data().size(); ++i) {
    const double a = r.alpha.data()[i];
    old += (1 - a) * (1 - a) * f.variance.data()[i] + a * a * std::max(0.0f, r.sure.data()[i]);
  }
  old /= static_cast<double>(truth.data().size());
  INFO("old estimate " << old);
  CHECK(std::abs(est - true_mse) < std::abs(old - true_mse));
}

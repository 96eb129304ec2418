// The NL-means + NFOR cascade (docs/cascade.md) and the fine-scale t-test: the blend follows
// NL-means where NFOR is badly biased and NFOR elsewhere, stays between the two, runs the same
// tiled and whole; the fine test rejects a spot smeared within the authors' t-test window.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>
#include <string>

#include "proden/accumulator.hpp"
#include "proden/denoise/cascade.hpp"
#include "proden/progressive.hpp"
#include "proden/tstat.hpp"
#include "test_support.hpp"

using namespace proden;

namespace {

FrameAccumulator frame(int w, int h, int passes, double spp = 4, float sigma = 0.1f) {
  FrameAccumulator f;
  for (int k = 0; k < passes; ++k) {
    f.add(test::make_pass(w, h, spp, 100 + static_cast<std::uint64_t>(k),
                          Layout{true, true, true, false}, sigma),
          std::to_string(k));
  }
  return f;
}

NlMeansParams small_nlmeans() {
  NlMeansParams p;
  p.search_radius = 3;
  p.patch_radius = 1;
  return p;
}

}  // namespace

TEST_CASE("the cascade follows NL-means where NFOR is badly biased, NFOR where it is not",
          "[cascade]") {
  const int W = 64, H = 48;
  const FrameAccumulator f = frame(W, H, 8);
  FrameEstimate est = f.estimate({.halves = true, .features = true});
  // NFOR reads the half buffers, NL-means the combined mean: lying in both halves (+2) over a
  // square makes NFOR's output off by about 2 there while NL-means' is not.
  const Rect bad{8, 8, 28, 28};
  for (int h = 0; h < 2; ++h) {
    for (int c = 0; c < 3; ++c) {
      for (int y = bad.y0; y < bad.y1; ++y) {
        for (int x = bad.x0; x < bad.x1; ++x) est.half_mean[h].at(x, y, c) += 2.0f;
      }
    }
  }
  const DenoiseInputs din = denoise_inputs(est, est.mean, est.variance, true);
  const Rect image{0, 0, W, H};
  const CascadeDenoiser cascade(small_nlmeans(), NforParams{});
  Buffer y(image, 3), dydx(image, 3), b;
  cascade.denoise_with_weight(din, y, &dydx, b);
  Buffer y1(image, 3), d1(image, 3), y2(image, 3), d2(image, 3);
  NlMeansDenoiser(small_nlmeans()).denoise(din, image, y1, &d1);
  NforDenoiser(NforParams{}).denoise(din, image, y2, &d2);

  // Inside the square, away from its edges: NFOR is off by ~2, the cascade is NL-means.
  double b_in = 0, off_nfor = 0, off_cascade = 0;
  int n_in = 0;
  for (int c = 0; c < 3; ++c) {
    for (int py = 12; py < 24; ++py) {
      for (int px = 12; px < 24; ++px, ++n_in) {
        b_in += b.at(px, py, c);
        off_nfor += std::abs(y2.at(px, py, c) - y1.at(px, py, c));
        off_cascade += std::abs(y.at(px, py, c) - y1.at(px, py, c));
      }
    }
  }
  INFO("mean b inside " << b_in / n_in << ", |NFOR - NL-means| " << off_nfor / n_in
                        << ", |cascade - NL-means| " << off_cascade / n_in);
  CHECK(off_nfor / n_in > 1.0);  // the premise: NFOR is badly biased there
  CHECK(b_in / n_in < 0.05);
  CHECK(off_cascade / n_in < 0.05);
  // Far from the square (beyond the blend's 12-pixel window), where both are sound, NFOR weighs.
  double b_out = 0;
  int n_out = 0;
  for (int c = 0; c < 3; ++c) {
    for (int py = 0; py < H; ++py) {
      for (int px = 44; px < W; ++px, ++n_out) b_out += b.at(px, py, c);
    }
  }
  INFO("mean b far away " << b_out / n_out);
  CHECK(b_out / n_out > 0.3);
  // Everywhere: b in [0, 1], y = y1 + b (y2 - y1) between the two, dy/dx blended alike.
  for (int c = 0; c < 3; ++c) {
    for (int py = 0; py < H; ++py) {
      for (int px = 0; px < W; ++px) {
        const float w = b.at(px, py, c), a = y1.at(px, py, c), v = y2.at(px, py, c);
        REQUIRE(w >= 0.0f);
        REQUIRE(w <= 1.0f);
        REQUIRE(y.at(px, py, c) >= std::min(a, v));
        REQUIRE(y.at(px, py, c) <= std::max(a, v));
        REQUIRE(y.at(px, py, c) == Approx(a + w * (v - a)).margin(1e-5));
        REQUIRE(dydx.at(px, py, c) ==
                Approx((1 - w) * d1.at(px, py, c) + w * d2.at(px, py, c)).margin(1e-5));
      }
    }
  }
}

TEST_CASE("the cascade in the pipeline: tiled equals whole, registry and halves", "[cascade]") {
  const FrameAccumulator f = frame(45, 37, 4);
  PipelineOptions o;
  o.denoiser = "cascade";
  o.nlmeans = small_nlmeans();
  Pipeline whole(o);
  whole.commit();
  CHECK(whole.estimate_options().halves);
  CHECK(whole.estimate_options().features);
  const FrameEstimate est = f.estimate(whole.estimate_options());
  o.tile = 4096;
  whole.set_options(o);
  whole.commit();
  const PipelineResult ref = whole.execute(est);
  CHECK(ref.denoiser == "cascade");
  CHECK(ref.divergence == "analytic");
  for (int tile : {7, 16, 33}) {
    PipelineOptions t = o;
    t.tile = tile;
    Pipeline p(t);
    p.commit();
    const PipelineResult r = p.execute(est);
    INFO("tile " << tile);
    CHECK(r.result.data().size() == ref.result.data().size());
    for (std::size_t i = 0; i < ref.result.data().size(); ++i) {
      REQUIRE(r.result.data()[i] == ref.result.data()[i]);
      REQUIRE(r.denoised.data()[i] == ref.denoised.data()[i]);
    }
  }
}

TEST_CASE("the fine t-test rejects a spot smeared within the authors' window", "[cascade]") {
  // A bright 3x3 spot (20) on 0.1, noisy enough (Var ~ 0.05) that the authors' window is flat
  // (sigma = 100 sqrt(var) >> 5): a blur that keeps the spot's energy inside the 11x11 window
  // keeps the window's mean, passes their test, and is caught pixel by pixel by the fine one.
  const int W = 31, H = 31, cx = 15, cy = 15;
  Image x(W, H, 3, 0.1f), var(W, H, 3, 0.05f), z(W, H, 3, 0.1f), alpha(W, H, 3, 1.0f);
  for (int c = 0; c < 3; ++c) {
    for (int dy = -1; dy <= 1; ++dy) {
      for (int dx = -1; dx <= 1; ++dx) x.at(cx + dx, cy + dy, c) = 20.0f;
    }
    // z: the spot's energy (9 x 19.9 over the background) spread evenly over the 9x9 around it.
    for (int dy = -4; dy <= 4; ++dy) {
      for (int dx = -4; dx <= 4; ++dx) z.at(cx + dx, cy + dy, c) = 0.1f + 9.0f * 19.9f / 81.0f;
    }
  }
  const PipelineOptions defaults;
  const Rect px{cx, cy, cx + 1, cy + 1};
  Buffer coarse(px, 3), fine(px, 3);
  const Image passes(W, H, 1, 16.0f);
  VarianceOrigin origin;
  origin.passes = view_of(passes);
  t_rescale(view_of(x), view_of(var), view_of(z), view_of(alpha), W, H, px, defaults.ttest, coarse,
            origin);
  t_rescale(view_of(x), view_of(var), view_of(z), view_of(alpha), W, H, px,
            defaults.ttest_fine_params, fine, origin);
  INFO("authors' keep " << coarse.at(cx, cy, 0) << ", fine keep " << fine.at(cx, cy, 0));
  CHECK(coarse.at(cx, cy, 0) > 0.5f);  // the premise: the authors' test lets it through
  CHECK(fine.at(cx, cy, 0) < 1e-3f);
  // And an unbiased z (= x) passes both.
  Buffer same(px, 3);
  t_rescale(view_of(x), view_of(var), view_of(x), view_of(alpha), W, H, px,
            defaults.ttest_fine_params, same, origin);
  CHECK(same.at(cx, cy, 0) > 0.99f);
}

TEST_CASE("the fine t-test's window may not exceed the authors'", "[cascade]") {
  PipelineOptions o;
  o.ttest_fine_params.radius = o.ttest.radius + 1;
  Pipeline p(o);
  CHECK_THROWS_AS(p.commit(), PipelineError);
  o.ttest_fine = false;
  p.set_options(o);
  CHECK_NOTHROW(p.commit());
}

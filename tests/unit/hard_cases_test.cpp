// Numerically hard frames through accumulation and the whole pipeline (with the closed-form and
// the learned mixer): each must give finite output, alpha in [0, 1], a result between render and
// denoised, and a denoised image inside the render's value range (the filter is a convex
// combination).
#include <catch2/catch.hpp>

#include <cmath>
#include <functional>
#include <limits>
#include <random>

#include "proden/accumulator.hpp"
#include "proden/network/builtin.hpp"
#include "proden/progressive.hpp"

using namespace proden;

namespace {

using Fill = std::function<float(int pass, int x, int y, int c)>;

FrameAccumulator frame_of(int w, int h, int passes, const Fill& fill) {
  FrameAccumulator f;
  for (int k = 0; k < passes; ++k) {
    Pass p;
    p.spp = 4;
    p.colour = Image(w, h, 3);
    for (int c = 0; c < 3; ++c) {
      for (int y = 0; y < h; ++y) {
        for (int x = 0; x < w; ++x) p.colour.at(x, y, c) = fill(k, x, y, c);
      }
    }
    f.add(p, "pass" + std::to_string(k));
  }
  return f;
}

float noise(int pass, int x, int y, int c) {
  const unsigned key = ((static_cast<unsigned>(pass) * 7919u + static_cast<unsigned>(x)) * 104729u +
                        static_cast<unsigned>(y)) *
                           3u +
                       static_cast<unsigned>(c);
  std::mt19937 rng(key);
  return std::normal_distribution<float>(0.0f, 1.0f)(rng);
}

PipelineOptions small_options() {
  PipelineOptions o;
  o.nlmeans.search_radius = 3;
  o.nlmeans.patch_radius = 1;
  o.tile = 16;
  return o;
}

void check_sane(const FrameEstimate& e, const PipelineResult& r) {
  REQUIRE(r.result.same_size(e.mean));
  float xmin = std::numeric_limits<float>::max(), xmax = -xmin;
  for (float v : e.mean.data()) {
    xmin = std::min(xmin, v);
    xmax = std::max(xmax, v);
  }
  for (std::size_t i = 0; i < e.mean.data().size(); ++i) {
    const float x = e.mean.data()[i], y = r.denoised.data()[i], z = r.result.data()[i];
    const float a = r.alpha.data()[i], s = r.sure.data()[i];
    INFO("value " << i << ": x " << x << " y " << y << " z " << z << " alpha " << a);
    REQUIRE(std::isfinite(z));
    REQUIRE(std::isfinite(y));
    REQUIRE(std::isfinite(s));
    REQUIRE(a >= 0.0f);
    REQUIRE(a <= 1.0f);
    const float tol = 1e-6f * std::max(std::abs(xmin), std::abs(xmax));
    REQUIRE(z >= std::min(x, y) - tol);
    REQUIRE(z <= std::max(x, y) + tol);
    REQUIRE(y >= xmin - tol);
    REQUIRE(y <= xmax + tol);
  }
}

// Runs the pipeline with the learned mixer and with the closed form (whose result is returned),
// checking both.
PipelineResult run_checked(const FrameAccumulator& f, const PipelineOptions& o = small_options()) {
  const FrameEstimate e = f.estimate();
  {
    INFO("learned mixer");
    PipelineOptions net = o;
    net.mixer = MixerKind::network;
    Pipeline pipeline(net);
    pipeline.commit();
    check_sane(e, pipeline.execute(e));
  }
  PipelineOptions closed = o;
  closed.mixer = MixerKind::closed_form;
  Pipeline pipeline(closed);
  pipeline.commit();
  const PipelineResult r = pipeline.execute(e);
  check_sane(e, r);
  return r;
}

}  // namespace

TEST_CASE("fireflies of 1e6 in a 1e-2 background stay put", "[pipeline][hard]") {
  const auto f = frame_of(40, 40, 4, [](int k, int x, int y, int c) {
    if (k == 1 && ((x == 20 && y == 20) || (x == 5 && y == 30))) return 1e6f;
    return 1e-2f + 1e-3f * noise(k, x, y, c);
  });
  const PipelineResult r = run_checked(f);
  // Far from the fireflies the result is still the background, not smeared firefly energy.
  for (int y = 0; y < 12; ++y) {
    for (int x = 0; x < 40; ++x) CHECK(r.result.at(x, y, 0) < 0.05f);
  }
  // Near a firefly the pipeline may spread its energy (that lowers the squared error: the
  // mixer and t-test read a pooled variance), but it must not create energy: the result's sum
  // over the firefly's neighbourhood stays within the render's.
  const FrameEstimate e = f.estimate();
  double sum_x = 0, sum_z = 0;
  for (int y = 13; y <= 27; ++y) {
    for (int x = 13; x <= 27; ++x) {
      sum_x += e.mean.at(x, y, 0);
      sum_z += r.result.at(x, y, 0);
    }
  }
  INFO("energy around the firefly: render " << sum_x << ", result " << sum_z);
  CHECK(sum_z <= 1.02 * sum_x);
  CHECK(sum_z >= 0.5 * sum_x);
}

TEST_CASE("an all-black frame (variance 0) passes through", "[pipeline][hard]") {
  const auto f = frame_of(24, 24, 3, [](int, int, int, int) { return 0.0f; });
  const PipelineResult r = run_checked(f);
  CHECK(r.noise_free);
  for (float v : r.result.data()) CHECK(v == 0.0f);
}

TEST_CASE("a constant frame passes through unchanged", "[pipeline][hard]") {
  const auto f =
      frame_of(24, 24, 3, [](int, int, int, int c) { return 0.5f + 0.1f * static_cast<float>(c); });
  const PipelineResult r = run_checked(f);
  for (int c = 0; c < 3; ++c) {
    for (float v : r.result.plane(c)) CHECK(v == 0.5f + 0.1f * static_cast<float>(c));
  }
}

TEST_CASE("half black (zero variance), half noisy runs the full pipeline", "[pipeline][hard]") {
  const auto f = frame_of(32, 32, 4, [](int k, int x, int, int c) {
    return x < 16 ? 0.0f : 0.5f + 0.1f * noise(k, x, 0, c);
  });
  const PipelineResult r = run_checked(f);
  CHECK_FALSE(r.noise_free);
  // Exactly-known black pixels stay exactly black away from the noisy half.
  for (int y = 0; y < 32; ++y) {
    for (int x = 0; x < 8; ++x) CHECK(r.result.at(x, y, 1) == 0.0f);
  }
}

TEST_CASE("a single pass (spatial variance fallback) and two passes", "[pipeline][hard]") {
  for (int passes : {1, 2}) {
    const auto f = frame_of(30, 30, passes, [](int k, int x, int y, int c) {
      return 0.3f + 0.2f * static_cast<float>(x > 15) + 0.05f * noise(k, x, y, c);
    });
    INFO(passes << " pass(es)");
    const FrameEstimate e = f.estimate();
    CHECK(e.low_confidence() == (passes == 1));
    run_checked(f);
  }
}

TEST_CASE("very dark images (~1e-8)", "[pipeline][hard]") {
  const auto f = frame_of(32, 32, 4, [](int k, int x, int y, int c) {
    return 1e-8f * (1.0f + 0.3f * noise(k, x, y, c)) * (x > 16 ? 2.0f : 1.0f);
  });
  run_checked(f);
}

TEST_CASE("NaN and Inf samples in a pass", "[pipeline][hard]") {
  const auto f = frame_of(32, 32, 3, [](int k, int x, int y, int c) {
    if (k == 1 && x == 3 && y == 3) return std::numeric_limits<float>::quiet_NaN();
    if (k == 2 && x == 10 && y == 12) return std::numeric_limits<float>::infinity();
    if (k == 0 && x == 20 && y == 20 && c == 2) return -std::numeric_limits<float>::infinity();
    return 0.4f + 0.05f * noise(k, x, y, c);
  });
  CHECK(f.dropped_samples() == 3);
  run_checked(f);
}

TEST_CASE("1-pixel-wide, 1-pixel-tall and 1x1 frames", "[pipeline][hard]") {
  for (auto [w, h] : {std::pair{1, 40}, std::pair{40, 1}, std::pair{1, 1}}) {
    INFO(w << "x" << h);
    for (int passes : {1, 3}) {
      const auto f = frame_of(
          w, h, passes, [](int k, int x, int y, int c) { return 0.5f + 0.1f * noise(k, x, y, c); });
      for (int tile : {1, 16}) {
        PipelineOptions o = small_options();
        o.tile = tile;
        run_checked(f, o);
      }
    }
  }
}

TEST_CASE("features with 1e6 dynamic range and Monte-Carlo divergence stay finite",
          "[pipeline][hard]") {
  FrameAccumulator f;
  for (int k = 0; k < 3; ++k) {
    Pass p;
    p.spp = 1;
    p.colour = Image(24, 24, 3);
    p.albedo = Image(24, 24, 3, 0.5f);
    p.normal = Image(24, 24, 3, 0.0f);
    p.depth = Image(24, 24, 1, 1e6f);
    for (int y = 0; y < 24; ++y) {
      for (int x = 0; x < 24; ++x) {
        for (int c = 0; c < 3; ++c) {
          p.colour.at(x, y, c) = (x == y ? 1e4f : 1e-2f) * (1.0f + 0.2f * noise(k, x, y, c));
        }
        p.depth.at(x, y, 0) = x < 12 ? 1.0f : 1e6f;
      }
    }
    f.add(p, "p" + std::to_string(k));
  }
  PipelineOptions o = small_options();
  o.divergence = DivergenceMethod::monte_carlo;
  const PipelineResult r = run_checked(f, o);
  CHECK(r.inputs.depth);
}

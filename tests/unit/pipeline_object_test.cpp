// The pipeline object's lifecycle (commit validates and builds once, execute runs per frame on
// kept scratch), whole-frame denoisers, denoiser "none", and the options' vocabulary: a job's
// pipeline object parses to the options it names, old spellings included.
#include <tbb/global_control.h>

#include <catch2/catch.hpp>

#include <atomic>
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "proden/accumulator.hpp"
#include "proden/denoise/nlmeans.hpp"
#include "proden/network/weights.hpp"
#include "proden/progressive.hpp"
#include "proden/protocol/api.hpp"
#include "proden/protocol/pipeline_spec.hpp"
#include "test_support.hpp"

using namespace proden;
using nlohmann::json;

namespace {

// Four noisy passes of a 45x31 frame with albedo, normal and depth.
FrameEstimate small_frame() {
  FrameAccumulator f;
  for (std::uint64_t k = 0; k < 4; ++k) {
    f.add(test::make_pass(45, 31, 4, 100 + k, Layout{true, true, true, false}, 0.2f),
          "p" + std::to_string(k));
  }
  return f.estimate();
}

PipelineOptions small_options() {
  PipelineOptions o;
  o.denoiser = "nlmeans";  // small and fast; the default (the cascade) has its own cases
  o.nlmeans.search_radius = 3;
  o.nlmeans.patch_radius = 1;
  o.closed_form.radius = 4;
  o.tile = 16;
  return o;
}

bool same(const Image& a, const Image& b) {
  if (!a.same_size(b) || a.channels() != b.channels()) return false;
  for (std::size_t i = 0; i < a.data().size(); ++i) {
    if (a.data()[i] != b.data()[i]) return false;
  }
  return true;
}

double max_abs_diff(const Image& a, const Image& b) {
  REQUIRE(a.same_size(b));
  double m = 0;
  for (std::size_t i = 0; i < a.data().size(); ++i) {
    m = std::max(m, std::abs(static_cast<double>(a.data()[i]) - b.data()[i]));
  }
  return m;
}

// The key the PipelineError from committing `o` names ("" if it commits).
std::string commit_error(const PipelineOptions& o) {
  Pipeline p(o);
  try {
    p.commit();
  } catch (const PipelineError& e) {
    CHECK_FALSE(p.committed());
    CHECK(std::string(e.what()).rfind(e.key() + ": ", 0) == 0);
    return e.key();
  }
  CHECK(p.committed());
  return "";
}

// A registered denoiser run as a whole-frame one, counting its calls and the regions it saw:
// the pipeline must run it over the full image, once (plus its Monte-Carlo probes).
class WholeFrame final : public Denoiser {
 public:
  explicit WholeFrame(std::unique_ptr<const Denoiser> inner, bool derivative = true)
      : inner_(std::move(inner)), derivative_(derivative) {}
  std::string name() const override { return "whole-" + inner_->name(); }
  int radius() const override { return inner_->radius(); }
  bool has_derivative() const override { return derivative_ && inner_->has_derivative(); }
  bool whole_frame() const override { return true; }
  bool linear() const override { return inner_->linear(); }
  void denoise(const DenoiseInputs& in, const Rect& out, Buffer& y, Buffer* dydx) const override {
    ++calls;
    if (out != Rect{0, 0, in.width, in.height}) ++partial_calls;
    inner_->denoise(in, out, y, dydx);
  }
  mutable std::atomic<int> calls{0}, partial_calls{0};

 private:
  std::unique_ptr<const Denoiser> inner_;
  bool derivative_;
};

// A registered (tiled) denoiser counting the pixels it was asked for: the pipeline must denoise
// each pixel once, in halo-free tiles (plus the Monte-Carlo probes' runs).
class CountingTiles final : public Denoiser {
 public:
  explicit CountingTiles(std::unique_ptr<const Denoiser> inner) : inner_(std::move(inner)) {}
  std::string name() const override { return "counted-" + inner_->name(); }
  int radius() const override { return inner_->radius(); }
  bool has_derivative() const override { return inner_->has_derivative(); }
  void denoise(const DenoiseInputs& in, const Rect& out, Buffer& y, Buffer* dydx) const override {
    ++calls;
    pixels += static_cast<long>(out.area());
    inner_->denoise(in, out, y, dydx);
  }
  mutable std::atomic<long> calls{0}, pixels{0};

 private:
  std::unique_ptr<const Denoiser> inner_;
};

}  // namespace

TEST_CASE("commit: every invalid option is refused by its name", "[pipeline][object]") {
  CHECK(commit_error(small_options()).empty());
  const std::vector<std::pair<std::string, void (*)(PipelineOptions&)>> cases = {
      {"tile", [](PipelineOptions& o) { o.tile = 0; }},
      {"mixer_radius", [](PipelineOptions& o) { o.closed_form.radius = -1; }},
      {"search_radius", [](PipelineOptions& o) { o.nlmeans.search_radius = -2; }},
      {"patch_radius", [](PipelineOptions& o) { o.nlmeans.patch_radius = -1; }},
      {"probes", [](PipelineOptions& o) { o.probes.count = 0; }},
      {"probes", [](PipelineOptions& o) { o.probes.epsilon = 0.0f; }},
      {"gaussian_sigma", [](PipelineOptions& o) { o.gaussian_sigma = 0.0f; }},
      {"gaussian_sigma", [](PipelineOptions& o) { o.gaussian_sigma = 40.0f; }},
      {"variance_pool_radius", [](PipelineOptions& o) { o.variance_pool_radius = -1; }},
      {"denoiser", [](PipelineOptions& o) { o.denoiser = "magic"; }},
      {"denoiser", [](PipelineOptions& o) { o.nlmeans.k = 0.0f; }},  // refused by NL-means itself
      {"weights",
       [](PipelineOptions& o) {
         o.weights = {1, 2, 3};
       }},  // closed-form mixer
      {"weights",
       [](PipelineOptions& o) {
         o.mixer = MixerKind::network;
         o.weights = {'P', 'D', 'N', 'W', 1, 0, 0, 0, 'x', 'y', 'z'};
         o.weights_source = "bad.pdnw";
       }},
  };
  for (const auto& [key, spoil] : cases) {
    PipelineOptions o = small_options();
    spoil(o);
    INFO("expected " << key);
    CHECK(commit_error(o) == key);
  }
  // The message says what is wrong and what would be right.
  PipelineOptions o = small_options();
  o.denoiser = "magic";
  try {
    Pipeline(o).commit();
    FAIL("committed an unknown denoiser");
  } catch (const PipelineError& e) {
    CHECK_THAT(e.message(), Catch::Contains("magic") && Catch::Contains("nlmeans") &&
                                Catch::Contains("gaussian") && Catch::Contains("none"));
  }
  o = small_options();
  o.mixer = MixerKind::network;
  o.weights = network::serialize_weights(network::random_weights(8, 1));
  o.weights.back() ^= 1;  // break the checksum
  o.weights_source = "broken.pdnw";
  try {
    Pipeline(o).commit();
    FAIL("committed corrupt weights");
  } catch (const PipelineError& e) {
    CHECK(e.key() == "weights");
    CHECK_THAT(e.message(), Catch::Contains("broken.pdnw"));
  }
  // Analytic divergence from a denoiser without a Jacobian diagonal.
  Pipeline p(small_options());
  p.set_options([] {
    PipelineOptions a = small_options();
    a.divergence = DivergenceMethod::analytic;
    return a;
  }());
  p.set_denoiser(std::make_shared<WholeFrame>(std::make_unique<GaussianDenoiser>(2.0f), false));
  try {
    p.commit();
    FAIL("committed analytic divergence without a derivative");
  } catch (const PipelineError& e) {
    CHECK(e.key() == "divergence");
  }
}

TEST_CASE("execute needs a commit after every change of options", "[pipeline][object]") {
  const FrameEstimate f = small_frame();
  Pipeline p(small_options());
  CHECK_THROWS_AS(p.execute(f), std::logic_error);
  p.commit();
  CHECK_NOTHROW(p.execute(f));
  p.set_options(small_options());
  CHECK_FALSE(p.committed());
  CHECK_THROWS_AS(p.execute(f), std::logic_error);
  FrameEstimate no_variance = f;
  no_variance.variance = Image();
  p.commit();
  CHECK_THROWS_AS(p.execute(no_variance), std::invalid_argument);
  // A moved pipeline keeps its build; the moved-from one must be committed again.
  const PipelineResult before = p.execute(f);
  Pipeline q = std::move(p);
  CHECK(q.committed());
  CHECK(same(q.execute(f).result, before.result));
  CHECK_FALSE(p.committed());  // NOLINT(bugprone-use-after-move): the state after a move is set
  CHECK_THROWS_AS(p.execute(f), std::logic_error);
  p.set_options(small_options());
  p.commit();
  CHECK(same(p.execute(f).result, before.result));
}

TEST_CASE("execute twice reuses the built stages and the scratch", "[pipeline][object]") {
  const FrameEstimate f = small_frame();
  // One thread, so both runs give each tile to the same thread's scratch (with more, a thread
  // that only met a small border tile grows its buffers the first time it meets a full one).
  tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
  for (const MixerKind mixer : {MixerKind::closed_form, MixerKind::network}) {
    PipelineOptions o = small_options();
    o.mixer = mixer;
    o.tile = 24;  // several tiles, with little halo overhead (the network is slow under ASan)
    Pipeline p(o);
    p.commit();
    const Denoiser* denoiser = p.denoiser();
    const Mixer* mix = p.mixer();
    REQUIRE(denoiser);
    REQUIRE(mix);
    CHECK(p.scratch_bytes() == 0);  // nothing allocated before the first run
    const PipelineResult a = p.execute(f);
    const std::size_t kept = p.scratch_bytes();
    INFO(a.mixer << ": scratch " << kept << " bytes");
    // Frame copies of x and Var[x] (3 planes each) at least, and the tiles' buffers.
    CHECK(kept > 2 * 3 * 45 * 31 * sizeof(float));
    const PipelineResult b = p.execute(f);
    CHECK(p.denoiser() == denoiser);
    CHECK(p.mixer() == mix);
    CHECK(p.scratch_bytes() == kept);  // reused, not grown
    CHECK(same(a.result, b.result));
    CHECK(same(a.alpha, b.alpha));
    CHECK(same(a.sure, b.sure));
    CHECK(a.estimated_error.mse == b.estimated_error.mse);
    // A fresh pipeline computes the same thing: the reused scratch leaks nothing between runs.
    Pipeline fresh(o);
    fresh.commit();
    CHECK(same(fresh.execute(f).result, a.result));
    // A new commit builds new stages.
    p.set_options(o);
    p.commit();
    CHECK(p.committed());
    CHECK(same(p.execute(f).result, a.result));
  }
}

TEST_CASE("a whole-frame denoiser runs once over the full image and tiles equal the whole",
          "[pipeline][object][tiles]") {
  const FrameEstimate f = small_frame();
  for (const auto method : {DivergenceMethod::analytic, DivergenceMethod::monte_carlo}) {
    PipelineOptions o = small_options();
    o.denoiser = "gaussian";
    o.divergence = method;
    o.probes.count = 2;
    o.tile = 4096;
    Pipeline tiled_ref(o);
    tiled_ref.commit();
    const PipelineResult ref = tiled_ref.execute(f);  // the registry's (tiled) gaussian, one tile
    for (int tile : {3, 7, 4096}) {  // smaller than the halo, not dividing 45x31, one tile
      o.tile = tile;
      Pipeline p(o);
      auto whole = std::make_shared<WholeFrame>(std::make_unique<GaussianDenoiser>(2.0f));
      p.set_denoiser(whole);
      p.commit();
      // The denoiser's radius is no part of the halo, whole-frame or tiled: y and SURE are
      // computed over the frame before the mixer's tiles read them.
      CHECK(p.halo() == tiled_ref.halo());
      CHECK(p.halo() == p.mixer()->radius() + o.ttest.radius);
      const PipelineResult r = p.execute(f);
      INFO("tile " << tile << ", divergence " << r.divergence);
      // One run for y (plus the probes), and one on each half for the error estimate's
      // cross-validation (docs/error_estimate.md).
      CHECK(r.estimated_error.source == "variance+cross-validation");
      CHECK(whole->calls.load() ==
            (method == DivergenceMethod::analytic ? 1 : 1 + o.probes.count) + 2);
      CHECK(whole->partial_calls.load() == 0);
      CHECK(r.denoiser == "whole-gaussian");
      CHECK(max_abs_diff(r.denoised, ref.denoised) <= 1e-6);
      CHECK(max_abs_diff(r.sure, ref.sure) <= 1e-6);
      CHECK(max_abs_diff(r.alpha, ref.alpha) <= 1e-6);
      CHECK(max_abs_diff(r.result, ref.result) <= 1e-6);
      CHECK(r.estimated_error.mse == Approx(ref.estimated_error.mse).epsilon(1e-9));
    }
  }
}

TEST_CASE("denoiser none publishes the render with its variance as the error",
          "[pipeline][object]") {
  const FrameEstimate f = small_frame();
  PipelineOptions o = small_options();
  o.denoiser = std::string(kNoDenoiser);
  Pipeline p(o);
  p.commit();
  CHECK(p.denoiser() == nullptr);
  CHECK(p.mixer() == nullptr);
  const PipelineResult r = p.execute(f);
  CHECK(same(r.result, f.mean));
  double mean_var = 0;
  for (float v : f.variance.data()) mean_var += v;
  mean_var /= static_cast<double>(f.variance.data().size());
  CHECK(r.estimated_error.mse == Approx(mean_var).epsilon(1e-12));
  CHECK(r.estimated_error.source == error_source::variance);
  CHECK(r.denoiser == "none");
  std::vector<std::string_view> names;
  for (const auto& [name, img] : r.layers()) names.push_back(name);
  CHECK(names == std::vector<std::string_view>{layer::render, layer::variance});
  // With a linear denoiser every layer is there, in the vocabulary's order; a data-adaptive one
  // (the default) has no cvspread (docs/error_estimate.md, "A linear denoiser").
  PipelineOptions lin = small_options();
  lin.denoiser = "gaussian";
  Pipeline d(lin);
  d.commit();
  names.clear();
  for (const auto& [name, img] : d.execute(f).layers()) names.push_back(name);
  CHECK(names == std::vector<std::string_view>(layer_names().begin() + 1, layer_names().end()));
  Pipeline adaptive(small_options());
  adaptive.commit();
  names.clear();
  for (const auto& [name, img] : adaptive.execute(f).layers()) names.push_back(name);
  std::vector<std::string_view> want(layer_names().begin() + 1, layer_names().end());
  std::erase(want, layer::cv_spread);
  CHECK(names == want);
}

TEST_CASE("a job's pipeline object parses to the options it names, old spellings included",
          "[pipeline][object][protocol]") {
  const auto parse = [](const json& p) { return protocol::parse_pipeline_options(p); };
  const PipelineOptions defaults;
  // The spellings jobs have always used.
  CHECK(parse({{"denoiser", "auto"}, {"mixer", "auto"}}).denoiser == kDefaultDenoiser);
  CHECK(parse({{"mixer", "auto"}}).mixer == kDefaultMixerKind);
  CHECK(parse({{"denoiser", "none"}}).denoiser == "none");
  const PipelineOptions stein = parse({{"mixer", "stein"}});
  CHECK((stein.mixer == MixerKind::closed_form && stein.closed_form.rule == ClosedFormRule::stein));
  const PipelineOptions inv = parse({{"mixer", "inverse-error"}});
  CHECK((inv.mixer == MixerKind::closed_form &&
         inv.closed_form.rule == ClosedFormRule::inverse_error));
  CHECK(parse({{"mixer", "closed-form"}}).closed_form.rule == ClosedFormRule::stein);
  CHECK(parse({{"mixer", "network"}}).mixer == MixerKind::network);
  // The CLI's spellings, now also job keys.
  const PipelineOptions all = parse({{"denoiser", "gaussian"},
                                     {"mixer", "closed-form"},
                                     {"closed_form_rule", "inverse-error"},
                                     {"mixer_radius", 6},
                                     {"divergence", "mc"},
                                     {"probes", 3},
                                     {"t_test", false},
                                     {"ttest_dof", false},
                                     {"ttest_fine", false},
                                     {"features", false},
                                     {"tile", 64},
                                     {"search_radius", 4},
                                     {"patch_radius", 2}});
  CHECK(all.denoiser == "gaussian");
  CHECK(all.closed_form.rule == ClosedFormRule::inverse_error);
  CHECK(all.closed_form.radius == 6);
  CHECK(all.divergence == DivergenceMethod::monte_carlo);
  CHECK(all.probes.count == 3);
  CHECK_FALSE(all.t_test);
  CHECK_FALSE(all.ttest_fine);
  CHECK_FALSE(all.ttest.dof_correction);
  CHECK_FALSE(all.features);
  CHECK(all.tile == 64);
  CHECK(all.nlmeans.search_radius == 4);
  CHECK(all.nlmeans.patch_radius == 2);
  // settings_json reads back what parse set, and parses back to itself.
  const json s = protocol::settings_json(all);
  CHECK(s["closed_form_rule"] == "inverse-error");
  CHECK(s["tile"] == 64);
  CHECK(protocol::settings_json(parse(s)) == s);
  CHECK(protocol::settings_json(parse(json::object())) == protocol::settings_json(defaults));

  // Errors name the key; the job API prefixes it with "pipeline.".
  const auto key_of = [&](const json& p) {
    try {
      parse(p);
    } catch (const PipelineError& e) {
      return e.key();
    }
    return std::string();
  };
  CHECK(key_of({{"tile", 4}}) == "tile");           // below the front ends' bound
  CHECK(key_of({{"tile", "64"}}) == "tile");        // wrong type
  CHECK(key_of({{"t_test", 1}}) == "t_test");       // wrong type
  CHECK(key_of({{"mixer", "neural"}}) == "mixer");  // not a value
  CHECK(key_of({{"denoiser", "magic"}}) == "denoiser");
  CHECK(key_of({{"weights", "/etc/passwd"}}) == "weights");  // CLI only
  CHECK(key_of({{"mixer_raduis", 3}}) == "mixer_raduis");    // unknown key
  CHECK(key_of({{"mixer", "stein"}, {"closed_form_rule", "inverse-error"}}) == "closed_form_rule");
  CHECK(key_of({{"mixer", "stein"}, {"closed_form_rule", "stein"}}).empty());
  try {
    protocol::parse_job_spec(
        {{"name", "j"}, {"output", {{"dir", "/tmp/x"}}}, {"pipeline", {{"mixer", "neural"}}}});
    FAIL("accepted mixer neural");
  } catch (const protocol::ApiError& e) {
    CHECK(e.status() == 400);
    CHECK_THAT(std::string(e.what()), Catch::StartsWith("pipeline.mixer: ") &&
                                          Catch::Contains("network") &&
                                          Catch::Contains("inverse-error"));
  }
  // The job echoes what was given, denoiser and mixer defaulting to "auto", and round-trips.
  const auto job = protocol::parse_job_spec(
      {{"name", "j"}, {"output", {{"dir", "/tmp/x"}}}, {"pipeline", {{"tile", 64}}}});
  const json echoed = protocol::to_json(job)["pipeline"];
  CHECK(echoed == json{{"denoiser", "auto"}, {"mixer", "auto"}, {"tile", 64}});
  json persisted = protocol::to_json(job);
  persisted["id"] = "j1";
  CHECK(protocol::settings_json(protocol::job_from_json(persisted).pipeline.options) ==
        protocol::settings_json(job.pipeline.options));
}

TEST_CASE("the pipeline asks the accumulator only for what its denoiser reads",
          "[pipeline][object]") {
  const auto reads = [](const std::string& denoiser, bool features) {
    PipelineOptions o;
    o.denoiser = denoiser;
    o.features = features;
    Pipeline p(o);
    p.commit();
    return p.estimate_options();
  };
  CHECK(reads("nlmeans", true).features);
  CHECK_FALSE(reads("nlmeans", false).features);
  CHECK_FALSE(reads("gaussian", true).features);
  CHECK_FALSE(reads("none", true).features);
  // NFOR regresses each half buffer on the other's weights (docs/nfor.md), and the cascade runs
  // it (docs/cascade.md).
  CHECK(reads("cascade", true).halves);
  CHECK(reads("cascade", true).features);
  CHECK(reads("nfor", true).halves);
  CHECK(reads("nfor", true).features);
  CHECK(reads("nfor", false).halves);
  CHECK_FALSE(reads("nfor", false).features);
  // Every other denoiser reads them for the error estimate, which cross-validates it on half A
  // against half B (docs/error_estimate.md); "none" reads nothing.
  for (const auto& d : denoisers()) CHECK(reads(std::string(d.name), true).halves);
  CHECK_FALSE(reads("none", true).halves);
  // A denoiser that reads the halves is cross-validated on a half with its quarters as halves.
  CHECK(reads("nfor", true).quarters);
  CHECK(reads("cascade", false).quarters);
  CHECK_FALSE(reads("nlmeans", true).quarters);
  CHECK_FALSE(reads("gaussian", true).quarters);
  CHECK_FALSE(reads("none", true).quarters);
  // A frame estimated that way runs, and its inputs say what was used.
  FrameAccumulator f;
  for (std::uint64_t k = 0; k < 3; ++k) {
    f.add(test::make_pass(20, 20, 4, 7 + k, Layout{true, true, true, false}), std::to_string(k));
  }
  for (const auto& [name, want] : {std::pair{"nlmeans", "HDR+ALB+NRM+DEP"},
                                   {"nfor", "HDR+ALB+NRM+DEP"},
                                   {"gaussian", "HDR"}}) {
    PipelineOptions o = small_options();
    o.denoiser = name;
    Pipeline p(o);
    p.commit();
    CHECK(p.execute(f.estimate(p.estimate_options())).inputs.to_string() == want);
  }
}

TEST_CASE("a tiled denoiser sees each pixel once: no tile re-denoises a halo",
          "[pipeline][object][tiles]") {
  const FrameEstimate f = small_frame();  // 45x31
  PipelineOptions o = small_options();
  o.tile = 8;  // 6 x 4 tiles, much smaller than the mixer's and the t-test's halo
  Pipeline ref(o);
  ref.commit();
  const PipelineResult want = ref.execute(f);
  Pipeline p(o);
  auto counted = std::make_shared<CountingTiles>(std::make_unique<NlMeansDenoiser>(o.nlmeans));
  p.set_denoiser(counted);
  p.commit();
  const PipelineResult got = p.execute(f);
  // Every pixel once for y, and once on each half for the error estimate's cross-validation.
  CHECK(got.estimated_error.source == "variance+cross-validation");
  CHECK(counted->calls.load() == 3 * 6 * 4);
  CHECK(counted->pixels.load() == 3 * 45 * 31);
  CHECK(same(got.result, want.result));
  CHECK(same(got.denoised, want.denoised));
  CHECK(same(got.sure, want.sure));
}

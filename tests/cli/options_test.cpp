// The CLI's flags and a job's `pipeline` object are one vocabulary: the same choices given either
// way parse to the same PipelineOptions, and pipelines built from them compute the same frame.
// Parses real command lines with the CLI's own parser (cli::DenoiseCommand, as `proden` does).
#include <catch2/catch.hpp>

#include <cmath>
#include <string>
#include <vector>

#include "cli/options.hpp"
#include "proden/progressive.hpp"
#include "proden/protocol/api.hpp"
#include "proden/protocol/pipeline_spec.hpp"

using namespace proden;
using nlohmann::json;

namespace {

// The options `proden denoise <flags> --out o.exr p.exr` runs with.
PipelineOptions from_cli(std::vector<std::string> flags) {
  CLI::App app;
  cli::DenoiseCommand den;
  den.add_to(app);
  std::vector<std::string> args = {"proden", "denoise"};
  args.insert(args.end(), flags.begin(), flags.end());
  args.insert(args.end(), {"--out", "o.exr", "p.exr"});
  std::vector<const char*> argv;
  for (const auto& a : args) argv.push_back(a.c_str());
  app.parse(static_cast<int>(argv.size()), argv.data());
  den.finish();
  return protocol::parse_pipeline_options(den.options.pipeline);
}

// The options a job created with this `pipeline` object runs with.
PipelineOptions from_job(const json& pipeline) {
  return protocol::parse_job_spec(
             {{"name", "j"}, {"output", {{"dir", "/tmp/o"}}}, {"pipeline", pipeline}})
      .pipeline.options;
}

// A small noisy frame with features.
FrameEstimate frame() {
  FrameEstimate f;
  const int w = 37, h = 29;
  f.mean = Image(w, h, 3);
  f.variance = Image(w, h, 3);
  f.albedo = Image(w, h, 3, 0.5f);
  f.normal = Image(w, h, 3, 0.0f);
  f.depth = Image(w, h, 1, 1.0f);
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const float truth = 0.3f + (x > w / 2 ? 0.4f : 0.0f) + 0.01f * static_cast<float>(y);
        const float noise = 0.1f * std::sin(12.9898f * static_cast<float>(x * 3 + y * 7 + c));
        f.mean.at(x, y, c) = truth + noise;
        f.variance.at(x, y, c) = 0.01f * truth;
        if (x < w / 3) f.albedo.at(x, y, c) = 0.9f;
      }
    }
  }
  return f;
}

}  // namespace

TEST_CASE("CLI flags and the job's pipeline object parse to the same options", "[cli][options]") {
  struct Case {
    std::vector<std::string> flags;
    json job;
  };
  const std::vector<Case> cases = {
      {{}, json::object()},
      {{}, {{"denoiser", "auto"}, {"mixer", "auto"}}},
      {{"--mixer", "closed-form", "--closed-form-rule", "inverse-error"},
       {{"mixer", "inverse-error"}}},
      {{"--mixer", "inverse-error"},
       {{"mixer", "closed-form"}, {"closed_form_rule", "inverse-error"}}},
      {{"--mixer", "stein"}, {{"mixer", "closed-form"}}},
      {{"--mixer", "network"}, {{"mixer", "network"}}},
      {{"--denoiser", "gaussian", "--no-ttest", "--tile", "64"},
       {{"denoiser", "gaussian"}, {"t_test", false}, {"tile", 64}}},
      {{"--no-features", "--no-ttest-dof", "--divergence", "mc", "--probes", "2", "--search-radius",
        "3", "--patch-radius", "1", "--mixer-radius", "5"},
       {{"features", false},
        {"ttest_dof", false},
        {"divergence", "mc"},
        {"probes", 2},
        {"search_radius", 3},
        {"patch_radius", 1},
        {"mixer_radius", 5}}},
      {{"--denoiser", "none"}, {{"denoiser", "none"}}},
  };
  const FrameEstimate f = frame();
  for (const auto& c : cases) {
    std::string cmd;
    for (const auto& a : c.flags) cmd += a + " ";
    INFO("proden denoise " << cmd << "<-> pipeline " << c.job.dump());
    const PipelineOptions cli = from_cli(c.flags);
    const PipelineOptions job = from_job(c.job);
    CHECK(protocol::settings_json(cli) == protocol::settings_json(job));
    CHECK(cli.denoiser == job.denoiser);
    CHECK(cli.mixer == job.mixer);
    CHECK(cli.closed_form.rule == job.closed_form.rule);
    CHECK(cli.closed_form.radius == job.closed_form.radius);
    CHECK(cli.t_test == job.t_test);
    CHECK(cli.ttest.dof_correction == job.ttest.dof_correction);
    CHECK(cli.features == job.features);
    CHECK(cli.divergence == job.divergence);
    CHECK(cli.probes.count == job.probes.count);
    CHECK(cli.tile == job.tile);
    CHECK(cli.nlmeans.search_radius == job.nlmeans.search_radius);
    CHECK(cli.nlmeans.patch_radius == job.nlmeans.patch_radius);
    // And they compute the same frame.
    Pipeline a(cli), b(job);
    a.commit();
    b.commit();
    const PipelineResult ra = a.execute(f), rb = b.execute(f);
    CHECK(ra.denoiser == rb.denoiser);
    CHECK(ra.mixer == rb.mixer);
    CHECK(std::equal(ra.result.data().begin(), ra.result.data().end(), rb.result.data().begin()));
    CHECK(ra.estimated_error.mse == rb.estimated_error.mse);
  }
  // The flags really change something (the comparison above could not pass vacuously).
  CHECK(from_cli({"--mixer", "inverse-error"}).closed_form.rule == ClosedFormRule::inverse_error);
  CHECK(from_cli({"--tile", "64"}).tile == 64);
  CHECK_FALSE(from_cli({"--no-features"}).features);
  CHECK(from_cli({"--denoiser", "gaussian"}).denoiser == "gaussian");
}

TEST_CASE("every option of the vocabulary is a denoise flag, and every denoiser a choice",
          "[cli][options]") {
  CLI::App app;
  cli::DenoiseCommand den;
  den.add_to(app);
  for (const auto& info : protocol::pipeline_option_table()) {
    INFO(info.key() << " " << info.flag);
    CHECK(den.command->get_option_no_throw(info.flag) != nullptr);
    CHECK(protocol::cli_flag(info.key()) == info.flag);
  }
  const auto& choices = protocol::find_option("denoiser")->choices;
  for (const auto& d : denoisers()) {
    CHECK(std::find(choices.begin(), choices.end(), std::string(d.name)) != choices.end());
  }
  CHECK(std::find(choices.begin(), choices.end(), "none") != choices.end());
}

// proden command line: denoise (accumulate passes and run the pipeline), eval (error metrics
// against a reference), info (what a pass file holds).
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <tbb/global_control.h>

#include <CLI/CLI.hpp>
#include <memory>

#include "cli/commands.hpp"
#include "cli/options.hpp"
#include "daemon/serve.hpp"
#include "proden/protocol/publish.hpp"

namespace {

using namespace proden;

void add_input_options(CLI::App* cmd, cli::InputOptions& in, std::string& renderer) {
  cmd->add_option("--renderer", renderer, "Renderer profile: auto, cycles, povray, generic")
      ->check(CLI::IsMember({"auto", "cycles", "povray", "generic"}))
      ->capture_default_str();
  cmd->add_option("--spp", in.spp, "Samples per pixel of each pass whose file does not say")
      ->check(CLI::PositiveNumber);
  cmd->add_flag("!--no-features", in.features,
                "Ignore albedo/normal/depth even if the passes carry them");
}

}  // namespace

int main(int argc, char** argv) {
  auto logger = spdlog::stderr_color_mt("proden");
  logger->set_pattern("proden: %^%l%$: %v");
  spdlog::set_default_logger(logger);

  CLI::App app{"proden: progressive denoising of render-farm passes"};
  app.set_version_flag("--version", protocol::software());
  app.require_subcommand(1);
  int threads = 0;
  bool verbose = false;
  app.add_option("--threads", threads, "Worker threads (0 = all cores)")
      ->check(CLI::NonNegativeNumber);
  app.add_flag("-v,--verbose", verbose, "Debug logging");

  std::string renderer = "auto";
  cli::DenoiseOptions den;
  bool quiet = false;
  auto* d = app.add_subcommand("denoise", "Accumulate one frame's passes and write the result");
  add_input_options(d, den.input, renderer);
  d->add_option("--out", den.out, "Output EXR")->required();
  d->add_flag("--aov", den.aov,
              "Also write render, variance, denoised, alpha, sure and mixvariance layers");
  d->add_flag("--half", den.half, "Write 16-bit half floats instead of 32-bit");
  d->add_flag("--json", den.json, "Print a JSON summary of the frame on stdout");
  d->add_flag("-q,--quiet", quiet, "No progress display");
  d->add_option("passes", den.passes, "Pass files of one frame")->required();
  // The pipeline's options, spelt as the daemon's job JSON spells them (docs/api.md).
  cli::PipelineFlags pipeline_flags;
  pipeline_flags.add_to(*d);
  d->add_flag("--timings", den.timings, "Print the time of each stage");

  cli::EvalOptions ev;
  auto* e = app.add_subcommand("eval", "Error metrics (RMSE, relMSE, SMAPE) against a reference");
  add_input_options(e, ev.input, renderer);
  e->add_option("--ref", ev.references,
                "Reference image; repeat for a reference rendered in passes (their mean is used)")
      ->required()
      ->allow_extra_args(false);
  e->add_option("images", ev.images, "Images to evaluate")->required();
  e->add_flag("--json", ev.json, "JSON output");
  e->add_option("--layer", ev.layers,
                "Layer to evaluate: result (R,G,B), render, denoised, ...; repeatable")
      ->allow_extra_args(false);

  cli::InfoOptions inf;
  auto* i = app.add_subcommand("info", "Show what proden detects in pass files");
  add_input_options(i, inf.input, renderer);
  i->add_option("files", inf.files, "Pass files")->required();
  i->add_flag("--json", inf.json, "JSON output");

  proden::daemon::add_serve_command(app);  // `proden serve`: runs the daemon and exits

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& err) {
    const int rc = app.exit(err);
    return rc == 0 ? cli::kOk : cli::kUsage;
  }
  if (verbose) spdlog::set_level(spdlog::level::debug);
  const auto r = io::parse_renderer(renderer).value_or(io::Renderer::automatic);
  den.input.renderer = ev.input.renderer = inf.input.renderer = r;
  den.progress = !quiet;
  den.pipeline = pipeline_flags.given();

  std::unique_ptr<tbb::global_control> limit;
  if (threads > 0) {
    limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                  static_cast<std::size_t>(threads));
  }
  try {
    if (d->parsed()) return cli::run_denoise(den);
    if (e->parsed()) return cli::run_eval(ev);
    if (i->parsed()) return cli::run_info(inf);
  } catch (const std::exception& ex) {
    spdlog::critical("internal error: {}", ex.what());
    return cli::kInternalError;
  }
  return cli::kUsage;
}

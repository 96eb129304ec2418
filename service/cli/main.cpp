// proden command line: denoise (accumulate passes and run the pipeline), eval (error metrics
// against a reference), info (what a pass file holds).
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <tbb/global_control.h>

#include <CLI/CLI.hpp>
#include <memory>

#include "cli/commands.hpp"
#include "cli/wait.hpp"
#include "daemon/serve.hpp"

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
  cmd->add_option("--view-layer", in.view_layer,
                  "Blender view layer to read from multilayer EXRs (default: the "
                  "alphabetically first)");
}

}  // namespace

int main(int argc, char** argv) {
  auto logger = spdlog::stderr_color_mt("proden");
  logger->set_pattern("proden: %^%l%$: %v");
  spdlog::set_default_logger(logger);

  CLI::App app{"proden: progressive denoising of render-farm passes"};
  app.set_version_flag("--version", std::string("proden ") + PRODEN_VERSION);
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
  std::string divergence = "auto", mixer = "closed-form", rule = "stein", denoiser = "nlmeans";
  d->add_option("--denoiser", denoiser,
                "nlmeans (feature-guided, default) or gaussian (fast, biased reference)")
      ->check(CLI::IsMember({"nlmeans", "gaussian"}))
      ->capture_default_str();
  d->add_option("--divergence", divergence,
                "SURE divergence: auto (analytic when the denoiser offers it), analytic, mc")
      ->check(CLI::IsMember({"auto", "analytic", "mc"}))
      ->capture_default_str();
  d->add_option("--probes", den.pipeline.probes.count, "Monte-Carlo probes for --divergence mc")
      ->check(CLI::Range(1, 64))
      ->capture_default_str();
  mixer = network::kDefaultMixer;
  d->add_option("--mixer", mixer,
                "Mixing weights: network (the learned PDNet) or closed-form (Stein window rule)")
      ->check(CLI::IsMember({"network", "closed-form"}))
      ->capture_default_str();
  d->add_option("--weights", den.weights,
                "Network weights file (.pdnw) instead of the built-in ones (--mixer network)");
  d->add_option("--closed-form-rule", rule,
                "stein (MSE-optimal, accounts for y depending on x) or inverse-error")
      ->check(CLI::IsMember({"stein", "inverse-error"}))
      ->capture_default_str();
  d->add_flag("!--no-ttest", den.pipeline.t_test, "Skip the t-statistic rescale of alpha");
  d->add_flag("!--no-ttest-dof", den.pipeline.ttest.dof_correction,
              "The authors' fixed t-test threshold (no degrees-of-freedom correction)");
  d->add_option("--mixer-radius", den.pipeline.mixer.radius,
                "Closed-form mixer: window radius of its smoothed estimates")
      ->check(CLI::Range(0, 16))
      ->capture_default_str();
  d->add_option("--tile", den.pipeline.tile, "Tile size in pixels")
      ->check(CLI::Range(8, 4096))
      ->capture_default_str();
  d->add_option("--search-radius", den.pipeline.nlmeans.search_radius, "NL-means search radius")
      ->check(CLI::Range(0, 32))
      ->capture_default_str();
  d->add_option("--patch-radius", den.pipeline.nlmeans.patch_radius, "NL-means patch radius")
      ->check(CLI::Range(0, 16))
      ->capture_default_str();
  d->add_flag("--timings", den.timings, "Print the time of each stage");
  d->add_flag(
      "!--no-renderer-aovs", den.renderer_aovs,
      "Do not accumulate the passes' AOVs (Combined.A, Depth, Mist, ...) beside the result");

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

  cli::WaitOptions wt;
  auto* w = app.add_subcommand(
      "wait",
      "Block until a frame on a running `proden serve` is converged or has a version > K "
      "(exit 0; 4 timeout, 5 no such job, 6 daemon unreachable)");
  w->add_option("--job", wt.job, "Job id")->required();
  w->add_option("--frame", wt.frame, "Frame number")->required()->check(CLI::NonNegativeNumber);
  w->add_option("--until", wt.until, "converged (default) or version>K")->capture_default_str();
  w->add_option("--timeout", wt.timeout, "Seconds to wait (default: no limit)")
      ->check(CLI::NonNegativeNumber);
  w->add_option("--url", wt.url, "Daemon URL (default: $PRODEN_URL or http://127.0.0.1:8080)");
  w->add_option("--token-file", wt.token_file, "Bearer token file");
  w->add_flag("--json", wt.json, "Print the frame status as JSON");
  w->add_flag("-q,--quiet", wt.quiet, "Print nothing; the exit code says");

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
  den.pipeline.features = den.input.features;
  den.pipeline.denoiser =
      denoiser == "gaussian" ? BuiltinDenoiser::gaussian : BuiltinDenoiser::nlmeans;
  den.pipeline.divergence = divergence == "analytic" ? DivergenceMethod::analytic
                            : divergence == "mc"     ? DivergenceMethod::monte_carlo
                                                     : DivergenceMethod::automatic;
  den.mixer = mixer;
  den.pipeline.mixer.rule =
      rule == "inverse-error" ? ClosedFormRule::inverse_error : ClosedFormRule::stein;

  std::unique_ptr<tbb::global_control> limit;
  if (threads > 0) {
    limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                  static_cast<std::size_t>(threads));
  }
  try {
    if (d->parsed()) return cli::run_denoise(den);
    if (e->parsed()) return cli::run_eval(ev);
    if (i->parsed()) return cli::run_info(inf);
    if (w->parsed()) return cli::run_wait(wt);
  } catch (const std::exception& ex) {
    spdlog::critical("internal error: {}", ex.what());
    return cli::kInternalError;
  }
  return cli::kUsage;
}

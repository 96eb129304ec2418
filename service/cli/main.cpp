// proden command line: denoise (accumulate passes and run the pipeline), eval (error metrics
// against a reference), info (what a pass file holds).
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <signal.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <CLI/CLI.hpp>
#include <memory>

#include "cli/commands.hpp"
#include "cli/options.hpp"
#include "cli/wait.hpp"
#include "daemon/serve.hpp"
#include "huge_pages.hpp"
#include "proden/protocol/publish.hpp"
#include "thread_limit.hpp"

using namespace proden;

namespace {

constexpr unsigned long kStopSignalMask = (1UL << (SIGTERM - 1)) | (1UL << (SIGINT - 1));

// Blocks SIGTERM and SIGINT before any shared library's constructor runs (.preinit_array runs
// first), so every thread a library starts (OpenBLAS starts its pool when it is loaded) inherits
// the mask and `proden serve` takes its stop signals on one thread, from a signalfd
// (daemon/serve.cpp). The raw system call: this may run before a sanitizer's runtime has set up
// its interceptors. main() unblocks them again for the other commands.
extern "C" void proden_block_stop_signals(int, char**, char**) {
  ::syscall(SYS_rt_sigprocmask, SIG_BLOCK, &kStopSignalMask, nullptr, sizeof kStopSignalMask);
}
[[gnu::section(".preinit_array"),
  gnu::used]] void (*const block_early)(int, char**, char**) = proden_block_stop_signals;

}  // namespace

int main(int argc, char** argv) {
  auto logger = spdlog::stderr_color_mt("proden");
  logger->set_pattern("proden: %^%l%$: %v");
  spdlog::set_default_logger(logger);

  // Before parsing: `proden serve` runs inside its parse callback (one thread in a TSan build).
  auto limit = limit_threads(0);
  CLI::App app{"proden: progressive denoising of render-farm passes"};
  app.set_version_flag("--version", protocol::software());
  app.require_subcommand(1);
  int threads = 0;
  bool verbose = false;
  app.add_option("--threads", threads, "Worker threads (0 = all cores)")
      ->check(CLI::NonNegativeNumber);
  app.add_flag("-v,--verbose", verbose, "Debug logging");

  cli::DenoiseCommand den;
  den.add_to(app);

  std::string renderer = "auto";
  cli::EvalOptions ev;
  auto* e = app.add_subcommand("eval", "Error metrics (RMSE, relMSE, SMAPE) against a reference");
  cli::add_input_flags(*e, ev.input, renderer);
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
  cli::add_input_flags(*i, inf.input, renderer);
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

  // `proden serve`: runs the daemon and exits; its start-up line says how large blocks are paged.
  proden::daemon::add_serve_command(app, huge_pages_name(huge_pages()));

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& err) {
    const int rc = app.exit(err);
    return rc == 0 ? cli::kOk : cli::kUsage;
  }
  // Not `serve` (whose callback ran the daemon and exited): Ctrl-C and SIGTERM end the command.
  ::syscall(SYS_rt_sigprocmask, SIG_UNBLOCK, &kStopSignalMask, nullptr, sizeof kStopSignalMask);
  if (verbose) spdlog::set_level(spdlog::level::debug);
  den.finish();
  const auto r = io::parse_renderer(renderer).value_or(io::Renderer::automatic);
  ev.input.renderer = inf.input.renderer = r;

  if (threads > 0) limit = limit_threads(threads);
  try {
    if (den.command->parsed()) return cli::run_denoise(den.options);
    if (e->parsed()) return cli::run_eval(ev);
    if (i->parsed()) return cli::run_info(inf);
    if (w->parsed()) return cli::run_wait(wt);
  } catch (const std::exception& ex) {
    spdlog::critical("internal error: {}", ex.what());
    return cli::kInternalError;
  }
  return cli::kUsage;
}

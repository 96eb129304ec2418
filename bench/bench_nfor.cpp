// NFOR's speed against NL-means in one run (issue 10's target: <= 10 us of wall time per pixel
// at 1920x1080 with features, 2 threads): the same synthetic Cycles-like frame (colour + albedo +
// normal + depth, 8 passes of 4 spp, both half buffers), NL-means alone in the pipeline's tiles,
// then NFOR whole-frame with each kernel build this CPU has, with its stage times; optionally
// also with the cross-validation error estimate and the hat diagonal.
//
//   proden_bench_nfor [--width W --height H] [--threads N] [--repeat R] [--isa NAME]...
//                     [--extras] [--no-second-pass] [--bandwidths K1,K2] [--json FILE]
#include <sys/resource.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "../pipeline/src/denoise/nfor_internal.hpp"
#include "bench_common.hpp"
#include "proden/accumulator.hpp"
#include "proden/denoise/nfor.hpp"
#include "proden/progressive.hpp"

using namespace proden;
using Clock = std::chrono::steady_clock;

namespace {

double since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Peak resident set (VmHWM) in bytes, 0 if unknown.
double peak_rss_bytes() {
  std::FILE* f = std::fopen("/proc/self/status", "r");
  if (!f) return 0.0;
  char line[256];
  double kb = 0.0;
  while (std::fgets(line, sizeof line, f)) {
    if (std::strncmp(line, "VmHWM:", 6) == 0) kb = std::atof(line + 6);
  }
  std::fclose(f);
  return kb * 1024.0;
}

// CPU seconds (user + system) of the process so far.
double cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

struct Row {
  std::string what;
  double wall = 0;  // best of the repeats
  double cpu = 0;   // process CPU seconds of that repeat
  NforExtras::Timings stages;
};

}  // namespace

int main(int argc, char** argv) {
  int w = 1920, h = 1080, threads = 2, repeat = 1;
  bool extras_too = false;
  NforParams base;
  std::vector<std::string> isas;
  std::string json_path;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const bool more = i + 1 < argc;
    if (a == "--width" && more) {
      w = std::atoi(argv[++i]);
    } else if (a == "--height" && more) {
      h = std::atoi(argv[++i]);
    } else if (a == "--threads" && more) {
      threads = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--repeat" && more) {
      repeat = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--isa" && more) {
      isas.emplace_back(argv[++i]);
    } else if (a == "--extras") {
      extras_too = true;
    } else if (a == "--no-second-pass") {
      base.second_pass = false;
    } else if (a == "--bandwidths" && more) {
      if (std::sscanf(argv[++i], "%f,%f", &base.bandwidths[0], &base.bandwidths[1]) != 2) {
        std::fprintf(stderr, "--bandwidths K1,K2\n");
        return 2;
      }
    } else if (a == "--json" && more) {
      json_path = argv[++i];
    } else {
      std::fprintf(stderr,
                   "usage: %s [--width W --height H] [--threads N] [--repeat R] [--isa NAME]... "
                   "[--extras] [--no-second-pass] [--bandwidths K1,K2] [--json FILE]\n",
                   argv[0]);
      return 2;
    }
  }
  if (isas.empty()) isas = nfor::isas_available();
  tbb::global_control limit(tbb::global_control::max_allowed_parallelism,
                            static_cast<std::size_t>(threads));
  FrameAccumulator acc;
  for (int k = 0; k < 8; ++k)
    acc.add(bench::synthetic_pass(w, h, k, 4.0), "pass_" + std::to_string(k));
  const FrameEstimate est = acc.estimate();
  const DenoiseInputs din = denoise_inputs(est, est.mean, est.variance, true);
  const double px = static_cast<double>(w) * h;
  std::printf(
      "%dx%d, HDR+ALB+NRM+DEP, 8 passes x 4 spp (both halves), %d thread(s), best of %d; NFOR "
      "bandwidths %g,%g, second pass %s\n",
      w, h, threads, repeat, static_cast<double>(base.bandwidths[0]),
      static_cast<double>(base.bandwidths[1]), base.second_pass ? "on" : "off");

  std::vector<Row> rows;
  const double rss_before = peak_rss_bytes();
  {
    Row r;
    r.what = "nlmeans (r=5 f=3, tiles 256, no Jacobian)";
    r.wall = 1e30;
    const NlMeansDenoiser nl;
    for (int i = 0; i < repeat; ++i) {
      const double c0 = cpu_seconds();
      const auto t0 = Clock::now();
      bench::tiled_denoise(nl, din, 256);
      const double s = since(t0);
      if (s < r.wall) {
        r.wall = s;
        r.cpu = cpu_seconds() - c0;
      }
    }
    rows.push_back(r);
  }
  auto nfor_row = [&](const std::string& isa, bool cv, bool hat) {
    NforParams p = base;
    p.isa = isa;
    const NforDenoiser den(p);
    Row r;
    r.what = "nfor " + isa + (cv ? " + cross-validation" : "") + (hat ? " + hat" : "");
    r.wall = 1e30;
    for (int i = 0; i < repeat; ++i) {
      NforExtras ex;
      ex.want_cross_validation = cv;
      ex.want_hat = hat;
      const double c0 = cpu_seconds();
      const auto t0 = Clock::now();
      den.run(din, &ex);
      const double s = since(t0);
      if (s < r.wall) {
        r.wall = s;
        r.cpu = cpu_seconds() - c0;
        r.stages = ex.seconds;
      }
    }
    rows.push_back(r);
  };
  for (const auto& isa : isas) nfor_row(isa, false, false);
  if (extras_too) {
    nfor_row(isas.back(), true, false);
    nfor_row(isas.back(), false, true);
  }

  const double nl_us = rows[0].wall / px * 1e6;
  const double rss_after = peak_rss_bytes();
  std::printf(
      "peak RSS: %.0f MB with the frame's passes, accumulator and estimate; %.0f MB after "
      "the denoisers (NFOR's planes: +%.0f MB)\n",
      rss_before / 1e6, rss_after / 1e6, (rss_after - rss_before) / 1e6);
  std::printf("%-44s %8s %8s %8s %8s %6s | %7s %7s %7s %7s %7s\n", "denoiser", "wall s", "us/px",
              "/NLM", "CPU us", "cores", "load", "prefilt", "pass 1", "select", "pass 2");
  for (const Row& r : rows) {
    const double us = r.wall / px * 1e6;
    std::printf("%-44s %8.3f %8.2f %8.2f %8.2f %6.2f", r.what.c_str(), r.wall, us, us / nl_us,
                r.cpu / px * 1e6, r.cpu / r.wall);
    if (r.stages.total > 0) {
      std::printf(" | %7.3f %7.3f %7.3f %7.3f %7.3f", r.stages.load, r.stages.prefilter,
                  r.stages.first_pass, r.stages.selection, r.stages.second_pass);
    }
    std::printf("\n");
  }
  if (!json_path.empty()) {
    std::FILE* f = std::fopen(json_path.c_str(), "w");
    if (!f) {
      std::perror(json_path.c_str());
      return 1;
    }
    std::fprintf(f,
                 "{\"width\": %d, \"height\": %d, \"threads\": %d, \"repeat\": %d, "
                 "\"second_pass\": %s, \"peak_rss_before\": %.0f, \"peak_rss_after\": %.0f, "
                 "\"rows\": [\n",
                 w, h, threads, repeat, base.second_pass ? "true" : "false", rss_before, rss_after);
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const Row& r = rows[i];
      std::fprintf(f,
                   "  {\"denoiser\": \"%s\", \"wall_s\": %.6f, \"us_per_pixel\": %.4f, "
                   "\"over_nlmeans\": %.4f, \"cpu_us_per_pixel\": %.4f, "
                   "\"stages\": {\"load\": %.6f, \"prefilter\": %.6f, "
                   "\"first_pass\": %.6f, \"selection\": %.6f, \"second_pass\": %.6f}}%s\n",
                   r.what.c_str(), r.wall, r.wall / px * 1e6, r.wall / rows[0].wall,
                   r.cpu / px * 1e6, r.stages.load, r.stages.prefilter, r.stages.first_pass,
                   r.stages.selection, r.stages.second_pass, i + 1 < rows.size() ? "," : "");
    }
    std::fprintf(f, "]}\n");
    std::fclose(f);
  }
  return 0;
}

// Performance harness: per-stage time of a full progressive update on synthetic Cycles-like
// frames (colour + albedo + normal + depth, 8 passes of 4 spp) at 1920x1080 and 3840x2160, with 1
// and N threads: EXR read of a pass and write of the published frame (I/O), accumulate (add one
// pass), estimate, denoise, SURE, mixer, t-test, compose; megapixels per second; peak memory
// (VmHWM) and bytes of accumulated state per pixel; and the ratios the project tracks, all from
// this one run:
//   update / one more Cycles spp (needs --cycles-spp-seconds, measured by bench/run_all.sh with
//   Blender in the same run), SURE / one denoiser run (analytic and Monte-Carlo), mixer GFLOP/s /
//   sgemm GFLOP/s (n/a until the learned mixer lands; sgemm is measured), N threads / 1, 4K /
//   1080p.
//
//   proden_bench_pipeline [--width W --height H] [--no-4k] [--no-mc] [--no-io] [--threads N]
//                         [--cycles-spp-seconds S] [--json FILE] [--tmp DIR] [--repeat N]
//                         [--pass FILE]...
//
// --pass FILE (repeated): a real frame instead of the synthetic ones, its passes in this order
// (e.g. Cycles renders of bench/cycles_frame.py at 1920x1080): the last is the one read and
// added timed, and the update publishes what the pipeline made of the real frame. Synthetic
// noise compresses worse than a rendered frame: the published frame's PIZ write took 2.0 s on
// synthetic data and 1.5-1.9 s on Cycles frames (bench/RESULTS.md, "A full update on real
// frames").
//
// --repeat N: the estimate, each pipeline, the denoiser alone and the published frame's write run
// N times on the same objects (warm scratch and heap, as in a daemon that keeps a frame), each
// stage's median reported; 1 (the default) is one cold call, whose time includes first-touch page
// faults.
#include <tbb/global_control.h>

#include <fcntl.h>
#include <sys/resource.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "bench_common.hpp"
#include "huge_pages.hpp"
#include "proden/accumulator.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/progressive.hpp"
#include "proden/protocol/publish.hpp"
#include "sgemm.hpp"

using namespace proden;
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {

double since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Peak resident set (VmHWM) in bytes, 0 if unknown.
double peak_rss_bytes() {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line)) {
    if (line.rfind("VmHWM:", 0) == 0) return std::atof(line.c_str() + 6) * 1024.0;
  }
  return 0.0;
}

// CPU seconds (user + system) of the process so far.
double cpu_seconds() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_utime.tv_sec + u.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(u.ru_utime.tv_usec + u.ru_stime.tv_usec);
}

using bench::synthetic_pass;

// Per-field median of repeated runs' timings.
StageTimings median_timings(const std::vector<StageTimings>& runs) {
  StageTimings m;
  for (double StageTimings::*f :
       {&StageTimings::denoise, &StageTimings::sure, &StageTimings::mixer, &StageTimings::ttest,
        &StageTimings::compose, &StageTimings::cross_validation, &StageTimings::wall}) {
    std::vector<double> v;
    for (const StageTimings& t : runs) v.push_back(t.*f);
    m.*f = bench::median(v);
  }
  return m;
}

// The denoiser alone (no Jacobian), tiled and parallel like the pipeline: "one denoiser run".
double denoise_only(const FrameEstimate& est, const PipelineOptions& po) {
  const NlMeansDenoiser nl(po.nlmeans);
  const DenoiseInputs din = denoise_inputs(est, est.mean, est.variance, true);
  const auto t0 = Clock::now();
  bench::tiled_denoise(nl, din, po.tile);
  return since(t0);
}

struct SizeResult {
  int w = 0, h = 0;
  double read_s = 0, write_s = 0, exr_mb = 0;
  // The published frame: written uncompressed as the daemon publishes it (auto), PIZ at once as
  // the CLI writes it, and the daemon's compression of it later (read back + PIZ write).
  double write_published_s = 0, write_piz_s = 0, compress_later_s = 0;
  int published_channels = 0;
  double add_s[2] = {0, 0}, estimate_s[2] = {0, 0};
  StageTimings an[2];  // analytic, [0] = 1 thread, [1] = N threads
  StageTimings mc;     // Monte Carlo, N threads
  bool have_mc = false;
  double denoise_only_s[2] = {0, 0};
  // The Jacobian's cost over the denoiser alone, paired (bench::jacobian_pair, 1 thread): the
  // median over `jacobian_pairs` pairs of with / without - 1.
  double jacobian_paired = 0, jacobian_paired_lo = 0, jacobian_paired_hi = 0;
  int jacobian_pairs = 0;
  double cores_obtained[2] = {0, 0};  // process CPU seconds / wall during the analytic run
  double peak_bytes = 0;
  double state_bpp = 0, layout_bpp = 0;
  double update_s = 0;      // read + add + estimate + pipeline + write as published (N threads)
  double update_piz_s = 0;  // the same, the frame written PIZ at once
};

void print_json_stage(std::FILE* f, const char* name, const StageTimings& t, bool last) {
  std::fprintf(f,
               "    \"%s\": {\"denoise\": %.6f, \"sure\": %.6f, \"mixer\": %.6f, \"ttest\": %.6f, "
               "\"compose\": %.6f, \"cross_validation\": %.6f, \"wall\": %.6f}%s\n",
               name, t.denoise, t.sure, t.mixer, t.ttest, t.compose, t.cross_validation, t.wall,
               last ? "" : ",");
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<std::pair<int, int>> sizes = {{1920, 1080}, {3840, 2160}};
  int w = 0, h = 0;
  bool mc = true, io = true, four_k = true;
  int repeat = 1;
  double cycles_spp_s = 0;
  std::string json_path, tmp = fs::temp_directory_path().string();
  unsigned cores = std::max(1u, std::thread::hardware_concurrency());
  std::vector<std::string> real;  // --pass files: a real frame
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const bool more = i + 1 < argc;
    if (a == "--width" && more)
      w = std::atoi(argv[++i]);
    else if (a == "--height" && more)
      h = std::atoi(argv[++i]);
    else if (a == "--no-mc")
      mc = false;
    else if (a == "--no-io")
      io = false;
    else if (a == "--no-4k")
      four_k = false;
    else if (a == "--threads" && more)
      cores = static_cast<unsigned>(std::max(1, std::atoi(argv[++i])));
    else if (a == "--cycles-spp-seconds" && more)
      cycles_spp_s = std::atof(argv[++i]);
    else if (a == "--json" && more)
      json_path = argv[++i];
    else if (a == "--tmp" && more)
      tmp = argv[++i];
    else if (a == "--repeat" && more)
      repeat = std::max(1, std::atoi(argv[++i]));
    else if (a == "--pass" && more)
      real.emplace_back(argv[++i]);
    else {
      std::fprintf(stderr,
                   "usage: %s [--width W --height H] [--no-4k] [--no-mc] [--no-io] "
                   "[--threads N] [--cycles-spp-seconds S] [--json FILE] [--tmp DIR] [--repeat N] "
                   "[--pass FILE]...\n",
                   argv[0]);
      return 2;
    }
  }
  // A real frame: its passes read once (all but the last untimed), its size the only size.
  std::vector<Pass> real_passes;
  double real_read_s = 0, real_mb = 0;
  for (std::size_t k = 0; k < real.size(); ++k) {
    const auto t0 = Clock::now();
    real_passes.push_back(io::read_pass(real[k]));
    if (k + 1 == real.size()) {
      real_read_s = since(t0);
      real_mb = static_cast<double>(fs::file_size(real[k])) / 1e6;
    }
    if (real_passes.back().width() != real_passes.front().width() ||
        real_passes.back().height() != real_passes.front().height()) {
      std::fprintf(stderr, "%s: not the size of %s\n", real[k].c_str(), real[0].c_str());
      return 2;
    }
  }
  if (!real_passes.empty())
    sizes = {{real_passes.front().width(), real_passes.front().height()}};
  else if (w > 0 && h > 0)
    sizes = {{w, h}};
  else if (!four_k)
    sizes.resize(1);
  const int npass = real_passes.empty() ? 8 : static_cast<int>(real_passes.size());
  const double spp_per_pass = 4;
  const unsigned thr[2] = {1u, cores};
  std::vector<SizeResult> results;

  if (real_passes.empty()) {
    std::printf("synthetic Cycles-like frames: HDR+ALB+NRM+DEP, %d passes x %.0f spp; ", npass,
                spp_per_pass);
  } else {
    std::printf("a real frame: %d passes (%s ... %s); ", npass, real.front().c_str(),
                real.back().c_str());
  }
  std::printf(
      "default pipeline (NL-means r=5 f=3, closed-form Stein mixer r=12, t-test, tile 256); "
      "threads 1 and %u; estimate and pipeline: %s; large blocks on huge pages: %s\n",
      cores,
      repeat > 1 ? ("median of " + std::to_string(repeat) + " warm runs").c_str() : "one cold run",
      huge_pages_name(huge_pages()));
  for (const auto& [W, H] : sizes) {
    SizeResult s;
    s.w = W;
    s.h = H;
    const double mp = static_cast<double>(W) * H / 1e6;
    std::printf("\n== %dx%d (%.2f MP)\n", W, H, mp);
    std::fflush(stdout);
    // Passes: 7 in memory, the last one through an EXR round trip when I/O is measured; or the
    // real frame's, read above.
    std::vector<Pass> passes = std::move(real_passes);
    if (passes.empty()) {
      for (int k = 0; k < npass; ++k) passes.push_back(synthetic_pass(W, H, k, spp_per_pass));
    } else if (io) {
      s.read_s = real_read_s;
      s.exr_mb = real_mb;
    }
    if (io && real.empty()) {
      const std::string path = (fs::path(tmp) / ("proden_bench_pass_" + std::to_string(W) + "x" +
                                                 std::to_string(H) + ".exr"))
                                   .string();
      const Pass& p = passes.back();
      std::vector<io::NamedChannel> ch;
      io::add_layer(ch, "ViewLayer.Combined.", p.colour);
      io::add_layer(ch, "ViewLayer.Denoising Albedo.", p.albedo);
      io::add_layer(ch, "ViewLayer.Denoising Normal.", p.normal, "XYZ");
      io::add_layer(ch, "ViewLayer.Denoising Depth.", p.depth, "Z");
      io::WriteOptions wo;
      wo.attributes = {{"cycles.ViewLayer.samples", "4"}};
      io::write_image(path, W, H, ch, wo);  // the farm's pass (not timed: the renderer writes it)
      s.exr_mb = static_cast<double>(fs::file_size(path)) / 1e6;
      auto t0 = Clock::now();
      Pass back = io::read_pass(path);
      s.read_s = since(t0);
      fs::remove(path);
      if (back.width() != W || back.albedo.empty() || back.depth.empty()) {
        std::fprintf(stderr, "EXR round trip lost data\n");
        return 1;
      }
      passes.back() = std::move(back);
    }
    // Accumulate: all passes at 1 and N threads (fresh accumulators), add timed per pass. The
    // first add allocates the state and faults its pages in, which a resident frame's adds do
    // not: with 2 or more passes, the later ones are the time of adding a pass.
    FrameEstimate est;
    for (int ti = 0; ti < 2; ++ti) {
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism, thr[ti]);
      FrameAccumulator acc;
      double add = 0;
      const int timed_from = npass >= 2 ? 1 : 0;
      for (int k = 0; k < npass; ++k) {
        const auto t0 = Clock::now();
        acc.add(passes[static_cast<std::size_t>(k)], "pass_" + std::to_string(k));
        if (k >= timed_from) add += since(t0);
      }
      s.add_s[ti] = add / (npass - timed_from);
      FrameEstimate e;
      std::vector<double> est_s;
      for (int i = 0; i < repeat; ++i) {
        const auto t0 = Clock::now();
        e = acc.estimate();
        est_s.push_back(since(t0));
      }
      s.estimate_s[ti] = bench::median(est_s);
      s.state_bpp = static_cast<double>(acc.state_bytes()) / (static_cast<double>(W) * H);
      s.layout_bpp = static_cast<double>(FrameAccumulator::bytes_per_pixel(acc.layout()));
      if (ti == 1) est = std::move(e);
    }
    passes.clear();
    passes.shrink_to_fit();
    // Pipeline: analytic at 1 and N threads, denoiser alone at 1 and N, MC at N.
    PipelineResult run;  // the N-thread run's, written as the daemon publishes it
    for (int ti = 0; ti < 2; ++ti) {
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism, thr[ti]);
      PipelineOptions o;
      o.divergence = DivergenceMethod::analytic;
      Pipeline pipeline(o);
      pipeline.commit();
      const double c0 = cpu_seconds();
      PipelineResult r;
      std::vector<StageTimings> runs;
      double wall = 0;
      for (int i = 0; i < repeat; ++i) {
        r = pipeline.execute(est);
        runs.push_back(r.timings);
        wall += r.timings.wall;
      }
      s.cores_obtained[ti] = (cpu_seconds() - c0) / wall;
      s.an[ti] = median_timings(runs);
      std::vector<double> alone;  // the same number of runs, so the ratios compare like with like
      for (int i = 0; i < repeat; ++i) alone.push_back(denoise_only(est, o));
      s.denoise_only_s[ti] = bench::median(alone);
      if (ti == 0) {
        const NlMeansDenoiser nl(o.nlmeans);
        const DenoiseInputs din = denoise_inputs(est, est.mean, est.variance, true);
        std::vector<double> ratios;
        s.jacobian_pairs = std::max(6, 2 * repeat);
        for (int i = 0; i < s.jacobian_pairs; ++i) {
          ratios.push_back(bench::jacobian_pair(nl, din, o.tile, i % 2 == 1).cost());
        }
        s.jacobian_paired = bench::median(ratios);
        s.jacobian_paired_lo = *std::min_element(ratios.begin(), ratios.end());
        s.jacobian_paired_hi = *std::max_element(ratios.begin(), ratios.end());
      }
      if (ti == 1) run = std::move(r);
    }
    if (mc && (W * H <= 1920 * 1080 || sizes.size() == 1)) {
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism, cores);
      PipelineOptions o;
      o.divergence = DivergenceMethod::monte_carlo;
      Pipeline pipeline(o);
      pipeline.commit();
      s.mc = pipeline.execute(est).timings;
      s.have_mc = true;
    }
    if (io) {
      const std::string path = (fs::path(tmp) / "proden_bench_out.exr").string();
      std::vector<io::NamedChannel> ch;
      io::add_layer(ch, "", run.result);
      auto t0 = Clock::now();
      io::write_image(path, W, H, ch);
      s.write_s = since(t0);
      // What the daemon writes for every version (protocol/publish.hpp): every layer, with the
      // default compression `auto`, which the daemon writes uncompressed and compresses to PIZ
      // once it is idle (docs/api.md, output.compression); the CLI writes PIZ at once. With
      // --repeat, the median of that many of each.
      std::vector<double> writes, pizs, laters;
      const int dir_fd = ::open(tmp.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
      if (dir_fd < 0) throw std::runtime_error(tmp + ": cannot open");
      for (int i = 0; i < repeat; ++i) {
        protocol::FrameFormat format;
        format.compression = "piz";
        t0 = Clock::now();
        protocol::write_frame(path, run, {}, format);
        pizs.push_back(since(t0));
        format.compression = "none";
        t0 = Clock::now();
        protocol::write_frame(path, run, {}, format);
        writes.push_back(since(t0));
        t0 = Clock::now();
        io::compress_image_at(dir_fd, fs::path(path).filename().string(),
                              std::string(protocol::resolve_frame_compression("auto")), path);
        laters.push_back(since(t0));
      }
      ::close(dir_fd);
      s.write_published_s = bench::median(writes);
      s.write_piz_s = bench::median(pizs);
      s.compress_later_s = bench::median(laters);
      s.published_channels = 3 * (1 + static_cast<int>(run.layers().size()));
      fs::remove(path);
    }
    s.peak_bytes = peak_rss_bytes();
    s.update_s = s.read_s + s.add_s[1] + s.estimate_s[1] + s.an[1].wall + s.write_published_s;
    s.update_piz_s = s.update_s - s.write_published_s + s.write_piz_s;

    std::printf(
        "I/O: read one %s pass EXR (%.1f MB) %.3f s; write result RGB %.3f s; the published "
        "frame (%d ch): as the daemon publishes it (auto: none) %.3f s, then compressed to PIZ "
        "when idle %.3f s; PIZ at once (the CLI) %.3f s\n",
        real.empty() ? "synthetic Cycles-like (float, zip, 10 ch)" : "real", s.exr_mb, s.read_s,
        s.write_s, s.published_channels, s.write_published_s, s.compress_later_s, s.write_piz_s);
    std::printf("%-22s %9s %9s\n", "stage (s)", "1 thread",
                (std::to_string(cores) + " threads").c_str());
    std::printf("%-22s %9.3f %9.3f\n", "accumulate (add 1)", s.add_s[0], s.add_s[1]);
    std::printf("%-22s %9.3f %9.3f\n", "estimate", s.estimate_s[0], s.estimate_s[1]);
    std::printf("%-22s %9.3f %9.3f   (CPU s summed over tiles)\n", "denoise + Jacobian",
                s.an[0].denoise, s.an[1].denoise);
    std::printf("%-22s %9.3f %9.3f\n", "SURE", s.an[0].sure, s.an[1].sure);
    std::printf("%-22s %9.3f %9.3f\n", "mixer", s.an[0].mixer, s.an[1].mixer);
    std::printf("%-22s %9.3f %9.3f\n", "t-test", s.an[0].ttest, s.an[1].ttest);
    std::printf("%-22s %9.3f %9.3f\n", "compose", s.an[0].compose, s.an[1].compose);
    std::printf("%-22s %9.3f %9.3f   (the error estimate's 2 half runs)\n", "cross-validation",
                s.an[0].cross_validation, s.an[1].cross_validation);
    std::printf("%-22s %9.3f %9.3f\n", "pipeline wall", s.an[0].wall, s.an[1].wall);
    std::printf("%-22s %9.2f %9.2f\n", "pipeline MP/s", mp / s.an[0].wall, mp / s.an[1].wall);
    std::printf("%-22s %9.2f %9.2f   (process CPU s / wall: < threads = machine busy)\n",
                "cores obtained", s.cores_obtained[0], s.cores_obtained[1]);
    std::printf("%-22s %9.3f %9.3f   (wall)\n", "denoiser alone", s.denoise_only_s[0],
                s.denoise_only_s[1]);
    if (s.have_mc)
      std::printf("Monte-Carlo divergence (K=4), %u threads: denoise %.3f sure %.3f wall %.3f\n",
                  cores, s.mc.denoise, s.mc.sure, s.mc.wall);
    std::printf(
        "full update (read pass + add + estimate + pipeline + write), %u threads: %.3f s "
        "(%.2f MP/s); written PIZ at once: %.3f s\n",
        cores, s.update_s, mp / s.update_s, s.update_piz_s);
    std::printf("state %.0f B/px (bytes_per_pixel(layout) %.0f), peak RSS so far %.0f MB\n",
                s.state_bpp, s.layout_bpp, s.peak_bytes / 1e6);
    std::fflush(stdout);
    results.push_back(s);
  }

  // Ratios (same run).
  const SizeResult& a = results.front();
  std::string how;
  const int gemm_n = a.w * a.h < 100000 ? 256 : 1024;
  const double gf1 = bench::sgemm_gflops(gemm_n, 1, how);
  const double gfN = bench::sgemm_gflops(gemm_n, static_cast<int>(cores), how);
  const double sure_an =
      (a.an[0].denoise + a.an[0].sure - a.denoise_only_s[0]) / a.denoise_only_s[0];
  const double sure_an_stage = a.an[0].sure / a.denoise_only_s[0];
  const double sure_mc = a.have_mc ? a.mc.sure / a.mc.denoise : NAN;
  const double thr_ratio = a.an[0].wall / a.an[1].wall;
  const double k4 = results.size() > 1 ? results[1].an[1].wall / a.an[1].wall : NAN;
  const double k4_1 = results.size() > 1 ? results[1].an[0].wall / a.an[0].wall : NAN;
  const double upd_ratio = cycles_spp_s > 0 ? a.update_s / cycles_spp_s : NAN;
  const double upd_piz_ratio = cycles_spp_s > 0 ? a.update_piz_s / cycles_spp_s : NAN;
  std::printf("\nsgemm %dx%d: %.1f GFLOP/s (1 thread), %.1f GFLOP/s (%u threads) via %s\n", gemm_n,
              gemm_n, gf1, gfN, cores, how.c_str());
  std::printf("\nratios (same run, %dx%d unless noted):\n", a.w, a.h);
  if (cycles_spp_s > 0)
    std::printf(
        "  full update / one more Cycles spp (%.3f s)           %.2f   (issue 12: the fast path "
        "<= 0.5, the default pipeline <= 2; %.2f written PIZ at once)\n",
        cycles_spp_s, upd_ratio, upd_piz_ratio);
  else
    std::printf(
        "  full update / one more Cycles spp                    n/a (no --cycles-spp-seconds)\n");
  std::printf(
      "  SURE / one denoiser run, analytic (Jacobian + SURE)  %.3f  (goal <= 0.2; SURE "
      "stage alone %.3f)\n",
      sure_an, sure_an_stage);
  std::printf(
      "  Jacobian / one denoiser run, paired (1 thread)       %.3f  (issue 12: divergence <= "
      "0.25; median of %d pairs timed back to back, range %.3f-%.3f)\n",
      a.jacobian_paired, a.jacobian_pairs, a.jacobian_paired_lo, a.jacobian_paired_hi);
  if (a.have_mc)
    std::printf("  SURE / one denoiser run, Monte-Carlo probe (K=4)     %.3f\n", sure_mc);
  std::printf(
      "  mixer network GFLOP/s / sgemm GFLOP/s                n/a until the learned mixer "
      "lands (sgemm %.1f GFLOP/s on %u threads)\n",
      gfN, cores);
  std::printf(
      "  %u threads / 1, pipeline wall                         %.2fx (goal >= 1.8x; the "
      "process obtained %.2f cores with %u threads)\n",
      cores, thr_ratio, a.cores_obtained[1], cores);
  if (results.size() > 1)
    std::printf(
        "  4K / 1080p, pipeline wall, %u threads                 %.2fx (goal <= 4.2x; 1 "
        "thread %.2fx)\n",
        cores, k4, k4_1);

  if (!json_path.empty()) {
    std::FILE* f = std::fopen(json_path.c_str(), "w");
    if (!f) {
      std::perror(json_path.c_str());
      return 1;
    }
    // "frame": the real frame's passes ([] = synthetic).
    std::fprintf(f,
                 "{\n \"threads\": %u,\n \"repeat\": %d,\n \"huge_pages\": \"%s\",\n \"frame\": "
                 "%s,\n \"sizes\": [\n",
                 cores, repeat, huge_pages_name(huge_pages()), nlohmann::json(real).dump().c_str());
    for (std::size_t i = 0; i < results.size(); ++i) {
      const SizeResult& s = results[i];
      std::fprintf(
          f,
          "  {\"width\": %d, \"height\": %d, \"read_s\": %.6f, \"write_s\": %.6f, "
          "\"write_published_s\": %.6f, \"write_piz_s\": %.6f, \"compress_later_s\": %.6f, "
          "\"exr_mb\": %.3f,\n"
          "   \"add_s\": [%.6f, %.6f], \"estimate_s\": [%.6f, %.6f], "
          "\"denoise_only_s\": [%.6f, %.6f],\n"
          "   \"update_s\": %.6f, \"update_piz_s\": %.6f, \"peak_rss_bytes\": %.0f, "
          "\"state_bytes_per_pixel\": %.1f, "
          "\"layout_bytes_per_pixel\": %.1f, \"cores_obtained\": [%.3f, %.3f],\n",
          s.w, s.h, s.read_s, s.write_s, s.write_published_s, s.write_piz_s, s.compress_later_s,
          s.exr_mb, s.add_s[0], s.add_s[1], s.estimate_s[0], s.estimate_s[1], s.denoise_only_s[0],
          s.denoise_only_s[1], s.update_s, s.update_piz_s, s.peak_bytes, s.state_bpp, s.layout_bpp,
          s.cores_obtained[0], s.cores_obtained[1]);
      print_json_stage(f, "analytic_1", s.an[0], false);
      print_json_stage(f, "analytic_n", s.an[1], !s.have_mc);
      if (s.have_mc) print_json_stage(f, "mc_n", s.mc, true);
      std::fprintf(f, "  }%s\n", i + 1 < results.size() ? "," : "");
    }
    auto num = [](double v) { return std::isfinite(v) ? std::to_string(v) : std::string("null"); };
    std::fprintf(f,
                 " ],\n \"sgemm\": {\"n\": %d, \"gflops_1\": %.3f, \"gflops_n\": %.3f, \"how\": "
                 "\"%s\"},\n",
                 gemm_n, gf1, gfN, how.c_str());
    std::fprintf(f,
                 " \"ratios\": {\"update_over_cycles_spp\": %s, \"cycles_spp_seconds\": %s, "
                 "\"sure_over_denoise_analytic\": %s, \"sure_stage_over_denoise_analytic\": %s, "
                 "\"jacobian_over_denoise_paired\": %s, \"sure_over_denoise_mc\": %s, "
                 "\"mixer_over_sgemm\": null, \"threads_speedup\": %s, \"k4_over_1080p\": %s, "
                 "\"k4_over_1080p_1thread\": %s}\n}\n",
                 num(upd_ratio).c_str(), num(cycles_spp_s > 0 ? cycles_spp_s : NAN).c_str(),
                 num(sure_an).c_str(), num(sure_an_stage).c_str(), num(a.jacobian_paired).c_str(),
                 num(sure_mc).c_str(), num(thr_ratio).c_str(), num(k4).c_str(), num(k4_1).c_str());
    std::fclose(f);
  }
  return 0;
}

// Per-stage time of the progressive pipeline on a synthetic frame (default 1920x1080 with
// albedo/normal/depth), with 1 and all threads, analytic and Monte-Carlo divergence.
// Prints seconds per stage, megapixels per second and the ratios the project tracks.
#include <tbb/global_control.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <thread>

#include "proden/progressive.hpp"

using namespace proden;

namespace {

FrameEstimate synthetic(int w, int h) {
  std::mt19937 rng(1);
  std::normal_distribution<float> n(0.0f, 1.0f);
  FrameEstimate f;
  f.mean = Image(w, h, 3);
  f.variance = Image(w, h, 3);
  f.albedo = Image(w, h, 3);
  f.normal = Image(w, h, 3);
  f.depth = Image(w, h, 1);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const bool right = x > w / 2;
      const float base =
          0.3f + 0.2f * std::sin(0.05f * static_cast<float>(x)) + (right ? 0.3f : 0.0f);
      for (int c = 0; c < 3; ++c) {
        const float var = 0.01f * base;
        f.variance.at(x, y, c) = var;
        f.mean.at(x, y, c) = base + std::sqrt(var) * n(rng);
        f.albedo.at(x, y, c) = right ? 0.8f : 0.4f;
        f.normal.at(x, y, c) = c == 2 ? 1.0f : 0.0f;
      }
      f.depth.at(x, y, 0) = right ? 2.0f : 5.0f;
    }
  }
  f.albedo_variance = Image(w, h, 3);
  f.normal_variance = Image(w, h, 3);
  f.depth_variance = Image(w, h, 1);
  return f;
}

}  // namespace

int main(int argc, char** argv) {
  int w = 1920, h = 1080;
  bool mc = true;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--width") && i + 1 < argc) w = std::atoi(argv[++i]);
    if (!std::strcmp(argv[i], "--height") && i + 1 < argc) h = std::atoi(argv[++i]);
    if (!std::strcmp(argv[i], "--no-mc")) mc = false;
  }
  const FrameEstimate f = synthetic(w, h);
  const double mpix = static_cast<double>(w) * h / 1e6;
  const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
  std::printf(
      "frame %dx%d (%.2f MP), HDR+ALB+NRM+DEP, default options (NL-means r=7 f=3, tile 128)\n", w,
      h, mpix);
  std::printf("%-10s %7s %9s %9s %9s %9s %9s %9s %9s\n", "divergence", "threads", "denoise", "sure",
              "mixer", "t-test", "compose", "wall", "MP/s");
  double wall1 = 0, wallN = 0, denoise1 = 0, sure_an = 0, sure_mc = 0;
  for (const bool use_mc : {false, true}) {
    if (use_mc && !mc) continue;
    for (unsigned threads : {1u, cores}) {
      if (use_mc && threads == 1) continue;  // MC at full width only: it is 5x the cost
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
      PipelineOptions o;
      o.divergence = use_mc ? DivergenceMethod::monte_carlo : DivergenceMethod::analytic;
      const PipelineResult r = run_pipeline(f, o);
      const auto& t = r.timings;
      std::printf("%-10s %7u %9.3f %9.3f %9.3f %9.3f %9.3f %9.3f %9.2f\n", r.divergence.c_str(),
                  threads, t.denoise, t.sure, t.mixer, t.ttest, t.compose, t.wall, mpix / t.wall);
      if (!use_mc && threads == 1) {
        wall1 = t.wall;
        denoise1 = t.denoise;
        sure_an = t.sure;
      }
      if (!use_mc && threads == cores) wallN = t.wall;
      if (use_mc) sure_mc = t.sure / t.denoise;
    }
  }
  std::printf("\nratios (same run):\n");
  std::printf("  %u threads vs 1 (analytic)          %.2fx\n", cores, wall1 / wallN);
  std::printf("  SURE / one denoiser run, analytic   %.3f\n", sure_an / denoise1);
  if (mc) std::printf("  SURE / one denoiser run, MC (K=4)   %.3f\n", sure_mc);
  // Cycles costs ~1.4 us per sample-pixel on this machine (design.md §7; measured in bench/
  // accuracy runs): one more sample per pixel of this frame.
  const double one_spp = 1.4e-6 * w * h;
  std::printf("  update (%u threads) / one more Cycles spp (%.2f s est.)  %.2f\n", cores, one_spp,
              wallN / one_spp);
  return 0;
}

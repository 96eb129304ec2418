// Throughput of pass accumulation and estimate() for a 1920x1080 frame (or --width/--height),
// with 1 and all threads. Prints megapixels per second and the ratio between thread counts. The
// first add() allocates the state (and faults its pages in); the daemon's resident frames pay
// only the later ones, so "add MP/s" is passes 2..N and the first is shown on its own.
#include <tbb/global_control.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <thread>
#include <vector>

#include "proden/accumulator.hpp"

using namespace proden;

namespace {

Pass noisy(int w, int h, std::uint64_t seed, Layout layout) {
  std::mt19937 rng(static_cast<std::uint32_t>(seed));
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Pass p;
  p.spp = 4;
  p.colour = Image(w, h, 3);
  for (auto& v : p.colour.data()) v = u(rng);
  if (layout.albedo) p.albedo = Image(w, h, 3, 0.5f);
  if (layout.normal) p.normal = Image(w, h, 3, 0.0f);
  if (layout.depth) p.depth = Image(w, h, 1, 2.0f);
  return p;
}

double seconds_since(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

int main(int argc, char** argv) {
  int w = 1920, h = 1080, passes = 8;
  for (int i = 1; i + 1 < argc; i += 2) {
    if (!std::strcmp(argv[i], "--width")) w = std::atoi(argv[i + 1]);
    if (!std::strcmp(argv[i], "--height")) h = std::atoi(argv[i + 1]);
    if (!std::strcmp(argv[i], "--passes")) passes = std::max(2, std::atoi(argv[i + 1]));
  }
  const unsigned cores = std::max(1u, std::thread::hardware_concurrency());
  const double mpix = static_cast<double>(w) * h / 1e6;
  std::printf("frame %dx%d, %d passes, layouts HDR and HDR+ALB+NRM+DEP\n", w, h, passes);
  std::printf("%-18s %8s %14s %14s %14s\n", "layout", "threads", "add MP/s", "first add MP/s",
              "estimate MP/s");
  for (Layout layout : {Layout{}, Layout{true, true, true, false}}) {
    std::vector<Pass> ps;
    for (int k = 0; k < passes; ++k)
      ps.push_back(noisy(w, h, static_cast<std::uint64_t>(k), layout));
    double add_rate[2] = {0, 0};
    int slot = 0;
    for (unsigned threads : {1u, cores}) {
      tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
      FrameAccumulator f;
      auto t0 = std::chrono::steady_clock::now();
      f.add(ps[0], "0");
      const double first_s = seconds_since(t0);
      t0 = std::chrono::steady_clock::now();
      for (int k = 1; k < passes; ++k) f.add(ps[static_cast<std::size_t>(k)], std::to_string(k));
      const double add_s = seconds_since(t0) / (passes - 1);
      t0 = std::chrono::steady_clock::now();
      const FrameEstimate e = f.estimate();
      const double est_s = seconds_since(t0);
      add_rate[slot++] = mpix / add_s;
      std::printf("%-18s %8u %14.1f %14.1f %14.1f   (state %.0f B/px)\n",
                  layout.to_string().c_str(), threads, mpix / add_s, mpix / first_s, mpix / est_s,
                  static_cast<double>(FrameAccumulator::bytes_per_pixel(layout)));
      if (e.mean.empty()) return 1;
    }
    std::printf("%-18s speed-up %u threads vs 1: %.2fx\n", layout.to_string().c_str(), cores,
                add_rate[1] / add_rate[0]);
  }
  return 0;
}

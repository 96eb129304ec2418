// Learned-mixer inference speed: megapixels per second of NetworkMixer over a 1920x1080 frame in
// the pipeline's tiles (256 px + halo 7), and the achieved GFLOP/s against this machine's sgemm
// measured in the same run (target >= 70 %), for 1 and N threads and each network width.
//
//   proden_bench_network [--width W]... [--weights FILE]... [--size WxH] [--tile T]
//                        [--threads N] [--json FILE]
// Widths default to 48 (the paper's) and 24, with random weights (speed does not depend on
// their values); --weights benchmarks a trained file instead.
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>

#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "../pipeline/src/network/conv.hpp"
#include "proden/io/network_file.hpp"
#include "proden/network/pdnet.hpp"
#include "sgemm.hpp"

using namespace proden;
using namespace proden::network;
using Clock = std::chrono::steady_clock;

namespace {

// GFLOP/s of one convolution layer shape on a 256x256 tile, 1 thread (where the time goes).
double layer_gflops(int cin, int cout, int k) {
  std::mt19937 rng(3);
  std::normal_distribution<float> n(0.0f, 0.1f);
  ConvLayer L;
  L.name = "bench";
  L.k = k;
  L.cin = cin;
  L.cout = cout;
  L.cout_pad = (cout + 15) / 16 * 16;
  L.weights.resize(static_cast<std::size_t>(k * k * cin * L.cout_pad));
  for (auto& v : L.weights) v = n(rng);
  L.bias.assign(static_cast<std::size_t>(L.cout_pad), 0.01f);
  const int T = 256;
  std::vector<float> in_store, out_store;
  const auto in = detail::Activation::bind(in_store, T, T, cin);
  auto out = detail::Activation::bind(out_store, T, T, L.cout_pad);
  for (int y = 0; y < T; ++y)
    for (int x = 0; x < T; ++x)
      for (int c = 0; c < cin; ++c) in.px(y, x)[c] = std::abs(n(rng));
  detail::conv_forward(L, in, out, nullptr, true);
  int reps = 0;
  double secs = 0;
  const auto t0 = Clock::now();
  while (secs < 0.5 || reps < 2) {
    detail::conv_forward(L, in, out, nullptr, true);
    ++reps;
    secs = std::chrono::duration<double>(Clock::now() - t0).count();
  }
  return 2.0 * k * k * cin * cout * T * T * reps / secs / 1e9;
}

struct Run {
  std::string label;
  int width = 0;
  unsigned threads = 1;
  double seconds = 0, mps = 0, gflops_exec = 0, gflops_useful = 0, sgemm = 0;
};

}  // namespace

int main(int argc, char** argv) {
  std::vector<int> widths;
  std::vector<std::string> weight_files;
  int W = 1920, H = 1080, tile = 256;
  unsigned cores = std::max(1u, std::thread::hardware_concurrency());
  std::string json_path;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "%s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--width")
      widths.push_back(std::stoi(next()));
    else if (a == "--weights")
      weight_files.push_back(next());
    else if (a == "--size")
      std::sscanf(next().c_str(), "%dx%d", &W, &H);
    else if (a == "--tile")
      tile = std::stoi(next());
    else if (a == "--threads")
      cores = static_cast<unsigned>(std::stoi(next()));
    else if (a == "--json")
      json_path = next();
    else {
      std::fprintf(stderr, "unknown argument %s (see the header of bench_network.cpp)\n",
                   a.c_str());
      return 2;
    }
  }
  if (widths.empty() && weight_files.empty()) widths = {48, 24};

  std::vector<std::pair<std::string, std::shared_ptr<const PdNet>>> nets;
  for (int w : widths) {
    nets.emplace_back("random w" + std::to_string(w),
                      std::make_shared<const PdNet>(random_weights(w, 42)));
  }
  for (const auto& path : weight_files) nets.emplace_back(path, io::load_network(path));

  // Synthetic inputs in the ranges the mixer sees (values do not change the work done).
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  const Rect image{0, 0, W, H};
  Buffer x(image, 3), y(image, 3), var(image, 3), sure(image, 3);
  for (int c = 0; c < 3; ++c)
    for (int py = 0; py < H; ++py)
      for (int px = 0; px < W; ++px) {
        x.at(px, py, c) = u(rng) * 2.0f;
        y.at(px, py, c) = x.at(px, py, c) * (0.9f + 0.2f * u(rng));
        var.at(px, py, c) = 0.01f * u(rng);
        sure.at(px, py, c) = 0.005f * u(rng);
      }
  const MixInputs mi{W, H, x.view(), y.view(), var.view(), sure.view(), View{}};
  const int tx = (W + tile - 1) / tile, ty = (H + tile - 1) / tile;
  double exec_px = 0;  // pixels the network runs on, halos included
  for (int t = 0; t < tx * ty; ++t) {
    const Rect in{(t % tx) * tile, (t / tx) * tile, std::min((t % tx + 1) * tile, W),
                  std::min((t / tx + 1) * tile, H)};
    exec_px += static_cast<double>(in.expanded(PdNet::kRadius).intersect(image).area());
  }

  std::printf("learned-mixer inference, %dx%d, tiles %d + halo %d, kernel build: %s\n", W, H, tile,
              PdNet::kRadius, detail::conv_isa());
  std::vector<Run> runs;
  std::vector<unsigned> thread_counts = {1};
  if (cores > 1) thread_counts.push_back(cores);
  std::string how;
  for (unsigned threads : thread_counts) {
    const double sg = proden::bench::sgemm_gflops(1024, static_cast<int>(threads), how);
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
    for (const auto& [label, net] : nets) {
      const NetworkMixer mixer(net);
      auto pass = [&] {
        tbb::parallel_for(0, tx * ty, [&](int t) {
          const Rect out{(t % tx) * tile, (t / tx) * tile, std::min((t % tx + 1) * tile, W),
                         std::min((t / tx + 1) * tile, H)};
          Buffer alpha(out, 3);
          mixer.mix(mi, out, alpha);
        });
      };
      pass();  // warm-up (page faults, dispatch)
      int reps = 0;
      const auto t0 = Clock::now();
      double secs = 0;
      while (reps < 2 || secs < 3.0) {
        pass();
        ++reps;
        secs = std::chrono::duration<double>(Clock::now() - t0).count();
      }
      Run r;
      r.label = label;
      r.width = net->width();
      r.threads = threads;
      r.seconds = secs / reps;
      r.mps = W * static_cast<double>(H) / r.seconds / 1e6;
      r.gflops_exec = exec_px * net->flops_per_pixel() / r.seconds / 1e9;
      r.gflops_useful = W * static_cast<double>(H) * net->flops_per_pixel() / r.seconds / 1e9;
      r.sgemm = sg;
      std::printf(
          "%-28s width %3d  %u thr: %.3f s/frame  %.2f MP/s  %.1f GFLOP/s executed (%.1f useful)"
          "  sgemm %.1f GFLOP/s  ratio %.0f %%\n",
          label.c_str(), r.width, threads, r.seconds, r.mps, r.gflops_exec, r.gflops_useful, sg,
          100.0 * r.gflops_exec / sg);
      std::fflush(stdout);
      runs.push_back(r);
    }
  }
  std::printf("sgemm via %s, 1024x1024\n", how.c_str());
  std::printf("per layer, 256x256 tile, 1 thread (GFLOP/s): ");
  std::vector<std::array<double, 4>> layers;  // width, conv_in, residual 3x3, conv_out
  for (const auto& [label, net] : nets) {
    const int w = net->width();
    bool seen = false;
    for (const auto& l : layers) seen = seen || static_cast<int>(l[0]) == w;
    if (seen) continue;
    layers.push_back({static_cast<double>(w), layer_gflops(18, w, 5), layer_gflops(w, w, 3),
                      layer_gflops(w, 9, 3)});
    const auto& l = layers.back();
    std::printf("w%d: conv_in %.1f, residual %.1f, conv_out %.1f; ", w, l[1], l[2], l[3]);
  }
  std::printf("\n");
  if (!json_path.empty()) {
    std::FILE* f = std::fopen(json_path.c_str(), "w");
    if (!f) {
      std::perror(json_path.c_str());
      return 1;
    }
    std::fprintf(
        f, "{\"size\": [%d, %d], \"tile\": %d, \"isa\": \"%s\", \"sgemm\": \"%s\", \"runs\": [\n",
        W, H, tile, detail::conv_isa(), how.c_str());
    for (std::size_t i = 0; i < runs.size(); ++i) {
      const Run& r = runs[i];
      std::fprintf(
          f,
          " {\"net\": \"%s\", \"width\": %d, \"threads\": %u, \"seconds\": %.5f, \"mp_per_s\": "
          "%.4f, \"gflops_executed\": %.2f, \"gflops_useful\": %.2f, \"sgemm_gflops\": "
          "%.2f, \"ratio\": %.4f}%s\n",
          r.label.c_str(), r.width, r.threads, r.seconds, r.mps, r.gflops_exec, r.gflops_useful,
          r.sgemm, r.gflops_exec / r.sgemm, i + 1 < runs.size() ? "," : "");
    }
    std::fprintf(f, "], \"layers_1thread_gflops\": [\n");
    for (std::size_t i = 0; i < layers.size(); ++i) {
      std::fprintf(
          f, " {\"width\": %.0f, \"conv_in\": %.2f, \"residual\": %.2f, \"conv_out\": %.2f}%s\n",
          layers[i][0], layers[i][1], layers[i][2], layers[i][3], i + 1 < layers.size() ? "," : "");
    }
    std::fprintf(f, "]}\n");
    std::fclose(f);
  }
  return 0;
}

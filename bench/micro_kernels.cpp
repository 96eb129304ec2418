// Google Benchmark microbenchmarks of the pipeline's hot loops on small inputs (one tile):
// the NL-means offset kernel through NlMeansDenoiser::denoise (with and without the Jacobian
// diagonal, with and without features), the closed-form mixer, the t-test rescale and
// FrameAccumulator::add. Items/s are pixels/s. Run: build-bench/bench/proden_micro_kernels.
#include <benchmark/benchmark.h>

#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "proden/accumulator.hpp"
#include "proden/denoise/nlmeans.hpp"
#include "proden/mixer.hpp"
#include "proden/region.hpp"
#include "proden/tstat.hpp"

using namespace proden;

namespace {

constexpr int kTile = 64;  // output tile; inputs carry a 32-pixel margin on every side
constexpr int kMargin = 32;
constexpr int kW = kTile + 2 * kMargin;

Image noise_image(int w, int h, int ch, float base, float sd, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<float> n(0.0f, 1.0f);
  Image img(w, h, ch);
  for (int c = 0; c < ch; ++c)
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        img.at(x, y, c) =
            std::max(0.0f, base + 0.2f * std::sin(0.1f * static_cast<float>(x)) + sd * n(rng));
  return img;
}

struct Frame {
  Image x = noise_image(kW, kW, 3, 0.5f, 0.1f, 1);
  Image var = Image(kW, kW, 3, 0.01f);
  Image albedo = noise_image(kW, kW, 3, 0.6f, 0.0f, 2);
  Image normal = Image(kW, kW, 3, 0.5f);
  Image depth = Image(kW, kW, 1, 3.0f);
  Image zeros3 = Image(kW, kW, 3, 0.0f);
  Image zeros1 = Image(kW, kW, 1, 0.0f);
  Image y = noise_image(kW, kW, 3, 0.5f, 0.02f, 3);
  Image sure = Image(kW, kW, 3, 0.002f);
  Image div = Image(kW, kW, 3, 0.001f);
  Image alpha = Image(kW, kW, 3, 0.7f);
};

const Frame& frame() {
  static const Frame f;
  return f;
}

const Rect kOut{kMargin, kMargin, kMargin + kTile, kMargin + kTile};

void BM_NlMeans(benchmark::State& state) {
  const Frame& f = frame();
  const bool jac = state.range(0) != 0, features = state.range(1) != 0;
  NlMeansParams p;
  p.use_features = features;
  const NlMeansDenoiser nl(p);
  DenoiseInputs in;
  in.width = kW;
  in.height = kW;
  in.colour = view_of(f.x);
  in.variance = view_of(f.var);
  if (features) {
    in.albedo = view_of(f.albedo);
    in.normal = view_of(f.normal);
    in.depth = view_of(f.depth);
    in.albedo_variance = view_of(f.zeros3);
    in.normal_variance = view_of(f.zeros3);
    in.depth_variance = view_of(f.zeros1);
  }
  Buffer y(kOut, 3), d(kOut, 3);
  for (auto _ : state) {
    nl.denoise(in, kOut, y, jac ? &d : nullptr);
    benchmark::DoNotOptimize(y.at(kOut.x0, kOut.y0, 0));
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(kOut.area()));
  state.SetLabel(std::string(jac ? "with Jacobian" : "no Jacobian") +
                 (features ? ", features" : ", colour only"));
}
BENCHMARK(BM_NlMeans)->Args({0, 1})->Args({1, 1})->Args({0, 0})->Args({1, 0});

void BM_ClosedFormMixer(benchmark::State& state) {
  const Frame& f = frame();
  ClosedFormParams p;
  p.rule = state.range(0) ? ClosedFormRule::stein : ClosedFormRule::inverse_error;
  const ClosedFormMixer mixer(p);
  MixInputs in{kW, kW, view_of(f.x), view_of(f.y), view_of(f.var), view_of(f.sure), view_of(f.div)};
  Buffer alpha(kOut, 3);
  for (auto _ : state) {
    mixer.mix(in, kOut, alpha);
    benchmark::DoNotOptimize(alpha.at(kOut.x0, kOut.y0, 0));
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(kOut.area()));
  state.SetLabel(state.range(0) ? "stein" : "inverse-error");
}
BENCHMARK(BM_ClosedFormMixer)->Arg(1)->Arg(0);

void BM_TRescale(benchmark::State& state) {
  const Frame& f = frame();
  const TTestParams p;
  Buffer out(kOut, 3);
  for (auto _ : state) {
    t_rescale(view_of(f.x), view_of(f.var), view_of(f.y), view_of(f.alpha), kW, kW, kOut, p, out);
    benchmark::DoNotOptimize(out.at(kOut.x0, kOut.y0, 0));
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(kOut.area()));
}
BENCHMARK(BM_TRescale);

void BM_AccumulatorAdd(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  const bool features = state.range(1) != 0;
  std::vector<Pass> passes;
  for (unsigned k = 0; k < 8; ++k) {
    Pass p;
    p.spp = 4;
    p.colour = noise_image(n, n, 3, 0.5f, 0.1f, 10 + k);
    if (features) {
      p.albedo = noise_image(n, n, 3, 0.6f, 0.01f, 30 + k);
      p.normal = noise_image(n, n, 3, 0.5f, 0.01f, 50 + k);
      p.depth = noise_image(n, n, 1, 3.0f, 0.01f, 70 + k);
    }
    passes.push_back(std::move(p));
  }
  FrameAccumulator acc;
  int k = 0;
  for (auto _ : state) {
    if (k == 8) {  // restart: a pass may be added once per frame (duplicates are refused)
      state.PauseTiming();
      acc = FrameAccumulator();
      k = 0;
      state.ResumeTiming();
    }
    acc.add(passes[static_cast<std::size_t>(k)], "p" + std::to_string(k));
    ++k;
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(n) * n);
  state.SetLabel(features ? "HDR+ALB+NRM+DEP" : "HDR");
}
BENCHMARK(BM_AccumulatorAdd)->Args({256, 0})->Args({256, 1});

}  // namespace

BENCHMARK_MAIN();

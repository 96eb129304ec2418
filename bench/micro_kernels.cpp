// Google Benchmark microbenchmarks of the pipeline's hot loops on small inputs (one tile):
// the NL-means offset kernel through NlMeansDenoiser::denoise (with and without the Jacobian
// diagonal, with and without features; per kernel build; over a whole 1080p frame; and the
// Jacobian's cost over the denoiser alone, both timed in every iteration), the
// closed-form mixer, the t-test rescale and FrameAccumulator::add, and the machine's FMA and
// copy peaks. Items/s are pixels/s. Run: build-bench/bench/proden_micro_kernels.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <ctime>
#include <random>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "proden/accumulator.hpp"
#include "proden/denoise/nlmeans.hpp"
#include "proden/mixer.hpp"
#include "proden/progressive.hpp"
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

// The benchmark frame as NL-means reads it, with or without its features (noise-free).
DenoiseInputs nlmeans_inputs(const Frame& f, bool features) {
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
  return in;
}

void BM_NlMeans(benchmark::State& state) {
  const Frame& f = frame();
  const bool jac = state.range(0) != 0, features = state.range(1) != 0;
  NlMeansParams p;
  p.use_features = features;
  const NlMeansDenoiser nl(p);
  const DenoiseInputs in = nlmeans_inputs(f, features);
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

// The kernel build that arg 0 indexes in `builds` (best last), or "" when this CPU has no such
// build (the benchmark is then skipped with that error).
std::string build_arg(benchmark::State& state, const std::vector<std::string>& builds) {
  const auto which = static_cast<std::size_t>(state.range(0));
  if (which < builds.size()) return builds[which];
  state.SkipWithError("build not available on this CPU");
  return {};
}

// The NL-means kernel per build (0 baseline, 1 avx2, 2 avx512), with the Jacobian and features.
void BM_NlMeansIsa(benchmark::State& state) {
  NlMeansParams p;
  p.isa = build_arg(state, nlmeans_isas_available());
  if (p.isa.empty()) return;
  const Frame& f = frame();
  const NlMeansDenoiser nl(p);
  const DenoiseInputs in = nlmeans_inputs(f, true);
  Buffer y(kOut, 3), d(kOut, 3);
  for (auto _ : state) {
    nl.denoise(in, kOut, y, &d);
    benchmark::DoNotOptimize(y.at(kOut.x0, kOut.y0, 0));
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(kOut.area()));
  state.SetLabel(p.isa + ", with Jacobian, features");
}
BENCHMARK(BM_NlMeansIsa)->Arg(0)->Arg(1)->Arg(2);

// One 1920x1080 frame (bench_common's synthetic passes, 8 x 4 spp, accumulated: real variances
// and feature variances), every pixel denoised once in the pipeline's 256-pixel tiles, 1 thread:
// CPU time per iteration = CPU seconds per 1080p frame, with and without the Jacobian.
const FrameEstimate& frame_1080p() {
  static const FrameEstimate est = [] {
    FrameAccumulator acc;
    for (int k = 0; k < 8; ++k) acc.add(bench::synthetic_pass(1920, 1080, k, 4), std::to_string(k));
    return acc.estimate();
  }();
  return est;
}

void BM_NlMeansFrame(benchmark::State& state) {
  const FrameEstimate& est = frame_1080p();
  const DenoiseInputs din = denoise_inputs(est, est.mean, est.variance, true);
  const bool jac = state.range(0) != 0;
  const NlMeansDenoiser nl{NlMeansParams{}};
  for (auto _ : state) bench::serial_denoise(nl, din, 256, jac);
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(din.width) * din.height);
  state.SetLabel(std::string("1920x1080, tiles 256, ") + (jac ? "with Jacobian" : "no Jacobian"));
}
BENCHMARK(BM_NlMeansFrame)->Arg(1)->Arg(0)->Unit(benchmark::kMillisecond);

// The divergence's cost against the denoiser alone (issue 12's "divergence <= 0.25x the denoiser
// alone"): one bench::jacobian_pair per iteration, the counter the median of with / without - 1.
void BM_NlMeansJacobianCost(benchmark::State& state) {
  const FrameEstimate& est = frame_1080p();
  const DenoiseInputs din = denoise_inputs(est, est.mean, est.variance, true);
  const NlMeansDenoiser nl{NlMeansParams{}};
  std::vector<double> ratio, without, with;
  for (auto _ : state) {
    const bench::JacobianPair p = bench::jacobian_pair(nl, din, 256, ratio.size() % 2 == 1);
    without.push_back(p.without);
    with.push_back(p.with);
    ratio.push_back(p.cost());
  }
  if (ratio.empty()) return;
  auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v[v.size() / 2];
  };
  state.counters["jacobian_over_denoiser"] = median(ratio);
  // The same from each half's fastest iteration (the least disturbed by the VM's neighbours).
  state.counters["jacobian_over_denoiser_best"] =
      *std::min_element(with.begin(), with.end()) /
          *std::min_element(without.begin(), without.end()) -
      1.0;
  state.counters["denoiser_s"] = median(without);
  state.counters["with_jacobian_s"] = median(with);
  state.SetLabel("1920x1080, tiles 256, " + nl.isa() + ", medians over iterations");
}
BENCHMARK(BM_NlMeansJacobianCost)->Unit(benchmark::kMillisecond)->MinTime(10);

// The machine's peaks in the same run, for the kernels' share of them: single-precision FMA
// throughput (AVX-512 when the CPU has it, else AVX2; 2 flops per lane per FMA; independent
// chains that fit the registers with the two constants: 16 of the 32 AVX-512 registers, 12 of the
// 16 AVX2 ones, where 16 chains spilled and read 58 of the 95 GFLOP/s sgemm reaches on an AMD
// EPYC) and copy bandwidth of a buffer well beyond the caches (bytes read + written).
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
typedef float V16 __attribute__((vector_size(64)));
typedef float V8 __attribute__((vector_size(32)));
constexpr int kChainsAvx512 = 16, kChainsAvx2 = 12;
template <int kChains, class V>
[[gnu::always_inline]] inline float fma_chains(std::int64_t n) {
  V acc[kChains];
  for (int j = 0; j < kChains; ++j) acc[j] = V{} + static_cast<float>(j);
  const V a = V{} + 0.999999f, b = V{} + 1e-7f;
  for (std::int64_t i = 0; i < n; ++i) {
    for (int j = 0; j < kChains; ++j) acc[j] = acc[j] * a + b;
  }
  float s = 0;
  for (int j = 0; j < kChains; ++j) s += acc[j][0];
  return s;
}
__attribute__((target("avx512f"), optimize("fp-contract=fast"))) float fma_avx512(std::int64_t n) {
  return fma_chains<kChainsAvx512, V16>(n);
}
__attribute__((target("avx2,fma"), optimize("fp-contract=fast"))) float fma_avx2(std::int64_t n) {
  return fma_chains<kChainsAvx2, V8>(n);
}

void BM_PeakFma(benchmark::State& state) {
  __builtin_cpu_init();
  const bool avx512 = __builtin_cpu_supports("avx512f");
  if (!avx512 && !(__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"))) {
    state.SkipWithError("no AVX2+FMA");
    return;
  }
  constexpr std::int64_t kIter = 1 << 16;
  for (auto _ : state) {
    std::int64_t n = kIter;
    benchmark::DoNotOptimize(n);  // not loop-invariant: the call is not hoisted
    benchmark::DoNotOptimize(avx512 ? fma_avx512(n) : fma_avx2(n));
  }
  const int lanes = avx512 ? 16 : 8, chains = avx512 ? kChainsAvx512 : kChainsAvx2;
  state.counters["GFLOPs"] = benchmark::Counter(
      static_cast<double>(state.iterations()) * kIter * chains * lanes * 2 * 1e-9,
      benchmark::Counter::kIsRate);
  state.SetLabel(avx512 ? "avx512 FMA" : "avx2 FMA");
}
BENCHMARK(BM_PeakFma);
#endif

void BM_MemCopy(benchmark::State& state) {
  const std::size_t n = std::size_t{64} << 20;  // 256 MiB of floats each way
  std::vector<float> a(n / 4, 1.0f), b(n / 4, 0.0f);
  for (auto _ : state) {
    std::memcpy(b.data(), a.data(), n);
    benchmark::DoNotOptimize(b.data());
    benchmark::ClobberMemory();
  }
  state.SetBytesProcessed(state.iterations() * static_cast<int64_t>(2 * n));
  state.SetLabel("read + write");
}
BENCHMARK(BM_MemCopy)->Unit(benchmark::kMillisecond);

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

// Arg 0: the authors' window (11x11) or the fine one (5x5, docs/cascade.md); arg 1: variance of
// exact origin, or from 8 passes pooled over 5x5 (the pipeline's case: Welch-Satterthwaite degrees
// of freedom and the tabulated Student-t rejection curve).
void BM_TRescale(benchmark::State& state) {
  const Frame& f = frame();
  const bool fine = state.range(0) != 0, dof = state.range(1) != 0;
  TTestParams p;
  if (fine) p = TTestParams{.radius = 2, .sigma_scale = 0.0f, .sigma_floor = 1.0f};
  static const Image passes(kW, kW, 1, 8.0f);
  static const Image pooled = pool_variance(f.var, 2);
  const VarianceOrigin origin =
      dof ? VarianceOrigin{view_of(passes), false, 2, view_of(f.var)} : VarianceOrigin{};
  const View var = dof ? view_of(pooled) : view_of(f.var);
  Buffer out(kOut, 3);
  for (auto _ : state) {
    t_rescale(view_of(f.x), var, view_of(f.y), view_of(f.alpha), kW, kW, kOut, p, out, origin);
    benchmark::DoNotOptimize(out.at(kOut.x0, kOut.y0, 0));
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(kOut.area()));
  state.SetLabel(std::string(fine ? "5x5" : "11x11") + (dof ? ", 8 passes pooled" : ", exact"));
}
BENCHMARK(BM_TRescale)->Args({0, 0})->Args({0, 1})->Args({1, 1});

// The pipeline's case of BM_TRescale (11x11, 8 passes pooled) with each kernel build this CPU
// runs (arg: index in t_test_builds(), best last).
void BM_TRescaleIsa(benchmark::State& state) {
  TTestParams p;
  p.isa = build_arg(state, t_test_builds());
  if (p.isa.empty()) return;
  const Frame& f = frame();
  static const Image passes(kW, kW, 1, 8.0f);
  static const Image pooled = pool_variance(f.var, 2);
  const VarianceOrigin origin{view_of(passes), false, 2, view_of(f.var)};
  Buffer out(kOut, 3);
  for (auto _ : state) {
    t_rescale(view_of(f.x), view_of(pooled), view_of(f.y), view_of(f.alpha), kW, kW, kOut, p, out,
              origin);
    benchmark::DoNotOptimize(out.at(kOut.x0, kOut.y0, 0));
  }
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(kOut.area()));
  state.SetLabel(p.isa + ", 11x11, 8 passes pooled");
}
BENCHMARK(BM_TRescaleIsa)->Arg(0)->Arg(1)->Arg(2);

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

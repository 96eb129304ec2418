#include "conv.hpp"

#include <algorithm>
#include <cstdlib>
#include <stdexcept>
#include <string>

#include "../simd.hpp"

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace proden::network::detail {
namespace {

struct Args {
  const ConvLayer* layer;
  const Activation* in;
  Activation* out;
  const Activation* residual;
  bool relu;
};

// Portable build: GCC vector extensions of 4 floats (one SSE2 / NEON register), FMA where the
// target has it (this file allows contraction).
namespace portable {
typedef float v4 __attribute__((vector_size(16)));
typedef float v4u __attribute__((vector_size(16), aligned(4)));
struct V {
  using T = v4;
  static constexpr int kLanes = 4;
  static T load(const float* p) { return *reinterpret_cast<const v4u*>(p); }
  static void store(float* p, T v) { *reinterpret_cast<v4u*>(p) = v; }
  static T set1(float x) { return T{x, x, x, x}; }
  static T fma(T a, T b, T c) { return a * b + c; }
  static T add(T a, T b) { return a + b; }
  static T relu(T v) {
    const T zero = {};
    return v > zero ? v : zero;
  }
};
constexpr int kP1 = 8, kP2 = 5, kP3 = 3;  // 16 registers: 9-10 accumulators
#include "conv_kernel.inc"
}  // namespace portable

#ifdef PRODEN_KERNEL_BUILDS_X86

// AVX2 + FMA: 8 floats per register, 16 registers (12 accumulators, 3 weights, 1 broadcast).
#pragma GCC push_options
#pragma GCC target("avx2,fma")
namespace avx2 {
struct V {
  using T = __m256;
  static constexpr int kLanes = 8;
  static T load(const float* p) { return _mm256_loadu_ps(p); }
  static void store(float* p, T v) { _mm256_storeu_ps(p, v); }
  static T set1(float x) { return _mm256_set1_ps(x); }
  static T fma(T a, T b, T c) { return _mm256_fmadd_ps(a, b, c); }
  static T add(T a, T b) { return _mm256_add_ps(a, b); }
  static T relu(T v) { return _mm256_and_ps(v, _mm256_cmp_ps(v, _mm256_setzero_ps(), _CMP_GT_OQ)); }
};
constexpr int kP1 = 12, kP2 = 6, kP3 = 4;
#include "conv_kernel.inc"
}  // namespace avx2
#pragma GCC pop_options

// AVX-512: 16 floats, 32 registers (21 accumulators for G=3 x P=7, 3 weights, 1 broadcast: 10
// loads per 21 FMAs; P=8 made GCC spill a weight).
#pragma GCC push_options
#pragma GCC target("avx512f")
namespace avx512 {
struct V {
  using T = __m512;
  static constexpr int kLanes = 16;
  static T load(const float* p) { return _mm512_loadu_ps(p); }
  static void store(float* p, T v) { _mm512_storeu_ps(p, v); }
  static T set1(float x) { return _mm512_set1_ps(x); }
  static T fma(T a, T b, T c) { return _mm512_fmadd_ps(a, b, c); }
  static T add(T a, T b) { return _mm512_add_ps(a, b); }
  // (Not _mm512_max_ps: GCC 12 flags its _mm512_undefined_ps as maybe-uninitialized.)
  static T relu(T v) {
    return _mm512_maskz_mov_ps(_mm512_cmp_ps_mask(v, _mm512_setzero_ps(), _CMP_GT_OQ), v);
  }
};
constexpr int kP1 = 16, kP2 = 12, kP3 = 7;
#include "conv_kernel.inc"
}  // namespace avx512
#pragma GCC pop_options
#endif

enum class Isa { baseline, avx2, avx512 };

Isa hardware() {
  const std::string best = cpu_kernel_builds().back();
  return best == "avx512" ? Isa::avx512 : best == "avx2" ? Isa::avx2 : Isa::baseline;
}

// The best build for this CPU, capped by PRODEN_CONV_ISA=avx2|baseline (to measure or rule out
// the portable kernels on an AVX-512 machine); other values are ignored.
Isa detect() {
  const Isa hw = hardware();
  const char* cap = std::getenv("PRODEN_CONV_ISA");
  if (cap && std::string(cap) == "baseline") return Isa::baseline;
  if (cap && std::string(cap) == "avx2" && hw == Isa::avx512) return Isa::avx2;
  return hw;
}

Isa isa() {
  static const Isa chosen = detect();
  return chosen;
}

}  // namespace

Activation Activation::bind(std::vector<float>& storage, int h, int w, int cs) {
  Activation a;
  a.h = h;
  a.w = w;
  a.cs = cs;
  const std::size_t need = static_cast<std::size_t>(h + 2 * kBorder) *
                           static_cast<std::size_t>(w + 2 * kBorder) * static_cast<std::size_t>(cs);
  if (storage.size() < need) storage.resize(need);
  a.data = storage.data();
  const std::ptrdiff_t rs = a.row_stride();
  for (int y = 0; y < h + 2 * kBorder; ++y) {
    float* row = a.data + y * rs;
    if (y < kBorder || y >= h + kBorder) {
      std::fill(row, row + rs, 0.0f);
    } else {
      std::fill(row, row + kBorder * cs, 0.0f);
      std::fill(row + (w + kBorder) * cs, row + rs, 0.0f);
    }
  }
  return a;
}

const char* conv_isa() {
  switch (isa()) {
    case Isa::avx512:
      return "avx512";
    case Isa::avx2:
      return "avx2";
    default:
      return "baseline";
  }
}

std::vector<std::string> conv_isas_available() {
  std::vector<std::string> out = {"baseline"};
#ifdef PRODEN_KERNEL_BUILDS_X86
  if (isa() == Isa::avx2 || isa() == Isa::avx512) out.emplace_back("avx2");
  if (isa() == Isa::avx512) out.emplace_back("avx512");
#endif
  return out;
}

void conv_forward_with(const std::string& which, const ConvLayer& layer, const Activation& in,
                       Activation& out, const Activation* residual, bool relu) {
  const Args a{&layer, &in, &out, residual, relu};
#ifdef PRODEN_KERNEL_BUILDS_X86
  if (which == "avx512" && isa() == Isa::avx512) {
    avx512::run(a);
    return;
  }
  if (which == "avx2" && (isa() == Isa::avx2 || isa() == Isa::avx512)) {
    avx2::run(a);
    return;
  }
#endif
  if (which != "baseline") throw std::invalid_argument("conv: ISA " + which + " not available");
  portable::run(a);
}

void conv_forward(const ConvLayer& layer, const Activation& in, Activation& out,
                  const Activation* residual, bool relu) {
  conv_forward_with(conv_isa(), layer, in, out, residual, relu);
}

}  // namespace proden::network::detail

// Builds of NFOR's per-chunk regression kernel (nfor_kernel.inc) for AVX-512, AVX2+FMA and a
// portable baseline, chosen at run time (no -march=native), and the plain double-precision
// reference of its normal equations the tests compare every build with.
#include <algorithm>
#include <cstdint>
#include <cstring>
#include <iterator>
#include <stdexcept>
#include <utility>

#include "nfor_internal.hpp"

#include "../simd.hpp"

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace proden::nfor {
namespace {

// Index of (i, j), i <= j, in the packed upper triangle of X^T W X.
constexpr int packed(int i, int j) {
  return i * kColumns - i * (i - 1) / 2 + (j - i);
}

// Portable build: GCC vectors of 4 floats (one SSE2 / NEON register).
namespace portable {
typedef float T __attribute__((vector_size(16)));
typedef std::int32_t I __attribute__((vector_size(16)));
constexpr int kL = 4;
inline T vsqrt(T v) {
#if defined(__SSE2__)
  return _mm_sqrt_ps(v);
#else
  for (int l = 0; l < kL; ++l) v[l] = __builtin_sqrtf(v[l]);
  return v;
#endif
}
inline T vfma(T a, T b, T c) {
  return a * b + c;  // no FMA in the baseline
}
// 16 registers: blocks of 1-2 rows of the normal equations.
constexpr int kRows3[] = {0, 1, 2, 3, 4, 6, 8};
constexpr int kRows9[] = {0, 1, 2, 3, 4, 5, 6, 7, 8};
#include "nfor_kernel.inc"
}  // namespace portable

#ifdef PRODEN_KERNEL_BUILDS_X86

#pragma GCC push_options
#pragma GCC target("avx2,fma")
namespace avx2 {
typedef float T __attribute__((vector_size(32)));
typedef std::int32_t I __attribute__((vector_size(32)));
constexpr int kL = 8;
inline T vsqrt(T v) {
  return _mm256_sqrt_ps(v);
}
inline T vfma(T a, T b, T c) {
  return _mm256_fmadd_ps(a, b, c);
}
constexpr int kRows3[] = {0, 1, 2, 3, 4, 6, 8};
constexpr int kRows9[] = {0, 1, 2, 3, 4, 5, 6, 7, 8};
#include "nfor_kernel.inc"
}  // namespace avx2
#pragma GCC pop_options

#pragma GCC push_options
#pragma GCC target("avx512f")
namespace avx512 {
typedef float T __attribute__((vector_size(64)));
typedef std::int32_t I __attribute__((vector_size(64)));
constexpr int kL = 16;
// (Not _mm512_sqrt_ps: GCC 12 flags its _mm512_undefined_ps as uninitialised.)
inline T vsqrt(T v) {
  return _mm512_maskz_sqrt_ps(0xFFFF, v);
}
inline T vfma(T a, T b, T c) {
  return _mm512_fmadd_ps(a, b, c);
}
// 32 registers: two rows per block (~21 accumulators + the block's features and data).
constexpr int kRows3[] = {0, 2, 4, 8};
constexpr int kRows9[] = {0, 1, 2, 3, 4, 6, 8};
#include "nfor_kernel.inc"
}  // namespace avx512
#pragma GCC pop_options
#endif

constexpr Kernels kPortable{"baseline", 4, portable::regress, portable::normal_equations,
                            portable::weights};
#ifdef PRODEN_KERNEL_BUILDS_X86
constexpr Kernels kAvx2{"avx2", 8, avx2::regress, avx2::normal_equations, avx2::weights};
constexpr Kernels kAvx512{"avx512", 16, avx512::regress, avx512::normal_equations, avx512::weights};
#endif

}  // namespace

std::vector<std::string> isas_available() {
  return cpu_kernel_builds();
}

const Kernels& kernels(const std::string& isa) {
  static const std::vector<std::string> available = isas_available();
  const std::string& name = isa.empty() ? available.back() : isa;
  if (std::find(available.begin(), available.end(), name) == available.end()) {
    throw std::invalid_argument("nfor: kernel build '" + name + "' is not available on this CPU");
  }
#ifdef PRODEN_KERNEL_BUILDS_X86
  if (name == "avx512") return kAvx512;
  if (name == "avx2") return kAvx2;
#endif
  return kPortable;
}

std::size_t chunk_scratch_floats() {
  // Normal equations, coefficients and the packed inverse, for 9 data channels and 16 lanes.
  return static_cast<std::size_t>(kPacked + kColumns * kMaxData + kColumns * kMaxData + kPacked) *
         16;
}

void normal_equations_reference(const ChunkArgs& a, int lanes, double* out) {
  const int m = a.data_channels;
  const int entries = kPacked + kColumns * m;
  for (int e = 0; e < entries * lanes; ++e) out[e] = 0.0;
  for (int l = 0; l < lanes; ++l) {
    for (int o = 0; o < a.offsets; ++o) {
      const std::ptrdiff_t q = a.doff[o] + l;
      const double w = a.w[static_cast<std::ptrdiff_t>(o) * a.w_stride + l];
      double x[kColumns] = {1.0};
      for (int j = 1; j < kColumns; ++j) {
        x[j] = static_cast<double>(a.features[j - 1][q]) - a.features[j - 1][l];
      }
      for (int i = 0; i < kColumns; ++i) {
        for (int j = i; j < kColumns; ++j) out[packed(i, j) * lanes + l] += w * x[i] * x[j];
        for (int c = 0; c < m; ++c)
          out[(kPacked + i * m + c) * lanes + l] += w * x[i] * a.data[c][q];
      }
    }
  }
}

}  // namespace proden::nfor

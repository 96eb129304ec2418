#include "conv.hpp"

#include <algorithm>
#include <stdexcept>
#include <string>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace proden::network::detail {
namespace {

// 16 floats; the unaligned variant loads/stores anywhere. GCC lowers these to zmm, 2 ymm or
// 4 xmm registers depending on the function's target.
typedef float v16 __attribute__((vector_size(64)));
typedef float v16u __attribute__((vector_size(64), aligned(4)));

struct Args {
  const ConvLayer* layer;
  const Activation* in;
  Activation* out;
  const Activation* residual;
  bool relu;
};

// G output-channel vectors x P pixels of one row, accumulated over k*k*cin taps.
template <int G, int P>
requires(G >= 1 && G <= 3)
    [[gnu::always_inline]] inline void block(const Args& a, int oy, int ox, int oc0) {
  const ConvLayer& L = *a.layer;
  const int r = L.k / 2;
  const std::ptrdiff_t ps = a.in->cs, rs = a.in->row_stride();
  const float* src = a.in->px(oy - r, ox - r);
  v16 acc[G][P];
  for (int g = 0; g < G; ++g) {
    const v16 b = *reinterpret_cast<const v16u*>(L.bias.data() + oc0 + 16 * g);
    for (int p = 0; p < P; ++p) acc[g][p] = b;
  }
  const std::ptrdiff_t ws = L.cout_pad;
  for (int ky = 0; ky < L.k; ++ky) {
    for (int kx = 0; kx < L.k; ++kx) {
      const float* s = src + ky * rs + kx * ps;
      const float* w =
          L.weights.data() + static_cast<std::ptrdiff_t>(ky * L.k + kx) * L.cin * ws + oc0;
      for (int ic = 0; ic < L.cin; ++ic) {
        // Named registers, not an array: GCC keeps an array of vectors in memory.
        const v16 w0 = *reinterpret_cast<const v16u*>(w + ic * ws);
        const v16 w1 = G > 1 ? *reinterpret_cast<const v16u*>(w + ic * ws + 16) : w0;
        const v16 w2 = G > 2 ? *reinterpret_cast<const v16u*>(w + ic * ws + 32) : w0;
#pragma GCC unroll 16
        for (int p = 0; p < P; ++p) {
          const float sv = s[p * ps + ic];
          acc[0][p] += w0 * sv;
          if constexpr (G > 1) acc[1][p] += w1 * sv;
          if constexpr (G > 2) acc[2][p] += w2 * sv;
        }
      }
    }
  }
  const v16 zero = {};
  for (int p = 0; p < P; ++p) {
    float* dst = a.out->px(oy, ox + p) + oc0;
    const float* res = a.residual ? a.residual->px(oy, ox + p) + oc0 : nullptr;
    for (int g = 0; g < G; ++g) {
      v16 v = acc[g][p];
      if (res) v += *reinterpret_cast<const v16u*>(res + 16 * g);
      if (a.relu) v = v > zero ? v : zero;
      *reinterpret_cast<v16u*>(dst + 16 * g) = v;
    }
  }
}

template <int G, int P>
[[gnu::always_inline]] inline void row_group(const Args& a, int oy, int oc0) {
  const int w = a.out->w;
  int ox = 0;
  for (; ox + P <= w; ox += P) block<G, P>(a, oy, ox, oc0);
  for (; ox < w; ++ox) block<G, 1>(a, oy, ox, oc0);
}

// P1/P2/P3: pixels per block for 1/2/3 output vectors, sized to the target's register file.
template <int P1, int P2, int P3>
[[gnu::always_inline]] inline void run(const Args& a) {
  const int vectors = a.layer->cout_pad / 16;
  for (int oy = 0; oy < a.out->h; ++oy) {
    for (int v = 0; v < vectors;) {
      const int g = std::min(3, vectors - v);
      if (g == 3) {
        row_group<3, P3>(a, oy, 16 * v);
      } else if (g == 2) {
        row_group<2, P2>(a, oy, 16 * v);
      } else {
        row_group<1, P1>(a, oy, 16 * v);
      }
      v += g;
    }
  }
}

void run_baseline(const Args& a) {
  run<2, 1, 1>(a);
}

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define PRODEN_X86_DISPATCH 1

// AVX-512 with intrinsics: GCC spills vector-extension temporaries to the stack here, which
// turns every FMA into a load; named __m512 registers keep 21 accumulators (G=3 x P=7), 3 weights
// and one broadcast in the 32 zmm registers (10 loads per 21 FMAs; P=8 made GCC spill a weight).
// `ky` is the kernel row this call adds (see row_group512).
template <int G, int P>
requires(G >= 1 && G <= 3)
    __attribute__((target("avx512f"), always_inline)) inline void block512(const Args& a, int oy,
                                                                           int ox, int oc0,
                                                                           int ky) {
  const ConvLayer& L = *a.layer;
  const int r = L.k / 2;
  const std::ptrdiff_t ps = a.in->cs, rs = a.in->row_stride();
  const float* src = a.in->px(oy - r, ox - r);
  __m512 acc[G][P];
  if (ky == 0) {
    for (int g = 0; g < G; ++g) {
      const __m512 b = _mm512_loadu_ps(L.bias.data() + oc0 + 16 * g);
      for (int p = 0; p < P; ++p) acc[g][p] = b;
    }
  } else {  // the partial sums of the kernel rows before this one
    for (int p = 0; p < P; ++p) {
      const float* part = a.out->px(oy, ox + p) + oc0;
      for (int g = 0; g < G; ++g) acc[g][p] = _mm512_loadu_ps(part + 16 * g);
    }
  }
  const std::ptrdiff_t ws = L.cout_pad;
  {
    for (int kx = 0; kx < L.k; ++kx) {
      const float* s = src + ky * rs + kx * ps;
      const float* w =
          L.weights.data() + static_cast<std::ptrdiff_t>(ky * L.k + kx) * L.cin * ws + oc0;
      for (int ic = 0; ic < L.cin; ++ic) {
        const __m512 w0 = _mm512_loadu_ps(w + ic * ws);
        const __m512 w1 = G > 1 ? _mm512_loadu_ps(w + ic * ws + 16) : w0;
        const __m512 w2 = G > 2 ? _mm512_loadu_ps(w + ic * ws + 32) : w0;
#pragma GCC unroll 16
        for (int p = 0; p < P; ++p) {
          const __m512 sv = _mm512_set1_ps(s[p * ps + ic]);
          acc[0][p] = _mm512_fmadd_ps(w0, sv, acc[0][p]);
          if constexpr (G > 1) acc[1][p] = _mm512_fmadd_ps(w1, sv, acc[1][p]);
          if constexpr (G > 2) acc[2][p] = _mm512_fmadd_ps(w2, sv, acc[2][p]);
        }
      }
    }
  }
  if (ky + 1 < L.k) {  // not the last kernel row: keep the partial sums in the output
    for (int p = 0; p < P; ++p) {
      float* part = a.out->px(oy, ox + p) + oc0;
      for (int g = 0; g < G; ++g) _mm512_storeu_ps(part + 16 * g, acc[g][p]);
    }
    return;
  }
  const __m512 zero = _mm512_setzero_ps();
  for (int p = 0; p < P; ++p) {
    float* dst = a.out->px(oy, ox + p) + oc0;
    const float* res = a.residual ? a.residual->px(oy, ox + p) + oc0 : nullptr;
    for (int g = 0; g < G; ++g) {
      __m512 v = acc[g][p];
      if (res) v = _mm512_add_ps(v, _mm512_loadu_ps(res + 16 * g));
      // (Not _mm512_max_ps: GCC 12 flags its _mm512_undefined_ps as maybe-uninitialized.)
      if (a.relu) v = _mm512_maskz_mov_ps(_mm512_cmp_ps_mask(v, zero, _CMP_GT_OQ), v);
      _mm512_storeu_ps(dst + 16 * g, v);
    }
  }
}

template <int G, int P>
__attribute__((target("avx512f"), always_inline)) inline void row_group512(const Args& a, int oy,
                                                                           int oc0) {
  // One kernel row at a time over the whole output row, so that row's weights (k x cin x cout:
  // 27 KB for 48 channels) stay in L1 instead of streaming all k rows from L2 per pixel block;
  // partial sums go through the output row (L1/L2), ~3 % extra loads and stores.
  const int w = a.out->w;
  for (int ky = 0; ky < a.layer->k; ++ky) {
    int ox = 0;
    for (; ox + P <= w; ox += P) block512<G, P>(a, oy, ox, oc0, ky);
    for (; ox < w; ++ox) block512<G, 1>(a, oy, ox, oc0, ky);
  }
}

__attribute__((target("avx512f"))) void run_avx512(const Args& a) {
  const int vectors = a.layer->cout_pad / 16;
  for (int oy = 0; oy < a.out->h; ++oy) {
    for (int v = 0; v < vectors;) {
      const int g = std::min(3, vectors - v);
      if (g == 3) {
        row_group512<3, 7>(a, oy, 16 * v);
      } else if (g == 2) {
        row_group512<2, 12>(a, oy, 16 * v);
      } else {
        row_group512<1, 16>(a, oy, 16 * v);
      }
      v += g;
    }
  }
}
__attribute__((target("avx2,fma"))) void run_avx2(const Args& a) {
  run<6, 3, 2>(a);
}
#endif

enum class Isa { baseline, avx2, avx512 };

Isa detect() {
#ifdef PRODEN_X86_DISPATCH
  __builtin_cpu_init();
  if (__builtin_cpu_supports("avx512f")) return Isa::avx512;
  if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) return Isa::avx2;
#endif
  return Isa::baseline;
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
#ifdef PRODEN_X86_DISPATCH
  if (isa() == Isa::avx2 || isa() == Isa::avx512) out.emplace_back("avx2");
  if (isa() == Isa::avx512) out.emplace_back("avx512");
#endif
  return out;
}

void conv_forward_with(const std::string& which, const ConvLayer& layer, const Activation& in,
                       Activation& out, const Activation* residual, bool relu) {
  const Args a{&layer, &in, &out, residual, relu};
#ifdef PRODEN_X86_DISPATCH
  if (which == "avx512" && isa() == Isa::avx512) {
    run_avx512(a);
    return;
  }
  if (which == "avx2" && (isa() == Isa::avx2 || isa() == Isa::avx512)) {
    run_avx2(a);
    return;
  }
#endif
  if (which != "baseline") throw std::invalid_argument("conv: ISA " + which + " not available");
  run_baseline(a);
}

void conv_forward(const ConvLayer& layer, const Activation& in, Activation& out,
                  const Activation* residual, bool relu) {
  conv_forward_with(conv_isa(), layer, in, out, residual, relu);
}

}  // namespace proden::network::detail

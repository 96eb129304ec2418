#include "proden/denoise/nlmeans.hpp"

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#include "../simd.hpp"

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace proden {
namespace {

// Copies channel c of `v` over `rect` (which may extend past the image) into channel row `slot`
// of a row-interleaved block (row stride `rs` floats, channel rows of rect.width() floats), with
// replicate padding: position (x, y) holds the image pixel (clamp(x), clamp(y)). Columns past
// `x_end` (the region the denoiser reads, radius() around the output: all a view must cover)
// only feed vector lanes nobody reads; they repeat column x_end - 1. Interleaving the channels
// by row keeps the kernel's many planes in a few long memory streams.
void pad_into(float* block, std::size_t rs, int slot, const View& v, int c, const Rect& rect,
              int x_end, int width, int height) {
  const std::size_t cw = static_cast<std::size_t>(rect.width());
  for (int y = rect.y0; y < rect.y1; ++y) {
    const int sy = std::clamp(y, 0, height - 1);
    float* dst =
        block + static_cast<std::size_t>(y - rect.y0) * rs + static_cast<std::size_t>(slot) * cw;
    // Source column clamp(min(x, x_end - 1), 0, width - 1): the left edge, a contiguous run, then
    // the last column read, repeated.
    const int mid0 = std::clamp(rect.x0, 0, rect.x1), mid1 = std::max(mid0, std::min(x_end, width));
    const int last = std::min(x_end, width) - 1;
    // Row sy of the view from its first column: image column x is row[x - vx0].
    const std::ptrdiff_t vx0 = v.rect.x0;
    const float* row = v.ptr(v.rect.x0, sy, c);
    int x = rect.x0;
    for (; x < mid0; ++x) *dst++ = row[-vx0];
    for (; x < std::min(mid1, rect.x1); ++x) *dst++ = row[x - vx0];
    for (; x < rect.x1; ++x) *dst++ = row[last - vx0];
  }
}

// Everything one search offset needs: padded tile planes, the fused rows' scratch and the tile's
// accumulators. The padded planes are channel rows of one block (row stride ps); a channel row
// is at least ewv + 2R wide, so full vectors never leave it and lanes past the output width
// compute values nobody reads. The accumulators are row-interleaved too (row stride acc_rs).
struct Kernel {
  int R, F, P;              // search radius, patch radius, R + F
  int ow, oh, eh;           // output size, patch-extended height oh + 2F
  std::ptrdiff_t owv, ewv;  // output width and patch-extended width, rounded up to vectors
  std::ptrdiff_t ps;        // padded block row stride
  const float* X[3];
  const float* V[3];
  const float* alb[3] = {nullptr, nullptr, nullptr};
  const float* alb_v[3] = {nullptr, nullptr, nullptr};
  const float* nrm[3] = {nullptr, nullptr, nullptr};
  const float* nrm_v[3] = {nullptr, nullptr, nullptr};
  const float* dep = nullptr;
  float k2, alpha, eps, inv_patch3, inv_kf2, tau, depth_scale;
  bool features, derivative;
  // Scratch. Pair planes over E with a margin of R (kL more on the right): the colour distance of
  // offsets delta and -delta, and the pairs' Jacobian factors (x_a - x_{a+delta}) / (eps + k^2
  // (v_a + v_{a+delta})) (3 channel planes gjac_c apart); row stride gs, g0 = index of E's (0, 0).
  float *gdp, *gdm, *gjac;
  std::ptrdiff_t gs, g0, gjac_c;
  // Feature planes of delta and -delta over the output with the same margins (stride fs, f0).
  float *gfp, *gfm;
  std::ptrdiff_t fs, f0;
  float* hring;         // 2 (2F + 1) owv: row sums of the last 2F + 1 rows, per offset
  const float** hrows;  // 2 (2F + 1) pointers into hring
  float* w;             // 2 owv: one row of weights per offset
  // Accumulators (per output row: one row each, per channel where 3, n_acc apart).
  std::ptrdiff_t n_acc, acc_rs;
  float* wsum;
  float* self;
  float* num;
  float* A;
  float* B;
  int gx0, gy0, width, height;  // global position of the output, image size
};

// Kernel builds: GCC vectors, one instruction set each (no -march=native; chosen at run time).
namespace portable {
typedef float T __attribute__((vector_size(16)));
typedef std::int32_t I __attribute__((vector_size(16)));
constexpr int kL = 4;
inline T vfma(T a, T b, T c) {
  return a * b + c;  // no FMA in the baseline
}
#include "nlmeans_kernel.inc"
}  // namespace portable

#ifdef PRODEN_KERNEL_BUILDS_X86

#pragma GCC push_options
#pragma GCC target("avx2,fma")
namespace avx2 {
typedef float T __attribute__((vector_size(32)));
typedef std::int32_t I __attribute__((vector_size(32)));
constexpr int kL = 8;
inline T vfma(T a, T b, T c) {
  return _mm256_fmadd_ps(a, b, c);
}
#include "nlmeans_kernel.inc"
}  // namespace avx2
#pragma GCC pop_options

#pragma GCC push_options
#pragma GCC target("avx512f")
namespace avx512 {
typedef float T __attribute__((vector_size(64)));
typedef std::int32_t I __attribute__((vector_size(64)));
constexpr int kL = 16;
inline T vfma(T a, T b, T c) {
  return _mm512_fmadd_ps(a, b, c);
}
#include "nlmeans_kernel.inc"
}  // namespace avx512
#pragma GCC pop_options
#endif

enum class Build { baseline, avx2, avx512 };

struct BuildInfo {
  const char* name;
  int lanes;
  void (*pass)(const Kernel&, int, int);
};

BuildInfo info(Build b) {
#ifdef PRODEN_KERNEL_BUILDS_X86
  if (b == Build::avx512) return {"avx512", 16, avx512::pass};
  if (b == Build::avx2) return {"avx2", 8, avx2::pass};
#endif
  (void)b;
  return {"baseline", 4, portable::pass};
}

std::vector<Build> builds_available() {
  std::vector<Build> out;
  for (const auto& name : cpu_kernel_builds()) {
    out.push_back(name == "avx512" ? Build::avx512
                  : name == "avx2" ? Build::avx2
                                   : Build::baseline);
  }
  return out;
}

// The build for `isa` ("" = the best for this CPU, capped by PRODEN_NLMEANS_ISA=avx2|baseline
// to measure the portable builds on an AVX-512 machine).
Build choose(const std::string& isa) {
  static const std::vector<Build> available = builds_available();
  std::string want = isa;
  if (want.empty()) {
    const char* cap = std::getenv("PRODEN_NLMEANS_ISA");
    want = info(available.back()).name;
    if (cap && (std::string(cap) == "baseline" || std::string(cap) == "avx2")) want = cap;
  }
  for (Build b : available) {
    if (want == info(b).name) return b;
  }
  if (isa.empty()) return available.back();  // a cap above this CPU: the best it has
  throw std::invalid_argument("NlMeansDenoiser: kernel build '" + isa +
                              "' is not available on this CPU");
}

// denoise() works in blocks of at most this size: one offset's pass over a block's padded planes
// (up to 19 channels) then stays in L2, and the tile size is free (bigger tiles were up to 1.3x
// slower per pixel without it). Results do not depend on the blocking.
constexpr int kBlockWidth = 128;
constexpr int kBlockHeight = 32;

std::size_t round_up(std::size_t n, std::size_t m) {
  return (n + m - 1) / m * m;
}

}  // namespace

std::vector<std::string> nlmeans_isas_available() {
  std::vector<std::string> out;
  for (Build b : builds_available()) out.emplace_back(info(b).name);
  return out;
}

NlMeansDenoiser::NlMeansDenoiser(NlMeansParams params) : params_(params) {
  if (params_.search_radius < 0 || params_.patch_radius < 0 || !(params_.k > 0.0f)) {
    throw std::invalid_argument("NlMeansDenoiser: radii must be >= 0 and k > 0");
  }
  build_ = static_cast<int>(choose(params_.isa));
}

std::string NlMeansDenoiser::isa() const {
  return info(static_cast<Build>(build_)).name;
}

void NlMeansDenoiser::denoise(const DenoiseInputs& in, const Rect& out, Buffer& y_out,
                              Buffer* dydx_out) const {
  if (out.empty()) return;
  const int bw = kBlockWidth, bh = kBlockHeight;
  for (int y0 = out.y0; y0 < out.y1; y0 += bh) {
    for (int x0 = out.x0; x0 < out.x1; x0 += bw) {
      denoise_block(in, Rect{x0, y0, std::min(x0 + bw, out.x1), std::min(y0 + bh, out.y1)}, y_out,
                    dydx_out);
    }
  }
}

void NlMeansDenoiser::denoise_block(const DenoiseInputs& in, const Rect& out, Buffer& y_out,
                                    Buffer* dydx_out) const {
  const BuildInfo build = info(static_cast<Build>(build_));
  const std::size_t L = static_cast<std::size_t>(build.lanes);
  const int R = params_.search_radius;
  const int F = params_.patch_radius;
  const int P = R + F;
  const int ow = out.width(), oh = out.height();
  const Rect prect = out.expanded(P);
  const std::size_t owv = round_up(static_cast<std::size_t>(ow), L);
  const std::size_t ewv = round_up(owv + 2 * static_cast<std::size_t>(F), L);
  // Channel rows run on to the right so that every vector load stays inside them.
  const std::size_t cw = ewv + 2 * static_cast<std::size_t>(R) + L;
  const Rect wide{prect.x0, prect.y0, prect.x0 + static_cast<int>(cw), prect.y1};
  const bool feats = params_.use_features;
  const bool has_alb = feats && in.albedo.valid(), has_nrm = feats && in.normal.valid();
  const bool has_dep = feats && in.depth.valid();
  const int nch = 6 + (has_alb ? 6 : 0) + (has_nrm ? 6 : 0) + (has_dep ? 1 : 0);
  const std::size_t ps = static_cast<std::size_t>(nch) * cw;
  std::vector<float> block(ps * static_cast<std::size_t>(prect.height()), 0.0f);
  int slot = 0;
  // Pads channel c of v (zeros when v is invalid) into the next slot; returns its first pixel.
  auto add = [&](const View& v, int c) {
    if (v.valid()) pad_into(block.data(), ps, slot, v, c, wide, prect.x1, in.width, in.height);
    return block.data() + static_cast<std::size_t>(slot++) * cw;
  };
  Kernel k{};
  k.R = R;
  k.F = F;
  k.P = P;
  k.ow = ow;
  k.oh = oh;
  k.eh = oh + 2 * F;
  k.owv = static_cast<std::ptrdiff_t>(owv);
  k.ewv = static_cast<std::ptrdiff_t>(ewv);
  k.ps = static_cast<std::ptrdiff_t>(ps);
  for (int c = 0; c < 3; ++c) k.X[c] = add(in.colour, c);
  for (int c = 0; c < 3; ++c) k.V[c] = add(in.variance, c);
  if (has_alb) {
    for (int c = 0; c < 3; ++c) k.alb[c] = add(in.albedo, c);
    for (int c = 0; c < 3; ++c) k.alb_v[c] = add(in.albedo_variance, c);
  }
  if (has_nrm) {
    for (int c = 0; c < 3; ++c) k.nrm[c] = add(in.normal, c);
    for (int c = 0; c < 3; ++c) k.nrm_v[c] = add(in.normal_variance, c);
  }
  if (has_dep) k.dep = add(in.depth, 0);
  k.features = k.alb[0] || k.nrm[0] || k.dep;
  k.k2 = params_.k * params_.k;
  k.alpha = params_.alpha;
  k.eps = params_.epsilon;
  k.inv_patch3 = 1.0f / static_cast<float>((2 * F + 1) * (2 * F + 1) * 3);
  k.inv_kf2 = 1.0f / (params_.k_feature * params_.k_feature);
  k.tau = params_.tau;
  k.depth_scale = params_.depth_scale;
  k.derivative = dydx_out != nullptr;

  const std::size_t nr = 2 * static_cast<std::size_t>(F) + 1;
  // Per output row: wsum, self, num (3), and the derivative's A (3), B (3).
  const std::size_t acc_rs = (k.derivative ? 11 : 5) * owv;
  const std::size_t gs = ewv + 2 * static_cast<std::size_t>(R) + L;
  const std::size_t gh = static_cast<std::size_t>(k.eh + 2 * R);
  const std::size_t fs = owv + 2 * static_cast<std::size_t>(R) + L;
  const std::size_t fh = static_cast<std::size_t>(oh + 2 * R);
  std::vector<float> gdp(gs * gh, 0.0f), gdm(gs * gh, 0.0f);
  std::vector<float> gjac(k.derivative ? 3 * gs * gh : 0, 0.0f);
  std::vector<float> gfp(k.features ? fs * fh : 0, 0.0f), gfm(k.features ? fs * fh : 0, 0.0f);
  std::vector<float> hring(2 * nr * owv);
  std::vector<const float*> hrows(2 * nr);
  std::vector<float> wrow(2 * owv), acc(acc_rs * static_cast<std::size_t>(oh), 0.0f);
  k.gdp = gdp.data();
  k.gdm = gdm.data();
  k.gjac = gjac.data();
  k.gs = static_cast<std::ptrdiff_t>(gs);
  k.g0 =
      static_cast<std::ptrdiff_t>(static_cast<std::size_t>(R) * gs + static_cast<std::size_t>(R));
  k.gjac_c = static_cast<std::ptrdiff_t>(gs * gh);
  k.gfp = gfp.data();
  k.gfm = gfm.data();
  k.fs = static_cast<std::ptrdiff_t>(fs);
  k.f0 =
      static_cast<std::ptrdiff_t>(static_cast<std::size_t>(R) * fs + static_cast<std::size_t>(R));
  k.hring = hring.data();
  k.hrows = hrows.data();
  k.w = wrow.data();
  k.n_acc = static_cast<std::ptrdiff_t>(owv);
  k.acc_rs = static_cast<std::ptrdiff_t>(acc_rs);
  k.wsum = acc.data();
  k.self = k.wsum + owv;
  k.num = k.self + owv;
  k.A = k.num + 3 * owv;
  k.B = k.A + 3 * owv;
  k.gx0 = out.x0;
  k.gy0 = out.y0;
  k.width = in.width;
  k.height = in.height;

  // delta = 0, then every pair (delta, -delta) once: delta with dy > 0, or dy = 0 and dx > 0.
  for (int dy = 0; dy <= R; ++dy) {
    for (int dx = dy == 0 ? 0 : -R; dx <= R; ++dx) build.pass(k, dx, dy);
  }

  for (int oy = 0; oy < oh; ++oy) {
    const std::size_t row = static_cast<std::size_t>(oy) * acc_rs;
    const float* wsum = k.wsum + row;
    const float* self = k.self + row;
    for (int ox = 0; ox < ow; ++ox) {
      const std::size_t i = static_cast<std::size_t>(ox);
      const float W = wsum[i];  // >= the centre's own weight, so > 0
      for (int c = 0; c < 3; ++c) {
        const std::size_t ci = static_cast<std::size_t>(c) * owv + i;
        const float yv = k.num[row + ci] / W;
        y_out.row(out.y0 + oy, c)[out.x0 - y_out.rect().x0 + ox] = yv;
        if (k.derivative) {
          dydx_out->row(out.y0 + oy, c)[out.x0 - dydx_out->rect().x0 + ox] =
              self[i] / W + (k.A[row + ci] - yv * k.B[row + ci]) / W;
        }
      }
    }
  }
}

}  // namespace proden

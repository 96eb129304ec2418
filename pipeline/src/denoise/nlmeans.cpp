#include "proden/denoise/nlmeans.hpp"

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

namespace proden {
namespace {

// Planar copy of a view over `rect` (which may extend past the image), with replicate padding:
// position (x, y) holds the image pixel (clamp(x), clamp(y)).
struct Padded {
  Rect rect;
  int channels = 0;
  std::vector<float> data;
  int stride() const { return rect.width(); }
  const float* plane(int c) const {
    return data.data() + static_cast<std::size_t>(c) * rect.area();
  }
};

Padded pad(const View& v, const Rect& rect, int width, int height) {
  Padded p{rect, v.channels,
           std::vector<float>(rect.area() * static_cast<std::size_t>(v.channels))};
  for (int c = 0; c < v.channels; ++c) {
    float* dst = p.data.data() + static_cast<std::size_t>(c) * rect.area();
    for (int y = rect.y0; y < rect.y1; ++y) {
      const int sy = std::clamp(y, 0, height - 1);
      for (int x = rect.x0; x < rect.x1; ++x) {
        const int sx = std::clamp(x, 0, width - 1);
        *dst++ = v.at(sx, sy, c);
      }
    }
  }
  return p;
}

// Everything one search offset needs: padded tile planes, the fused rows' scratch and the tile's
// accumulators. Padded planes have row stride ps >= ewv + 2R, so full vectors never leave them;
// lanes past the output width compute values nobody reads.
struct Kernel {
  int R, F, P;              // search radius, patch radius, R + F
  int ow, oh, eh;           // output size, patch-extended height oh + 2F
  std::ptrdiff_t owv, ewv;  // output width and patch-extended width, rounded up to vectors
  std::ptrdiff_t ps;        // padded plane row stride
  const float* X[3];
  const float* V[3];
  const float* alb[3] = {nullptr, nullptr, nullptr};
  const float* alb_v[3] = {nullptr, nullptr, nullptr};
  const float* nrm[3] = {nullptr, nullptr, nullptr};
  const float* nrm_v[3] = {nullptr, nullptr, nullptr};
  const float* dep = nullptr;
  float k2, alpha, eps, inv_patch3, inv_kf2, tau, depth_scale;
  bool features, derivative;
  // Scratch.
  float* drow;          // ewv: one row's colour distance
  float* hring;         // (2F + 1) * owv: row sums of the last 2F + 1 rows
  float* isring;        // (2F + 1) * 3 * ewv: 1 / (eps + k^2 (v_a + v_{a+delta})) of those rows
  const float** hrows;  // 2F + 1 pointers into hring
  float* w;             // owv: one row of weights
  // Accumulators (owv * oh each, planar per channel where 3, n_acc apart).
  std::ptrdiff_t n_acc;
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

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define PRODEN_NLMEANS_X86 1

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
  void (*offset)(const Kernel&, int, int);
};

BuildInfo info(Build b) {
#ifdef PRODEN_NLMEANS_X86
  if (b == Build::avx512) return {"avx512", 16, avx512::offset};
  if (b == Build::avx2) return {"avx2", 8, avx2::offset};
#endif
  (void)b;
  return {"baseline", 4, portable::offset};
}

std::vector<Build> builds_available() {
  std::vector<Build> out = {Build::baseline};
#ifdef PRODEN_NLMEANS_X86
  __builtin_cpu_init();
  if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) out.push_back(Build::avx2);
  if (__builtin_cpu_supports("avx512f")) out.push_back(Build::avx512);
#endif
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
  const BuildInfo build = info(static_cast<Build>(build_));
  const std::size_t L = static_cast<std::size_t>(build.lanes);
  const int R = params_.search_radius;
  const int F = params_.patch_radius;
  const int P = R + F;
  const int ow = out.width(), oh = out.height();
  const Rect prect = out.expanded(P);
  const std::size_t owv = round_up(static_cast<std::size_t>(ow), L);
  const std::size_t ewv = round_up(owv + 2 * static_cast<std::size_t>(F), L);
  // Padded planes run on to the right so that every vector load stays inside them.
  const std::size_t ps = ewv + 2 * static_cast<std::size_t>(R);
  const Rect wide{prect.x0, prect.y0, prect.x0 + static_cast<int>(ps), prect.y1};

  const Padded X = pad(in.colour, wide, in.width, in.height);
  const Padded V = pad(in.variance, wide, in.width, in.height);
  const bool feats = params_.use_features;
  auto pad_or_zero = [&](const View& v, int ch) {
    if (v.valid()) return pad(v, wide, in.width, in.height);
    return Padded{wide, ch, std::vector<float>(wide.area() * static_cast<std::size_t>(ch), 0.0f)};
  };
  Padded alb, alb_v, nrm, nrm_v, dep;
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
  for (int c = 0; c < 3; ++c) {
    k.X[c] = X.plane(c);
    k.V[c] = V.plane(c);
  }
  if (feats && in.albedo.valid()) {
    alb = pad(in.albedo, wide, in.width, in.height);
    alb_v = pad_or_zero(in.albedo_variance, 3);
    for (int c = 0; c < 3; ++c) {
      k.alb[c] = alb.plane(c);
      k.alb_v[c] = alb_v.plane(c);
    }
  }
  if (feats && in.normal.valid()) {
    nrm = pad(in.normal, wide, in.width, in.height);
    nrm_v = pad_or_zero(in.normal_variance, 3);
    for (int c = 0; c < 3; ++c) {
      k.nrm[c] = nrm.plane(c);
      k.nrm_v[c] = nrm_v.plane(c);
    }
  }
  if (feats && in.depth.valid()) {
    dep = pad(in.depth, wide, in.width, in.height);
    k.dep = dep.plane(0);
  }
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
  const std::size_t n_acc = owv * static_cast<std::size_t>(oh);
  std::vector<float> drow(ewv), hring(nr * owv), isring(k.derivative ? nr * 3 * ewv : 0);
  std::vector<const float*> hrows(nr);
  std::vector<float> wrow(owv), wsum(n_acc, 0.0f), self(n_acc, 0.0f), num(3 * n_acc, 0.0f);
  std::vector<float> A(k.derivative ? 3 * n_acc : 0, 0.0f), B(k.derivative ? 3 * n_acc : 0, 0.0f);
  k.drow = drow.data();
  k.hring = hring.data();
  k.isring = isring.data();
  k.hrows = hrows.data();
  k.w = wrow.data();
  k.n_acc = static_cast<std::ptrdiff_t>(n_acc);
  k.wsum = wsum.data();
  k.self = self.data();
  k.num = num.data();
  k.A = A.data();
  k.B = B.data();
  k.gx0 = out.x0;
  k.gy0 = out.y0;
  k.width = in.width;
  k.height = in.height;

  for (int dy = -R; dy <= R; ++dy) {
    for (int dx = -R; dx <= R; ++dx) build.offset(k, dx, dy);
  }

  for (int oy = 0; oy < oh; ++oy) {
    for (int ox = 0; ox < ow; ++ox) {
      const std::size_t i = static_cast<std::size_t>(oy) * owv + static_cast<std::size_t>(ox);
      const float W = wsum[i];  // >= the centre's own weight, so > 0
      for (int c = 0; c < 3; ++c) {
        const std::size_t ci = static_cast<std::size_t>(c) * n_acc + i;
        const float yv = num[ci] / W;
        y_out.at(out.x0 + ox, out.y0 + oy, c) = yv;
        if (k.derivative) {
          dydx_out->at(out.x0 + ox, out.y0 + oy, c) = self[i] / W + (A[ci] - yv * B[ci]) / W;
        }
      }
    }
  }
}

}  // namespace proden

#include "proden/mixer.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

#include "simd.hpp"

namespace proden {
namespace {

constexpr double kTinyVariance = 1e-30;  // keeps 1 / var finite where a pixel is exact
constexpr int kBlock = 16;               // window sums are split at absolute multiples of this
// Lanes (columns) the vertical pass keeps in flight: its prefix and suffix sums stay in L2.
constexpr int kStrip = 32;

// Vertical window sums: for every output row y in [o0, o1) and lane i in [0, w),
//   out_y[i] = sum of in_q[i] over q in [max(y - r, lo), min(y + r + 1, hi)),
// with in_q = in + (q - lo) in_stride and out_y = out + (y - o0) out_stride; rows [lo, hi) are the
// input there is (the caller clips it to the image, and o0 - r .. o1 + r to it). Each window is
//   the suffix of a's block (a to the next multiple of kBlock) + whole blocks + the prefix of b's
// block (its start to b), or a direct sum when no multiple of kBlock lies in [a, b]. Every part
// starts at an absolute block boundary and adds in a fixed order, so a window's sum does not
// depend on [lo, hi) or [o0, o1): tiles equal the whole image bit for bit. A window adds only its
// own values (no running sum subtracts a firefly that left it). O(1 + r / kBlock) per window,
// vectorised across lanes. `acc` is scratch.
PRODEN_MULTIVERSION void vertical_sums(const float* in, std::ptrdiff_t in_stride, int lo, int hi,
                                       int w, int o0, int o1, int r, float* out,
                                       std::ptrdiff_t out_stride, std::vector<double>& acc) {
  const std::size_t rows = static_cast<std::size_t>(hi - lo) + 1, nblk = hi / kBlock + 1;
  acc.resize((2 * rows + nblk) * kStrip);
  double* const pre = acc.data();           // pre[b]: sum over [b's block start, b); rows lo..hi
  double* const suf = pre + rows * kStrip;  // suf[a]: sum over [a, a's block end); 0 on a boundary
  double* const blk = suf + rows * kStrip;  // whole block k's sum
  const auto row_of = [&](double* base, int q) {
    return base + static_cast<std::size_t>(q - lo) * kStrip;
  };
  for (int s0 = 0; s0 < w; s0 += kStrip) {
    const int n = std::min(kStrip, w - s0);
    const auto in_row = [&](int q) { return in + (q - lo) * in_stride + s0; };
    std::fill(row_of(pre, lo), row_of(pre, lo) + kStrip, 0.0);
    for (int b = lo + 1; b <= hi; ++b) {
      double* __restrict p = row_of(pre, b);
      const double* __restrict prev = row_of(pre, b - 1);
      const float* __restrict v = in_row(b - 1);
      if ((b - 1) % kBlock == 0) {
        for (int l = 0; l < n; ++l) p[l] = static_cast<double>(v[l]);
      } else {
        for (int l = 0; l < n; ++l) p[l] = prev[l] + static_cast<double>(v[l]);
      }
      if (b % kBlock == 0) {
        if (b - kBlock >= lo)
          std::copy(p, p + n, blk + static_cast<std::size_t>(b / kBlock - 1) * kStrip);
        std::fill(p, p + n, 0.0);
      }
    }
    std::fill(row_of(suf, hi), row_of(suf, hi) + kStrip, 0.0);
    for (int a = hi - 1; a >= lo; --a) {
      double* __restrict sa = row_of(suf, a);
      if (a % kBlock == 0) {
        std::fill(sa, sa + n, 0.0);
        continue;
      }
      const double* __restrict next = row_of(suf, a + 1);
      const float* __restrict v = in_row(a);
      for (int l = 0; l < n; ++l) sa[l] = static_cast<double>(v[l]) + next[l];
    }
    double sum[kStrip];
    for (int y = o0; y < o1; ++y) {
      const int a = std::max(y - r, lo), b = std::min(y + r + 1, hi);
      const int ka = (a + kBlock - 1) / kBlock, kb = b / kBlock;
      if (ka > kb) {  // no boundary inside [a, b]: direct
        for (int l = 0; l < n; ++l) sum[l] = 0.0;
        for (int q = a; q < b; ++q) {
          const float* __restrict v = in_row(q);
          for (int l = 0; l < n; ++l) sum[l] += static_cast<double>(v[l]);
        }
      } else {
        const double* __restrict sa = row_of(suf, a);
        for (int l = 0; l < n; ++l) sum[l] = sa[l];
        for (int k = ka; k < kb; ++k) {
          const double* __restrict bk = blk + static_cast<std::size_t>(k) * kStrip;
          for (int l = 0; l < n; ++l) sum[l] += bk[l];
        }
        const double* __restrict pb = row_of(pre, b);
        for (int l = 0; l < n; ++l) sum[l] += pb[l];
      }
      float* __restrict o = out + (y - o0) * out_stride + s0;
      for (int l = 0; l < n; ++l) o[l] = static_cast<float>(sum[l]);
    }
  }
}

// dst (rows x cols, stride ds) = src^T (cols x rows, stride ss), in 8x8 blocks (the compiler keeps
// a whole block in registers), then the ragged edges.
PRODEN_MULTIVERSION void transpose(const float* __restrict src, std::ptrdiff_t ss, int rows,
                                   int cols, float* __restrict dst, std::ptrdiff_t ds) {
  constexpr int kT = 8;
  const int r8 = rows / kT * kT, c8 = cols / kT * kT;
  for (int i0 = 0; i0 < r8; i0 += kT) {
    for (int j0 = 0; j0 < c8; j0 += kT) {
      float blk[kT][kT];
      for (int j = 0; j < kT; ++j)
        for (int i = 0; i < kT; ++i) blk[i][j] = src[(j0 + j) * ss + i0 + i];
      for (int i = 0; i < kT; ++i)
        for (int j = 0; j < kT; ++j) dst[(i0 + i) * ds + j0 + j] = blk[i][j];
    }
  }
  for (int i = 0; i < rows; ++i) {
    for (int j = i < r8 ? c8 : 0; j < cols; ++j) dst[i * ds + j] = src[j * ss + i];
  }
}

struct BoxScratch {
  std::vector<float> v, vt, ht;  // vertical sums, transposed, horizontal sums (transposed)
  std::vector<double> acc;
};

// Sums of plane `c` of `src` (a buffer covering at least out ⊕ r ∩ image) over each pixel's
// (2r+1)^2 window clipped to the image, for every pixel of `out`, into plane `dst_c` of `dst`.
// Separable: columns, then rows (as columns of the transpose), each with vertical_sums.
void box_sums(const Buffer& src, int c, const Rect& out, int r, const Rect& image, Buffer& dst,
              int dst_c, BoxScratch& sc) {
  const int lo_y = std::max(out.y0 - r, image.y0), hi_y = std::min(out.y1 + r, image.y1);
  const int lo_x = std::max(out.x0 - r, image.x0), hi_x = std::min(out.x1 + r, image.x1);
  const int wx = hi_x - lo_x, h = out.height(), w = out.width();
  const std::ptrdiff_t ss = src.rect().width();
  sc.v.resize(static_cast<std::size_t>(h) * wx);
  sc.vt.resize(static_cast<std::size_t>(h) * wx);
  sc.ht.resize(static_cast<std::size_t>(h) * w);
  vertical_sums(src.row(lo_y, c) + (lo_x - src.rect().x0), ss, lo_y, hi_y, wx, out.y0, out.y1, r,
                sc.v.data(), wx, sc.acc);
  transpose(sc.v.data(), wx, wx, h, sc.vt.data(), h);  // rows: x in [lo_x, hi_x); lanes: y
  vertical_sums(sc.vt.data(), h, lo_x, hi_x, h, out.x0, out.x1, r, sc.ht.data(), h, sc.acc);
  transpose(sc.ht.data(), h, h, w, dst.row(out.y0, dst_c) + (out.x0 - dst.rect().x0),
            dst.rect().width());
}

// One thread's buffers for mix().
struct Scratch {
  Buffer planes, terms, sums, wide, local;
  BoxScratch box;
};

// Window sums feeding one alpha estimate (stein rule) and its sampling variance.
struct WindowEstimate {
  double alpha = 0.0;     // S(w (var - div)) / S(w d^2), unclamped
  double variance = 0.0;  // delta method: (Var[S(var)] + alpha^2 Var[S(d^2)]) / S(d^2)^2
  bool valid = false;     // S(d^2) > 0
};

WindowEstimate stein_estimate(double s_a, double s_d2, double n_a, double n_d2) {
  WindowEstimate e;
  if (!(s_d2 > 0.0)) return e;
  e.alpha = s_a / s_d2;
  e.variance = (n_a + e.alpha * e.alpha * n_d2) / (s_d2 * s_d2);
  e.valid = std::isfinite(e.alpha) && std::isfinite(e.variance);
  return e;
}

}  // namespace

std::string ClosedFormMixer::name() const {
  return params_.rule == ClosedFormRule::stein ? "closed-form-stein" : "closed-form-inverse-error";
}

void ClosedFormMixer::mix(const MixInputs& in, const Rect& out, Buffer& alpha) const {
  const int r = params_.radius;
  const bool two_scales =
      params_.rule == ClosedFormRule::stein && params_.wide_radius > params_.radius;
  const int R = two_scales ? params_.wide_radius : r;
  const Rect image{0, 0, in.width, in.height};
  const Rect wrect = out.expanded(R).intersect(image);
  const Rect vrect = wrect.expanded(1).intersect(image);
  // Terms, weighted per pixel by w. stein: A = w (var - div) and D = w d^2, and (two scales) their
  // sampling noise w^2 var^2 2 / dof (a chi-square estimate; 0 when the variance is exact) and
  // w^2 d^4 2 / 3 (Var[d^2] = 2 E[d^2]^2 = 2/3 E[d^4] for Gaussian d). inverse-error: w var and
  // w SURE.
  const bool stein = params_.rule == ClosedFormRule::stein;
  const int n_terms = two_scales ? 4 : 2;
  // Per-thread scratch, reused from tile to tile (mix() runs on several threads at once).
  thread_local Scratch scratch;
  Buffer &planes = scratch.planes, &terms = scratch.terms, &sums = scratch.sums,
         &wide = scratch.wide, &local = scratch.local;
  planes.reset(vrect, 2);
  terms.reset(wrect, n_terms);
  sums.reset(out, n_terms);
  wide.reset(out, n_terms);
  local.reset(wrect, 2);
  BoxScratch& box = scratch.box;
  const bool relative = params_.weight == WindowWeight::relative;
  const bool exact = in.origin.renderer || !in.origin.passes.valid();
  const double g2 = static_cast<double>(params_.garrote) * params_.garrote;
  for (int c = 0; c < 3; ++c) {
    for (int y = vrect.y0; y < vrect.y1; ++y) {
      const float* v = in.variance.ptr(vrect.x0, y, c);
      const float* xr = in.x.ptr(vrect.x0, y, c);
      std::copy(v, v + vrect.width(), planes.row(y, 0));
      std::copy(xr, xr + vrect.width(), planes.row(y, 1));
    }
    // Weights 1 / (3x3 mean of var): smoothing gives the weight many more degrees of freedom
    // than the pixel's own estimate, whose noise would otherwise bias alpha low
    // (E[1/s^2] > 1/sigma^2). Weighting by 1/var makes alpha minimise the window's
    // variance-normalised error, so a firefly's huge variance cannot make its neighbours trust
    // a y it smeared into them (a plain sum would be dominated by it).
    // The variance floor (1 % relative standard deviation of the local mean, or of 0.1 where it
    // is black) stops a pixel whose few passes happened to agree exactly (var = 0 in a dark,
    // undersampled region) from taking over its whole window with an infinite weight.
    box_sums(planes, 0, wrect, 1, image, local, 0, box);
    box_sums(planes, 1, wrect, 1, image, local, 1, box);
    const int w_n = wrect.width();
    for (int y = wrect.y0; y < wrect.y1; ++y) {
      const int ny = std::min(y + 2, image.y1) - std::max(y - 1, image.y0);
      const float *lv = local.row(y, 0), *lx = local.row(y, 1);
      const float* vr = in.variance.ptr(wrect.x0, y, c);
      const float* xr = in.x.ptr(wrect.x0, y, c);
      const float* yr = in.y.ptr(wrect.x0, y, c);
      const float* er = (stein ? in.divergence : in.sure).ptr(wrect.x0, y, c);
      const float* pr = exact ? nullptr : in.origin.passes.ptr(wrect.x0, y, 0);
      float* t0 = terms.row(y, 0);
      float* t1 = terms.row(y, 1);
      float* t2 = two_scales ? terms.row(y, 2) : nullptr;
      float* t3 = two_scales ? terms.row(y, 3) : nullptr;
      for (int i = 0; i < w_n; ++i) {
        const int x = wrect.x0 + i;
        const int nx = std::min(x + 2, image.x1) - std::max(x - 1, image.x0);
        const double mv = static_cast<double>(lv[i]) / (nx * ny);
        const double mx = static_cast<double>(lx[i]) / (nx * ny);
        const double w =
            params_.weight == WindowWeight::uniform ? 1.0
            : relative                              ? 1.0 / (mx * mx + 0.01)
                       : 1.0 / (mv + params_.variance_floor * (mx * mx + 0.01) + kTinyVariance);
        const double var = vr[i];
        if (!stein) {
          t0[i] = static_cast<float>(w * var);
          t1[i] = static_cast<float>(w * er[i]);
          continue;
        }
        const double d = static_cast<double>(yr[i]) - xr[i];
        t0[i] = static_cast<float>(w * (var - er[i]));
        t1[i] = static_cast<float>(w * d * d);
        if (two_scales) {
          t2[i] = static_cast<float>(exact ? 0.0 : w * w * var * var * 2.0 / pixel_dof(pr[i]));
          t3[i] = static_cast<float>(w * w * d * d * d * d * (2.0 / 3.0));
        }
      }
    }
    for (int t = 0; t < n_terms; ++t) {
      box_sums(terms, t, out, r, image, sums, t, box);
      if (two_scales) box_sums(terms, t, out, R, image, wide, t, box);
    }
    for (int y = out.y0; y < out.y1; ++y) {
      const float *n0 = sums.row(y, 0), *n1 = sums.row(y, 1);
      const float *n2 = two_scales ? sums.row(y, 2) : nullptr,
                  *n3 = two_scales ? sums.row(y, 3) : nullptr;
      const float *l0 = wide.row(y, 0), *l1 = wide.row(y, 1);
      const float *l2 = two_scales ? wide.row(y, 2) : nullptr,
                  *l3 = two_scales ? wide.row(y, 3) : nullptr;
      float* ar = alpha.row(y, c) + (out.x0 - alpha.rect().x0);
      for (int i = 0; i < out.width(); ++i) {
        const double s0 = n0[i], s1 = n1[i];
        double a = 0.0;
        if (!stein) {
          const double ex = s0, ey = std::max(s1, 0.0);
          if (ex + ey > 0.0) a = ex / (ex + ey);
        } else if (!two_scales) {
          if (s1 > 0.0) a = s0 / s1;
        } else {
          const WindowEstimate n = stein_estimate(s0, s1, n2[i], n3[i]);
          const WindowEstimate l = stein_estimate(l0[i], l1[i], l2[i], l3[i]);
          if (n.valid && l.valid) {
            // The difference of nested window estimates has variance ~ V_narrow - V_wide.
            const double delta = n.alpha - l.alpha;
            const double noise = std::max(n.variance - l.variance, 0.0);
            const double keep =
                delta != 0.0 ? std::max(0.0, 1.0 - g2 * noise / (delta * delta)) : 0.0;
            a = l.alpha + keep * delta;
          } else if (l.valid) {
            a = l.alpha;
          } else if (n.valid) {
            a = n.alpha;
          }
        }
        ar[i] = static_cast<float>(std::clamp(std::isfinite(a) ? a : 0.0, 0.0, 1.0));
      }
    }
  }
}

}  // namespace proden

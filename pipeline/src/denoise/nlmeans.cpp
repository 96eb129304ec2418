#include "proden/denoise/nlmeans.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "../fast_math.hpp"
#include "../simd.hpp"

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

// Everything one search offset needs: padded tile planes and the tile's accumulators.
struct Kernel {
  int R, F, P;     // search radius, patch radius, R + F
  int ow, oh, pw;  // output size, padded row stride
  int ew, eh;      // patch-extended region (output + F on each side)
  const float* X[3];
  const float* V[3];
  const float* alb[3] = {nullptr, nullptr, nullptr};
  const float* alb_v[3] = {nullptr, nullptr, nullptr};
  const float* nrm[3] = {nullptr, nullptr, nullptr};
  const float* nrm_v[3] = {nullptr, nullptr, nullptr};
  const float* dep = nullptr;
  float k2, alpha, eps, inv_patch3, inv_kf2, tau, depth_scale;
  bool derivative;
  // Scratch.
  float* dist;      // ew * eh
  float* inv_s[3];  // ew * eh per channel: 1 / (eps + k^2 (v_a + v_{a+delta}))
  float* hsum;      // ow * eh
  float* dpatch;    // ow * oh
  float* fdist;     // ow * oh
  float* fscratch;  // 2 * ow
  float* w;         // ow (one row of weights)
  // Accumulators (ow * oh, planar per channel where 3).
  float* wsum;
  float* self;
  float* num;
  float* A;
  float* B;
  const int* gx;  // global x of each output column
  int gy0, width, height;
};

PRODEN_MULTIVERSION void feature_distance(const Kernel& k, std::ptrdiff_t doff) {
  const std::size_t n = static_cast<std::size_t>(k.ow) * static_cast<std::size_t>(k.oh);
  for (std::size_t i = 0; i < n; ++i) k.fdist[i] = 0.0f;
  for (int oy = 0; oy < k.oh; ++oy) {
    const std::size_t base = static_cast<std::size_t>(oy + k.P) * static_cast<std::size_t>(k.pw) +
                             static_cast<std::size_t>(k.P);
    float* __restrict frow =
        k.fdist + static_cast<std::size_t>(oy) * static_cast<std::size_t>(k.ow);
    // Per channel, few memory streams per loop (vectorisable), then combine.
    float* __restrict dd = k.fscratch;
    float* __restrict vs = k.fscratch + k.ow;
    auto vec3 = [&](const float* const* f, const float* const* fv) {
      for (int c = 0; c < 3; ++c) {
        const float* fp = f[c] + base;
        const float* fq = fp + doff;
        const float* vp = fv[c] + base;
        const float* vq = vp + doff;
        const bool first = c == 0;
        for (int ox = 0; ox < k.ow; ++ox) {
          const float d = fp[ox] - fq[ox], a = vp[ox], b = vq[ox];
          const float term = d * d - (a + (a < b ? a : b));
          dd[ox] = first ? term : dd[ox] + term;
          vs[ox] = first ? a + b : vs[ox] + a + b;
        }
      }
      const float tau = k.tau, inv_kf2 = k.inv_kf2;
      for (int ox = 0; ox < k.ow; ++ox) {
        const float d = dd[ox] / (vs[ox] > tau ? vs[ox] : tau) * inv_kf2;
        frow[ox] = frow[ox] > d ? frow[ox] : d;
      }
    };
    if (k.alb[0]) vec3(k.alb, k.alb_v);
    if (k.nrm[0]) vec3(k.nrm, k.nrm_v);
    if (k.dep) {
      const float* zp = k.dep + base;
      const float* zq = zp + doff;
      for (int ox = 0; ox < k.ow; ++ox) {
        const float z0 = zp[ox], z1 = zq[ox];
        const float az0 = z0 < 0.0f ? -z0 : z0, az1 = z1 < 0.0f ? -z1 : z1;
        const float scale = k.depth_scale * (az0 + az1) * 0.5f + 1e-6f;
        const float rel = (z0 - z1) / scale;
        const float d = rel * rel * k.inv_kf2;
        frow[ox] = frow[ox] > d ? frow[ox] : d;
      }
    }
  }
}

PRODEN_MULTIVERSION void accumulate_offset(const Kernel& k, int dx, int dy, bool features) {
  const std::ptrdiff_t doff = static_cast<std::ptrdiff_t>(dy) * k.pw + dx;
  const std::size_t ew = static_cast<std::size_t>(k.ew), ow = static_cast<std::size_t>(k.ow);
  const int taps = 2 * k.F + 1;
  // 1. Per-pixel colour distance d(a, a + delta) over the patch-extended region; the inverse
  // denominators are kept for the derivative below.
  // Local copies of the plane pointers: the stores below could otherwise alias the Kernel struct
  // in the compiler's eyes and force reloads that block vectorisation.
  const float *X0 = k.X[0], *X1 = k.X[1], *X2 = k.X[2];
  const float *V0 = k.V[0], *V1 = k.V[1], *V2 = k.V[2];
  float *I0 = k.inv_s[0], *I1 = k.inv_s[1], *I2 = k.inv_s[2];
  const float alpha = k.alpha, eps = k.eps, k2 = k.k2;
  const std::size_t pw = static_cast<std::size_t>(k.pw), R = static_cast<std::size_t>(k.R);
  for (int ey = 0; ey < k.eh; ++ey) {
    const std::size_t base = (static_cast<std::size_t>(ey) + R) * pw + R;
    const std::size_t erow = static_cast<std::size_t>(ey) * ew;
    // Separate pointers for the shifted pixel: an unsigned index plus a negative offset is not
    // an affine address and would block vectorisation.
    const float *xa0 = X0 + base, *xa1 = X1 + base, *xa2 = X2 + base;
    const float *va0 = V0 + base, *va1 = V1 + base, *va2 = V2 + base;
    const float *xb0 = xa0 + doff, *xb1 = xa1 + doff, *xb2 = xa2 + doff;
    const float *vb0 = va0 + doff, *vb1 = va1 + doff, *vb2 = va2 + doff;
    float* __restrict drow = k.dist + erow;
    float* __restrict i0 = I0 + erow;
    float* __restrict i1 = I1 + erow;
    float* __restrict i2 = I2 + erow;
    const int n_ex = k.ew;
    // One channel at a time keeps the loop at four memory streams (vectorisable).
    auto channel = [&](const float* xa, const float* xb, const float* va, const float* vb,
                       float* __restrict inv, bool first) {
      for (int ex = 0; ex < n_ex; ++ex) {
        const float d = xa[ex] - xb[ex], a = va[ex], b = vb[ex];
        const float is = 1.0f / (eps + k2 * (a + b));
        inv[ex] = is;
        const float term = (d * d - alpha * (a + (a < b ? a : b))) * is;
        drow[ex] = first ? term : drow[ex] + term;
      }
    };
    channel(xa0, xb0, va0, vb0, i0, true);
    channel(xa1, xb1, va1, vb1, i1, false);
    channel(xa2, xb2, va2, vb2, i2, false);
  }
  // 2. Box filter over the patch (separable), scaled to a mean over patch and channels.
  for (int ey = 0; ey < k.eh; ++ey) {
    const float* drow = k.dist + static_cast<std::size_t>(ey) * ew;
    float* __restrict hrow = k.hsum + static_cast<std::size_t>(ey) * ow;
    for (std::size_t ox = 0; ox < ow; ++ox) hrow[ox] = drow[ox];
    for (int j = 1; j < taps; ++j) {
      for (std::size_t ox = 0; ox < ow; ++ox) hrow[ox] += drow[ox + static_cast<std::size_t>(j)];
    }
  }
  for (int oy = 0; oy < k.oh; ++oy) {
    float* __restrict prow = k.dpatch + static_cast<std::size_t>(oy) * ow;
    const float* h0 = k.hsum + static_cast<std::size_t>(oy) * ow;
    for (std::size_t ox = 0; ox < ow; ++ox) prow[ox] = h0[ox];
    for (int i = 1; i < taps; ++i) {
      const float* hrow = k.hsum + static_cast<std::size_t>(oy + i) * ow;
      for (std::size_t ox = 0; ox < ow; ++ox) prow[ox] += hrow[ox];
    }
    for (std::size_t ox = 0; ox < ow; ++ox) prow[ox] *= k.inv_patch3;
  }
  // 3. Weights and accumulation; the weights' derivative w.r.t. the centre pixel: p appears as
  // the first pixel of the o = 0 pair, and as the second of the o = -delta pair when that offset
  // lies inside the patch.
  const bool second = (dx < 0 ? -dx : dx) <= k.F && (dy < 0 ? -dy : dy) <= k.F;
  const std::size_t n_out = ow * static_cast<std::size_t>(k.oh);
  for (int oy = 0; oy < k.oh; ++oy) {
    const int gy = k.gy0 + oy;
    const int qy = gy + dy < 0 ? 0 : (gy + dy >= k.height ? k.height - 1 : gy + dy);
    const bool same_y = qy == gy;
    const std::size_t prow = static_cast<std::size_t>(oy + k.P) * static_cast<std::size_t>(k.pw) +
                             static_cast<std::size_t>(k.P);
    const std::size_t orow = static_cast<std::size_t>(oy) * ow;
    const float* dp = k.dpatch + orow;
    const float* fd = features ? k.fdist + orow : nullptr;
    float* __restrict wrow = k.w;
    float* __restrict ws = k.wsum + orow;
    float* __restrict sf = k.self + orow;
    if (fd) {
      for (std::size_t ox = 0; ox < ow; ++ox) {
        const float dc = dp[ox] > 0.0f ? dp[ox] : 0.0f;
        const float f = fd[ox] > 0.0f ? fd[ox] : 0.0f;
        wrow[ox] = detail::exp_neg(-(dc + f));
        ws[ox] += wrow[ox];
      }
    } else {
      for (std::size_t ox = 0; ox < ow; ++ox) {
        const float dc = dp[ox] > 0.0f ? dp[ox] : 0.0f;
        wrow[ox] = detail::exp_neg(-dc);
        ws[ox] += wrow[ox];
      }
    }
    // Weight on the centre pixel itself: q = clamp(p + delta) == p, i.e. delta = 0, or delta
    // pointing out of the image from a border pixel.
    if (same_y) {
      if (dx == 0) {
        for (std::size_t ox = 0; ox < ow; ++ox) sf[ox] += wrow[ox];
      } else if (dx < 0 && k.gx[0] == 0) {
        sf[0] += wrow[0];
      } else if (dx > 0 && k.gx[ow - 1] == k.width - 1) {
        sf[ow - 1] += wrow[ow - 1];
      }
    }
    for (int c = 0; c < 3; ++c) {
      const float* xp = k.X[c] + prow;
      const float* xqp = xp + doff;  // q = p + delta
      const float* xap = xp - doff;  // p - delta
      float* __restrict nu = k.num + static_cast<std::size_t>(c) * n_out + orow;
      for (std::size_t ox = 0; ox < ow; ++ox) nu[ox] += wrow[ox] * xqp[ox];
      if (!k.derivative) continue;
      float* __restrict a = k.A + static_cast<std::size_t>(c) * n_out + orow;
      float* __restrict b = k.B + static_cast<std::size_t>(c) * n_out + orow;
      const float scale = 2.0f * k.inv_patch3;
      // inv_s in E coordinates: p is at (ox + F, oy + F), p - delta at (ox + F - dx, oy + F - dy).
      const float* is_p =
          k.inv_s[c] + static_cast<std::size_t>(oy + k.F) * ew + static_cast<std::size_t>(k.F);
      if (second) {
        const float* is_a =
            is_p - (static_cast<std::ptrdiff_t>(dy) * static_cast<std::ptrdiff_t>(ew) + dx);
        for (std::size_t ox = 0; ox < ow; ++ox) {
          const float xc = xp[ox], xq = xqp[ox], xa = xap[ox];
          const float g = (xc - xq) * is_p[ox] + (xc - xa) * is_a[ox];
          const float dw = dp[ox] > 0.0f ? -wrow[ox] * g * scale : 0.0f;
          a[ox] += dw * xq;
          b[ox] += dw;
        }
      } else {
        for (std::size_t ox = 0; ox < ow; ++ox) {
          const float xc = xp[ox], xq = xqp[ox];
          const float g = (xc - xq) * is_p[ox];
          const float dw = dp[ox] > 0.0f ? -wrow[ox] * g * scale : 0.0f;
          a[ox] += dw * xq;
          b[ox] += dw;
        }
      }
    }
  }
}

}  // namespace

NlMeansDenoiser::NlMeansDenoiser(NlMeansParams params) : params_(params) {
  if (params_.search_radius < 0 || params_.patch_radius < 0 || !(params_.k > 0.0f)) {
    throw std::invalid_argument("NlMeansDenoiser: radii must be >= 0 and k > 0");
  }
}

void NlMeansDenoiser::denoise(const DenoiseInputs& in, const Rect& out, Buffer& y_out,
                              Buffer* dydx_out) const {
  if (out.empty()) return;
  const int R = params_.search_radius;
  const int F = params_.patch_radius;
  const int P = R + F;
  const int ow = out.width(), oh = out.height();
  const Rect prect = out.expanded(P);

  const Padded X = pad(in.colour, prect, in.width, in.height);
  const Padded V = pad(in.variance, prect, in.width, in.height);
  const bool feats = params_.use_features;
  auto pad_or_zero = [&](const View& v, int ch) {
    if (v.valid()) return pad(v, prect, in.width, in.height);
    return Padded{prect, ch, std::vector<float>(prect.area() * static_cast<std::size_t>(ch), 0.0f)};
  };
  Padded alb, alb_v, nrm, nrm_v, dep;
  Kernel k{};
  k.R = R;
  k.F = F;
  k.P = P;
  k.ow = ow;
  k.oh = oh;
  k.pw = prect.width();
  k.ew = ow + 2 * F;
  k.eh = oh + 2 * F;
  for (int c = 0; c < 3; ++c) {
    k.X[c] = X.plane(c);
    k.V[c] = V.plane(c);
  }
  if (feats && in.albedo.valid()) {
    alb = pad(in.albedo, prect, in.width, in.height);
    alb_v = pad_or_zero(in.albedo_variance, 3);
    for (int c = 0; c < 3; ++c) {
      k.alb[c] = alb.plane(c);
      k.alb_v[c] = alb_v.plane(c);
    }
  }
  if (feats && in.normal.valid()) {
    nrm = pad(in.normal, prect, in.width, in.height);
    nrm_v = pad_or_zero(in.normal_variance, 3);
    for (int c = 0; c < 3; ++c) {
      k.nrm[c] = nrm.plane(c);
      k.nrm_v[c] = nrm_v.plane(c);
    }
  }
  if (feats && in.depth.valid()) {
    dep = pad(in.depth, prect, in.width, in.height);
    k.dep = dep.plane(0);
  }
  const bool features = k.alb[0] || k.nrm[0] || k.dep;
  k.k2 = params_.k * params_.k;
  k.alpha = params_.alpha;
  k.eps = params_.epsilon;
  k.inv_patch3 = 1.0f / static_cast<float>((2 * F + 1) * (2 * F + 1) * 3);
  k.inv_kf2 = 1.0f / (params_.k_feature * params_.k_feature);
  k.tau = params_.tau;
  k.depth_scale = params_.depth_scale;
  k.derivative = dydx_out != nullptr;

  const std::size_t n_out = static_cast<std::size_t>(ow) * static_cast<std::size_t>(oh);
  const std::size_t n_e = static_cast<std::size_t>(k.ew) * static_cast<std::size_t>(k.eh);
  std::vector<float> dist(n_e), inv_s(3 * n_e);
  std::vector<float> hsum(static_cast<std::size_t>(ow) * static_cast<std::size_t>(k.eh));
  std::vector<float> dpatch(n_out), fdist(n_out), wrow(static_cast<std::size_t>(ow));
  std::vector<float> wsum(n_out, 0.0f), self(n_out, 0.0f);
  std::vector<float> num(3 * n_out, 0.0f), A(3 * n_out, 0.0f), B(3 * n_out, 0.0f);
  std::vector<int> gx(static_cast<std::size_t>(ow));
  for (int ox = 0; ox < ow; ++ox) gx[static_cast<std::size_t>(ox)] = out.x0 + ox;
  k.dist = dist.data();
  for (int c = 0; c < 3; ++c) k.inv_s[c] = inv_s.data() + static_cast<std::size_t>(c) * n_e;
  k.hsum = hsum.data();
  k.dpatch = dpatch.data();
  k.fdist = fdist.data();
  std::vector<float> fscratch(2 * static_cast<std::size_t>(ow));
  k.fscratch = fscratch.data();
  k.w = wrow.data();
  k.wsum = wsum.data();
  k.self = self.data();
  k.num = num.data();
  k.A = A.data();
  k.B = B.data();
  k.gx = gx.data();
  k.gy0 = out.y0;
  k.width = in.width;
  k.height = in.height;

  for (int dy = -R; dy <= R; ++dy) {
    for (int dx = -R; dx <= R; ++dx) {
      if (features) feature_distance(k, static_cast<std::ptrdiff_t>(dy) * k.pw + dx);
      accumulate_offset(k, dx, dy, features);
    }
  }

  for (int oy = 0; oy < oh; ++oy) {
    for (int ox = 0; ox < ow; ++ox) {
      const std::size_t i = static_cast<std::size_t>(oy) * static_cast<std::size_t>(ow) +
                            static_cast<std::size_t>(ox);
      const float W = wsum[i];  // >= the centre's own weight, so > 0
      for (int c = 0; c < 3; ++c) {
        const std::size_t ci = static_cast<std::size_t>(c) * n_out + i;
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

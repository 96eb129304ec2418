#include "proden/denoise/nlmeans.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

#include "../fast_math.hpp"

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

}  // namespace

NlMeansDenoiser::NlMeansDenoiser(NlMeansParams params) : params_(params) {
  if (params_.search_radius < 0 || params_.patch_radius < 0 || !(params_.k > 0.0f)) {
    throw std::invalid_argument("NlMeansDenoiser: radii must be >= 0 and k > 0");
  }
}

void NlMeansDenoiser::denoise(const DenoiseInputs& in, const Rect& out, Buffer& y_out,
                              Buffer* dydx_out) const {
  const int R = params_.search_radius;
  const int F = params_.patch_radius;
  const int P = R + F;
  const int ow = out.width(), oh = out.height();
  if (out.empty()) return;
  const Rect prect = out.expanded(P);
  const int pw = prect.width();

  const Padded X = pad(in.colour, prect, in.width, in.height);
  const Padded V = pad(in.variance, prect, in.width, in.height);
  const bool feats = params_.use_features;
  Padded alb, alb_v, nrm, nrm_v, dep, dep_v;
  const bool has_alb = feats && in.albedo.valid();
  const bool has_nrm = feats && in.normal.valid();
  const bool has_dep = feats && in.depth.valid();
  auto pad_or_zero = [&](const View& v, int ch) {
    if (v.valid()) return pad(v, prect, in.width, in.height);
    return Padded{prect, ch, std::vector<float>(prect.area() * static_cast<std::size_t>(ch), 0.0f)};
  };
  if (has_alb) {
    alb = pad(in.albedo, prect, in.width, in.height);
    alb_v = pad_or_zero(in.albedo_variance, 3);
  }
  if (has_nrm) {
    nrm = pad(in.normal, prect, in.width, in.height);
    nrm_v = pad_or_zero(in.normal_variance, 3);
  }
  if (has_dep) {
    dep = pad(in.depth, prect, in.width, in.height);
    dep_v = pad_or_zero(in.depth_variance, 1);
  }

  const std::size_t n_out = static_cast<std::size_t>(ow) * oh;
  std::vector<float> wsum(n_out, 0.0f), self(n_out, 0.0f);
  std::vector<float> num(3 * n_out, 0.0f), A(3 * n_out, 0.0f), B(3 * n_out, 0.0f);
  const int ew = ow + 2 * F, eh = oh + 2 * F;
  std::vector<float> dist(static_cast<std::size_t>(ew) * eh);
  std::vector<float> hsum(static_cast<std::size_t>(ow) * eh);
  std::vector<float> dpatch(n_out);
  std::vector<float> fdist(n_out);
  std::vector<unsigned char> same_x(static_cast<std::size_t>(ow));

  const float k2 = params_.k * params_.k;
  const float alpha = params_.alpha;
  const float eps = params_.epsilon;
  const float inv_patch = 1.0f / static_cast<float>((2 * F + 1) * (2 * F + 1));
  const float inv_kf2 = 1.0f / (params_.k_feature * params_.k_feature);
  const float tau = params_.tau;
  const bool derivative = dydx_out != nullptr;
  const float dscale = inv_patch / 3.0f;  // the colour distance is a mean over patch and channels

  const float* Xc[3] = {X.plane(0), X.plane(1), X.plane(2)};
  const float* Vc[3] = {V.plane(0), V.plane(1), V.plane(2)};

  for (int dy = -R; dy <= R; ++dy) {
    for (int dx = -R; dx <= R; ++dx) {
      const std::ptrdiff_t doff = static_cast<std::ptrdiff_t>(dy) * pw + dx;
      // 1. Per-pixel colour distance d(a, a + delta) over the patch-extended region.
      for (int ey = 0; ey < eh; ++ey) {
        const std::size_t base = static_cast<std::size_t>(ey + R) * static_cast<std::size_t>(pw) +
                                 static_cast<std::size_t>(R);
        float* drow = dist.data() + static_cast<std::size_t>(ey) * static_cast<std::size_t>(ew);
        for (int ex = 0; ex < ew; ++ex) drow[ex] = 0.0f;
        for (int c = 0; c < 3; ++c) {
          const float* xa = Xc[c] + base;
          const float* va = Vc[c] + base;
          const float* xb = xa + doff;
          const float* vb = va + doff;
          for (int ex = 0; ex < ew; ++ex) {
            const float diff = xa[ex] - xb[ex];
            const float vmin = va[ex] < vb[ex] ? va[ex] : vb[ex];
            drow[ex] += (diff * diff - alpha * (va[ex] + vmin)) / (eps + k2 * (va[ex] + vb[ex]));
          }
        }
      }
      // 2. Box filter over the patch (separable), divided by patch size and channel count.
      for (int ey = 0; ey < eh; ++ey) {
        const float* drow =
            dist.data() + static_cast<std::size_t>(ey) * static_cast<std::size_t>(ew);
        float* hrow = hsum.data() + static_cast<std::size_t>(ey) * static_cast<std::size_t>(ow);
        for (int ox = 0; ox < ow; ++ox) {
          float s = 0.0f;
          for (int j = 0; j <= 2 * F; ++j) s += drow[ox + j];
          hrow[ox] = s;
        }
      }
      for (int oy = 0; oy < oh; ++oy) {
        float* prow = dpatch.data() + static_cast<std::size_t>(oy) * static_cast<std::size_t>(ow);
        for (int ox = 0; ox < ow; ++ox) prow[ox] = 0.0f;
        for (int i = 0; i <= 2 * F; ++i) {
          const float* hrow =
              hsum.data() + static_cast<std::size_t>(oy + i) * static_cast<std::size_t>(ow);
          for (int ox = 0; ox < ow; ++ox) prow[ox] += hrow[ox];
        }
        for (int ox = 0; ox < ow; ++ox) prow[ox] *= inv_patch / 3.0f;
      }
      // 3. Feature distance (max over features), independent of x.
      std::fill(fdist.begin(), fdist.end(), 0.0f);
      if (has_alb || has_nrm || has_dep) {
        for (int oy = 0; oy < oh; ++oy) {
          const std::size_t base = static_cast<std::size_t>(oy + P) * static_cast<std::size_t>(pw) +
                                   static_cast<std::size_t>(P);
          float* frow = fdist.data() + static_cast<std::size_t>(oy) * static_cast<std::size_t>(ow);
          auto vec_feature = [&](const Padded& f, const Padded& fv) {
            for (int ox = 0; ox < ow; ++ox) {
              float d = 0.0f, vs = 0.0f;
              for (int c = 0; c < 3; ++c) {
                const float* fp = f.plane(c) + base;
                const float* vp = fv.plane(c) + base;
                const float diff = fp[ox] - fp[ox + doff];
                const float vmin = vp[ox] < vp[ox + doff] ? vp[ox] : vp[ox + doff];
                d += diff * diff - (vp[ox] + vmin);
                vs += vp[ox] + vp[ox + doff];
              }
              d = d / std::max(tau, vs) * inv_kf2;
              frow[ox] = std::max(frow[ox], d);
            }
          };
          if (has_alb) vec_feature(alb, alb_v);
          if (has_nrm) vec_feature(nrm, nrm_v);
          if (has_dep) {
            const float* zp = dep.plane(0) + base;
            for (int ox = 0; ox < ow; ++ox) {
              const float z0 = zp[ox], z1 = zp[ox + doff];
              const float scale =
                  params_.depth_scale * (std::abs(z0) + std::abs(z1)) * 0.5f + 1e-6f;
              const float rel = (z0 - z1) / scale;
              frow[ox] = std::max(frow[ox], rel * rel * inv_kf2);
            }
          }
        }
      }
      // 4. Weights, accumulation, and the weight derivative w.r.t. the centre pixel.
      for (int ox = 0; ox < ow; ++ox) {
        const int gx = out.x0 + ox;
        same_x[static_cast<std::size_t>(ox)] = std::clamp(gx + dx, 0, in.width - 1) == gx;
      }
      const bool second = std::abs(dx) <= F && std::abs(dy) <= F;
      for (int oy = 0; oy < oh; ++oy) {
        const int gy = out.y0 + oy;
        const bool same_y = std::clamp(gy + dy, 0, in.height - 1) == gy;
        const std::size_t prow = static_cast<std::size_t>(oy + P) * static_cast<std::size_t>(pw) +
                                 static_cast<std::size_t>(P);
        const std::size_t orow = static_cast<std::size_t>(oy) * static_cast<std::size_t>(ow);
        const float* dp = dpatch.data() + orow;
        const float* fd = fdist.data() + orow;
        float* ws = wsum.data() + orow;
        float* sf = self.data() + orow;
        for (int ox = 0; ox < ow; ++ox) {
          const float dc = dp[ox] > 0.0f ? dp[ox] : 0.0f;
          const float fdv = fd[ox] > 0.0f ? fd[ox] : 0.0f;
          const float w = detail::exp_neg(-(dc + fdv));
          ws[ox] += w;
          sf[ox] += (same_y && same_x[static_cast<std::size_t>(ox)]) ? w : 0.0f;
        }
        for (int c = 0; c < 3; ++c) {
          const float* xp = Xc[c] + prow;
          const float* vp = Vc[c] + prow;
          float* nu = num.data() + static_cast<std::size_t>(c) * n_out + orow;
          float* a = A.data() + static_cast<std::size_t>(c) * n_out + orow;
          float* b = B.data() + static_cast<std::size_t>(c) * n_out + orow;
          for (int ox = 0; ox < ow; ++ox) {
            const float dc = dp[ox] > 0.0f ? dp[ox] : 0.0f;
            const float fdv = fd[ox] > 0.0f ? fd[ox] : 0.0f;
            const float w = detail::exp_neg(-(dc + fdv));
            const float xq = xp[ox + doff];
            nu[ox] += w * xq;
            if (derivative) {
              // dD/dx_p: p as the first pixel of the o = 0 pair, and as the second pixel of the
              // o = -delta pair when that offset lies in the patch.
              float g = 2.0f * (xp[ox] - xq) / (eps + k2 * (vp[ox] + vp[ox + doff]));
              if (second) {
                const float xa = xp[ox - doff];
                g += 2.0f * (xp[ox] - xa) / (eps + k2 * (vp[ox - doff] + vp[ox]));
              }
              const float dw = dp[ox] > 0.0f ? -w * g * dscale : 0.0f;
              a[ox] += dw * xq;
              b[ox] += dw;
            }
          }
        }
      }
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
        if (derivative) {
          dydx_out->at(out.x0 + ox, out.y0 + oy, c) = self[i] / W + (A[ci] - yv * B[ci]) / W;
        }
      }
    }
  }
}

}  // namespace proden

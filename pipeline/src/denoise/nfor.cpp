// NFOR's stages in order (Bitterli et al. 2016; docs/nfor.md): load the frame into padded
// whole-frame planes, prefilter the features (§5.1), regress each half with the other half's
// weights at every bandwidth (§4, §5.2), select per pixel (§5.3), and regress the full colour once
// more with weights from the selected result (§5.4). Without half buffers (a single pass) it runs
// one regression of x weighted on x itself (docs/nfor.md, "single-buffer mode").
#include "proden/denoise/nfor.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "nfor_internal.hpp"

namespace proden {
namespace {

using nfor::Geometry;
using nfor::Planes;
using Clock = std::chrono::steady_clock;

// f(i) for every index i of a plane (border included), in parallel.
template <class F>
void each_index(const Geometry& g, F&& f) {
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, g.plane_size(), std::size_t{1} << 14),
                    [&](const tbb::blocked_range<std::size_t>& r) {
                      for (std::size_t i = r.begin(); i < r.end(); ++i) f(i);
                    });
}

double since(Clock::time_point& t) {
  const auto now = Clock::now();
  const double s = std::chrono::duration<double>(now - t).count();
  t = now;
  return s;
}

// Input limits: squares of differences (and their sums over a patch) stay finite in float.
constexpr float kMaxValue = 1e18f;
constexpr float kMaxVariance = 1e36f;
// Albedo and normals are O(1); a sanitised +-Inf (1e10) must not dominate the normal equations.
constexpr float kMaxFeature = 1e6f;
// Bandwidth of the single regression without half buffers (NL-means' usual k = 1).
constexpr float kSingleBufferK = 1.0f;

// Depth enters the regression as |d| / (|d| + D), D = the frame's median |depth|: comparable to
// albedo and normals in scale, and the background's 1e10 (Cycles) maps to ~1 instead of
// swamping every window it touches (docs/nfor.md).
float depth_scale(const View& depth, int w, int h) {
  std::vector<float> v;
  v.reserve(static_cast<std::size_t>(w) * static_cast<std::size_t>(h));
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const float d = depth.at(x, y, 0);
      v.push_back(std::isfinite(d) ? std::abs(d) : 0.0f);
    }
  }
  auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return std::max(*mid, 1e-20f);
}

// The kFeatures planes (albedo, normal, mapped depth; zero planes where absent) of one set of
// views.
Planes feature_planes(const Geometry& g, const View& albedo, const View& normal, const View& depth,
                      float scale) {
  Planes f(g, nfor::kFeatures);
  tbb::parallel_for(0, g.height, [&](int y) {
    for (int x = 0; x < g.width; ++x) {
      const std::ptrdiff_t i = g.offset(x, y);
      for (int c = 0; c < 3; ++c) {
        if (albedo.valid()) {
          f.origin(c)[i] = std::clamp(albedo.at(x, y, c), -kMaxFeature, kMaxFeature);
        }
        if (normal.valid()) {
          f.origin(3 + c)[i] = std::clamp(normal.at(x, y, c), -kMaxFeature, kMaxFeature);
        }
      }
      if (depth.valid()) {
        const float d = depth.at(x, y, 0);
        const float a = std::isfinite(d) ? std::abs(d) : 0.0f;
        f.origin(6)[i] = a / (a + scale);
      }
      // NaN features were sanitised upstream (accumulator); keep any that slip through out.
      for (int c = 0; c < 6; ++c)
        f.origin(c)[i] = std::isnan(f.origin(c)[i]) ? 0.0f : f.origin(c)[i];
    }
  });
  nfor::replicate_border(g, f);
  return f;
}

nfor::WeightSpec weights_on(const nfor::Kernels& kernels, const Planes& guide,
                            const Planes& variance, int radius, int patch, float k) {
  nfor::WeightSpec s;
  s.kernels = &kernels;
  s.channels = 3;
  for (int c = 0; c < 3; ++c) {
    s.guide[c] = guide.origin(c);
    s.variance[c] = variance.origin(c);
  }
  s.radius = radius;
  s.patch = patch;
  s.k = k;
  return s;
}

void copy_out(const Geometry& g, const Planes& p, int c0, Image& img) {
  tbb::parallel_for(0, g.height, [&](int y) {
    for (int c = 0; c < img.channels(); ++c) {
      for (int x = 0; x < g.width; ++x) img.at(x, y, c) = p.at(x, y, c0 + c);
    }
  });
}

}  // namespace

NforDenoiser::NforDenoiser(NforParams params) : params_(std::move(params)) {
  const auto& p = params_;
  if (p.prefilter_radius < 0 || p.prefilter_patch < 0 || p.window_radius < 0 ||
      p.patch_radius < 0 || p.selection_radius < 0 || p.selection_patch < 0 ||
      !(p.prefilter_k > 0.0f) || !(p.bandwidths[0] > 0.0f) || !(p.bandwidths[1] > 0.0f) ||
      !(p.selection_k > 0.0f) || !(p.second_pass_k > 0.0f)) {
    throw std::invalid_argument("NforDenoiser: radii must be >= 0 and bandwidths > 0");
  }
  if (std::max({p.prefilter_patch, p.patch_radius, p.selection_patch}) > nfor::kMaxPatch) {
    throw std::invalid_argument("NforDenoiser: patch radii must be <= " +
                                std::to_string(nfor::kMaxPatch));
  }
  nfor::kernels(p.isa);  // throws for a kernel build this CPU cannot run
}

int NforDenoiser::radius() const {
  const auto& p = params_;
  return p.prefilter_radius + p.prefilter_patch + 2 * (p.window_radius + p.patch_radius) +
         p.selection_radius + p.selection_patch;
}

Image NforDenoiser::run(const DenoiseInputs& in, NforExtras* extras) const {
  const int W = in.width, H = in.height;
  const auto& p = params_;
  NforExtras::Timings sec;
  const auto t_start = Clock::now();
  auto t = t_start;
  const int border =
      std::max({p.window_radius + p.patch_radius, p.prefilter_radius + p.prefilter_patch,
                p.selection_radius + p.selection_patch});
  const Geometry g(W, H, border + nfor::kVectorMargin);
  const nfor::Kernels& kern = nfor::kernels(p.isa);
  Planes x = nfor::load(g, in.colour, kMaxValue);
  Planes var = nfor::load(g, in.variance, kMaxVariance);
  const bool halves = in.half_colour[0].valid() && in.half_colour[1].valid() &&
                      in.half_variance[0].valid() && in.half_variance[1].valid();
  const bool want_cv = extras && extras->want_cross_validation && halves;
  const bool want_hat = extras && extras->want_hat;

  // Features (§5.1): prefiltered from the halves where every present feature has them, else as
  // they are.
  const bool use = p.use_features;
  const View alb = use ? in.albedo : View{}, nrm = use ? in.normal : View{};
  const View dep = use ? in.depth : View{};
  const float scale = dep.valid() ? depth_scale(dep, W, H) : 1.0f;
  const std::array<bool, 3> present = {alb.valid(), nrm.valid(), dep.valid()};
  sec.load = since(t);
  const bool feature_halves =
      halves && (alb.valid() || nrm.valid() || dep.valid()) &&
      (!alb.valid() || (in.half_albedo[0].valid() && in.half_albedo[1].valid())) &&
      (!nrm.valid() || (in.half_normal[0].valid() && in.half_normal[1].valid())) &&
      (!dep.valid() || (in.half_depth[0].valid() && in.half_depth[1].valid()));
  Planes features;
  if (feature_halves) {
    auto half = [&](std::size_t h) {
      return feature_planes(g, alb.valid() ? in.half_albedo[h] : View{},
                            nrm.valid() ? in.half_normal[h] : View{},
                            dep.valid() ? in.half_depth[h] : View{}, scale);
    };
    nfor::PrefilterSpec ps{p.prefilter_radius, p.prefilter_patch, p.prefilter_k, &kern};
    features = nfor::prefilter_features(g, half(0), half(1), present, ps);
  } else {
    features = feature_planes(g, alb, nrm, dep, scale);
  }
  sec.prefilter = since(t);

  nfor::RegressionSpec rs;
  for (int j = 0; j < nfor::kFeatures; ++j) rs.features[j] = features.origin(j);
  Planes hat = want_hat ? Planes(g, 1) : Planes();
  Image y(W, H, 3);

  if (!halves) {
    // Single-buffer mode: x regressed with weights on x itself (no cross-validation possible).
    rs.weights = weights_on(kern, x, var, p.window_radius, p.patch_radius, kSingleBufferK);
    for (int c = 0; c < 3; ++c) rs.data[c] = x.origin(c);
    rs.data_channels = 3;
    Planes out(g, 3);
    nfor::regression(g, rs, {0}, {&out}, {want_hat ? &hat : nullptr});
    copy_out(g, out, 0, y);
    sec.second_pass = since(t);
  } else {
    Planes xa = nfor::load(g, in.half_colour[0], kMaxValue);
    Planes xb = nfor::load(g, in.half_colour[1], kMaxValue);
    Planes va = nfor::load(g, in.half_variance[0], kMaxVariance);
    Planes vb = nfor::load(g, in.half_variance[1], kMaxVariance);
    // §4, §5.2: each half regressed with NL-means weights on the other half, per bandwidth.
    // Bandwidths whose weights are a power of the widest one's share its weight computation.
    std::vector<Planes> fa, fb, hat_a, hat_b;
    const std::size_t nk = p.bandwidths.size();
    for (std::size_t i = 0; i < nk; ++i) {
      fa.emplace_back(g, 3);
      fb.emplace_back(g, 3);
      hat_a.push_back(want_hat ? Planes(g, 1) : Planes());
      hat_b.push_back(want_hat ? Planes(g, 1) : Planes());
    }
    const float widest = *std::max_element(p.bandwidths.begin(), p.bandwidths.end());
    std::vector<bool> done(nk, false);
    for (std::size_t i = 0; i < nk; ++i) {
      if (done[i]) continue;
      const float base =
          nfor::squarings_between(widest, p.bandwidths[i]) >= 0 ? widest : p.bandwidths[i];
      std::vector<int> squarings;
      std::vector<Planes*> out_a, out_b, h_a, h_b;
      for (std::size_t j = i; j < nk; ++j) {
        const int s = nfor::squarings_between(base, p.bandwidths[j]);
        if (done[j] || s < 0) continue;
        done[j] = true;
        squarings.push_back(s);
        out_a.push_back(&fa[j]);
        out_b.push_back(&fb[j]);
        h_a.push_back(want_hat ? &hat_a[j] : nullptr);
        h_b.push_back(want_hat ? &hat_b[j] : nullptr);
      }
      rs.data_channels = 3;
      rs.weights = weights_on(kern, xb, vb, p.window_radius, p.patch_radius, base);
      for (int c = 0; c < 3; ++c) rs.data[c] = xa.origin(c);
      nfor::regression(g, rs, squarings, out_a, h_a);
      rs.weights = weights_on(kern, xa, va, p.window_radius, p.patch_radius, base);
      for (int c = 0; c < 3; ++c) rs.data[c] = xb.origin(c);
      nfor::regression(g, rs, squarings, out_b, h_b);
    }
    sec.first_pass = since(t);
    // §5.3: per-pixel selection, smoothed with NL-means weights on the colour.
    Planes sel_a(g, 3), sel_b(g, 3), shares(g, static_cast<int>(nk));
    nfor::select_bandwidths(
        g, fa, fb, xa, xb, va, vb,
        weights_on(kern, x, var, p.selection_radius, p.selection_patch, p.selection_k), sel_a,
        sel_b, shares);
    if (extras && extras->want_stages) {
      auto mean_of = [&](const Planes& a, const Planes& b) {
        Image img(W, H, 3);
        for (int c = 0; c < 3; ++c) {
          for (int yy = 0; yy < H; ++yy) {
            for (int xx = 0; xx < W; ++xx) {
              img.at(xx, yy, c) = 0.5f * (a.at(xx, yy, c) + b.at(xx, yy, c));
            }
          }
        }
        return img;
      };
      for (std::size_t i = 0; i < nk; ++i) {
        extras->stages.emplace_back("pass1 k=" + std::to_string(p.bandwidths[i]),
                                    mean_of(fa[i], fb[i]));
      }
      extras->stages.emplace_back("selected", mean_of(sel_a, sel_b));
    }
    fa.clear();
    fb.clear();
    sec.selection = since(t);
    // §5.4: the selected result filtered once more, the regression weighted on the combined
    // colour x with its variance from the halves, (x_A - x_B)^2 / 4 (docs/nfor.md).
    // The halves combine like x = a x_A + b x_B (a = Var[x] / Var[x_A] = Var[x_B] / (Var[x_A] +
    // Var[x_B]), 1/2 for equal halves). From the halves alone: the pipeline may hand the weights
    // a Var[x] raised to the pooled variance (few passes, docs/pipeline.md).
    Planes sel(g, 3), xvar(g, 3), share_a(g, 1);
    each_index(g, [&](std::size_t i) {
      int c = 0;  // the channel with the largest Var[x_A] (Var = 0 says nothing)
      for (int cc = 1; cc < 3; ++cc) c = va.plane(cc)[i] > va.plane(c)[i] ? cc : c;
      const float v_a = va.plane(c)[i], v_b = vb.plane(c)[i];
      const float a = v_a > 0.0f ? std::clamp(v_b / (v_a + v_b), 0.0f, 1.0f) : 0.5f;
      share_a.plane(0)[i] = a;
      for (int cc = 0; cc < 3; ++cc) {
        sel.plane(cc)[i] = a * sel_a.plane(cc)[i] + (1.0f - a) * sel_b.plane(cc)[i];
        const float d = xa.plane(cc)[i] - xb.plane(cc)[i];
        xvar.plane(cc)[i] = std::min(0.25f * d * d, kMaxVariance);
      }
      if (want_hat) {
        // dy/dx (weights and selection fixed): cov(y, x) = Var[x] (dy/dx_A + dy/dx_B) since
        // Cov(x_A, x) = a Var[x_A] = Var[x]; the first pass gives dsel/dx_A = a sum_k s_k h_A,k.
        float h = 0.0f;
        for (std::size_t k = 0; k < nk; ++k) {
          h += shares.plane(static_cast<int>(k))[i] *
               (a * hat_a[k].plane(0)[i] + (1.0f - a) * hat_b[k].plane(0)[i]);
        }
        hat.plane(0)[i] = h;
      }
    });
    hat_a.clear();
    hat_b.clear();
    Planes out(g, want_cv ? 9 : 3);
    if (p.second_pass) {
      rs.weights = weights_on(kern, x, xvar, p.window_radius, p.patch_radius, p.second_pass_k);
      for (int c = 0; c < 3; ++c) {
        rs.data[c] = sel.origin(c);
        rs.data[3 + c] = sel_a.origin(c);
        rs.data[6 + c] = sel_b.origin(c);
      }
      rs.data_channels = out.channels();
      Planes hat2 = want_hat ? Planes(g, 1) : Planes();
      nfor::regression(g, rs, {0}, {&out}, {want_hat ? &hat2 : nullptr});
      // The composition's diagonal approximated by the product of the diagonals (a lower bound
      // for smoothing filters: docs/nfor.md measures it).
      if (want_hat) each_index(g, [&](std::size_t i) { hat.plane(0)[i] *= hat2.plane(0)[i]; });
    } else {
      for (int c = 0; c < 3; ++c) {
        std::copy(sel.plane(c), sel.plane(c) + g.plane_size(), out.plane(c));
        if (want_cv) {
          std::copy(sel_a.plane(c), sel_a.plane(c) + g.plane_size(), out.plane(3 + c));
          std::copy(sel_b.plane(c), sel_b.plane(c) + g.plane_size(), out.plane(6 + c));
        }
      }
    }
    copy_out(g, out, 0, y);
    if (want_cv) {
      // MSE(F(x)) for F linear in its data (weights fixed) and x = a x_A + b x_B:
      // a MSE(F_A) + b MSE(F_B) - a b E[(F_A - F_B)^2], MSE(F_A) ~ (F_A - x_B)^2 - Var[x_B].
      Image& e = extras->cross_validation;
      e = Image(W, H, 3);
      tbb::parallel_for(0, H, [&](int yy) {
        for (int c = 0; c < 3; ++c) {
          for (int xx = 0; xx < W; ++xx) {
            const double fa_ = out.at(xx, yy, 3 + c), fb_ = out.at(xx, yy, 6 + c);
            const double ya = xa.at(xx, yy, c), yb = xb.at(xx, yy, c);
            const double v_a = va.at(xx, yy, c), v_b = vb.at(xx, yy, c);
            const double a = share_a.at(xx, yy, 0), b = 1.0 - a;
            const double est = a * ((fa_ - yb) * (fa_ - yb) - v_b) +
                               b * ((fb_ - ya) * (fb_ - ya) - v_a) -
                               a * b * (fa_ - fb_) * (fa_ - fb_);
            e.at(xx, yy, c) = static_cast<float>(std::clamp(est, -1e36, 1e36));
          }
        }
      });
    }
    sec.second_pass = since(t);
  }
  // A regression extrapolates: near fireflies and sharp caustics it can predict negative colour.
  // When the render has none, neither may y (docs/nfor.md: glass at 32 spp, relMSE -6 %).
  bool nonnegative = true;
  for (int c = 0; c < 3 && nonnegative; ++c) {
    const auto plane = in.colour.data + static_cast<std::size_t>(c) * in.colour.rect.area();
    nonnegative = std::all_of(plane, plane + in.colour.rect.area(), [](float v) { return v >= 0; });
  }
  if (nonnegative) {
    for (float& v : y.data()) v = std::max(v, 0.0f);
  }
  if (extras) {
    sec.total = std::chrono::duration<double>(Clock::now() - t_start).count();
    extras->seconds = sec;
    extras->mode = halves ? "nfor" : "single-buffer";
    extras->prefiltered_features = feature_halves;
    if (want_hat) {  // the same for every channel (the weights and design are shared)
      Image one(W, H, 1);
      copy_out(g, hat, 0, one);
      extras->hat = Image(W, H, 3);
      for (int c = 0; c < 3; ++c) {
        std::copy(one.plane(0).begin(), one.plane(0).end(), extras->hat.plane(c).begin());
      }
    }
  }
  return y;
}

void NforDenoiser::denoise(const DenoiseInputs& in, const Rect& out, Buffer& y,
                           Buffer* dydx) const {
  if (out.empty()) return;
  NforExtras extras;
  extras.want_hat = dydx != nullptr;
  const Image full = run(in, &extras);
  for (int c = 0; c < 3; ++c) {
    for (int py = out.y0; py < out.y1; ++py) {
      for (int px = out.x0; px < out.x1; ++px) {
        y.at(px, py, c) = full.at(px, py, c);
        if (dydx) dydx->at(px, py, c) = extras.hat.at(px, py, c);
      }
    }
  }
}

}  // namespace proden

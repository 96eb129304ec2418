// NL-means (denoise/nlmeans.*): every kernel build (AVX-512, AVX2, portable) against a plain
// double-precision reference written here from the formula, pixel by pixel and offset by offset
// (Rousselle et al. 2012's variance-normalised patch distance, the feature weights and the exact
// Jacobian diagonal of docs/pipeline.md), with and without features, border pixels included;
// and tiles against the whole image bit for bit.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "proden/denoise/nlmeans.hpp"
#include "proden/image.hpp"

using namespace proden;

namespace {

// The pinned tolerances: the float kernels (the old single-pass one too) against the double
// reference, as |got - want| <= tol * (1 + |want|).
constexpr double kTolY = 5e-6;
constexpr double kTolDydx = 5e-6;

struct Scene {
  int w = 0, h = 0;
  Image x, var, alb, alb_v, nrm, nrm_v, dep;
  bool features = false;
};

Scene scene(int w, int h, bool features, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Scene s;
  s.w = w;
  s.h = h;
  s.features = features;
  s.x = Image(w, h, 3);
  s.var = Image(w, h, 3);
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        // A step edge and a ramp under noise, so weights span the whole range.
        const float base = (x > w / 2 ? 0.7f : 0.2f) + 0.01f * static_cast<float>(y);
        s.x.at(x, y, c) = base + 0.15f * (u(rng) - 0.5f);
        s.var.at(x, y, c) = 0.0005f + 0.004f * u(rng);
      }
    }
  }
  if (!features) return s;
  s.alb = Image(w, h, 3);
  s.alb_v = Image(w, h, 3);
  s.nrm = Image(w, h, 3);
  s.nrm_v = Image(w, h, 3);
  s.dep = Image(w, h, 1);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < 3; ++c) {
        s.alb.at(x, y, c) = (y > h / 3 ? 0.6f : 0.3f) + 0.05f * u(rng);
        s.alb_v.at(x, y, c) = 0.001f * u(rng);
        s.nrm.at(x, y, c) = (x + y > w / 2 ? 0.8f : -0.4f) + 0.1f * u(rng);
        s.nrm_v.at(x, y, c) = 0.002f * u(rng);
      }
      s.dep.at(x, y, 0) = 2.0f + 0.5f * static_cast<float>(x % 9 > 4) + 0.05f * u(rng);
    }
  }
  return s;
}

DenoiseInputs inputs(const Scene& s) {
  DenoiseInputs in;
  in.width = s.w;
  in.height = s.h;
  in.colour = view_of(s.x);
  in.variance = view_of(s.var);
  if (s.features) {
    in.albedo = view_of(s.alb);
    in.albedo_variance = view_of(s.alb_v);
    in.normal = view_of(s.nrm);
    in.normal_variance = view_of(s.nrm_v);
    in.depth = view_of(s.dep);
  }
  return in;
}

// y and dy/dx of the whole image, straight from the formula in double precision. Pixels outside
// the image read the nearest border pixel (replicate). The weight derivative follows x_p through
// the two patch pairs it belongs to as itself, (p, q) and (p - delta, p) when -delta lies in the
// patch; the replicated border copies of x_p are not followed (the documented approximation).
struct Reference {
  std::vector<double> y, dydx;  // planar, 3 x w x h
};

Reference reference(const Scene& s, const NlMeansParams& p) {
  const int w = s.w, h = s.h, R = p.search_radius, F = p.patch_radius;
  auto cx = [&](int x) { return std::clamp(x, 0, w - 1); };
  auto cy = [&](int y) { return std::clamp(y, 0, h - 1); };
  auto X = [&](int x, int y, int c) -> double { return s.x.at(cx(x), cy(y), c); };
  auto V = [&](int x, int y, int c) -> double { return s.var.at(cx(x), cy(y), c); };
  const double k2 = static_cast<double>(p.k) * p.k, alpha = p.alpha, eps = p.epsilon;
  const double kf2 = static_cast<double>(p.k_feature) * p.k_feature, tau = p.tau;
  const double n_patch = 3.0 * (2 * F + 1) * (2 * F + 1);
  // Inverse denominator of the colour term of the pair (a, b).
  auto inv_s = [&](int ax, int ay, int bx, int by, int c) {
    return 1.0 / (eps + k2 * (V(ax, ay, c) + V(bx, by, c)));
  };
  auto feature3 = [&](const Image& f, const Image& fv, int px, int py, int qx, int qy) {
    double dd = 0, vs = 0;
    for (int c = 0; c < 3; ++c) {
      const double d = static_cast<double>(f.at(cx(px), cy(py), c)) - f.at(cx(qx), cy(qy), c);
      const double a = fv.at(cx(px), cy(py), c), b = fv.at(cx(qx), cy(qy), c);
      dd += d * d - (a + std::min(a, b));
      vs += a + b;
    }
    return dd / std::max(vs, tau) / kf2;
  };
  Reference out;
  out.y.assign(3 * static_cast<std::size_t>(w) * h, 0.0);
  out.dydx = out.y;
  struct Term {
    double w, dw[3];
    int qx, qy;
  };
  std::vector<Term> terms;
  for (int py = 0; py < h; ++py) {
    for (int px = 0; px < w; ++px) {
      terms.clear();
      for (int dy = -R; dy <= R; ++dy) {
        for (int dx = -R; dx <= R; ++dx) {
          const int qx = px + dx, qy = py + dy;
          double dist = 0;
          for (int ny = -F; ny <= F; ++ny) {
            for (int nx = -F; nx <= F; ++nx) {
              for (int c = 0; c < 3; ++c) {
                const int ax = px + nx, ay = py + ny, bx = qx + nx, by = qy + ny;
                const double d = X(ax, ay, c) - X(bx, by, c);
                const double va = V(ax, ay, c), vb = V(bx, by, c);
                dist += (d * d - alpha * (va + std::min(va, vb))) * inv_s(ax, ay, bx, by, c);
              }
            }
          }
          dist /= n_patch;
          double fd = 0;
          if (s.features && p.use_features) {
            fd = std::max(fd, feature3(s.alb, s.alb_v, px, py, qx, qy));
            fd = std::max(fd, feature3(s.nrm, s.nrm_v, px, py, qx, qy));
            const double z0 = s.dep.at(cx(px), cy(py), 0), z1 = s.dep.at(cx(qx), cy(qy), 0);
            const double scale = p.depth_scale * (std::abs(z0) + std::abs(z1)) / 2 + 1e-6;
            const double rel = (z0 - z1) / scale;
            fd = std::max(fd, rel * rel / kf2);
          }
          Term t{std::exp(-(std::max(dist, 0.0) + fd)), {0, 0, 0}, qx, qy};
          if (dist > 0) {  // d dist / d x_p, times dw/d dist = -w
            const bool second = std::abs(dx) <= F && std::abs(dy) <= F;
            for (int c = 0; c < 3; ++c) {
              double g = 2 * (X(px, py, c) - X(qx, qy, c)) * inv_s(px, py, qx, qy, c);
              if (second) {
                g += 2 * (X(px, py, c) - X(px - dx, py - dy, c)) *
                     inv_s(px - dx, py - dy, px, py, c);
              }
              t.dw[c] = -t.w * g / n_patch;
            }
          }
          terms.push_back(t);
        }
      }
      for (int c = 0; c < 3; ++c) {
        double W = 0, num = 0, self = 0;
        for (const Term& t : terms) {
          W += t.w;
          num += t.w * X(t.qx, t.qy, c);
          if (cx(t.qx) == px && cy(t.qy) == py) self += t.w;
        }
        const double y = num / W;
        // dy_p/dx_p = w_pp / W + sum_q (x_q - y_p) dw_pq/dx_p / W
        double dsum = 0;
        for (const Term& t : terms) dsum += (X(t.qx, t.qy, c) - y) * t.dw[c];
        const std::size_t i = (static_cast<std::size_t>(c) * h + py) * w + px;
        out.y[i] = y;
        out.dydx[i] = self / W + dsum / W;
      }
    }
  }
  return out;
}

struct Result {
  Buffer y, d;
};

Result run(const Scene& s, const NlMeansParams& p, const Rect& out) {
  Result r{Buffer(out, 3), Buffer(out, 3)};
  NlMeansDenoiser(p).denoise(inputs(s), out, r.y, &r.d);
  return r;
}

// Largest |got - want| / (1 + |want|) over the image, and where.
struct Worst {
  double err = 0;
  int x = -1, y = -1, c = -1;
};

Worst compare(const Buffer& got, const std::vector<double>& want, int w, int h) {
  Worst worst;
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const double ref = want[(static_cast<std::size_t>(c) * h + y) * w + x];
        const double e = std::abs(got.at(x, y, c) - ref) / (1.0 + std::abs(ref));
        if (!(e <= worst.err)) worst = {e, x, y, c};  // NaN counts as the worst
      }
    }
  }
  return worst;
}

bool bitwise_equal(const Buffer& a, const Buffer& b, int w, int h) {
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        const float u = a.at(x, y, c), v = b.at(x, y, c);
        if (std::memcmp(&u, &v, sizeof u) != 0) return false;
      }
    }
  }
  return true;
}

}  // namespace

TEST_CASE("NL-means: every kernel build matches the double-precision reference", "[nlmeans][isa]") {
  const std::vector<std::string> isas = nlmeans_isas_available();
  REQUIRE(isas.front() == "baseline");
  struct Radii {
    int r, f;
  };
  for (const bool features : {true, false}) {
    // Odd sizes: no row is a whole number of vectors; every pixel within r + f of a border.
    const Scene s = scene(37, 29, features, features ? 5u : 6u);
    const Rect all{0, 0, s.w, s.h};
    for (const Radii rf : {Radii{0, 1}, Radii{1, 0}, Radii{1, 1}, Radii{3, 2}, Radii{5, 3}}) {
      NlMeansParams p;
      p.search_radius = rf.r;
      p.patch_radius = rf.f;
      p.use_features = features;
      const Reference ref = reference(s, p);
      for (const std::string& isa : isas) {
        p.isa = isa;
        REQUIRE(NlMeansDenoiser(p).isa() == isa);
        const Result got = run(s, p, all);
        const Worst ey = compare(got.y, ref.y, s.w, s.h);
        const Worst ed = compare(got.d, ref.dydx, s.w, s.h);
        INFO("isa " << isa << " features " << features << " r " << rf.r << " f " << rf.f);
        INFO("y: worst " << ey.err << " at (" << ey.x << ", " << ey.y << ", " << ey.c << ")");
        INFO("dydx: worst " << ed.err << " at (" << ed.x << ", " << ed.y << ", " << ed.c << ")");
        CHECK(ey.err <= kTolY);
        CHECK(ed.err <= kTolDydx);
      }
    }
  }
}

TEST_CASE("NL-means: tiles equal the whole image bit for bit in every build", "[nlmeans][tiles]") {
  const Scene s = scene(50, 37, true, 9);
  NlMeansParams p;
  p.search_radius = 3;
  p.patch_radius = 2;
  const Rect all{0, 0, s.w, s.h};
  for (const std::string& isa : nlmeans_isas_available()) {
    p.isa = isa;
    const Result whole = run(s, p, all);
    for (const int tile : {1, 7, 16, 33}) {
      Result tiled{Buffer(all, 3), Buffer(all, 3)};
      const NlMeansDenoiser nl(p);
      for (int y0 = 0; y0 < s.h; y0 += tile) {
        for (int x0 = 0; x0 < s.w; x0 += tile) {
          const Rect t{x0, y0, std::min(x0 + tile, s.w), std::min(y0 + tile, s.h)};
          Buffer y(t, 3), d(t, 3);
          nl.denoise(inputs(s), t, y, &d);
          for (int c = 0; c < 3; ++c) {
            for (int yy = t.y0; yy < t.y1; ++yy) {
              for (int xx = t.x0; xx < t.x1; ++xx) {
                tiled.y.at(xx, yy, c) = y.at(xx, yy, c);
                tiled.d.at(xx, yy, c) = d.at(xx, yy, c);
              }
            }
          }
        }
      }
      INFO("isa " << isa << " tile " << tile);
      CHECK(bitwise_equal(tiled.y, whole.y, s.w, s.h));
      CHECK(bitwise_equal(tiled.d, whole.d, s.w, s.h));
    }
  }
}

TEST_CASE("NL-means: the Jacobian does not change y, and an unknown build is refused",
          "[nlmeans]") {
  const Scene s = scene(23, 19, true, 3);
  const Rect all{0, 0, s.w, s.h};
  for (const std::string& isa : nlmeans_isas_available()) {
    NlMeansParams p;
    p.isa = isa;
    const Result with = run(s, p, all);
    Buffer y(all, 3);
    NlMeansDenoiser(p).denoise(inputs(s), all, y, nullptr);
    INFO("isa " << isa);
    CHECK(bitwise_equal(y, with.y, s.w, s.h));
  }
  NlMeansParams bad;
  bad.isa = "sse9";
  CHECK_THROWS_AS(NlMeansDenoiser(bad), std::invalid_argument);
}

TEST_CASE("NL-means reads nothing beyond radius() of its output", "[nlmeans][tiles]") {
  // The Monte-Carlo probe and the pipeline hand views over just the region the denoiser reads;
  // the vector kernel's padding must not read past it (ASan checks the reads, this the values).
  const Scene s = scene(41, 30, true, 13);
  NlMeansParams p;
  p.search_radius = 3;
  p.patch_radius = 2;
  const Rect image{0, 0, s.w, s.h};
  for (const std::string& isa : nlmeans_isas_available()) {
    p.isa = isa;
    const NlMeansDenoiser nl(p);
    for (const Rect out : {Rect{5, 4, 23, 17}, Rect{30, 20, 41, 30}, Rect{0, 0, 3, 30}}) {
      const Rect reads = out.expanded(nl.radius()).intersect(image);
      auto crop = [&](const Image& img) {
        Buffer b(reads, img.channels());
        for (int c = 0; c < img.channels(); ++c) {
          for (int y = reads.y0; y < reads.y1; ++y) {
            for (int x = reads.x0; x < reads.x1; ++x) b.at(x, y, c) = img.at(x, y, c);
          }
        }
        return b;
      };
      const Buffer x = crop(s.x), var = crop(s.var), alb = crop(s.alb), alb_v = crop(s.alb_v),
                   nrm = crop(s.nrm), nrm_v = crop(s.nrm_v), dep = crop(s.dep);
      DenoiseInputs in = inputs(s);
      in.colour = x.view();
      in.variance = var.view();
      in.albedo = alb.view();
      in.albedo_variance = alb_v.view();
      in.normal = nrm.view();
      in.normal_variance = nrm_v.view();
      in.depth = dep.view();
      Buffer y(out, 3), d(out, 3);
      nl.denoise(in, out, y, &d);
      const Result want = run(s, p, out);
      INFO("isa " << isa << " output " << out.to_string());
      bool same = true;
      for (int c = 0; c < 3; ++c) {
        for (int yy = out.y0; yy < out.y1; ++yy) {
          for (int xx = out.x0; xx < out.x1; ++xx) {
            const float g[2] = {y.at(xx, yy, c), d.at(xx, yy, c)};
            const float w[2] = {want.y.at(xx, yy, c), want.d.at(xx, yy, c)};
            same = same && std::memcmp(g, w, sizeof g) == 0;
          }
        }
      }
      CHECK(same);
    }
  }
}

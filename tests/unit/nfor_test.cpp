// NFOR (docs/nfor.md): exact reconstruction of images linear in their features, every kernel
// build against the double-precision reference, rank-deficient windows, the single-buffer
// fallback, and whole-frame runs inside the tiled pipeline.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>

#include "../../pipeline/src/denoise/nfor_internal.hpp"
#include "proden/denoise/nfor.hpp"
#include "proden/progressive.hpp"

using namespace proden;

namespace {

// Deterministic uniform [0, 1) per (salt, x, y, c).
float hash01(std::uint32_t salt, int x, int y, int c) {
  std::uint32_t h = salt * 0x9E3779B9u ^ static_cast<std::uint32_t>(x) * 0x85EBCA6Bu ^
                    static_cast<std::uint32_t>(y) * 0xC2B2AE35u ^ static_cast<std::uint32_t>(c);
  h ^= h >> 16;
  h *= 0x7FEB352Du;
  h ^= h >> 15;
  h *= 0x846CA68Bu;
  h ^= h >> 16;
  return static_cast<float>(h >> 8) / 16777216.0f;
}

float gauss(std::uint32_t salt, int x, int y, int c) {
  const float u1 = std::max(hash01(salt, x, y, c), 1e-7f), u2 = hash01(salt + 77, x, y, c);
  return std::sqrt(-2.0f * std::log(u1)) * std::cos(6.2831853f * u2);
}

// A frame's images for NFOR, with both halves (or only A), features per half.
struct Frame {
  int w, h;
  Image colour, variance, albedo, normal, depth;
  std::array<Image, 2> half, half_var, half_albedo, half_normal, half_depth;
  bool halves = true;
  bool feature_halves = true;

  Frame(int w_, int h_) : w(w_), h(h_) {
    colour = Image(w, h, 3);
    variance = Image(w, h, 3);
    albedo = Image(w, h, 3);
    normal = Image(w, h, 3);
    depth = Image(w, h, 1);
    for (int i = 0; i < 2; ++i) {
      half[i] = Image(w, h, 3);
      half_var[i] = Image(w, h, 3);
      half_albedo[i] = Image(w, h, 3);
      half_normal[i] = Image(w, h, 3);
      half_depth[i] = Image(w, h, 1);
    }
  }
  // The full frame is the mean of equal halves.
  void combine() {
    for (std::size_t i = 0; i < colour.data().size(); ++i) {
      colour.data()[i] = 0.5f * (half[0].data()[i] + half[1].data()[i]);
      variance.data()[i] = 0.25f * (half_var[0].data()[i] + half_var[1].data()[i]);
    }
    auto mean = [](Image& full, const std::array<Image, 2>& hv) {
      for (std::size_t i = 0; i < full.data().size(); ++i)
        full.data()[i] = 0.5f * (hv[0].data()[i] + hv[1].data()[i]);
    };
    mean(albedo, half_albedo);
    mean(normal, half_normal);
    mean(depth, half_depth);
  }
  DenoiseInputs inputs() const {
    DenoiseInputs in;
    in.width = w;
    in.height = h;
    in.colour = view_of(colour);
    in.variance = view_of(variance);
    in.albedo = view_of(albedo);
    in.normal = view_of(normal);
    in.depth = view_of(depth);
    for (std::size_t i = 0; i < 2 && halves; ++i) {
      in.half_colour[i] = view_of(half[i]);
      in.half_variance[i] = view_of(half_var[i]);
      if (feature_halves) {
        in.half_albedo[i] = view_of(half_albedo[i]);
        in.half_normal[i] = view_of(half_normal[i]);
        in.half_depth[i] = view_of(half_depth[i]);
      }
    }
    return in;
  }
};

// Random features (never collinear), colour exactly linear in albedo and normal; halves that
// differ (each linear too, with other coefficients) so every pass has non-trivial weights; a
// variance that makes the NL-means weights broad, so each window's fit is well determined.
Frame linear_frame(int w, int h) {
  Frame f(w, h);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < 3; ++c) {
        const float a = 0.1f + 0.8f * hash01(1, x, y, c);
        const float n = 2.0f * hash01(2, x, y, c) - 1.0f;
        for (int i = 0; i < 2; ++i) {
          f.half_albedo[i].at(x, y, c) = a;
          f.half_normal[i].at(x, y, c) = n;
        }
      }
      for (int i = 0; i < 2; ++i) f.half_depth[i].at(x, y, 0) = 1.0f + 5.0f * hash01(3, x, y, 0);
      for (int i = 0; i < 2; ++i) {
        const float s = i == 0 ? 1.0f : 1.25f;
        for (int c = 0; c < 3; ++c) {
          float col = 0.3f + 0.1f * static_cast<float>(c + i);
          for (int j = 0; j < 3; ++j) {
            col += s * (0.2f + 0.1f * static_cast<float>(j + c)) * f.half_albedo[0].at(x, y, j) -
                   s * (0.15f - 0.05f * static_cast<float>(j)) * f.half_normal[0].at(x, y, j);
          }
          f.half[i].at(x, y, c) = col;
          f.half_var[i].at(x, y, c) = 0.5f;
        }
      }
    }
  }
  f.combine();
  return f;
}

// A noisy scene: two regions with edges, a texture in albedo, normals bending; halves with
// independent noise of standard deviation sigma.
Frame noisy_frame(int w, int h, float sigma, std::uint32_t seed = 11) {
  Frame f(w, h);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      const bool right = x > w / 2;
      const float tex = 0.5f + 0.4f * static_cast<float>(((x / 3) + (y / 3)) % 2);
      for (int i = 0; i < 2; ++i) {
        for (int c = 0; c < 3; ++c) {
          f.half_albedo[i].at(x, y, c) = right ? tex : 0.3f + 0.1f * static_cast<float>(c);
          f.half_normal[i].at(x, y, c) =
              c == 2 ? 0.8f : 0.4f * std::sin(0.1f * static_cast<float>(x + c * y));
        }
        f.half_depth[i].at(x, y, 0) = right ? 2.0f : 5.0f + 0.01f * static_cast<float>(y);
      }
      for (int c = 0; c < 3; ++c) {
        const float truth = f.half_albedo[0].at(x, y, c) * (0.6f + 0.4f * f.half_normal[0].at(x, y, 0));
        for (int i = 0; i < 2; ++i) {
          f.half[i].at(x, y, c) =
              truth + sigma * gauss(seed + static_cast<std::uint32_t>(i), x, y, c);
          f.half_var[i].at(x, y, c) = sigma * sigma;
        }
      }
    }
  }
  f.combine();
  return f;
}

double max_abs_diff(const Image& a, const Image& b) {
  double m = 0;
  for (std::size_t i = 0; i < a.data().size(); ++i)
    m = std::max(m, std::abs(static_cast<double>(a.data()[i]) - b.data()[i]));
  return m;
}

void require_finite(const Image& img) {
  for (std::size_t i = 0; i < img.data().size(); ++i) {
    INFO("value " << i << " of " << img.to_string());
    REQUIRE(std::isfinite(img.data()[i]));
  }
}

NforParams with_isa(const std::string& isa) {
  NforParams p;
  p.isa = isa;
  return p;
}

}  // namespace

TEST_CASE("NFOR reconstructs an image exactly linear in its features", "[nfor]") {
  const Frame f = linear_frame(40, 36);
  for (const std::string& isa : nfor::isas_available()) {
    INFO("kernel build " << isa);
    NforExtras extras;
    const Image y = NforDenoiser(with_isa(isa)).run(f.inputs(), &extras);
    CHECK(extras.mode == "nfor");
    CHECK(extras.prefiltered_features);
    CHECK(max_abs_diff(y, f.colour) < 1e-5);
  }
  // Without halves (single-buffer mode) too.
  Frame one = f;
  one.halves = false;
  NforExtras extras;
  const Image y = NforDenoiser().run(one.inputs(), &extras);
  CHECK(extras.mode == "single-buffer");
  CHECK(max_abs_diff(y, f.colour) < 1e-5);
}

TEST_CASE("a zeroth-order filter does not reconstruct it (the test can fail)", "[nfor]") {
  // The same frame without features: the regression degenerates to collaborative NL-means,
  // which must blur the random, feature-driven colour (so the weights are far from identity).
  Frame f = linear_frame(40, 36);
  NforParams p;
  p.use_features = false;
  const Image y = NforDenoiser(p).run(f.inputs());
  CHECK(max_abs_diff(y, f.colour) > 1e-2);
}

TEST_CASE("every kernel build's normal equations match the double reference", "[nfor][simd]") {
  // One chunk at the centre of a 48x48 frame with random weights, features and 9 data channels.
  const int W = 48, H = 48, r = 9;
  const nfor::Geometry g(W, H, 16);
  nfor::Planes feats(g, nfor::kFeatures), data(g, nfor::kMaxData);
  for (int y = -g.border; y < g.rows - g.border; ++y) {
    for (int x = -g.border; x < g.stride - g.border; ++x) {
      for (int j = 0; j < nfor::kFeatures; ++j) feats.at(x, y, j) = hash01(10 + j, x, y, 0);
      for (int c = 0; c < nfor::kMaxData; ++c) data.at(x, y, c) = 2.0f * hash01(30 + c, x, y, 0);
    }
  }
  std::vector<std::ptrdiff_t> doff;
  for (int dy = -r; dy <= r; ++dy) {
    for (int dx = -r; dx <= r; ++dx) doff.push_back(g.offset(dx, dy));
  }
  const int n_off = static_cast<int>(doff.size());
  std::vector<float> w(static_cast<std::size_t>(n_off) * 16);
  for (int o = 0; o < n_off; ++o) {
    for (int l = 0; l < 16; ++l) w[static_cast<std::size_t>(o * 16 + l)] = hash01(50, o, l, 0);
  }
  for (int m : {3, 9}) {
    nfor::ChunkArgs a;
    a.w = w.data();
    a.w_stride = 16;
    a.doff = doff.data();
    a.offsets = n_off;
    a.data_channels = m;
    const std::ptrdiff_t p = g.offset(16, 20);
    for (int j = 0; j < nfor::kFeatures; ++j) a.features[j] = feats.origin(j) + p;
    for (int c = 0; c < m; ++c) a.data[c] = data.origin(c) + p;
    const int entries = nfor::kPacked + nfor::kColumns * m;
    for (const std::string& isa : nfor::isas_available()) {
      const nfor::Kernels& kern = nfor::kernels(isa);
      const int L = kern.lanes;
      std::vector<float> got(static_cast<std::size_t>(entries * L));
      std::vector<double> want(static_cast<std::size_t>(entries * L));
      kern.normal_equations(a, got.data());
      nfor::normal_equations_reference(a, L, want.data());
      double worst = 0;
      for (std::size_t i = 0; i < got.size(); ++i) {
        worst = std::max(worst, std::abs(got[i] - want[i]) / (1.0 + std::abs(want[i])));
      }
      INFO("build " << isa << ", " << m << " data channels: worst relative error " << worst);
      // float sums of 361 terms of O(1): a few 1e-6.
      CHECK(worst < 1e-5);
      CHECK(worst > 0.0);  // it really ran in float
    }
  }
}

TEST_CASE("every kernel build gives the same NFOR output within 1e-4", "[nfor][simd]") {
  const Frame f = noisy_frame(48, 40, 0.1f);
  const Image ref = NforDenoiser(with_isa("baseline")).run(f.inputs());
  require_finite(ref);
  for (const std::string& isa : nfor::isas_available()) {
    const Image y = NforDenoiser(with_isa(isa)).run(f.inputs());
    INFO("build " << isa << " vs baseline: max difference " << max_abs_diff(y, ref));
    CHECK(max_abs_diff(y, ref) < 1e-4);
  }
}

TEST_CASE("NFOR denoises a noisy frame", "[nfor]") {
  const Frame clean = noisy_frame(64, 48, 0.0f);
  const Frame f = noisy_frame(64, 48, 0.15f);
  const DenoiseInputs in = f.inputs();
  const Image y = NforDenoiser().run(in);
  const Rect all{0, 0, 64, 48};
  Buffer nl(all, 3);
  NlMeansDenoiser().denoise(in, all, nl, nullptr);
  double ex = 0, ey = 0, en = 0;
  for (int c = 0; c < 3; ++c) {
    for (int py = 0; py < 48; ++py) {
      for (int px = 0; px < 64; ++px) {
        const double t = clean.colour.at(px, py, c);
        ex += std::pow(f.colour.at(px, py, c) - t, 2);
        ey += std::pow(y.at(px, py, c) - t, 2);
        en += std::pow(nl.at(px, py, c) - t, 2);
      }
    }
  }
  INFO("SSE render " << ex << ", NL-means " << en << ", NFOR " << ey);
  CHECK(ey < 0.5 * ex);
  CHECK(ey < en);
}

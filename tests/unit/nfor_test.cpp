// NFOR (docs/nfor.md): exact reconstruction of images linear in their features, every kernel
// build against the double-precision reference, rank-deficient windows, the single-buffer
// fallback, and whole-frame runs inside the tiled pipeline.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>

#include "../../pipeline/src/denoise/nfor_internal.hpp"
#include "proden/accumulator.hpp"
#include "proden/denoise/nfor.hpp"
#include "proden/metrics.hpp"
#include "proden/progressive.hpp"
#include "test_support.hpp"

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
        const float truth =
            f.half_albedo[0].at(x, y, c) * (0.6f + 0.4f * f.half_normal[0].at(x, y, 0));
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

namespace {

// The frame's features replaced: fn(x, y, albedo[3], normal[3], depth) for both halves.
template <class Fn>
void set_features(Frame& f, Fn fn) {
  for (int y = 0; y < f.h; ++y) {
    for (int x = 0; x < f.w; ++x) {
      float a[3], n[3], d;
      fn(x, y, a, n, d);
      for (int i = 0; i < 2; ++i) {
        for (int c = 0; c < 3; ++c) {
          f.half_albedo[i].at(x, y, c) = a[c];
          f.half_normal[i].at(x, y, c) = n[c];
        }
        f.half_depth[i].at(x, y, 0) = d;
      }
    }
  }
  f.combine();
}

}  // namespace

TEST_CASE("rank-deficient windows: constant, collinear and degenerate features", "[nfor]") {
  const Frame clean = noisy_frame(48, 40, 0.0f);
  struct Case {
    const char* name;
    void (*features)(int, int, float*, float*, float&);
  };
  const Case cases[] = {
      {"constant features",
       [](int, int, float* a, float* n, float& d) {
         a[0] = a[1] = a[2] = 0.5f;
         n[0] = n[1] = 0.0f;
         n[2] = 1.0f;
         d = 3.0f;
       }},
      {"all-zero normals and albedo, depth 0",
       [](int, int, float* a, float* n, float& d) {
         for (int c = 0; c < 3; ++c) a[c] = n[c] = 0.0f;
         d = 0.0f;
       }},
      {"collinear: normal = albedo = depth, one ramp",
       [](int x, int, float* a, float* n, float& d) {
         const float v = 0.02f * static_cast<float>(x);
         for (int c = 0; c < 3; ++c) a[c] = n[c] = v;
         d = v;
       }},
      {"sanitised infinities: normals +-1e10, background depth 1e10",
       [](int x, int y, float* a, float* n, float& d) {
         const bool bg = (x + y) % 7 == 0;
         for (int c = 0; c < 3; ++c) {
           a[c] = bg ? 0.0f : 0.4f;
           n[c] = bg ? (c == 0 ? 1e10f : -1e10f) : 0.5f;
         }
         d = bg ? 1e10f : 2.0f;
       }},
  };
  for (const Case& c : cases) {
    INFO(c.name);
    Frame f = noisy_frame(48, 40, 0.1f);
    set_features(f, c.features);
    // Every build on the degenerate ramp (the solve's masks differ per build), one elsewhere.
    const bool all = std::string(c.name).rfind("collinear", 0) == 0;
    for (const std::string& isa : all ? nfor::isas_available() : std::vector<std::string>{""}) {
      INFO("build " << isa);
      NforExtras ex;
      ex.want_cross_validation = ex.want_hat = true;
      const Image y = NforDenoiser(with_isa(isa)).run(f.inputs(), &ex);
      require_finite(y);
      require_finite(ex.cross_validation);
      require_finite(ex.hat);
      // Still a denoiser: the zeroth- (or lower-) order fit that remains averages noise away.
      CHECK(compute_metrics(y, clean.colour).mse <
            0.6 * compute_metrics(f.colour, clean.colour).mse);
    }
  }
}

TEST_CASE("a black, noise-free background stays black", "[nfor]") {
  // Left 80 columns: colour exactly 0 in every half (variance 0), Cycles-like background
  // features (albedo 0, normal 0, depth 1e10); right: a noisy lit surface.
  constexpr int kBlack = 80;
  Frame f = noisy_frame(kBlack + 32, 32, 0.1f);
  for (int y = 0; y < f.h; ++y) {
    for (int x = 0; x < kBlack; ++x) {
      for (int i = 0; i < 2; ++i) {
        for (int c = 0; c < 3; ++c) {
          f.half[i].at(x, y, c) = 0.0f;
          f.half_var[i].at(x, y, c) = 0.0f;
          f.half_albedo[i].at(x, y, c) = 0.0f;
          f.half_normal[i].at(x, y, c) = 0.0f;
        }
        f.half_depth[i].at(x, y, 0) = 1e10f;
      }
    }
  }
  f.combine();
  const Image y = NforDenoiser().run(f.inputs());
  require_finite(y);
  // Lit data reaches a pixel through a chain of windows: the first pass's fit (patch 3 +
  // window 9) and scatter (9), the selection's smoothing (1 + 3), the second pass's fit and
  // scatter (9 + 9): beyond 45 columns from the lit part the output is exactly 0.
  double near_max = 0;
  for (int py = 0; py < f.h; ++py) {
    for (int px = 0; px < kBlack; ++px) {
      for (int c = 0; c < 3; ++c) {
        if (px < kBlack - 45) {
          REQUIRE(y.at(px, py, c) == 0.0f);
        } else {
          near_max = std::max<double>(near_max, std::abs(y.at(px, py, c)));
        }
      }
    }
  }
  // Near the lit part, a black pixel receives predictions of fits that cover lit pixels: they
  // are weighted by how alike the patches are, so they stay small.
  INFO("largest value in the black part near the lit one: " << near_max);
  CHECK(near_max < 0.3);
}

TEST_CASE("1e6 fireflies stay local and finite", "[nfor]") {
  Frame f = noisy_frame(128, 48, 0.05f);
  for (auto& h : f.half) {
    for (float& v : h.data()) v = std::max(v, 0.0f);  // a render: no negative colour
  }
  // Two fireflies in half A only (one pass saw them), one in both; all within x < 32.
  f.half[0].at(10, 10, 0) = 1e6f;
  f.half[0].at(15, 40, 1) = 1e6f;
  for (int i = 0; i < 2; ++i) f.half[i].at(30, 20, 2) = 1e6f;
  f.combine();
  const Frame clean = noisy_frame(128, 48, 0.0f);
  for (bool second : {true, false}) {
    NforParams p;
    p.second_pass = second;
    NforExtras ex;
    ex.want_cross_validation = true;
    ex.want_hat = second;
    const Image y = NforDenoiser(p).run(f.inputs(), &ex);
    require_finite(y);
    require_finite(ex.cross_validation);
    if (second) require_finite(ex.hat);
    // Beyond the chain of windows (~45 px, see the black-background case) the fireflies leave
    // no trace; near them values stay within the fireflies' own scale.
    double far_err = 0, lo = 0, hi = 0;
    for (int c = 0; c < 3; ++c) {
      for (int py = 0; py < f.h; ++py) {
        for (int px = 0; px < f.w; ++px) {
          lo = std::min<double>(lo, y.at(px, py, c));
          hi = std::max<double>(hi, y.at(px, py, c));
          if (px >= 32 + 45) {
            far_err =
                std::max<double>(far_err, std::abs(y.at(px, py, c) - clean.colour.at(px, py, c)));
          }
        }
      }
    }
    INFO("second pass " << second << ": range [" << lo << ", " << hi
                        << "], largest error far from the fireflies " << far_err);
    CHECK(far_err < 0.2);
    CHECK(lo >= 0.0);  // the regression's negative overshoot is clamped for a non-negative x
    CHECK(hi < 2e6);
  }
}

TEST_CASE("one pass: single-buffer mode; two passes: both halves", "[nfor]") {
  FrameAccumulator one, two;
  const Layout feats{true, true, true, false};
  one.add(test::make_pass(40, 32, 4, 1, feats), "a");
  two.add(test::make_pass(40, 32, 4, 1, feats), "a");
  two.add(test::make_pass(40, 32, 4, 2, feats), "b");
  for (const FrameAccumulator* acc : {&one, &two}) {
    const FrameEstimate e = acc->estimate();
    NforExtras ex;
    ex.want_cross_validation = ex.want_hat = true;
    const Image y = NforDenoiser().run(denoise_inputs(e, e.mean, e.variance, true), &ex);
    require_finite(y);
    CHECK(ex.mode == (acc->passes() == 1 ? "single-buffer" : "nfor"));
    CHECK(ex.prefiltered_features == (acc->passes() == 2));
    CHECK(ex.cross_validation.empty() == (acc->passes() == 1));
    require_finite(ex.hat);
  }
}

TEST_CASE("without feature halves (a v1 state) the features are used unfiltered", "[nfor]") {
  Frame f = noisy_frame(48, 40, 0.1f);
  const Frame clean = noisy_frame(48, 40, 0.0f);
  f.feature_halves = false;
  NforExtras ex;
  const Image y = NforDenoiser().run(f.inputs(), &ex);
  CHECK(ex.mode == "nfor");
  CHECK_FALSE(ex.prefiltered_features);
  CHECK(compute_metrics(y, clean.colour).mse < 0.5 * compute_metrics(f.colour, clean.colour).mse);
}

TEST_CASE("NFOR in the tiled pipeline: every tile size gives the whole-frame result",
          "[nfor][pipeline]") {
  FrameAccumulator acc;
  const Layout feats{true, true, true, false};
  for (int k = 0; k < 4; ++k)
    acc.add(test::make_pass(53, 41, 4, 10 + static_cast<std::uint64_t>(k), feats),
            "p" + std::to_string(k));
  PipelineOptions o;
  o.denoiser = "nfor";
  o.tile = 1000;
  Pipeline pipeline(o);
  pipeline.commit();
  // The registry asks the accumulator for the halves NFOR reads.
  CHECK(pipeline.estimate_options().halves);
  CHECK(pipeline.estimate_options().features);
  const FrameEstimate e = acc.estimate(pipeline.estimate_options());
  const PipelineResult whole = pipeline.execute(e);
  CHECK(whole.denoiser == "nfor");
  CHECK(whole.inputs.albedo);
  // NFOR runs whole-frame: the halo is the mixer's and the t-test's only.
  CHECK(whole.halo == pipeline.mixer()->radius() + o.ttest.radius);
  for (int tile : {7, 16, 32}) {
    INFO("tile " << tile);
    o.tile = tile;
    pipeline.set_options(o);
    pipeline.commit();
    const PipelineResult r = pipeline.execute(e);
    CHECK(max_abs_diff(r.result, whole.result) == 0.0);
    CHECK(max_abs_diff(r.denoised, whole.denoised) == 0.0);
    CHECK(max_abs_diff(r.alpha, whole.alpha) == 0.0);
    CHECK(max_abs_diff(r.sure, whole.sure) == 0.0);
  }
}

TEST_CASE("the halves' shares come from the halves, not from the Var[x] the weights read",
          "[nfor]") {
  // The pipeline may raise the Var[x] NFOR's weights read (few passes: max(own, pooled),
  // docs/pipeline.md). Equal halves must still combine half and half: then swapping A and B
  // changes nothing. (With the share taken as Var[x] / Var[x_A] it went to 1, all A.)
  Frame f = noisy_frame(40, 33, 0.1f);
  for (float& v : f.variance.data()) v *= 4.0f;
  Frame g = f;
  std::swap(g.half[0], g.half[1]);
  std::swap(g.half_var[0], g.half_var[1]);
  std::swap(g.half_albedo[0], g.half_albedo[1]);
  std::swap(g.half_normal[0], g.half_normal[1]);
  std::swap(g.half_depth[0], g.half_depth[1]);
  const Image yf = NforDenoiser().run(f.inputs());
  const Image yg = NforDenoiser().run(g.inputs());
  require_finite(yf);
  CHECK(max_abs_diff(yf, yg) < 1e-5);
}

TEST_CASE("asking for the error estimates leaves y bit-identical", "[nfor]") {
  const Frame f = noisy_frame(40, 33, 0.1f);
  for (const std::string& isa : nfor::isas_available()) {
    INFO("build " << isa);
    const NforDenoiser den(with_isa(isa));
    const Image plain = den.run(f.inputs());
    NforExtras ex;
    ex.want_cross_validation = ex.want_hat = ex.want_stages = true;
    const Image with = den.run(f.inputs(), &ex);
    CHECK(max_abs_diff(plain, with) == 0.0);
  }
}

TEST_CASE("the pipeline takes NFOR's hat diagonal for SURE's divergence", "[nfor][pipeline]") {
  FrameAccumulator acc;
  const Layout feats{true, true, true, false};
  for (int k = 0; k < 4; ++k)
    acc.add(test::make_pass(40, 30, 4, 20 + static_cast<std::uint64_t>(k), feats),
            "p" + std::to_string(k));
  FrameEstimate e = acc.estimate();
  // Without pass counts the pipeline hands the denoiser each pixel's own Var[x] (with them, its
  // weights read max(own, pooled): docs/pipeline.md, "Few passes"), so the direct run below sees
  // exactly the pipeline's inputs.
  e.passes = Image();
  const NforDenoiser nfor;
  PipelineOptions o;
  o.denoiser = "nfor";
  Pipeline pipeline(o);
  pipeline.commit();
  const PipelineResult r = pipeline.execute(e);
  CHECK(r.divergence == "analytic");
  NforExtras ex;
  ex.want_hat = true;
  const Image y = nfor.run(denoise_inputs(e, e.mean, e.variance, true), &ex);
  CHECK(max_abs_diff(r.denoised, y) == 0.0);  // y is the whole-frame run's
  // SURE = (y - x)^2 - var + 2 hat var, and the hat is a leverage: in [0, 1].
  double worst = 0;
  for (std::size_t i = 0; i < y.data().size(); ++i) {
    const double h = ex.hat.data()[i], v = e.variance.data()[i];
    const double d = static_cast<double>(y.data()[i]) - e.mean.data()[i];
    REQUIRE(h >= 0.0);
    REQUIRE(h <= 1.0 + 1e-5);
    worst = std::max(worst, std::abs(r.sure.data()[i] - (d * d - v + 2 * h * v)) / (v + 1e-12));
  }
  INFO("largest difference of SURE and (y-x)^2 - var + 2 hat var, relative to var: " << worst);
  CHECK(worst < 1e-4);
  // One pass: single-buffer mode, still with its hat diagonal.
  FrameAccumulator one;
  one.add(test::make_pass(40, 30, 4, 20, feats), "p0");
  CHECK(pipeline.execute(one.estimate()).divergence == "analytic");
}

TEST_CASE("every kernel build's NL-means weights match a double-precision reference",
          "[nfor][simd]") {
  const int W = 45, H = 37, r = 4, f = 2;
  const nfor::Geometry g(W, H, 32);
  nfor::Planes guide(g, 3), var(g, 3);
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      for (int c = 0; c < 3; ++c) {
        guide.at(x, y, c) =
            0.5f + 0.3f * std::sin(0.3f * static_cast<float>(x + c)) + 0.05f * gauss(60, x, y, c);
        var.at(x, y, c) = (x + y) % 5 == 0 ? 0.0f : 0.0025f * (1.0f + hash01(61, x, y, c));
      }
    }
  }
  nfor::replicate_border(g, guide);
  nfor::replicate_border(g, var);
  const float k = 0.7f;
  // The reference: d^2 = mean over patch and channels of ((u_p - u_q)^2 - (V_p + min(V_p, V_q)))
  // / (k^2 (eps + V_p + V_q)), w = exp(-max(0, d^2)), 0 where q leaves the image.
  auto reference = [&](int px, int py, int dx, int dy) {
    const int qx = px + dx, qy = py + dy;
    if (qx < 0 || qy < 0 || qx >= W || qy >= H) return 0.0;
    double s = 0;
    for (int c = 0; c < 3; ++c) {
      for (int ny = -f; ny <= f; ++ny) {
        for (int nx = -f; nx <= f; ++nx) {
          const double up = guide.at(px + nx, py + ny, c), uq = guide.at(qx + nx, qy + ny, c);
          const double vp = var.at(px + nx, py + ny, c), vq = var.at(qx + nx, qy + ny, c);
          s += ((up - uq) * (up - uq) - (vp + std::min(vp, vq))) /
               (k * k * (nfor::kDistanceEpsilon + vp + vq));
        }
      }
    }
    const double d2 = s / (3.0 * (2 * f + 1) * (2 * f + 1));
    return std::exp(-std::max(0.0, d2));
  };
  const Rect tile = g.tile(1, 2);  // an interior tile that reaches past the image's bottom
  REQUIRE(tile.y1 > H);
  for (const std::string& isa : nfor::isas_available()) {
    nfor::WeightSpec spec;
    for (int c = 0; c < 3; ++c) {
      spec.guide[c] = guide.origin(c);
      spec.variance[c] = var.origin(c);
    }
    spec.radius = r;
    spec.patch = f;
    spec.k = k;
    spec.kernels = &nfor::kernels(isa);
    nfor::TileScratch sc;
    nfor::tile_weights(g, spec, tile, sc);
    double worst = 0;
    int o = 0, nonzero = 0;
    for (int dy = -r; dy <= r; ++dy) {
      for (int dx = -r; dx <= r; ++dx, ++o) {
        for (int py = tile.y0; py < tile.y1; ++py) {
          for (int px = tile.x0; px < tile.x1; ++px) {
            const float got = sc.weights[static_cast<std::size_t>(
                o * nfor::kTileArea + (py - tile.y0) * nfor::kTileWidth + (px - tile.x0))];
            const double want = px < W && py < H ? reference(px, py, dx, dy) : 0.0;
            worst = std::max(worst, std::abs(got - want));
            nonzero += want > 1e-3 ? 1 : 0;
          }
        }
      }
    }
    INFO("build " << isa << ": largest weight difference " << worst);
    CHECK(worst < 1e-6);  // float distance sums and exp_neg's ~2e-7 relative error
    CHECK(nonzero > 1000);
  }
}

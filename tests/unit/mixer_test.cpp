// The closed-form mixer (mixer.*) against a plain double-precision reference written here from
// its formulas (docs/pipeline.md, "The mixer's two scales"): direct window sums clipped to the
// image, every weighting and rule, border pixels included, for windows smaller and larger than
// the mixer's summation blocks; tiles against the whole image bit for bit; and a firefly that
// must not cost its neighbours' windows their precision.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "proden/image.hpp"
#include "proden/mixer.hpp"
#include "proden/region.hpp"
#include "proden/tstat.hpp"

using namespace proden;

namespace {

// |mixer - reference| on alpha in [0, 1]: the mixer rounds its terms and sums to float.
constexpr double kTolAlpha = 2e-5;

struct Inputs {
  int w = 0, h = 0;
  Image x, y, var, sure, div, passes;
};

Inputs inputs(int w, int h, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Inputs in;
  in.w = w;
  in.h = h;
  for (Image* plane : {&in.x, &in.y, &in.var, &in.sure, &in.div}) *plane = Image(w, h, 3);
  in.passes = Image(w, h, 1);
  for (int yy = 0; yy < h; ++yy) {
    for (int xx = 0; xx < w; ++xx) {
      in.passes.at(xx, yy, 0) = static_cast<float>(2 + (xx + 3 * yy) % 7);
      for (int c = 0; c < 3; ++c) {
        const float base = 0.3f + 0.2f * std::sin(0.15f * static_cast<float>(xx + c));
        in.var.at(xx, yy, c) = 0.002f + 0.02f * u(rng);
        in.x.at(xx, yy, c) = base + 0.2f * (u(rng) - 0.5f);
        in.y.at(xx, yy, c) = base + 0.03f * (u(rng) - 0.5f) + 0.02f * (xx > w / 2 ? 1.f : 0.f);
        in.div.at(xx, yy, c) = 0.3f * in.var.at(xx, yy, c) * u(rng);
        in.sure.at(xx, yy, c) = 0.004f * (u(rng) - 0.3f);
      }
    }
  }
  return in;
}

MixInputs mix_inputs(const Inputs& in, bool exact) {
  MixInputs m{in.w,           in.h, view_of(in.x), view_of(in.y), view_of(in.var), view_of(in.sure),
              view_of(in.div)};
  if (!exact) m.origin.passes = view_of(in.passes);
  return m;
}

// Sum of f over the (2r+1)^2 window of (px, py) clipped to the image, in double.
template <class F>
double window(const Inputs& in, int px, int py, int r, const F& f) {
  double s = 0.0;
  for (int qy = std::max(py - r, 0); qy <= std::min(py + r, in.h - 1); ++qy)
    for (int qx = std::max(px - r, 0); qx <= std::min(px + r, in.w - 1); ++qx) s += f(qx, qy);
  return s;
}

// The window weight of every pixel, per channel (from the 3x3 means of x and Var[x] around it),
// indexed (c * h + y) * w + x.
std::vector<double> window_weights(const Inputs& in, const ClosedFormParams& p) {
  std::vector<double> weights(static_cast<std::size_t>(3) * in.w * in.h);
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < in.h; ++y) {
      for (int x = 0; x < in.w; ++x) {
        const double n = window(in, x, y, 1, [](int, int) { return 1.0; });
        const double mv =
            window(in, x, y, 1, [&](int qx, int qy) { return in.var.at(qx, qy, c); }) / n;
        const double mx =
            window(in, x, y, 1, [&](int qx, int qy) { return in.x.at(qx, qy, c); }) / n;
        double w = 0.0;
        switch (p.weight) {
          case WindowWeight::uniform:
            w = 1.0;
            break;
          case WindowWeight::relative:
            w = 1.0 / (mx * mx + 0.01);
            break;
          case WindowWeight::variance:
            w = 1.0 / (mv + p.variance_floor * (mx * mx + 0.01) + 1e-30);
            break;
        }
        weights[(static_cast<std::size_t>(c) * in.h + y) * in.w + x] = w;
      }
    }
  }
  return weights;
}

// The mixer's alpha at (px, py, c), written from the formulas (weights: window_weights()).
double reference_alpha(const Inputs& in, const ClosedFormParams& p,
                       const std::vector<double>& weights, bool exact, int px, int py, int c) {
  const auto weight = [&](int x, int y) {
    return weights[(static_cast<std::size_t>(c) * in.h + y) * in.w + x];
  };
  const auto d = [&](int x, int y) {
    return static_cast<double>(in.y.at(x, y, c)) - in.x.at(x, y, c);
  };
  const auto v = [&](int x, int y) { return static_cast<double>(in.var.at(x, y, c)); };
  if (p.rule == ClosedFormRule::inverse_error) {
    const int r = p.radius;
    const double ex = window(in, px, py, r, [&](int x, int y) { return weight(x, y) * v(x, y); });
    const double ey = std::max(
        window(in, px, py, r, [&](int x, int y) { return weight(x, y) * in.sure.at(x, y, c); }),
        0.0);
    return ex + ey > 0.0 ? std::clamp(ex / (ex + ey), 0.0, 1.0) : 0.0;
  }
  struct Est {
    double alpha, variance;
    bool valid;
  };
  const auto estimate = [&](int r) {
    const double sa = window(
        in, px, py, r, [&](int x, int y) { return weight(x, y) * (v(x, y) - in.div.at(x, y, c)); });
    const double sd =
        window(in, px, py, r, [&](int x, int y) { return weight(x, y) * d(x, y) * d(x, y); });
    const double na = window(in, px, py, r, [&](int x, int y) {
      const double w = weight(x, y);
      return exact ? 0.0 : w * w * v(x, y) * v(x, y) * 2.0 / pixel_dof(in.passes.at(x, y, 0));
    });
    const double nd = window(in, px, py, r, [&](int x, int y) {
      const double w = weight(x, y), dd = d(x, y);
      return w * w * dd * dd * dd * dd * (2.0 / 3.0);
    });
    Est e{0.0, 0.0, sd > 0.0};
    if (e.valid) {
      e.alpha = sa / sd;
      e.variance = (na + e.alpha * e.alpha * nd) / (sd * sd);
    }
    return e;
  };
  const Est n = estimate(p.radius);
  if (p.wide_radius <= p.radius) return n.valid ? std::clamp(n.alpha, 0.0, 1.0) : 0.0;
  const Est l = estimate(p.wide_radius);
  double a = 0.0;
  if (n.valid && l.valid) {
    const double delta = n.alpha - l.alpha, noise = std::max(n.variance - l.variance, 0.0);
    const double g2 = static_cast<double>(p.garrote) * p.garrote;
    const double keep = delta != 0.0 ? std::max(0.0, 1.0 - g2 * noise / (delta * delta)) : 0.0;
    a = l.alpha + keep * delta;
  } else if (l.valid) {
    a = l.alpha;
  } else if (n.valid) {
    a = n.alpha;
  }
  return std::clamp(a, 0.0, 1.0);
}

double max_error(const Inputs& in, const ClosedFormParams& p, bool exact, const Rect& out) {
  const ClosedFormMixer mixer(p);
  Buffer alpha(out, 3);
  mixer.mix(mix_inputs(in, exact), out, alpha);
  const std::vector<double> weights = window_weights(in, p);
  double worst = 0.0;
  for (int c = 0; c < 3; ++c)
    for (int y = out.y0; y < out.y1; ++y)
      for (int x = out.x0; x < out.x1; ++x)
        worst = std::max(
            worst, std::abs(alpha.at(x, y, c) - reference_alpha(in, p, weights, exact, x, y, c)));
  return worst;
}

}  // namespace

TEST_CASE("closed-form mixer equals its formulas with direct window sums", "[mixer]") {
  const Inputs in = inputs(53, 41, 7);
  const Rect whole{0, 0, in.w, in.h};
  struct Case {
    ClosedFormRule rule;
    WindowWeight weight;
    int radius, wide;
    bool exact;
  };
  // Radii below, at and well above the 16-pixel summation blocks; a wide window wider than the
  // image.
  const Case cases[] = {
      {ClosedFormRule::stein, WindowWeight::relative, 12, 24, false},
      {ClosedFormRule::stein, WindowWeight::relative, 12, 24, true},
      {ClosedFormRule::stein, WindowWeight::variance, 3, 9, false},
      {ClosedFormRule::stein, WindowWeight::uniform, 7, 0, false},
      {ClosedFormRule::stein, WindowWeight::relative, 1, 40, false},
      {ClosedFormRule::inverse_error, WindowWeight::relative, 5, 0, false},
      {ClosedFormRule::inverse_error, WindowWeight::variance, 16, 0, true},
  };
  for (const Case& k : cases) {
    ClosedFormParams p;
    p.rule = k.rule;
    p.weight = k.weight;
    p.radius = k.radius;
    p.wide_radius = k.wide;
    INFO("rule " << static_cast<int>(k.rule) << " weight " << static_cast<int>(k.weight) << " r "
                 << k.radius << " wide " << k.wide << " exact " << k.exact);
    CHECK(max_error(in, p, k.exact, whole) <= kTolAlpha);
    // An interior rectangle that does not start on a block boundary.
    CHECK(max_error(in, p, k.exact, Rect{5, 3, 37, 29}) <= kTolAlpha);
  }
}

TEST_CASE("closed-form mixer: tiles equal the whole image bit for bit", "[mixer][tiles]") {
  const Inputs in = inputs(97, 70, 11);
  const ClosedFormMixer mixer{ClosedFormParams{}};
  const MixInputs mi = mix_inputs(in, false);
  const Rect whole{0, 0, in.w, in.h};
  Buffer all(whole, 3);
  mixer.mix(mi, whole, all);
  for (const int t : {13, 16, 32, 50}) {
    for (int y0 = 0; y0 < in.h; y0 += t) {
      for (int x0 = 0; x0 < in.w; x0 += t) {
        const Rect tile{x0, y0, std::min(x0 + t, in.w), std::min(y0 + t, in.h)};
        Buffer part(tile, 3);
        mixer.mix(mi, tile, part);
        for (int c = 0; c < 3; ++c)
          for (int y = tile.y0; y < tile.y1; ++y)
            for (int x = tile.x0; x < tile.x1; ++x) REQUIRE(part.at(x, y, c) == all.at(x, y, c));
      }
    }
  }
}

TEST_CASE("closed-form mixer: a firefly does not cost the windows without it", "[mixer]") {
  // A 1e6 outlier in x (and so in d^2 and d^4 = 1e24) at one pixel: windows that do not contain
  // it must see exactly what they see without it (no running sum subtracts it back out).
  Inputs in = inputs(90, 30, 3);
  Inputs spiked = in;
  spiked.x.at(20, 15, 1) = 1e6f;
  const ClosedFormParams p;  // r 12, wide 24
  const ClosedFormMixer mixer(p);
  const Rect whole{0, 0, in.w, in.h};
  Buffer a(whole, 3), b(whole, 3);
  mixer.mix(mix_inputs(in, false), whole, a);
  mixer.mix(mix_inputs(spiked, false), whole, b);
  const int reach = p.wide_radius + 1;  // the wide window plus the weights' 3x3
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < in.h; ++y) {
      for (int x = 20 + reach + 1; x < in.w; ++x) REQUIRE(a.at(x, y, c) == b.at(x, y, c));
    }
  }
  for (int c = 0; c < 3; ++c)
    for (int y = 0; y < in.h; ++y)
      for (int x = 0; x < in.w; ++x) REQUIRE(std::isfinite(b.at(x, y, c)));
}

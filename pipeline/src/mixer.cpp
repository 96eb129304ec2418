#include "proden/mixer.hpp"

#include <algorithm>
#include <cmath>
#include <vector>

namespace proden {
namespace {

constexpr double kTinyVariance = 1e-30;  // keeps 1 / var finite where a pixel is exact
constexpr int kBlock = 8;                // aligned block length of the box sums

// Floor division for possibly negative coordinates.
inline int floor_div(int a, int b) {
  return a >= 0 ? a / b : -((-a + b - 1) / b);
}

// Sum of line(q) for q in [a, b) (absolute coordinates) split at absolute multiples of kBlock:
// the left part, whole blocks (their sums precomputed in `blocks`, from block `first_block` on),
// the right part. Every window is summed in the same order whatever range a caller computes, so
// tiles equal the whole image bit for bit.
template <class Line>
double window_sum(const Line& line, const std::vector<double>& blocks, int first_block, int a,
                  int b) {
  const int k0 = floor_div(a + kBlock - 1, kBlock), k1 = floor_div(b, kBlock);  // whole blocks
  double s = 0.0;
  if (k0 >= k1) {
    for (int q = a; q < b; ++q) s += line(q);
    return s;
  }
  for (int q = a; q < k0 * kBlock; ++q) s += line(q);
  for (int k = k0; k < k1; ++k) s += blocks[static_cast<std::size_t>(k - first_block)];
  for (int q = k1 * kBlock; q < b; ++q) s += line(q);
  return s;
}

// Sums of plane `c` of `src` (a buffer covering at least out ⊕ r ∩ image) over each pixel's
// (2r+1)^2 window clipped to the image, for every pixel of `out`. Separable: rows, then columns,
// each with aligned block sums (O(kBlock + r / kBlock) per pixel).
void box_sums(const Buffer& src, int c, const Rect& out, int r, const Rect& image, Buffer& dst,
              int dst_c) {
  const Rect rows{out.x0, std::max(out.y0 - r, image.y0), out.x1, std::min(out.y1 + r, image.y1)};
  Buffer h(rows, 1);
  std::vector<double> blocks;
  auto block_sums = [&](int lo, int hi, auto&& value) {  // whole blocks inside [lo, hi)
    const int k0 = floor_div(lo + kBlock - 1, kBlock), k1 = floor_div(hi, kBlock);
    blocks.assign(static_cast<std::size_t>(std::max(k1 - k0, 0)), 0.0);
    for (int k = k0; k < k1; ++k) {
      double s = 0.0;
      for (int q = k * kBlock; q < (k + 1) * kBlock; ++q) s += value(q);
      blocks[static_cast<std::size_t>(k - k0)] = s;
    }
    return k0;
  };
  const int lo_x = std::max(out.x0 - r, image.x0), hi_x = std::min(out.x1 + r, image.x1);
  for (int y = rows.y0; y < rows.y1; ++y) {
    const float* row = src.row(y, c);
    const int x0 = src.rect().x0;
    auto line = [&](int q) { return static_cast<double>(row[q - x0]); };
    const int first = block_sums(lo_x, hi_x, line);
    for (int x = out.x0; x < out.x1; ++x) {
      const int a = std::max(x - r, image.x0), b = std::min(x + r + 1, image.x1);
      h.at(x, y, 0) = static_cast<float>(window_sum(line, blocks, first, a, b));
    }
  }
  // Columns: the same split per pixel, done a whole row at a time (contiguous, vectorisable);
  // each pixel still adds the same terms in the same order as a per-column pass would.
  const int w = out.width();
  const int kb0 = floor_div(rows.y0 + kBlock - 1, kBlock), kb1 = floor_div(rows.y1, kBlock);
  std::vector<double> block_rows(
      static_cast<std::size_t>(std::max(kb1 - kb0, 0)) * static_cast<std::size_t>(w), 0.0),
      acc(static_cast<std::size_t>(w));
  auto add_row = [&](double* __restrict to, int q) {
    const float* __restrict from = h.row(q, 0);
    for (int i = 0; i < w; ++i) to[i] += static_cast<double>(from[i]);
  };
  for (int k = kb0; k < kb1; ++k) {
    double* to =
        block_rows.data() + static_cast<std::size_t>(k - kb0) * static_cast<std::size_t>(w);
    for (int q = k * kBlock; q < (k + 1) * kBlock; ++q) add_row(to, q);
  }
  for (int y = out.y0; y < out.y1; ++y) {
    const int a = std::max(y - r, image.y0), b = std::min(y + r + 1, image.y1);
    const int k0 = floor_div(a + kBlock - 1, kBlock), k1 = floor_div(b, kBlock);
    std::fill(acc.begin(), acc.end(), 0.0);
    if (k0 >= k1) {
      for (int q = a; q < b; ++q) add_row(acc.data(), q);
    } else {
      for (int q = a; q < k0 * kBlock; ++q) add_row(acc.data(), q);
      for (int k = k0; k < k1; ++k) {
        const double* __restrict from =
            block_rows.data() + static_cast<std::size_t>(k - kb0) * static_cast<std::size_t>(w);
        double* __restrict to = acc.data();
        for (int i = 0; i < w; ++i) to[i] += from[i];
      }
      for (int q = k1 * kBlock; q < b; ++q) add_row(acc.data(), q);
    }
    float* __restrict o = dst.row(y, dst_c) + (out.x0 - dst.rect().x0);
    for (int i = 0; i < w; ++i) o[i] = static_cast<float>(acc[static_cast<std::size_t>(i)]);
  }
}

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
  Buffer planes(vrect, 2), terms(wrect, n_terms), sums(out, n_terms), wide(out, n_terms),
      local(wrect, 2);
  const bool relative = params_.weight == WindowWeight::relative;
  const bool exact = in.origin.renderer || !in.origin.passes.valid();
  for (int c = 0; c < 3; ++c) {
    for (int y = vrect.y0; y < vrect.y1; ++y) {
      for (int x = vrect.x0; x < vrect.x1; ++x) {
        planes.at(x, y, 0) = in.variance.at(x, y, c);
        planes.at(x, y, 1) = in.x.at(x, y, c);
      }
    }
    // Weights 1 / (3x3 mean of var): smoothing gives the weight many more degrees of freedom
    // than the pixel's own estimate, whose noise would otherwise bias alpha low
    // (E[1/s^2] > 1/sigma^2). Weighting by 1/var makes alpha minimise the window's
    // variance-normalised error, so a firefly's huge variance cannot make its neighbours trust
    // a y it smeared into them (a plain sum would be dominated by it).
    // The variance floor (1 % relative standard deviation of the local mean, or of 0.1 where it
    // is black) stops a pixel whose few passes happened to agree exactly (var = 0 in a dark,
    // undersampled region) from taking over its whole window with an infinite weight.
    box_sums(planes, 0, wrect, 1, image, local, 0);
    box_sums(planes, 1, wrect, 1, image, local, 1);
    for (int y = wrect.y0; y < wrect.y1; ++y) {
      const int ny = std::min(y + 2, image.y1) - std::max(y - 1, image.y0);
      for (int x = wrect.x0; x < wrect.x1; ++x) {
        const int nx = std::min(x + 2, image.x1) - std::max(x - 1, image.x0);
        const double mv = static_cast<double>(local.at(x, y, 0)) / (nx * ny);
        const double mx = static_cast<double>(local.at(x, y, 1)) / (nx * ny);
        const double w =
            params_.weight == WindowWeight::uniform ? 1.0
            : relative                              ? 1.0 / (mx * mx + 0.01)
                       : 1.0 / (mv + params_.variance_floor * (mx * mx + 0.01) + kTinyVariance);
        const double v = in.variance.at(x, y, c);
        const double d = static_cast<double>(in.y.at(x, y, c)) - in.x.at(x, y, c);
        const double dof = exact ? 0.0 : pixel_dof(in.origin.passes.at(x, y, 0));
        if (!stein) {
          terms.at(x, y, 0) = static_cast<float>(w * v);
          terms.at(x, y, 1) = static_cast<float>(w * in.sure.at(x, y, c));
          continue;
        }
        terms.at(x, y, 0) = static_cast<float>(w * (v - in.divergence.at(x, y, c)));
        terms.at(x, y, 1) = static_cast<float>(w * d * d);
        if (two_scales) {
          terms.at(x, y, 2) = static_cast<float>(exact ? 0.0 : w * w * v * v * 2.0 / dof);
          terms.at(x, y, 3) = static_cast<float>(w * w * d * d * d * d * (2.0 / 3.0));
        }
      }
    }
    for (int t = 0; t < n_terms; ++t) {
      box_sums(terms, t, out, r, image, sums, t);
      if (two_scales) box_sums(terms, t, out, R, image, wide, t);
    }
    for (int y = out.y0; y < out.y1; ++y) {
      for (int x = out.x0; x < out.x1; ++x) {
        const double s0 = sums.at(x, y, 0), s1 = sums.at(x, y, 1);
        double a = 0.0;
        if (!stein) {
          const double ex = s0, ey = std::max(s1, 0.0);
          if (ex + ey > 0.0) a = ex / (ex + ey);
        } else if (!two_scales) {
          if (s1 > 0.0) a = s0 / s1;
        } else {
          const WindowEstimate n = stein_estimate(s0, s1, sums.at(x, y, 2), sums.at(x, y, 3));
          const WindowEstimate l = stein_estimate(wide.at(x, y, 0), wide.at(x, y, 1),
                                                  wide.at(x, y, 2), wide.at(x, y, 3));
          if (n.valid && l.valid) {
            // The difference of nested window estimates has variance ~ V_narrow - V_wide.
            const double delta = n.alpha - l.alpha;
            const double noise = std::max(n.variance - l.variance, 0.0);
            const double g2 = static_cast<double>(params_.garrote) * params_.garrote;
            const double keep =
                delta != 0.0 ? std::max(0.0, 1.0 - g2 * noise / (delta * delta)) : 0.0;
            a = l.alpha + keep * delta;
          } else if (l.valid) {
            a = l.alpha;
          } else if (n.valid) {
            a = n.alpha;
          }
        }
        alpha.at(x, y, c) = static_cast<float>(std::clamp(std::isfinite(a) ? a : 0.0, 0.0, 1.0));
      }
    }
  }
}

}  // namespace proden

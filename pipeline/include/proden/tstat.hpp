// The t-statistic rescale of the mixing weight (design after Firmino et al. 2022, §2.4 of the
// method notes): where the mixed image drifts from the render by more than the samples' noise
// explains, alpha shrinks, so the output converges to the unbiased render as samples grow.
// The statistics (null distribution, degrees of freedom, quantiles) are derived in
// docs/pipeline.md, "The t-test's statistics".
#pragma once

#include <string>
#include <vector>

#include "proden/image.hpp"
#include "proden/region.hpp"

namespace proden {

// Largest window and variance-pooling radius the t-test takes (its kernel's lane arrays).
inline constexpr int kTTestMaxRadius = 15;

struct TTestParams {
  int radius = 5;              // 11x11 window
  float sigma_scale = 100.0f;  // s = sigma_scale * sqrt(clamp(mean_c var, 0, 1))
  float sigma_floor = 1e-3f;
  float t0 = 4.2f;  // alpha' = alpha (1 - Phi(slope (u - t0)))
  float slope = 2.0f;
  // On (proden's test): one statistic per channel with weights consistent between numerator and
  // variance, judged against its Student-t null with Welch-Satterthwaite degrees of freedom:
  // u is the normal score of t (the normal quantile of the same tail probability), so t0 keeps
  // the authors' tail probability 1 - Phi(t0) whatever the pass count. Off: exactly the authors'
  // test (channels summed, M's variance counted as if independent, u = t).
  bool dof_correction = true;
  // Kernel build: "" = the best for this CPU, or one of t_test_builds() (tests compare them; every
  // build gives the same bits).
  std::string isa = {};
};

// The t-test's kernel builds this CPU runs ("baseline", "avx2", "avx512"), best last.
std::vector<std::string> t_test_builds();

// Where the variance the t-test reads came from: it sets the degrees of freedom of its estimate.
struct VarianceOrigin {
  View passes;            // 1 channel, passes per pixel; invalid = unknown (treated as exact)
  bool renderer = false;  // the renderer's own variance channels (hundreds of samples: exact)
  int pool_radius = 0;    // the variance view is pool_variance(raw, pool_radius)
  View raw;               // the unpooled estimates, for the degrees of freedom (invalid: pooled)
};

// Var[x] as the mixer and the t-test read it: the mean over each pixel's (2r+1)^2 neighbourhood
// clipped to the image (r = 0: unchanged). With few passes a pixel's own estimate is
// chi-square with K - 1 degrees of freedom; pooling gives it about (2r+1)^2 times more.
Image pool_variance(const Image& variance, int radius);
// The same into `out`, with `tmp` as scratch for the separable pass (both reused when sized).
void pool_variance(const Image& variance, int radius, Image& tmp, Image& out);

// Degrees of freedom of one pixel's own variance estimate from `passes` passes: K - 1 between
// passes; the one-pass spatial fallback is the 3x3 spread of the mean (8).
inline double pixel_dof(double passes) {
  constexpr double kSpatialDof = 8.0;  // the one-pass spatial fallback (accumulator.cpp)
  return passes >= 2.0 ? passes - 1.0 : kSpatialDof;
}

// Exact Student-t quantile (Boost.Math): the t with P(T_dof > t) = upper_tail; dof = infinity
// gives the normal quantile.
double student_t_quantile(double dof, double upper_tail);

// The threshold on t equivalent to the authors' t0 for a statistic with `dof` degrees of freedom:
// the quantile at their tail probability 1 - Phi(t0). dof_correction off: t0.
double t_threshold(const TTestParams& params, double dof);

// How far from its true value the t-test may set a keep factor whose dof it skipped
// (RejectionCurve::dof_free_t): 50x below the tabulated curve's own error bound (5e-4, tests).
inline constexpr double kDofFreeKeepTolerance = 1e-5;

// The soft rejection curve keep(t, dof) = 1 - Phi(slope (u - t0)) with u = Phi^-1(F_dof(t)) the
// normal score of t under Student-t with `dof` degrees of freedom: with infinite dof u = t, the
// authors' curve. Tabulated once per (t0, slope) over u (steps of 0.1 within t0 +- 6 / slope, where
// keep moves from 1 - 1e-9 to 1e-9) and over 1/dof (129 rows spaced in sqrt(1/dof)), interpolated
// linearly in 1/dof and in asinh(t); tests bound the error against the exact Boost.Math value.
class RejectionCurve {
 public:
  RejectionCurve(double t0, double slope);
  // The curve for these parameters, built once per process and shared (thread-safe).
  static const RejectionCurve& shared(double t0, double slope);

  double normal_score(double t, double dof) const;  // tabulated u(t, dof), clamped to the grid
  double keep(double t, double dof) const;
  // keep for n statistics sharing one dof (the row is interpolated once).
  void keep(const double* t, int n, double dof, double* out) const;
  static double exact_normal_score(double t, double dof);  // Boost.Math, for tests
  // Statistics at or below this keep the first node's factor within kDofFreeKeepTolerance,
  // whatever their finite dof: the t-test need not compute the dof of a pixel whose t are all
  // this low, and gives it that factor. Every row starts at or above the infinite-dof row, so a
  // finite dof's keep lies between the infinite-dof curve and the first node's value; up to
  // dof_free_t the infinite-dof curve is within the tolerance of that value (t <= 2.07 with the
  // defaults, where the exact bound, the first node, is t <= 1.2).
  double dof_free_t() const { return dof_free_t_; }

 private:
  struct Row {  // the table interpolated at one dof
    const double *lo, *hi;
    double f, t_lo, t_hi;  // t <= t_lo: u at the first node or below; t >= t_hi: at the last
  };
  Row row(double dof) const;
  double normal_score(const Row& r, double t) const;
  double t0_, slope_, u_lo_, du_, keep_lo_, keep_hi_;  // keep at the first and last node
  double dof_free_t_ = 0.0;
  int nu_rows_, u_cols_;
  std::vector<double> table_;             // asinh(t) at [row * u_cols_ + col]
  std::vector<double> first_t_, last_t_;  // t at each row's first and last node
};

// Reads x, z (= x + alpha (y - x) with the un-rescaled alpha) and alpha over
// out.expanded(radius) ∩ image, and the (pooled) variance and pass counts over
// out.expanded(radius + origin.pool_radius) ∩ image; writes alpha' over `out`. Neighbours outside
// the image are skipped. The window's highest-variance pixel M is added to the sums with weight
// 1/3 (the authors' extra term).
void t_rescale(const View& x, const View& variance, const View& z, const View& alpha, int width,
               int height, const Rect& out, const TTestParams& params, Buffer& rescaled,
               const VarianceOrigin& origin = {});

// The statistic at one pixel, per channel (exposed for tests and diagnostics); with
// dof_correction off the three entries are the authors' single summed statistic. `dof` receives
// the Welch-Satterthwaite degrees of freedom (infinity when the variance counts as exact).
struct TStatistic {
  double t[3] = {0, 0, 0};
  double dof = 0;
};
TStatistic t_statistic(const View& x, const View& variance, const View& z, int width, int height,
                       int px, int py, const TTestParams& params,
                       const VarianceOrigin& origin = {});

}  // namespace proden

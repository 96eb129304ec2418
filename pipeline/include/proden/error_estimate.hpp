// The published result's estimated error, with an uncertainty: MSE, relMSE (the result standing
// in for the reference) and the "equivalent spp" (the spp plain Monte Carlo would need for the
// same relMSE), each with a 95 % interval. One function computes it (estimate_error); the frame
// JSON, events, EXR header and `proden denoise --json` all report its EstimatedError. The model
// and its assumptions: docs/error_estimate.md. It is NOT calibrated yet (see `calibration`).
#pragma once

#include <optional>
#include <string>
#include <string_view>

#include "proden/accumulator.hpp"
#include "proden/image.hpp"

namespace proden {

// How far one pass's random numbers reach: Cycles (scrambling distance 1) draws every pixel's
// samples independently (`pixel`); POV-Ray passes (samples/povray/proden_pass.inc) share one
// camera jitter, lens and light position for the whole image, and an unknown renderer may do the
// same (`frame`): then the frame holds only as many independent noise draws as it has passes.
enum class NoiseScope { pixel, frame };
std::string_view to_string(NoiseScope s);

// What the estimate needs besides the images.
struct ErrorContext {
  double spp = 0.0;  // samples per pixel of the render x (all passes)
  int passes = 0;
  VarianceSource variance_source = VarianceSource::between_passes;
  NoiseScope noise_scope = NoiseScope::frame;
  double confidence = 0.95;  // two-sided level of the intervals
};

// The images of one run (all RGB, same size). Without a denoised image (denoiser "none", a
// noise-free frame) the result is the render itself: denoised/alpha/sure stay null.
struct ErrorInputs {
  const Image* render = nullptr;    // x
  const Image* variance = nullptr;  // Var[x]
  const Image* result = nullptr;    // z (stands in for the reference in relMSE)
  const Image* denoised = nullptr;  // y
  const Image* alpha = nullptr;     // alpha (final)
  const Image* sure = nullptr;      // SURE(y)
  // Half-buffer cross-validation (docs/error_estimate.md, "Cross-validation"): the denoiser run on
  // each half alone, compared with the other, independent half. When set, they measure the
  // denoiser's error in place of SURE (which the features' noise biases low):
  const Image* cv_square = nullptr;    // ((y_A - x_B)^2 + (y_B - x_A)^2) / 2
  const Image* cv_variance = nullptr;  // (Var[x_A] + Var[x_B]) / 2
  // A linear denoiser's (Denoiser::linear) half runs' variance beyond the full run's,
  // (1/2 - w_A w_B) (y_A - y_B)^2 with w_h the halves' shares of the samples: when set, the
  // denoiser's error is exactly cv_square - cv_variance - cv_spread (no kHalfToFullMse).
  const Image* cv_spread = nullptr;
  // Without cross-validation (one pass): the denoiser's SURE is known to be biased low (NFOR's
  // and the cascade's hat diagonal, docs/error_estimate.md), so nothing bounds the estimate from
  // above and no target is met on it.
  bool sure_unbounded = false;
};

// MSE of a filter's output at the frame's samples per MSE of the same filter on half of them:
// 1/2 where its error is all variance (falls as 1/spp), 1 where it is all bias; 1/sqrt(2), the
// geometric middle, is within sqrt(2) of either (docs/error_estimate.md, "Cross-validation").
inline constexpr double kHalfToFullMse = 0.70710678118654752;

// The model's own error, as a factor on both ends of the published interval (low / band,
// high x band): what the statistics above do not see (the stand-in's window, the part all
// passes share, the half-to-full bracket). Measured on the evaluation scenes from 8 spp
// (bench/RESULTS.md, "Farm integration: calibration"): the render's 95 % intervals held the
// truth in 47 of 116 cells, NL-means' in 77; with 1.25, 116 and 110 (docs/error_estimate.md).
inline constexpr double kModelBand = 1.25;

// One element's (pixel and channel's) estimated squared error of z = x + a (y - x), split as the
// estimate's model splits it (docs/error_estimate.md, "The model"): `scaled` is proportional to
// the variance estimate, `measured` is not, `floor` = (1-a)^2 Var[x]. With the denoiser's own MSE
// m:
//   e = (1-a) v + a m - a (1-a) d^2,  d = y - x,
// m = SURE(y) (sure_error), or (cv_square - cv_variance) kHalfToFullMse (cv_error), or for a
// linear denoiser cv_square - cv_variance - cv_spread (cv_error with a spread). Non-finite
// inputs count as 0, as the pipeline's stages see them.
struct ElementError {
  double scaled = 0.0, measured = 0.0, floor = 0.0;
  double value() const { return scaled + measured; }
};
ElementError render_error(double v);  // denoiser "none": e = Var[x]
ElementError sure_error(double v, double a, double d, double sure);
ElementError cv_error(double v, double a, double d, double cv_square, double cv_variance,
                      std::optional<double> cv_spread = std::nullopt);

struct EstimatedError {
  // Point estimates (mean over pixels and RGB). mse is max(mean e, mean (1-a)^2 Var[x]) (the
  // mean of Var[x] without a denoised image).
  double mse = 0.0;
  double relmse = 0.0;          // mean of e / (z^2 + 0.01)
  double equivalent_spp = 0.0;  // spp * render_relmse / relmse
  double render_relmse = 0.0;   // relMSE of the render x itself (plain MC at `spp`)
  double spp = 0.0;
  // Bounds of the `confidence` interval; nullopt = unbounded (a single pass: the variance
  // itself is a guess). Low bounds are >= 0.
  double mse_low = 0.0, relmse_low = 0.0, equivalent_spp_low = 0.0;
  std::optional<double> mse_high, relmse_high, equivalent_spp_high;
  double confidence = 0.95;
  std::optional<double> dof;  // effective degrees of freedom of the variance scale (nullopt: 0)
  double sampling_rse = 0.0;  // relative standard error of the pixel average of the MSE terms
  // False when the error terms average below zero (SURE far below zero): the value is then the
  // floor and has no upper bound (mse_high, relmse_high unbounded, equivalent_spp_low 0).
  bool consistent = true;
  NoiseScope noise_scope = NoiseScope::frame;
  std::string source = "variance";   // "variance" | "variance+sure" | "variance+cross-validation"
  std::string calibration = "none";  // what calibrated the model ("none": raw pipeline numbers)
  double model_band = 1.0;           // the factor the interval's ends were widened by (kModelBand)
};

// Computes the estimate (docs/error_estimate.md): the per-pixel error terms of the result split
// into a part that scales with the variance and a part that does not; the variance scale's
// interval from its effective degrees of freedom (chi-square), widened by the standard error of
// the pixel average (from neighbouring pixels' differences), then by kModelBand at both ends.
// Throws std::invalid_argument on missing or mismatched images.
EstimatedError estimate_error(const ErrorInputs& in, const ErrorContext& ctx);

// Target test with confidence: relmse_high <= target (an unbounded high never meets it).
bool meets_relmse(const EstimatedError& e, double target);
// equivalent_spp_low >= target.
bool meets_equivalent_spp(const EstimatedError& e, double target);
// The opposite, with confidence: relmse_low > target / equivalent_spp_high < target.
bool misses_relmse(const EstimatedError& e, double target);
bool misses_equivalent_spp(const EstimatedError& e, double target);

}  // namespace proden

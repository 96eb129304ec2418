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
};

struct EstimatedError {
  // Point estimates (mean over pixels and RGB). mse equals estimated_result_mse() (or the mean of
  // Var[x] without a denoised image).
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
  std::string source = "variance";   // "variance" | "variance+sure"
  std::string calibration = "none";  // what calibrated the model ("none": raw pipeline numbers)
};

// Computes the estimate (docs/error_estimate.md): the per-pixel error terms of the result split
// into a part that scales with the variance and a part that does not; the variance scale's
// interval from its effective degrees of freedom (chi-square), widened by the standard error of
// the pixel average (from neighbouring pixels' differences). Throws std::invalid_argument on
// missing or mismatched images.
EstimatedError estimate_error(const ErrorInputs& in, const ErrorContext& ctx);

// Target test with confidence: relmse_high <= target (an unbounded high never meets it).
bool meets_relmse(const EstimatedError& e, double target);
// equivalent_spp_low >= target.
bool meets_equivalent_spp(const EstimatedError& e, double target);
// The opposite, with confidence: relmse_low > target / equivalent_spp_high < target.
bool misses_relmse(const EstimatedError& e, double target);
bool misses_equivalent_spp(const EstimatedError& e, double target);

}  // namespace proden

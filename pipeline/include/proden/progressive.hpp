// The progressive denoising pipeline over one frame (Firmino, Frisvad & Jensen 2022):
// denoise x into y, estimate SURE, mix with a per-pixel alpha, shrink alpha with the t-test,
// compose z = x + alpha' (y - x). Runs in tiles (in parallel) with a halo equal to the stages'
// summed footprints, so a tiled run equals the whole-image run.
#pragma once

#include <memory>
#include <string>

#include "proden/accumulator.hpp"
#include "proden/denoise/denoiser.hpp"
#include "proden/denoise/gaussian.hpp"
#include "proden/denoise/nlmeans.hpp"
#include "proden/mixer.hpp"
#include "proden/sure.hpp"
#include "proden/tstat.hpp"

namespace proden {

enum class DivergenceMethod {
  automatic,  // analytic when the denoiser offers its Jacobian diagonal, else Monte Carlo
  analytic,
  monte_carlo,
};

enum class BuiltinDenoiser { nlmeans, gaussian };

struct PipelineOptions {
  BuiltinDenoiser denoiser = BuiltinDenoiser::nlmeans;  // used when no denoiser is passed
  NlMeansParams nlmeans;
  float gaussian_sigma = 2.0f;
  bool features = true;  // let the denoiser use albedo/normal/depth when present
  DivergenceMethod divergence = DivergenceMethod::automatic;
  MonteCarloProbes probes;
  ClosedFormParams mixer;        // used when no mixer is passed
  int variance_pool_radius = 2;  // mixer and t-test read Var[x] averaged over (2r+1)^2
  bool t_test = true;
  TTestParams ttest;
  int tile = 256;  // inner tile size in pixels
};

// CPU seconds per stage (thread CPU time, summed over tiles: with N busy threads they add up to
// about N x wall), and the wall time of the whole run.
struct StageTimings {
  double denoise = 0, sure = 0, mixer = 0, ttest = 0, compose = 0;
  double wall = 0;
};

struct PipelineResult {
  Image result;        // z
  Image denoised;      // y
  Image alpha;         // alpha' (after the t-test, or the mixer's alpha with t_test off)
  Image sure;          // SURE of y
  Image mix_variance;  // Var[x] as the mixer and t-test read it (pooled over (2r+1)^2)
  StageTimings timings;
  std::string denoiser, mixer, divergence;
  Layout inputs;  // what the denoiser actually used
  int halo = 0;
  bool noise_free = false;  // Var[x] == 0 everywhere: nothing to denoise, z = x
};

// Views of a frame for a denoiser: `colour` and `variance` (the frame's own or sanitised copies,
// which must outlive the result) and, with `features`, the frame's feature means and variances.
DenoiseInputs denoise_inputs(const FrameEstimate& frame, const Image& colour, const Image& variance,
                             bool features);

// Mean squared error of the result z = x + alpha (y - x) estimated from the pipeline's own
// numbers, no reference: SURE of z with alpha held fixed, per pixel and channel
// (1 - a) var + a SURE(y) - a (1 - a) (y - x)^2 (it keeps the x-y covariance, div, that
// (1-a)^2 var + a^2 SURE drops), averaged without per-pixel clamping; the frame mean is floored
// at mean (1-a)^2 var (MSE(z) >= that when div >= 0).
double estimated_result_mse(const Image& x, const Image& variance, const PipelineResult& r);

// Halo the tiles need for these stages.
int pipeline_halo(const Denoiser& denoiser, const Mixer& mixer, const PipelineOptions& options);

// Runs the pipeline. `denoiser`/`mixer` default to NL-means and the closed-form mixer.
PipelineResult run_pipeline(const FrameEstimate& frame, const PipelineOptions& options,
                            const Denoiser* denoiser = nullptr, const Mixer* mixer = nullptr);

}  // namespace proden

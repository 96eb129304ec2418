// The progressive denoising pipeline over one frame (Firmino, Frisvad & Jensen 2022) as one
// validated object with Open Image Denoise's filter lifecycle: set options, commit() checks them
// and builds the stages once (denoiser, mixer, network), execute() runs per frame on scratch it
// keeps. Stages: denoise x into y, estimate SURE, mix with a per-pixel alpha, shrink alpha with the
// t-test, compose z = x + alpha' (y - x). The denoiser and SURE run over the frame in halo-free
// tiles, then the mixer and t-test in tiles with a halo derived from the built stages, so a tiled
// run equals the whole-image run (docs/pipeline.md).
#pragma once

#include <cstdint>
#include <memory>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "proden/accumulator.hpp"
#include "proden/denoise/cascade.hpp"
#include "proden/denoise/denoiser.hpp"
#include "proden/denoise/gaussian.hpp"
#include "proden/denoise/nfor.hpp"
#include "proden/denoise/nlmeans.hpp"
#include "proden/error_estimate.hpp"
#include "proden/mixer.hpp"
#include "proden/network/builtin.hpp"
#include "proden/sure.hpp"
#include "proden/tstat.hpp"

namespace proden {

enum class DivergenceMethod {
  automatic,  // analytic when the denoiser offers its Jacobian diagonal, else Monte Carlo
  analytic,
  monte_carlo,
};

enum class MixerKind { closed_form, network };

// The mixer used when none is asked for (network::kDefaultMixer, chosen on validation scenes).
inline constexpr MixerKind kDefaultMixerKind = std::string_view(network::kDefaultMixer) == "network"
                                                   ? MixerKind::network
                                                   : MixerKind::closed_form;
// The denoiser used when none is asked for ("auto").
inline constexpr std::string_view kDefaultDenoiser = "nlmeans";
// The denoiser name that runs no stage at all: the published result is the render x.
inline constexpr std::string_view kNoDenoiser = "none";

// Every option of the pipeline by one name: errors name it, and the front ends map it to their
// spelling (CLI flag, the job's `pipeline.<key>`; protocol/pipeline_spec.hpp).
enum class PipelineOption {
  denoiser,
  mixer,
  closed_form_rule,
  mixer_radius,
  weights,
  divergence,
  probes,
  t_test,
  ttest_dof,
  ttest_fine,
  features,
  tile,
  search_radius,
  patch_radius,
  gaussian_sigma,
  variance_pool_radius,
};
// "denoiser", "closed_form_rule", ...: the option's key.
std::string_view option_key(PipelineOption option);

// An option the pipeline cannot use; what() is "<key>: <message>". `key` is option_key() of a
// PipelineOption, or the name of an option that does not exist (a front end's parse).
class PipelineError : public std::invalid_argument {
 public:
  PipelineError(PipelineOption option, const std::string& message);
  PipelineError(std::string key, const std::string& message);
  const std::string& key() const { return key_; }
  const std::string& message() const { return message_; }

 private:
  std::string key_;
  std::string message_;
};

struct PipelineOptions {
  std::string denoiser{kDefaultDenoiser};  // a registered denoiser (denoisers()) or "none"
  NlMeansParams nlmeans;
  NforParams nfor;        // NFOR's parameters (docs/nfor.md); it reads the half buffers
  CascadeParams cascade;  // the NL-means + NFOR cascade's blend (docs/cascade.md)
  float gaussian_sigma = 2.0f;
  bool features = true;  // let the denoiser use albedo/normal/depth when present
  DivergenceMethod divergence = DivergenceMethod::automatic;
  MonteCarloProbes probes;
  MixerKind mixer = kDefaultMixerKind;
  ClosedFormParams closed_form;  // the closed-form mixer's parameters
  // The learned mixer's weights as `.pdnw` bytes (parsed by commit()); empty = the built-in ones.
  // `weights_source` names them in errors and in the output (e.g. the file they came from).
  std::vector<unsigned char> weights;
  std::string weights_source;
  int variance_pool_radius = 2;  // mixer and t-test read Var[x] averaged over (2r+1)^2
  bool t_test = true;
  TTestParams ttest;
  // A second t-test at a fine, fixed scale (Gaussian sigma 1 over 5x5), after the authors' one:
  // their window grows flat (sigma = 100 sqrt(var)) exactly where the render is noisy, so a
  // denoiser that smears a caustic within it keeps the window's mean and passes; the fine test
  // compares the render and the mix pixel by pixel (docs/cascade.md).
  bool ttest_fine = true;
  TTestParams ttest_fine_params{.radius = 2, .sigma_scale = 0.0f, .sigma_floor = 1.0f};
  int tile = 256;  // inner tile size in pixels
};

// The denoiser registry: adding a denoiser to proden is one entry here (progressive.cpp); the CLI's
// --denoiser and the job's pipeline.denoiser accept every registered name.
struct DenoiserEntry {
  std::string_view name;
  std::string_view summary;  // one line, for help texts
  std::unique_ptr<const Denoiser> (*make)(const PipelineOptions&);
  // What it reads of the frame: albedo/normal/depth (`features`), the half buffers (`halves`).
  EstimateOptions (*reads)(const PipelineOptions&);
};
std::span<const DenoiserEntry> denoisers();
const DenoiserEntry* find_denoiser(std::string_view name);

// Layer names of a published frame (docs/api.md): "result" is the frame's own R,G,B; the others
// are written as `<name>.R/G/B`.
namespace layer {
inline constexpr std::string_view result = "result";
inline constexpr std::string_view render = "render";             // x, the accumulated mean
inline constexpr std::string_view variance = "variance";         // Var[x]
inline constexpr std::string_view denoised = "denoised";         // y
inline constexpr std::string_view alpha = "alpha";               // alpha' (final mixing weight)
inline constexpr std::string_view sure = "sure";                 // SURE of y
inline constexpr std::string_view mix_variance = "mixvariance";  // Var[x] as mixer/t-test read it
// The error estimate's cross-validation (docs/error_estimate.md): PipelineResult::cv_square,
// cv_variance, cv_spread.
inline constexpr std::string_view cv_square = "cvsquare";
inline constexpr std::string_view cv_variance = "cvvariance";
inline constexpr std::string_view cv_spread = "cvspread";
}  // namespace layer
// All of them, "result" first.
std::span<const std::string_view> layer_names();

// Where an estimated error comes from: Var[x] alone (nothing denoised), or Var[x] and SURE(y).
namespace error_source {
inline constexpr std::string_view variance = "variance";
inline constexpr std::string_view variance_sure = "variance+sure";
}  // namespace error_source

// The pipeline's own estimate of the result's error (no reference): proden::EstimatedError of
// error_estimate.hpp (MSE, relMSE, equivalent spp, each with an interval), computed by
// estimate_error() at the end of Pipeline::execute.

// CPU seconds per stage (thread CPU time, summed over tiles: with N busy threads they add up to
// about N x wall; a whole-frame denoiser's stages count their wall time), and the wall time of the
// whole run.
struct StageTimings {
  double denoise = 0, sure = 0, mixer = 0, ttest = 0, compose = 0;
  double cross_validation = 0;  // the error estimate's denoiser run on half A (CPU s)
  double wall = 0;
};

struct PipelineResult {
  Image result;        // z
  Image render;        // x as accumulated
  Image variance;      // Var[x]
  Image denoised;      // y (empty with denoiser "none")
  Image alpha;         // alpha' (after the t-test, or the mixer's alpha with t_test off)
  Image sure;          // SURE of y
  Image mix_variance;  // Var[x] as the mixer and t-test read it (pooled over (2r+1)^2)
  // The filter run on each half against the other half's render: ((y_A - x_B)^2 + (y_B - x_A)^2)
  // / 2 and (Var[x_A] + Var[x_B]) / 2, what the estimated error measured the denoiser's error
  // with (empty when it used SURE; docs/error_estimate.md, "Cross-validation").
  Image cv_square, cv_variance;
  // A linear denoiser's (Denoiser::linear) (1/2 - w_A w_B) (y_A - y_B)^2, w_h the halves' shares of
  // the samples: how much more variance the half runs have than the full run (empty otherwise;
  // docs/error_estimate.md, "A linear denoiser").
  Image cv_spread;
  // The estimated error (docs/error_estimate.md): the mean over pixels and RGB of
  // (1-a) Var[x] + a m - a (1-a) (y-x)^2 with m the denoiser's error (cross-validated between the
  // halves, else SURE), floored at the mean of (1-a)^2 Var[x]; the mean of Var[x] when nothing
  // was denoised.
  EstimatedError estimated_error;
  StageTimings timings;
  std::string denoiser, mixer, divergence;  // what ran ("none" for stages that did not)
  std::string mixer_weights = "none";       // the network's weights source, if it mixed
  bool t_test = false;
  Layout inputs;  // what the run used: the denoiser's features, the renderer's variance
  int halo = 0;
  bool noise_free = false;  // Var[x] == 0 everywhere: nothing to denoise, z = x

  // The layers besides the result, in layer_names() order, without the empty ones.
  std::vector<std::pair<std::string_view, const Image*>> layers() const;
};

// Views of a frame for a denoiser: `colour` and `variance` (the frame's own or sanitised copies,
// which must outlive the result) and, with `features`, the frame's feature means and variances.
DenoiseInputs denoise_inputs(const FrameEstimate& frame, const Image& colour, const Image& variance,
                             bool features);

class Pipeline {
 public:
  Pipeline();
  explicit Pipeline(PipelineOptions options);  // sets the options; commit() before execute()
  ~Pipeline();
  Pipeline(Pipeline&&) noexcept;
  Pipeline& operator=(Pipeline&&) noexcept;

  // Replaces the options; the pipeline must be committed again before it executes.
  void set_options(PipelineOptions options);
  const PipelineOptions& options() const { return options_; }
  // A denoiser object to use instead of the registry's options().denoiser (an adapter around an
  // external program, or a test's variant); null returns to the registry.
  void set_denoiser(std::shared_ptr<const Denoiser> denoiser);

  // Validates the options (PipelineError names the first bad one) and builds the stages; the
  // tile halo follows from the built stages. On error the pipeline stays uncommitted.
  void commit();
  bool committed() const { return committed_; }

  // Runs the pipeline on one frame. Throws std::logic_error if not committed since the options
  // last changed, std::invalid_argument if the frame has no RGB mean and variance. Not reentrant:
  // one execute() at a time per Pipeline (it runs tiles in parallel itself).
  // `error` says what the error estimate needs besides the images (spp, passes, the renderer's
  // noise scope; the variance source comes from `frame`). Without it (spp 0) equivalent_spp is 0.
  PipelineResult execute(const FrameEstimate& frame, const ErrorContext& error = {});

  // After commit(): the built stages (null when not used: denoiser "none"), the halo, the names.
  const Denoiser* denoiser() const { return denoiser_.get(); }
  const Mixer* mixer() const { return mixer_.get(); }
  int halo() const { return halo_; }
  // What execute() needs of the accumulated frame (FrameAccumulator::estimate's options): the
  // features only if the denoiser reads them, the half buffers only if it does.
  EstimateOptions estimate_options() const { return reads_; }
  // Bytes of scratch the pipeline keeps between runs (frame-sized copies and per-thread tiles).
  std::size_t scratch_bytes() const;

 private:
  struct Scratch;
  PipelineOptions options_;
  std::shared_ptr<const Denoiser> custom_denoiser_;
  bool committed_ = false;
  std::shared_ptr<const Denoiser> denoiser_;
  std::unique_ptr<const Mixer> mixer_;
  std::string mixer_weights_ = "none";
  bool analytic_ = false;
  EstimateOptions reads_{.halves = false, .features = false};
  // The error estimate cross-validates the denoiser on each half against the other; a denoiser
  // that reads the halves itself (NFOR) runs on a half with its quarters as its halves, and keeps
  // SURE while the frame has no quarters (docs/error_estimate.md).
  bool cross_validate_ = false;
  bool cv_quarters_ = false;
  int halo_ = 0;
  std::unique_ptr<Scratch> scratch_;
};

}  // namespace proden

#include "proden/progressive.hpp"

#include <tbb/combinable.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <ctime>
#include <functional>
#include <stdexcept>
#include <vector>

#include "parallel.hpp"
#include "proden/network/pdnet.hpp"

namespace proden {
namespace detail {

// A denoiser's output over a region with what SURE needs: y, dy/dx (analytic divergence only),
// the divergence and SURE itself. Outside the anonymous namespace below because
// Pipeline::Scratch (external linkage) holds one.
struct Denoised {
  Buffer y, dydx, div, sure;
  std::size_t floats() const {
    return y.capacity() + dydx.capacity() + div.capacity() + sure.capacity();
  }
};

}  // namespace detail

namespace {

using detail::Denoised;
using Clock = std::chrono::steady_clock;

double seconds(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

// CPU time of the calling thread: per-stage costs stay meaningful on a loaded machine, where
// wall time would also count the time the thread waited for a core.
double thread_cpu() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

// Limits beyond which squares of differences would overflow float inside the stages.
constexpr float kMaxValue = 1e18f;
constexpr float kMaxVariance = 1e36f;
// GaussianDenoiser's supported sigmas (its radius 3 sigma must stay <= 64).
constexpr float kMaxGaussianSigma = 21.0f;

// Elements per task of the frame-wide element-wise passes around the stages.
constexpr std::size_t kElementGrain = std::size_t{1} << 16;

// `dst` shaped like `src`, keeping its allocation when it already is.
void shape_like(const Image& src, Image& dst) {
  if (!dst.same_size(src) || dst.channels() != src.channels()) {
    dst = Image(src.width(), src.height(), src.channels());
  }
}

// Copies `src` into `dst` (reusing dst's allocation when the size matches) with non-finite values
// set to 0 and the rest clamped to [lo, hi].
inline float sanitized(float v, float lo, float hi) {
  return std::isfinite(v) ? std::clamp(v, lo, hi) : 0.0f;
}
void sanitize_into(const Image& src, float lo, float hi, Image& dst) {
  shape_like(src, dst);
  const auto s = src.data();
  const auto d = dst.data();
  parallel_chunks(s.size(), kElementGrain, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) d[i] = sanitized(s[i], lo, hi);
  });
}

// Var[x] as the denoiser's weights read it when it is estimated between passes (docs/pipeline.md,
// "Few passes"): max(own, pooled), into `out`.
void weights_variance(const Image& own, const Image& pooled, Image& out) {
  shape_like(own, out);
  const auto v = own.data();
  const auto p = pooled.data();
  const auto o = out.data();
  parallel_chunks(o.size(), kElementGrain, [&](std::size_t b, std::size_t e) {
    for (std::size_t i = b; i < e; ++i) o[i] = std::max(v[i], p[i]);
  });
}

bool all_zero(const Image& img) {
  const auto d = img.data();
  return std::all_of(d.begin(), d.end(), [](float v) { return v == 0.0f; });
}

// Covers the frame with stages 1-2's buffers (dy/dx only for the analytic divergence).
void reset_full(Denoised& d, const Rect& image, bool analytic) {
  d.y.reset(image, 3);
  d.dydx.reset(analytic ? image : Rect{}, 3);
  d.div.reset(image, 3);
  d.sure.reset(image, 3);
}

// Stage 1 over `region` (the buffers cover it): y and, for the analytic divergence, the Jacobian
// diagonal.
void run_denoiser(const Denoiser& denoiser, const DenoiseInputs& din, const Rect& region,
                  bool analytic, Denoised& d) {
  denoiser.denoise(din, region, d.y, analytic ? &d.dydx : nullptr);
}

// Stage 2 over `region` (the buffers cover it): the divergence (from the Jacobian diagonal, or
// Monte-Carlo probes that re-run the denoiser) and SURE, both from `variance`, each pixel's own
// unbiased Var[x] (the denoiser's weights may read another: docs/pipeline.md, "Few passes").
void run_sure(const Denoiser& denoiser, const DenoiseInputs& din, const View& variance,
              const Rect& region, bool analytic, const MonteCarloProbes& probes, Denoised& d) {
  if (analytic) {
    divergence_from_derivative(variance, d.dydx, region, d.div);
  } else {
    divergence_monte_carlo(denoiser, din, region, d.y, probes, d.div);
    if (variance.data != din.variance.data) {
      // The probes draw b ~ N(0, din.variance), so they estimate dy/dx * din.variance.
      for (int c = 0; c < 3; ++c) {
        for (int py = region.y0; py < region.y1; ++py) {
          for (int px = region.x0; px < region.x1; ++px) {
            const float vw = din.variance.at(px, py, c);
            d.div.at(px, py, c) *= vw > 0.0f ? variance.at(px, py, c) / vw : 0.0f;
          }
        }
      }
    }
  }
  sure(din.colour, variance, d.y, d.div, region, d.sure);
}

[[noreturn]] void fail(PipelineOption option, const std::string& message) {
  throw PipelineError(option, message);
}

// The registry. A new denoiser is one more entry: its name, a line of help, how to build it from
// the options, and what it reads of the frame (features, half buffers).
const DenoiserEntry kDenoisers[] = {
    {"nlmeans", "feature-guided non-local means with its exact Jacobian",
     [](const PipelineOptions& o) -> std::unique_ptr<const Denoiser> {
       NlMeansParams p = o.nlmeans;
       p.use_features = p.use_features && o.features;
       return std::make_unique<NlMeansDenoiser>(p);
     },
     [](const PipelineOptions& o) {
       return EstimateOptions{.halves = false, .features = o.features && o.nlmeans.use_features};
     }},
    {"nfor", "NFOR, first-order regression on the features (Bitterli et al. 2016, docs/nfor.md)",
     [](const PipelineOptions& o) -> std::unique_ptr<const Denoiser> {
       NforParams p = o.nfor;
       p.use_features = p.use_features && o.features;
       return std::make_unique<NforDenoiser>(p);
     },
     // NFOR regresses each half on the other half's weights (§5.1-5.3): it needs the halves.
     [](const PipelineOptions& o) {
       return EstimateOptions{.halves = true, .features = o.features && o.nfor.use_features};
     }},
    {"cascade",
     "NL-means and NFOR blended per pixel by NL-means' SURE against their difference "
     "(docs/cascade.md)",
     [](const PipelineOptions& o) -> std::unique_ptr<const Denoiser> {
       NlMeansParams nl = o.nlmeans;
       nl.use_features = nl.use_features && o.features;
       NforParams nf = o.nfor;
       nf.use_features = nf.use_features && o.features;
       return std::make_unique<CascadeDenoiser>(nl, nf, o.cascade);
     },
     // It runs NFOR, which reads the half buffers, and both read the features.
     [](const PipelineOptions& o) {
       return EstimateOptions{
           .halves = true,
           .features = o.features && (o.nlmeans.use_features || o.nfor.use_features)};
     }},
    {"gaussian", "a Gaussian blur: fast, biased at edges",
     [](const PipelineOptions& o) -> std::unique_ptr<const Denoiser> {
       return std::make_unique<GaussianDenoiser>(o.gaussian_sigma);
     },
     [](const PipelineOptions&) { return EstimateOptions{.halves = false, .features = false}; }},
};

constexpr std::array<std::string_view, 10> kLayerNames = {
    layer::result, layer::render,       layer::variance,  layer::denoised,    layer::alpha,
    layer::sure,   layer::mix_variance, layer::cv_square, layer::cv_variance, layer::cv_spread,
};

}  // namespace

std::string_view option_key(PipelineOption option) {
  switch (option) {
    case PipelineOption::denoiser:
      return "denoiser";
    case PipelineOption::mixer:
      return "mixer";
    case PipelineOption::closed_form_rule:
      return "closed_form_rule";
    case PipelineOption::mixer_radius:
      return "mixer_radius";
    case PipelineOption::weights:
      return "weights";
    case PipelineOption::divergence:
      return "divergence";
    case PipelineOption::probes:
      return "probes";
    case PipelineOption::t_test:
      return "t_test";
    case PipelineOption::ttest_dof:
      return "ttest_dof";
    case PipelineOption::ttest_fine:
      return "ttest_fine";
    case PipelineOption::features:
      return "features";
    case PipelineOption::tile:
      return "tile";
    case PipelineOption::search_radius:
      return "search_radius";
    case PipelineOption::patch_radius:
      return "patch_radius";
    case PipelineOption::gaussian_sigma:
      return "gaussian_sigma";
    case PipelineOption::variance_pool_radius:
      return "variance_pool_radius";
  }
  return "?";
}

PipelineError::PipelineError(PipelineOption option, const std::string& message)
    : PipelineError(std::string(option_key(option)), message) {}

PipelineError::PipelineError(std::string key, const std::string& message)
    : std::invalid_argument(key + ": " + message), key_(std::move(key)), message_(message) {}

std::span<const DenoiserEntry> denoisers() {
  return kDenoisers;
}

const DenoiserEntry* find_denoiser(std::string_view name) {
  for (const auto& e : kDenoisers) {
    if (e.name == name) return &e;
  }
  return nullptr;
}

std::span<const std::string_view> layer_names() {
  return kLayerNames;
}

std::vector<std::pair<std::string_view, const Image*>> PipelineResult::layers() const {
  using Named = std::pair<std::string_view, const Image*>;
  const std::array<Named, 9> all = {
      Named{layer::render, &render},       Named{layer::variance, &variance},
      Named{layer::denoised, &denoised},   Named{layer::alpha, &alpha},
      Named{layer::sure, &sure},           Named{layer::mix_variance, &mix_variance},
      Named{layer::cv_square, &cv_square}, Named{layer::cv_variance, &cv_variance},
      Named{layer::cv_spread, &cv_spread}};
  std::vector<Named> out;
  for (const auto& named : all) {
    if (!named.second->empty()) out.push_back(named);
  }
  return out;
}

DenoiseInputs denoise_inputs(const FrameEstimate& frame, const Image& colour, const Image& variance,
                             bool features) {
  DenoiseInputs din;
  din.width = colour.width();
  din.height = colour.height();
  din.colour = view_of(colour);
  din.variance = view_of(variance);
  if (features) {
    din.albedo = view_of(frame.albedo);
    din.normal = view_of(frame.normal);
    din.depth = view_of(frame.depth);
    din.albedo_variance = view_of(frame.albedo_variance);
    din.normal_variance = view_of(frame.normal_variance);
    din.depth_variance = view_of(frame.depth_variance);
  }
  for (std::size_t h = 0; h < 2; ++h) {
    din.half_colour[h] = view_of(frame.half_mean[h]);
    din.half_variance[h] = view_of(frame.half_variance[h]);
    if (features) {
      din.half_albedo[h] = view_of(frame.half_albedo[h]);
      din.half_normal[h] = view_of(frame.half_normal[h]);
      din.half_depth[h] = view_of(frame.half_depth[h]);
    }
  }
  return din;
}

// What execute() reuses from run to run: frame-sized copies of the inputs, the denoiser's outputs
// over the frame, and each worker thread's tile buffers.
struct Pipeline::Scratch {
  struct Tile {
    Buffer alpha, alpha_final, alpha_coarse, z;
    std::size_t floats() const {
      return alpha.capacity() + alpha_final.capacity() + alpha_coarse.capacity() + z.capacity();
    }
  };
  Image x, var, box_tmp;  // sanitised x and Var[x], the box filter's pass
  Image var_weights;      // Var[x] as the denoiser's weights read it
  Denoised full;          // stages 1-2 over the frame
  // The error estimate's cross-validation, per half: x_h and Var[x_h] sanitised, Var[x_h] pooled
  // and as the weights read it, and y_h.
  struct Half {
    Image x, var, pooled, var_w;
    Buffer y;
    std::size_t floats() const {
      return x.data().size() + var.data().size() + pooled.data().size() + var_w.data().size() +
             y.capacity();
    }
  };
  Half cv;  // one half at a time
  tbb::enumerable_thread_specific<Tile> tiles;

  std::size_t bytes() const {
    std::size_t floats = x.data().size() + var.data().size() + box_tmp.data().size() +
                         var_weights.data().size() + full.floats() + cv.floats();
    for (const Tile& t : tiles) floats += t.floats();
    return floats * sizeof(float);
  }
};

Pipeline::Pipeline() : scratch_(std::make_unique<Scratch>()) {}
Pipeline::Pipeline(PipelineOptions options) : Pipeline() {
  options_ = std::move(options);
}
Pipeline::~Pipeline() = default;
Pipeline::Pipeline(Pipeline&& other) noexcept {
  *this = std::move(other);
}

Pipeline& Pipeline::operator=(Pipeline&& other) noexcept {
  options_ = std::move(other.options_);
  custom_denoiser_ = std::move(other.custom_denoiser_);
  committed_ = other.committed_;
  denoiser_ = std::move(other.denoiser_);
  mixer_ = std::move(other.mixer_);
  mixer_weights_ = std::move(other.mixer_weights_);
  analytic_ = other.analytic_;
  reads_ = other.reads_;
  cross_validate_ = other.cross_validate_;
  cv_quarters_ = other.cv_quarters_;
  halo_ = other.halo_;
  scratch_ = std::move(other.scratch_);
  other.committed_ = false;  // its stages are gone: it must be set up and committed again
  return *this;
}

void Pipeline::set_options(PipelineOptions options) {
  options_ = std::move(options);
  committed_ = false;
}

void Pipeline::set_denoiser(std::shared_ptr<const Denoiser> denoiser) {
  custom_denoiser_ = std::move(denoiser);
  committed_ = false;
}

std::size_t Pipeline::scratch_bytes() const {
  return scratch_ ? scratch_->bytes() : 0;
}

void Pipeline::commit() {
  committed_ = false;
  const PipelineOptions& o = options_;
  // Options every stage relies on, checked whether or not the stage will run.
  if (o.tile < 1) fail(PipelineOption::tile, "must be >= 1");
  if (o.variance_pool_radius < 0) fail(PipelineOption::variance_pool_radius, "must be >= 0");
  if (o.closed_form.radius < 0) fail(PipelineOption::mixer_radius, "must be >= 0");
  if (o.nlmeans.search_radius < 0) fail(PipelineOption::search_radius, "must be >= 0");
  if (o.nlmeans.patch_radius < 0) fail(PipelineOption::patch_radius, "must be >= 0");
  if (o.probes.count < 1) fail(PipelineOption::probes, "must be >= 1");
  if (!(o.probes.epsilon > 0.0f) || !std::isfinite(o.probes.epsilon)) {
    fail(PipelineOption::probes, "the probe step epsilon must be a positive number");
  }
  if (!(o.gaussian_sigma > 0.0f) || o.gaussian_sigma > kMaxGaussianSigma) {
    fail(PipelineOption::gaussian_sigma, "must be in (0, 21]");
  }
  if (o.t_test && (o.ttest.radius < 0 || o.ttest.radius > kTTestMaxRadius)) {
    fail(PipelineOption::t_test,
         "the window radius must be in [0, " + std::to_string(kTTestMaxRadius) + "]");
  }
  if (o.t_test && o.variance_pool_radius > kTTestMaxRadius) {
    fail(PipelineOption::variance_pool_radius,
         "must be <= " + std::to_string(kTTestMaxRadius) + " with the t-test");
  }
  if (o.t_test && o.ttest_fine && o.ttest_fine_params.radius > o.ttest.radius) {
    fail(PipelineOption::ttest_fine, "its window must not be wider than the t-test's");
  }
  if (!o.weights.empty() && o.mixer != MixerKind::network) {
    fail(PipelineOption::weights, "weights are for the network mixer (mixer network)");
  }

  // The t-test's rejection curve is tabulated once per (t0, slope) per process: now, not in the
  // first frame.
  if (o.t_test && o.ttest.dof_correction) {
    try {
      RejectionCurve::shared(o.ttest.t0, o.ttest.slope);
    } catch (const std::invalid_argument& e) {
      fail(PipelineOption::t_test, e.what());
    }
  }

  // The stages, built into locals so a failure leaves nothing half-built.
  std::shared_ptr<const Denoiser> denoiser;
  std::unique_ptr<const Mixer> mixer;
  std::string weights_source = "none";
  bool analytic = false;
  EstimateOptions reads{.halves = false, .features = false};
  if (custom_denoiser_) {
    denoiser = custom_denoiser_;
    reads.features = o.features;
  } else if (o.denoiser != kNoDenoiser) {
    const DenoiserEntry* entry = find_denoiser(o.denoiser);
    if (!entry) {
      std::string known;
      for (const auto& e : denoisers()) known += std::string(e.name) + ", ";
      fail(PipelineOption::denoiser, "unknown denoiser '" + o.denoiser + "' (one of " + known +
                                         std::string(kNoDenoiser) + ")");
    }
    try {
      denoiser = entry->make(o);
    } catch (const std::invalid_argument& e) {  // a parameter the denoiser itself refuses
      fail(PipelineOption::denoiser, o.denoiser + ": " + e.what());
    }
    reads = entry->reads(o);
  }
  if (denoiser) {
    analytic = o.divergence == DivergenceMethod::analytic ||
               (o.divergence == DivergenceMethod::automatic && denoiser->has_derivative());
    if (analytic && !denoiser->has_derivative()) {
      fail(PipelineOption::divergence, "denoiser " + denoiser->name() +
                                           " has no Jacobian diagonal for the analytic divergence");
    }
    if (o.mixer == MixerKind::network) {
      std::shared_ptr<const network::PdNet> net;
      const std::string source = o.weights_source.empty() ? "weights" : o.weights_source;
      try {
        net = o.weights.empty() ? network::builtin_network()
                                : std::make_shared<const network::PdNet>(
                                      network::parse_weights(o.weights, source), source);
      } catch (const network::WeightsError& e) {
        fail(PipelineOption::weights, e.what());
      }
      weights_source = net->source();
      mixer = std::make_unique<network::NetworkMixer>(std::move(net));
    } else {
      mixer = std::make_unique<ClosedFormMixer>(o.closed_form);
    }
  }

  denoiser_ = std::move(denoiser);
  mixer_ = std::move(mixer);
  mixer_weights_ = std::move(weights_source);
  analytic_ = analytic;
  // The error estimate's cross-validation needs the half buffers, and a denoiser that reads the
  // halves itself needs their own halves, the quarters (docs/error_estimate.md).
  cross_validate_ = denoiser_ != nullptr;
  cv_quarters_ = cross_validate_ && reads.halves;
  if (cross_validate_) reads.halves = true;
  reads.quarters = cv_quarters_;
  reads_ = reads;
  // The halo: what each mixer + t-test tile reads around itself of the full-frame y and SURE.
  // The denoiser adds nothing: it runs over the whole frame (or in halo-free tiles) first.
  halo_ = 0;
  if (denoiser_) halo_ = mixer_->radius() + (o.t_test ? o.ttest.radius : 0);
  committed_ = true;
}

PipelineResult Pipeline::execute(const FrameEstimate& frame, const ErrorContext& error_in) {
  const auto t_start = Clock::now();
  if (!committed_) {
    throw std::logic_error("Pipeline::execute: commit() the options before executing");
  }
  if (frame.mean.empty() || frame.mean.channels() != 3 || !frame.variance.same_size(frame.mean) ||
      frame.variance.channels() != 3) {
    throw std::invalid_argument("Pipeline::execute: the frame has no RGB mean/variance");
  }
  const PipelineOptions& o = options_;
  const int W = frame.mean.width(), H = frame.mean.height();
  if (!scratch_) scratch_ = std::make_unique<Scratch>();  // a moved-from pipeline, re-committed
  Scratch& s = *scratch_;

  ErrorContext error = error_in;
  error.variance_source = frame.variance_source;
  PipelineResult res;
  res.render = frame.mean;
  res.variance = frame.variance;
  res.inputs.variance = frame.variance_source == VarianceSource::renderer;
  res.halo = halo_;
  res.denoiser = std::string(kNoDenoiser);
  res.mixer = "none";
  res.divergence = "none";

  if (!denoiser_) {  // denoiser "none": publish the render; its own error is Var[x]
    res.result = frame.mean;
    res.estimated_error = estimate_error({&frame.mean, &frame.variance, &res.result}, error);
    res.timings.wall = seconds(t_start, Clock::now());
    return res;
  }
  const Denoiser& denoiser = *denoiser_;
  const Mixer& mixer = *mixer_;
  res.denoiser = denoiser.name();
  res.mixer = mixer.name();
  res.mixer_weights = mixer_weights_;
  res.divergence = analytic_ ? "analytic" : "monte-carlo";
  res.t_test = o.t_test;

  sanitize_into(frame.mean, -kMaxValue, kMaxValue, s.x);
  sanitize_into(frame.variance, 0.0f, kMaxVariance, s.var);
  const Image& x = s.x;
  const Image& var = s.var;
  // The mixer and the t-test judge x's error from a spatially pooled variance: with few passes a
  // pixel's own estimate is heavy-tailed (most pixels of a caustic never saw its fireflies).
  pool_variance(var, o.variance_pool_radius, s.box_tmp, res.mix_variance);

  // Simulate only what the frame calls for: a noise-free frame has nothing to denoise.
  if (all_zero(var)) {
    res.noise_free = true;
    res.result = x;
    res.denoised = x;
    res.alpha = Image(W, H, 3, 0.0f);
    res.sure = Image(W, H, 3, 0.0f);
    res.estimated_error = estimate_error({&x, &var, &res.result}, error);
    res.timings.wall = seconds(t_start, Clock::now());
    return res;
  }
  res.result = Image(W, H, 3);
  res.denoised = Image(W, H, 3);
  res.alpha = Image(W, H, 3);
  res.sure = Image(W, H, 3);

  // With few passes a pixel's own Var[x] has K - 1 degrees of freedom and often comes out far
  // too low, and the filter then keeps its noise: when the variance is estimated (between passes,
  // or the one-pass spatial fallback) the denoiser's weights read max(own, pooled). An outlier (a
  // firefly) keeps its own, so its neighbours still take a share of its energy instead of it
  // being averaged away. An exact variance (the renderer's, or pass counts unknown) is read as
  // is. SURE and the divergence read the pixel's own, unbiased estimate (docs/pipeline.md,
  // "Few passes").
  const bool estimated_variance =
      frame.variance_source != VarianceSource::renderer && frame.passes.same_size(frame.mean);
  const Image* var_weights = &var;
  if (estimated_variance) {
    weights_variance(var, res.mix_variance, s.var_weights);
    var_weights = &s.var_weights;
  }
  const DenoiseInputs din = denoise_inputs(frame, x, *var_weights, reads_.features);
  res.inputs.albedo = reads_.features && din.albedo.valid();
  res.inputs.normal = reads_.features && din.normal.valid();
  res.inputs.depth = reads_.features && din.depth.valid();

  const Rect image{0, 0, W, H};
  const int T = o.tile;
  const int tiles_x = (W + T - 1) / T, tiles_y = (H + T - 1) / T;
  const auto tile_rect = [&](int t) {
    const int x0 = (t % tiles_x) * T, y0 = (t / tiles_x) * T;
    return Rect{x0, y0, std::min(x0 + T, W), std::min(y0 + T, H)};
  };
  struct Times {
    double denoise = 0, sure = 0, mixer = 0, ttest = 0, compose = 0;
  };
  tbb::combinable<Times> times;

  // Stages 1-2, y, the divergence and SURE, over the whole frame into s.full, which the mixer and
  // t-test tiles below read, halos included: no pixel is denoised twice (issue 12's fast path; a
  // tile used to re-denoise a halo of the mixer's and the t-test's radii, 30 pixels with the
  // default mixer: 1.52x the pixels at 256). A whole-frame denoiser runs once (wall time: it may
  // parallelise internally); a local one in halo-free tiles, each writing only its own pixels (CPU
  // time summed over tiles).
  reset_full(s.full, image, analytic_);
  if (denoiser.whole_frame()) {
    const auto w0 = Clock::now();
    run_denoiser(denoiser, din, image, analytic_, s.full);
    const auto w1 = Clock::now();
    run_sure(denoiser, din, view_of(var), image, analytic_, o.probes, s.full);
    res.timings.denoise += seconds(w0, w1);
    res.timings.sure += seconds(w1, Clock::now());
  } else {
    tbb::parallel_for(0, tiles_x * tiles_y, [&](int t) {
      tbb::this_task_arena::isolate([&] {
        Times& tm = times.local();
        const Rect tile = tile_rect(t);
        const double t0 = thread_cpu();
        run_denoiser(denoiser, din, tile, analytic_, s.full);
        const double t1 = thread_cpu();
        run_sure(denoiser, din, view_of(var), tile, analytic_, o.probes, s.full);
        tm.denoise += t1 - t0;
        tm.sure += thread_cpu() - t1;
      });
    });
  }

  const int t_pad = o.t_test ? o.ttest.radius : 0;
  const View pooled = view_of(res.mix_variance);
  // What the mixer and the t-test need to know of the variance's degrees of freedom.
  const VarianceOrigin origin{frame.passes.same_size(frame.mean) ? view_of(frame.passes) : View{},
                              frame.variance_source == VarianceSource::renderer,
                              o.variance_pool_radius, view_of(var)};

  // One tile's stages 3-5. They use this thread's scratch, so a thread must not start another tile
  // while one is in flight: isolate() keeps any parallel work a stage waits on from lending the
  // thread to this loop's other tiles.
  const auto run_tile = [&](int t) {
    Times& tm = times.local();
    Scratch::Tile& b = s.tiles.local();
    const Rect tile = tile_rect(t);
    const Rect r_mix = tile.expanded(t_pad).intersect(image);  // alpha needed here
    const View y = s.full.y.view(), div = s.full.div.view(), sure_v = s.full.sure.view();
    const double t2 = thread_cpu();

    const MixInputs mi{W, H, din.colour, y, pooled, sure_v, div, origin};
    b.alpha.reset(r_mix, 3);
    mixer.mix(mi, r_mix, b.alpha);
    const double t3 = thread_cpu();

    b.alpha_final.reset(tile, 3);
    if (o.t_test) {
      b.z.reset(r_mix, 3);
      for (int c = 0; c < 3; ++c) {
        for (int py = r_mix.y0; py < r_mix.y1; ++py) {
          for (int px = r_mix.x0; px < r_mix.x1; ++px) {
            const float xv = x.at(px, py, c);
            b.z.at(px, py, c) = xv + b.alpha.at(px, py, c) * (y.at(px, py, c) - xv);
          }
        }
      }
      if (o.ttest_fine) {
        // The authors' test, then the fine one on the same mix (docs/cascade.md).
        b.alpha_coarse.reset(tile, 3);
        t_rescale(din.colour, pooled, b.z.view(), b.alpha.view(), W, H, tile, o.ttest,
                  b.alpha_coarse, origin);
        TTestParams fine = o.ttest_fine_params;
        fine.dof_correction = o.ttest.dof_correction;
        t_rescale(din.colour, pooled, b.z.view(), b.alpha_coarse.view(), W, H, tile, fine,
                  b.alpha_final, origin);
      } else {
        t_rescale(din.colour, pooled, b.z.view(), b.alpha.view(), W, H, tile, o.ttest,
                  b.alpha_final, origin);
      }
    } else {
      for (int c = 0; c < 3; ++c) {
        for (int py = tile.y0; py < tile.y1; ++py) {
          for (int px = tile.x0; px < tile.x1; ++px) {
            b.alpha_final.at(px, py, c) = b.alpha.at(px, py, c);
          }
        }
      }
    }
    const double t4 = thread_cpu();

    for (int c = 0; c < 3; ++c) {
      for (int py = tile.y0; py < tile.y1; ++py) {
        for (int px = tile.x0; px < tile.x1; ++px) {
          const float xv = x.at(px, py, c);
          const float yv = y.at(px, py, c);
          const float a = b.alpha_final.at(px, py, c);
          // Written as a convex combination so z stays within [min(x, y), max(x, y)].
          float z = (1.0f - a) * xv + a * yv;
          z = std::clamp(z, std::min(xv, yv), std::max(xv, yv));
          res.result.at(px, py, c) = z;
          res.denoised.at(px, py, c) = yv;
          res.alpha.at(px, py, c) = a;
          res.sure.at(px, py, c) = sure_v.at(px, py, c);
        }
      }
    }
    const double t5 = thread_cpu();
    tm.mixer += t3 - t2;
    tm.ttest += t4 - t3;
    tm.compose += t5 - t4;
  };
  tbb::parallel_for(0, tiles_x * tiles_y,
                    [&](int t) { tbb::this_task_arena::isolate([&] { run_tile(t); }); });

  times.combine_each([&](const Times& tm) {
    res.timings.denoise += tm.denoise;
    res.timings.sure += tm.sure;
    res.timings.mixer += tm.mixer;
    res.timings.ttest += tm.ttest;
    res.timings.compose += tm.compose;
  });
  // Error of z = x + a (y - x) from the pipeline's own estimates, with its interval: the
  // denoiser's error cross-validated between the halves where they exist, else SURE.
  ErrorInputs ein{&x, &var, &res.result, &res.denoised, &res.alpha, &res.sure};
  // A denoiser that reads the halves has only its hat-diagonal SURE when it is not
  // cross-validated (one pass: no halves): biased low, so it bounds nothing.
  ein.sure_unbounded = cv_quarters_;
  const bool have_quarters = std::all_of(frame.quarter_mean.begin(), frame.quarter_mean.end(),
                                         [](const Image& q) { return !q.empty(); });
  if (cross_validate_ && !frame.half_mean[0].empty() && !frame.half_mean[1].empty()) {
    // The denoiser on each half alone, as it would run on a frame of that half's passes: x_h
    // with its own Var[x_h] (read by the weights as the full run reads its own: max(own,
    // pooled)) and its own feature means; the feature variances stay the full frame's (measured
    // choice, docs/error_estimate.md). The other half is independent of all of it. No Jacobian.
    // Per element (docs/error_estimate.md, "Cross-validation"): each half's denoised image
    // against the other half's render, E[(y_A - x_B)^2] = MSE(y_A) + Var[x_B], averaged over the
    // two directions: cv = ((y_A - x_B)^2 + (y_B - x_A)^2) / 2, cv_var = (v_A + v_B) / 2.
    res.cv_square = Image(W, H, 3, 0.0f);
    res.cv_variance = Image(W, H, 3, 0.0f);
    if (denoiser.linear()) res.cv_spread = Image(W, H, 3, 0.0f);
    for (int h = 0; h < 2; ++h) {
      Scratch::Half& hs = s.cv;
      sanitize_into(frame.half_mean[h], -kMaxValue, kMaxValue, hs.x);
      sanitize_into(frame.half_variance[h], 0.0f, kMaxVariance, hs.var);
      const auto qv = res.cv_variance.data();
      const auto vh = hs.var.data();
      parallel_chunks(qv.size(), kElementGrain, [&](std::size_t b, std::size_t e) {
        for (std::size_t i = b; i < e; ++i) qv[i] += 0.5f * vh[i];
      });
      const Image* weights = &hs.var;
      if (estimated_variance) {
        pool_variance(hs.var, o.variance_pool_radius, s.box_tmp, hs.pooled);
        weights_variance(hs.var, hs.pooled, hs.var_w);
        weights = &hs.var_w;
      }
      DenoiseInputs dh = denoise_inputs(frame, hs.x, *weights, reads_.features);
      for (std::size_t k = 0; k < 2; ++k) {
        // The half's own halves are its quarters (a denoiser that reads halves; else none, and
        // such a denoiser runs without halves: NFOR's single-buffer mode, docs/error_estimate.md).
        const std::size_t q = 2 * static_cast<std::size_t>(h) + k;
        const bool quarters = cv_quarters_ && have_quarters;
        dh.half_colour[k] = quarters ? view_of(frame.quarter_mean[q]) : View{};
        dh.half_variance[k] = quarters ? view_of(frame.quarter_variance[q]) : View{};
        const bool qf = quarters && reads_.features;
        dh.half_albedo[k] = qf ? view_of(frame.quarter_albedo[q]) : View{};
        dh.half_normal[k] = qf ? view_of(frame.quarter_normal[q]) : View{};
        dh.half_depth[k] = qf ? view_of(frame.quarter_depth[q]) : View{};
      }
      if (reads_.features) {  // the half's own feature means
        if (!frame.half_albedo[h].empty()) dh.albedo = view_of(frame.half_albedo[h]);
        if (!frame.half_normal[h].empty()) dh.normal = view_of(frame.half_normal[h]);
        if (!frame.half_depth[h].empty()) dh.depth = view_of(frame.half_depth[h]);
      }
      hs.y.reset(image, 3);
      if (denoiser.whole_frame()) {
        const double t0 = thread_cpu();
        denoiser.denoise(dh, image, hs.y, nullptr);
        res.timings.cross_validation += thread_cpu() - t0;
      } else {
        tbb::combinable<double> cpu;
        tbb::parallel_for(0, tiles_x * tiles_y, [&](int t) {
          tbb::this_task_arena::isolate([&] {
            const double t0 = thread_cpu();
            denoiser.denoise(dh, tile_rect(t), hs.y, nullptr);
            cpu.local() += thread_cpu() - t0;
          });
        });
        res.timings.cross_validation += cpu.combine(std::plus<double>());
      }
      const Image& other = frame.half_mean[static_cast<std::size_t>(1 - h)];
      tbb::parallel_for(0, 3 * H, [&](int row) {
        const int c = row / H, py = row % H;
        const float* xo = other.plane(c).data() + static_cast<std::size_t>(py) * W;
        float* q = res.cv_square.plane(c).data() + static_cast<std::size_t>(py) * W;
        const float* yh = hs.y.row(py, c);
        for (int px = 0; px < W; ++px) {
          const double d = static_cast<double>(yh[px]) - sanitized(xo[px], -kMaxValue, kMaxValue);
          q[px] = static_cast<float>(std::min(q[px] + 0.5 * d * d, double{kMaxVariance}));
        }
        if (!denoiser.linear()) return;
        // A linear filter's bias is the same in both half runs, so they differ only by their
        // noise: E[(y_A - y_B)^2] = Var[y_A] + Var[y_B]. Of that, cv_square holds one half, and
        // the full run keeps w_A w_B of it, w_h the halves' shares of the samples (Var[x_h] is one
        // per-sample variance over each half's own samples, so w_A w_B = v_A v_B / (v_A + v_B)^2).
        // cv_spread keeps y_A until half B's run, then the difference (docs/error_estimate.md).
        float* sp = res.cv_spread.plane(c).data() + static_cast<std::size_t>(py) * W;
        if (h == 0) {
          std::copy(yh, yh + W, sp);
          return;
        }
        const float* va = frame.half_variance[0].plane(c).data() + static_cast<std::size_t>(py) * W;
        const float* vb = frame.half_variance[1].plane(c).data() + static_cast<std::size_t>(py) * W;
        for (int px = 0; px < W; ++px) {
          const double a = sanitized(va[px], 0.0f, kMaxVariance);
          const double b = sanitized(vb[px], 0.0f, kMaxVariance);
          const double share = a + b > 0.0 ? a * b / ((a + b) * (a + b)) : 0.25;
          const double d = static_cast<double>(sp[px]) - yh[px];
          sp[px] = static_cast<float>(std::min((0.5 - share) * d * d, double{kMaxVariance}));
        }
      });
    }
    ein.cv_square = &res.cv_square;
    ein.cv_variance = &res.cv_variance;
    if (!res.cv_spread.empty()) ein.cv_spread = &res.cv_spread;
  }
  res.estimated_error = estimate_error(ein, error);
  res.timings.wall = seconds(t_start, Clock::now());
  return res;
}

}  // namespace proden

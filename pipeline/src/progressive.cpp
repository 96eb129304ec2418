#include "proden/progressive.hpp"

#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <ctime>
#include <stdexcept>
#include <vector>

namespace proden {
namespace {

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

Image sanitized(const Image& img, float lo, float hi) {
  Image out = img;
  for (float& v : out.data()) v = std::isfinite(v) ? std::clamp(v, lo, hi) : 0.0f;
  return out;
}

bool all_zero(const Image& img) {
  const auto d = img.data();
  return std::all_of(d.begin(), d.end(), [](float v) { return v == 0.0f; });
}

}  // namespace

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
  return din;
}

double estimated_result_mse(const Image& x, const Image& variance, const PipelineResult& r) {
  const auto xv = x.data(), vv = variance.data(), yv = r.denoised.data(), av = r.alpha.data(),
             sv = r.sure.data();
  const std::size_t n = std::min({xv.size(), vv.size(), yv.size(), av.size(), sv.size()});
  if (n == 0) return 0.0;
  double sum = 0.0, floor = 0.0;
  for (std::size_t i = 0; i < n; ++i) {
    const double a = av[i], d = static_cast<double>(yv[i]) - xv[i];
    sum += (1.0 - a) * vv[i] + a * sv[i] - a * (1.0 - a) * d * d;
    floor += (1.0 - a) * (1.0 - a) * vv[i];
  }
  // Per-pixel clamping would bias the mean up (interior: 4-5x); the unclamped mean can go below
  // what the render's share alone contributes when SURE is biased low (noisy features correlated
  // with x's noise), so it is floored there: MSE(z) >= (1-a)^2 var when div >= 0.
  return std::max(sum, floor) / static_cast<double>(n);
}

int pipeline_halo(const Denoiser& denoiser, const Mixer& mixer, const PipelineOptions& options) {
  return denoiser.radius() + mixer.radius() + (options.t_test ? options.ttest.radius : 0);
}

PipelineResult run_pipeline(const FrameEstimate& frame, const PipelineOptions& options,
                            const Denoiser* denoiser_in, const Mixer* mixer_in) {
  const auto t_start = Clock::now();
  if (frame.mean.empty() || frame.mean.channels() != 3 || !frame.variance.same_size(frame.mean)) {
    throw std::invalid_argument("run_pipeline: the frame has no RGB mean/variance");
  }
  if (options.tile < 1) throw std::invalid_argument("run_pipeline: tile must be >= 1");
  const int W = frame.mean.width(), H = frame.mean.height();

  NlMeansParams nlp = options.nlmeans;
  nlp.use_features = nlp.use_features && options.features;
  const NlMeansDenoiser nlmeans(nlp);
  const GaussianDenoiser gaussian(options.gaussian_sigma);
  const ClosedFormMixer closed(options.mixer);
  const Denoiser& builtin = options.denoiser == BuiltinDenoiser::gaussian
                                ? static_cast<const Denoiser&>(gaussian)
                                : static_cast<const Denoiser&>(nlmeans);
  const Denoiser& denoiser = denoiser_in ? *denoiser_in : builtin;
  const Mixer& mixer = mixer_in ? *mixer_in : closed;

  PipelineResult res;
  res.denoiser = denoiser.name();
  res.mixer = mixer.name();
  const bool analytic =
      options.divergence == DivergenceMethod::analytic ||
      (options.divergence == DivergenceMethod::automatic && denoiser.has_derivative());
  if (analytic && !denoiser.has_derivative()) {
    throw std::invalid_argument("run_pipeline: denoiser " + denoiser.name() +
                                " has no Jacobian diagonal for the analytic divergence");
  }
  res.divergence = analytic ? "analytic" : "monte-carlo";
  res.halo = pipeline_halo(denoiser, mixer, options);

  const Image x = sanitized(frame.mean, -kMaxValue, kMaxValue);
  const Image var = sanitized(frame.variance, 0.0f, kMaxVariance);
  // The mixer and the t-test judge x's error from a spatially pooled variance: with few passes a
  // pixel's own estimate is heavy-tailed (most pixels of a caustic never saw its fireflies).
  const Image var_pooled = pool_variance(var, options.variance_pool_radius);
  res.result = x;
  res.denoised = x;
  res.alpha = Image(W, H, 3, 0.0f);
  res.sure = Image(W, H, 3, 0.0f);
  res.mix_variance = var_pooled;

  // Simulate only what the frame calls for: a noise-free frame has nothing to denoise.
  if (all_zero(var)) {
    res.noise_free = true;
    res.timings.wall = seconds(t_start, Clock::now());
    return res;
  }

  // With few passes a pixel's own Var[x] has K - 1 degrees of freedom and often comes out far
  // too low, and the filter then keeps its noise: when the variance is estimated (between passes,
  // or the one-pass spatial fallback) the denoiser's weights read max(own, pooled). An outlier (a
  // firefly) keeps its own, so its neighbours still take a share of its energy instead of it
  // being averaged away. An exact variance (the renderer's, or pass counts unknown) is read as
  // is. SURE and the divergence read the pixel's own, unbiased estimate (docs/pipeline.md,
  // "Few passes").
  const bool estimated_variance =
      frame.variance_source != VarianceSource::renderer && frame.passes.same_size(frame.mean);
  Image var_weights = var;
  if (estimated_variance) {
    for (std::size_t i = 0; i < var_weights.data().size(); ++i) {
      var_weights.data()[i] = std::max(var_weights.data()[i], var_pooled.data()[i]);
    }
  }
  const DenoiseInputs din =
      denoise_inputs(frame, x, var_weights, options.features && nlp.use_features);
  // Only a denoiser that reads features makes them inputs of this run.
  const bool reads_features = &denoiser == &nlmeans;
  res.inputs = {reads_features && din.albedo.valid(), reads_features && din.normal.valid(),
                reads_features && din.depth.valid(), false};

  const Rect image{0, 0, W, H};
  const int T = options.tile;
  const int tiles_x = (W + T - 1) / T, tiles_y = (H + T - 1) / T;
  const int mix_pad = mixer.radius() + (options.t_test ? options.ttest.radius : 0);
  const int t_pad = options.t_test ? options.ttest.radius : 0;

  struct Times {
    double denoise = 0, sure = 0, mixer = 0, ttest = 0, compose = 0;
  };
  tbb::combinable<Times> times;

  tbb::parallel_for(0, tiles_x * tiles_y, [&](int t) {
    Times& tm = times.local();
    const Rect inner = Rect{(t % tiles_x) * T, (t / tiles_x) * T, 0, 0};
    const Rect tile{inner.x0, inner.y0, std::min(inner.x0 + T, W), std::min(inner.y0 + T, H)};
    const Rect r_den = tile.expanded(mix_pad).intersect(image);  // y, SURE needed here
    const Rect r_mix = tile.expanded(t_pad).intersect(image);    // alpha needed here

    const double t0 = thread_cpu();
    Buffer y(r_den, 3), dydx(r_den, 3), div(r_den, 3), sure_buf(r_den, 3);
    denoiser.denoise(din, r_den, y, analytic ? &dydx : nullptr);
    const double t1 = thread_cpu();
    if (analytic) {
      divergence_from_derivative(view_of(var), dydx, r_den, div);
    } else {
      // The probes draw b ~ N(0, var_weights), so they estimate dy/dx * var_weights.
      divergence_monte_carlo(denoiser, din, r_den, y, options.probes, div);
      if (estimated_variance) {
        for (int c = 0; c < 3; ++c) {
          for (int py = r_den.y0; py < r_den.y1; ++py) {
            for (int px = r_den.x0; px < r_den.x1; ++px) {
              const float vw = var_weights.at(px, py, c);
              div.at(px, py, c) *= vw > 0.0f ? var.at(px, py, c) / vw : 0.0f;
            }
          }
        }
      }
    }
    sure(din.colour, view_of(var), y, div, r_den, sure_buf);
    const double t2 = thread_cpu();

    const View pooled = view_of(var_pooled);
    const VarianceOrigin origin{frame.passes.same_size(frame.mean) ? view_of(frame.passes) : View{},
                                frame.variance_source == VarianceSource::renderer,
                                options.variance_pool_radius, view_of(var)};
    MixInputs mi{W, H, din.colour, y.view(), pooled, sure_buf.view(), div.view(), origin};
    Buffer alpha(r_mix, 3);
    mixer.mix(mi, r_mix, alpha);
    const double t3 = thread_cpu();

    Buffer alpha_final(tile, 3);
    if (options.t_test) {
      Buffer z(r_mix, 3);
      for (int c = 0; c < 3; ++c) {
        for (int py = r_mix.y0; py < r_mix.y1; ++py) {
          for (int px = r_mix.x0; px < r_mix.x1; ++px) {
            const float xv = x.at(px, py, c);
            z.at(px, py, c) = xv + alpha.at(px, py, c) * (y.at(px, py, c) - xv);
          }
        }
      }
      t_rescale(din.colour, pooled, z.view(), alpha.view(), W, H, tile, options.ttest, alpha_final,
                origin);
    } else {
      for (int c = 0; c < 3; ++c) {
        for (int py = tile.y0; py < tile.y1; ++py) {
          for (int px = tile.x0; px < tile.x1; ++px)
            alpha_final.at(px, py, c) = alpha.at(px, py, c);
        }
      }
    }
    const double t4 = thread_cpu();

    for (int c = 0; c < 3; ++c) {
      for (int py = tile.y0; py < tile.y1; ++py) {
        for (int px = tile.x0; px < tile.x1; ++px) {
          const float xv = x.at(px, py, c);
          const float yv = y.at(px, py, c);
          const float a = alpha_final.at(px, py, c);
          // Written as a convex combination so z stays within [min(x, y), max(x, y)].
          float z = (1.0f - a) * xv + a * yv;
          z = std::clamp(z, std::min(xv, yv), std::max(xv, yv));
          res.result.at(px, py, c) = z;
          res.denoised.at(px, py, c) = yv;
          res.alpha.at(px, py, c) = a;
          res.sure.at(px, py, c) = sure_buf.at(px, py, c);
        }
      }
    }
    const double t5 = thread_cpu();
    tm.denoise += t1 - t0;
    tm.sure += t2 - t1;
    tm.mixer += t3 - t2;
    tm.ttest += t4 - t3;
    tm.compose += t5 - t4;
  });

  times.combine_each([&](const Times& tm) {
    res.timings.denoise += tm.denoise;
    res.timings.sure += tm.sure;
    res.timings.mixer += tm.mixer;
    res.timings.ttest += tm.ttest;
    res.timings.compose += tm.compose;
  });
  res.timings.wall = seconds(t_start, Clock::now());
  return res;
}

}  // namespace proden

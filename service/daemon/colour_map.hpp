// How the daemon draws a published frame's layers for people (docs/api.md, "Images"): colour
// layers tone-mapped with an exposure, weights and errors through perceptual colour maps (errors
// on a log scale), box-filtered thumbnails, the result's per-pixel error. Pure image math.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "proden/image.hpp"

namespace proden::daemon {

// An 8-bit sRGB image, pixels interleaved R,G,B, rows top to bottom (what a PNG stores).
struct Rgb8 {
  int width = 0, height = 0;
  std::vector<std::uint8_t> data;
};

enum class ColourMap { viridis, magma };
enum class Scale { linear, log };

struct ScalarRange {
  double lo = 0.0, hi = 1.0;
  Scale scale = Scale::linear;
};

// How a layer is shown: tone-mapped colour (result, render, denoised), or one value per pixel
// (the mean over R,G,B) through a colour map: alpha linear over [0,1] with viridis; the errors
// (variance, mixvariance, sure, error) on a log scale with magma.
struct LayerView {
  bool colour = true;
  ColourMap map = ColourMap::viridis;
  Scale scale = Scale::linear;
};
LayerView layer_view(std::string_view layer);

std::string_view name(ColourMap map);
std::string_view name(Scale scale);
// The map's colour at t in [0,1] (clamped), as "#rrggbb"; `n` evenly spaced stops for a legend.
std::vector<std::string> colour_stops(ColourMap map, int n);

// Box-filter (area-average) reduction so that the longer side is at most `max_side` pixels;
// returns `img` unchanged when it already fits. Non-finite samples are left out of the average.
Image downscale(const Image& img, int max_side);

// Linear RGB -> 8-bit sRGB for viewing: scale by 2^exposure_ev, Reinhard x/(1+x) per channel,
// sRGB transfer. Non-finite and negative values show as 0. A 1-channel image is shown as grey.
Rgb8 tone_map(const Image& rgb, double exposure_ev);

// One value per pixel: the mean over the image's channels (non-finite channels count as 0).
std::vector<float> channel_mean(const Image& img);

// A log-scale range in whole decades covering the 1st..99th percentile of the positive finite
// values (at least one decade, at most eight); [1e-6, 1e-2] when there is none.
ScalarRange auto_log_range(std::span<const float> values);

// Maps values through `map` over `range`: linear t = (v-lo)/(hi-lo), log t = log(v/lo)/log(hi/lo);
// values below the range, zero/negative values on a log scale and non-finite values take the
// lowest colour, values above it the highest.
Rgb8 apply_colour_map(std::span<const float> values, int width, int height, ColourMap map,
                      const ScalarRange& range);

// The result's estimated squared error per pixel and channel, from the published layers: the
// summand of the frame's estimated error (proden::sure_error, or proden::cv_error when the
// cross-validation layers are given, with `cv_spread` for a linear denoiser:
// docs/error_estimate.md), floored per pixel at the render's
// share (1-a)^2 Var[x] so the map is positive where the estimate is (its mean can exceed the
// frame's estimated mse, which floors the mean instead).
Image result_error(const Image& render, const Image& variance, const Image& denoised,
                   const Image& alpha, const Image& sure, const Image* cv_square = nullptr,
                   const Image* cv_variance = nullptr, const Image* cv_spread = nullptr);

}  // namespace proden::daemon

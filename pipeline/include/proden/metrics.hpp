// Image error metrics over linear RGB against a reference (docs/pipeline.md, "Error
// metrics"): RMSE, relMSE, SMAPE.
#pragma once

#include <cstddef>

#include "proden/image.hpp"

namespace proden {

struct ErrorMetrics {
  double mse = 0.0;     // mean of (i - r)^2
  double rmse = 0.0;    // sqrt(mse)
  double relmse = 0.0;  // mean of (i - r)^2 / (r^2 + 0.01)
  double smape = 0.0;   // mean of |i - r| / (|i| + |r| + 0.01)
  // relMSE without its highest kRelMseTrim share of values: a few fireflies (glass: 1e3-1e4 per
  // value) otherwise decide the whole frame's relMSE, and the render's curve over spp stops being
  // monotone (bench/savings.py interpolates it).
  double relmse_trimmed = 0.0;
  std::size_t values = 0;     // channel values compared (finite in both images)
  std::size_t nonfinite = 0;  // channel values skipped because either image was NaN/Inf there
};

// The share of the largest per-value relative errors relmse_trimmed drops (0.1 %).
inline constexpr double kRelMseTrim = 1e-3;

// Compares the first three channels of `image` and `reference` (same size, >= 3 channels each;
// throws std::invalid_argument otherwise). Non-finite values are counted, not averaged.
ErrorMetrics compute_metrics(const Image& image, const Image& reference);

}  // namespace proden

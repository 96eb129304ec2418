#include "proden/metrics.hpp"

#include <cmath>
#include <stdexcept>

namespace proden {

ErrorMetrics compute_metrics(const Image& image, const Image& reference) {
  if (!image.same_size(reference) || image.channels() < 3 || reference.channels() < 3) {
    throw std::invalid_argument("compute_metrics: " + image.to_string() + " vs reference " +
                                reference.to_string() + " (need equal size, >= 3 channels)");
  }
  ErrorMetrics m;
  double se = 0.0, rel = 0.0, sm = 0.0;
  for (int c = 0; c < 3; ++c) {
    const auto ip = image.plane(c);
    const auto rp = reference.plane(c);
    for (std::size_t p = 0; p < ip.size(); ++p) {
      const double i = ip[p], r = rp[p];
      if (!std::isfinite(i) || !std::isfinite(r)) {
        ++m.nonfinite;
        continue;
      }
      const double d = i - r;
      se += d * d;
      rel += d * d / (r * r + 0.01);
      sm += std::abs(d) / (std::abs(i) + std::abs(r) + 0.01);
      ++m.values;
    }
  }
  if (m.values > 0) {
    const double n = static_cast<double>(m.values);
    m.mse = se / n;
    m.rmse = std::sqrt(m.mse);
    m.relmse = rel / n;
    m.smape = sm / n;
  }
  return m;
}

}  // namespace proden

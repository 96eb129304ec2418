#include "proden/metrics.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <vector>

namespace proden {

ErrorMetrics compute_metrics(const Image& image, const Image& reference) {
  if (!image.same_size(reference) || image.channels() < 3 || reference.channels() < 3) {
    throw std::invalid_argument("compute_metrics: " + image.to_string() + " vs reference " +
                                reference.to_string() + " (need equal size, >= 3 channels)");
  }
  ErrorMetrics m;
  double se = 0.0, rel = 0.0, sm = 0.0;
  std::vector<double> rels;
  rels.reserve(image.plane(0).size() * 3);
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
      const double rv = d * d / (r * r + 0.01);
      rel += rv;
      rels.push_back(rv);
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
    // Keep the smallest (1 - trim) share; partial sort, then sum in index order.
    const auto keep = static_cast<std::size_t>(std::llround(n * (1.0 - kRelMseTrim)));
    if (keep > 0 && keep < rels.size()) {
      std::nth_element(rels.begin(), rels.begin() + static_cast<std::ptrdiff_t>(keep), rels.end());
      rels.resize(keep);
    }
    double kept = 0.0;
    for (double v : rels) kept += v;
    m.relmse_trimmed = rels.empty() ? 0.0 : kept / static_cast<double>(rels.size());
  }
  return m;
}

}  // namespace proden

#include "proden/sure.hpp"

#include <cmath>

#include "proden/hash.hpp"

namespace proden {

float probe_normal(std::uint64_t seed, int probe, int x, int y, int c) {
  const std::int32_t key[4] = {probe, x, y, c};
  const std::uint64_t h = hash_span(std::span<const std::int32_t>(key), seed);
  // Box-Muller from two 24-bit uniforms in (0, 1].
  const double u1 = (static_cast<double>(h >> 40) + 1.0) / 16777216.0;
  const double u2 = static_cast<double>((h >> 16) & 0xFFFFFF) / 16777216.0;
  return static_cast<float>(std::sqrt(-2.0 * std::log(u1)) * std::cos(6.283185307179586 * u2));
}

void divergence_from_derivative(const View& variance, const Buffer& dydx, const Rect& region,
                                Buffer& div) {
  for (int c = 0; c < 3; ++c) {
    for (int y = region.y0; y < region.y1; ++y) {
      for (int x = region.x0; x < region.x1; ++x) {
        div.at(x, y, c) = dydx.at(x, y, c) * variance.at(x, y, c);
      }
    }
  }
}

void divergence_monte_carlo(const Denoiser& denoiser, const DenoiseInputs& in, const Rect& region,
                            const Buffer& y, const MonteCarloProbes& probes, Buffer& div) {
  const Rect src = region.expanded(denoiser.radius()).intersect({0, 0, in.width, in.height});
  Buffer perturbed(src, 3);
  Buffer yk(region, 3);
  for (int c = 0; c < 3; ++c) {
    for (int py = region.y0; py < region.y1; ++py) {
      for (int px = region.x0; px < region.x1; ++px) div.at(px, py, c) = 0.0f;
    }
  }
  const int K = probes.count > 0 ? probes.count : 1;
  for (int k = 0; k < K; ++k) {
    for (int c = 0; c < 3; ++c) {
      for (int py = src.y0; py < src.y1; ++py) {
        for (int px = src.x0; px < src.x1; ++px) {
          const float b =
              std::sqrt(in.variance.at(px, py, c)) * probe_normal(probes.seed, k, px, py, c);
          perturbed.at(px, py, c) = in.colour.at(px, py, c) + probes.epsilon * b;
        }
      }
    }
    DenoiseInputs pin = in;
    pin.colour = perturbed.view();
    denoiser.denoise(pin, region, yk, nullptr);
    for (int c = 0; c < 3; ++c) {
      for (int py = region.y0; py < region.y1; ++py) {
        for (int px = region.x0; px < region.x1; ++px) {
          const float b =
              std::sqrt(in.variance.at(px, py, c)) * probe_normal(probes.seed, k, px, py, c);
          div.at(px, py, c) += b * (yk.at(px, py, c) - y.at(px, py, c));
        }
      }
    }
  }
  const float scale = 1.0f / (probes.epsilon * static_cast<float>(K));
  for (int c = 0; c < 3; ++c) {
    for (int py = region.y0; py < region.y1; ++py) {
      for (int px = region.x0; px < region.x1; ++px) div.at(px, py, c) *= scale;
    }
  }
}

void sure(const View& x, const View& variance, const Buffer& y, const Buffer& div,
          const Rect& region, Buffer& out) {
  for (int c = 0; c < 3; ++c) {
    for (int py = region.y0; py < region.y1; ++py) {
      for (int px = region.x0; px < region.x1; ++px) {
        const float d = y.at(px, py, c) - x.at(px, py, c);
        out.at(px, py, c) = d * d - variance.at(px, py, c) + 2.0f * div.at(px, py, c);
      }
    }
  }
}

}  // namespace proden

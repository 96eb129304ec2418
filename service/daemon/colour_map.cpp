#include "daemon/colour_map.hpp"

#include "proden/error_estimate.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

namespace proden::daemon {

namespace {

#include "daemon/colour_map_tables.inc"

const unsigned char (*table(ColourMap map))[3] {
  return map == ColourMap::magma ? k_magma : k_viridis;
}

std::uint8_t to_byte(float v01) {
  return static_cast<std::uint8_t>(std::lround(std::clamp(v01, 0.0f, 1.0f) * 255.0f));
}

float srgb(float linear) {
  return linear <= 0.0031308f ? 12.92f * linear : 1.055f * std::pow(linear, 1.0f / 2.4f) - 0.055f;
}

}  // namespace

LayerView layer_view(std::string_view layer) {
  if (layer == "alpha") return {false, ColourMap::viridis, Scale::linear};
  if (layer == "variance" || layer == "mixvariance" || layer == "sure" || layer == "cvsquare" ||
      layer == "cvvariance" || layer == "cvspread" || layer == "error") {
    return {false, ColourMap::magma, Scale::log};
  }
  return {true, ColourMap::viridis, Scale::linear};
}

std::string_view name(ColourMap map) {
  return map == ColourMap::magma ? "magma" : "viridis";
}

std::string_view name(Scale scale) {
  return scale == Scale::log ? "log" : "linear";
}

std::vector<std::string> colour_stops(ColourMap map, int n) {
  std::vector<std::string> out;
  n = std::max(n, 2);
  for (int i = 0; i < n; ++i) {
    const int k = static_cast<int>(std::lround(255.0 * i / (n - 1)));
    const auto* c = table(map)[k];
    char buf[8];
    std::snprintf(buf, sizeof buf, "#%02x%02x%02x", c[0], c[1], c[2]);
    out.emplace_back(buf);
  }
  return out;
}

Image downscale(const Image& img, int max_side) {
  const int w = img.width(), h = img.height();
  if (img.empty() || max_side <= 0 || std::max(w, h) <= max_side) return img;
  const double f = static_cast<double>(std::max(w, h)) / max_side;
  const int ow = std::max(1, static_cast<int>(std::lround(w / f)));
  const int oh = std::max(1, static_cast<int>(std::lround(h / f)));
  Image out(ow, oh, img.channels());
  // Output pixel (ox, oy) averages source columns [ox*w/ow, (ox+1)*w/ow) (integer bounds: every
  // source pixel lands in exactly one output pixel).
  for (int c = 0; c < img.channels(); ++c) {
    const auto src = img.plane(c);
    auto dst = out.plane(c);
    for (int oy = 0; oy < oh; ++oy) {
      const int y0 = oy * h / oh, y1 = std::max(y0 + 1, (oy + 1) * h / oh);
      for (int ox = 0; ox < ow; ++ox) {
        const int x0 = ox * w / ow, x1 = std::max(x0 + 1, (ox + 1) * w / ow);
        double sum = 0.0;
        int n = 0;
        for (int y = y0; y < y1; ++y) {
          for (int x = x0; x < x1; ++x) {
            const float v = src[static_cast<std::size_t>(y) * w + x];
            if (std::isfinite(v)) {
              sum += v;
              ++n;
            }
          }
        }
        dst[static_cast<std::size_t>(oy) * ow + ox] = n ? static_cast<float>(sum / n) : 0.0f;
      }
    }
  }
  return out;
}

Rgb8 tone_map(const Image& rgb, double exposure_ev) {
  Rgb8 out{rgb.width(), rgb.height(), {}};
  const std::size_t n = rgb.pixels();
  out.data.resize(n * 3);
  const float scale = static_cast<float>(std::exp2(exposure_ev));
  for (int c = 0; c < 3; ++c) {
    const auto src = rgb.plane(std::min(c, rgb.channels() - 1));
    for (std::size_t p = 0; p < n; ++p) {
      float x = std::isfinite(src[p]) ? std::max(src[p], 0.0f) * scale : 0.0f;
      x = x / (1.0f + x);
      out.data[p * 3 + static_cast<std::size_t>(c)] = to_byte(srgb(x));
    }
  }
  return out;
}

std::vector<float> channel_mean(const Image& img) {
  std::vector<float> out(img.pixels(), 0.0f);
  if (img.channels() == 0) return out;
  for (int c = 0; c < img.channels(); ++c) {
    const auto p = img.plane(c);
    for (std::size_t i = 0; i < out.size(); ++i) {
      if (std::isfinite(p[i])) out[i] += p[i];
    }
  }
  const float inv = 1.0f / static_cast<float>(img.channels());
  for (float& v : out) v *= inv;
  return out;
}

ScalarRange auto_log_range(std::span<const float> values) {
  std::vector<float> pos;
  pos.reserve(values.size());
  for (float v : values) {
    if (std::isfinite(v) && v > 0.0f) pos.push_back(v);
  }
  ScalarRange r{1e-6, 1e-2, Scale::log};
  if (pos.empty()) return r;
  const auto at = [&](double q) {
    const auto k = static_cast<std::size_t>(q * static_cast<double>(pos.size() - 1));
    std::nth_element(pos.begin(), pos.begin() + static_cast<std::ptrdiff_t>(k), pos.end());
    return static_cast<double>(pos[k]);
  };
  const double p01 = at(0.01), p99 = at(0.99);
  // A value on a decade (1e-4 stored as a float) must not widen the range by a decade.
  double hi = std::ceil(std::log10(p99) - 1e-5);
  double lo = std::floor(std::log10(p01) + 1e-5);
  if (hi <= lo) hi = lo + 1.0;
  lo = std::max(lo, hi - 8.0);
  r.lo = std::pow(10.0, lo);
  r.hi = std::pow(10.0, hi);
  return r;
}

Rgb8 apply_colour_map(std::span<const float> values, int width, int height, ColourMap map,
                      const ScalarRange& range) {
  Rgb8 out{width, height, {}};
  const std::size_t n = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  out.data.resize(n * 3);
  const auto* lut = table(map);
  const bool log = range.scale == Scale::log;
  const double lo = log ? std::log(std::max(range.lo, 1e-300)) : range.lo;
  const double hi = log ? std::log(std::max(range.hi, 1e-300)) : range.hi;
  const double span = hi > lo ? hi - lo : 1.0;
  for (std::size_t p = 0; p < n && p < values.size(); ++p) {
    const double v = values[p];
    double t = 0.0;
    if (std::isfinite(v) && (!log || v > 0.0)) t = ((log ? std::log(v) : v) - lo) / span;
    const int k = static_cast<int>(std::lround(std::clamp(t, 0.0, 1.0) * 255.0));
    for (int c = 0; c < 3; ++c) out.data[p * 3 + static_cast<std::size_t>(c)] = lut[k][c];
  }
  return out;
}

Image result_error(const Image& render, const Image& variance, const Image& denoised,
                   const Image& alpha, const Image& sure, const Image* cv_square,
                   const Image* cv_variance, const Image* cv_spread) {
  Image out(render.width(), render.height(), render.channels());
  const auto x = render.data(), v = variance.data(), y = denoised.data(), a = alpha.data(),
             s = sure.data();
  const bool cv = cv_square && cv_variance && cv_square->data().size() == x.size() &&
                  cv_variance->data().size() == x.size();
  const bool spread = cv && cv_spread && cv_spread->data().size() == x.size();
  auto e = out.data();
  const std::size_t n = std::min({x.size(), v.size(), y.size(), a.size(), s.size()});
  for (std::size_t i = 0; i < n; ++i) {
    const double d = static_cast<double>(y[i]) - x[i];
    const ElementError el =
        cv ? cv_error(v[i], a[i], d, cv_square->data()[i], cv_variance->data()[i],
                      spread ? std::optional<double>(cv_spread->data()[i]) : std::nullopt)
           : sure_error(v[i], a[i], d, s[i]);
    e[i] = static_cast<float>(std::max(el.value(), el.floor));
  }
  return out;
}

}  // namespace proden::daemon

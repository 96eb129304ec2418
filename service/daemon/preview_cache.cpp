#include "daemon/preview_cache.hpp"

#include <cmath>
#include <cstdio>
#include <cstdlib>

#include <nlohmann/json.hpp>

#include "daemon/colour_map.hpp"
#include "daemon/files.hpp"
#include "daemon/processor.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/progressive.hpp"
#include "proden/protocol/api.hpp"

namespace proden::daemon {

namespace fs = std::filesystem;
using protocol::ApiError;

namespace {

constexpr int kMinSize = 8, kMaxSize = 4096;
constexpr double kMaxExposure = 20.0;

double parse_number(const std::string& s, const char* field) {
  std::size_t used = 0;
  double v = 0.0;
  try {
    v = std::stod(s, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used == 0 || used != s.size() || !std::isfinite(v)) {
    throw ApiError(400, "invalid_parameter", std::string(field) + " must be a finite number");
  }
  return v;
}

std::string fmt(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

// Reads the layers `error` is computed from; empty Image when one is missing.
Image read_error_layer(const std::string& exr) {
  const std::vector<Image> l = io::read_layers(
      exr, {"render", "variance", "denoised", "alpha", "sure", std::string(layer::cv_square),
            std::string(layer::cv_variance), std::string(layer::cv_spread)});
  const Image &x = l[0], &v = l[1], &y = l[2], &a = l[3], &s = l[4], &q = l[5], &qv = l[6],
              &sp = l[7];
  const auto fits = [&x](const Image& i) {
    return !i.empty() && i.same_size(x) && i.channels() == x.channels();
  };
  for (const Image* i : {&x, &v, &y, &a, &s}) {
    if (!fits(*i)) return {};
  }
  // The cross-validation layers, when the estimate used them (docs/error_estimate.md).
  if (!fits(q) || !fits(qv)) return result_error(x, v, y, a, s);
  return result_error(x, v, y, a, s, &q, &qv, fits(sp) ? &sp : nullptr);
}

}  // namespace

void PreviewCache::check_request(const std::string& format, const std::string& layer) {
  if (format != "exr" && format != "png") {
    throw ApiError(400, "invalid_parameter", "format must be exr or png");
  }
  if (!layer.empty() && !known_layer(layer) && layer != "error") {
    throw ApiError(400, "invalid_parameter", "layer must be one of " + known_layers() + ", error");
  }
}

PreviewCache::Request PreviewCache::Request::from_query(
    const std::map<std::string, std::string>& q) {
  Request r;
  if (auto it = q.find("format"); it != q.end()) r.format = it->second;
  if (auto it = q.find("layer"); it != q.end()) r.layer = it->second;
  check_request(r.format, r.layer);
  const bool png = r.format == "png";
  if (auto it = q.find("size"); it != q.end()) {
    const double s = parse_number(it->second, "size");
    if (!png || s != std::floor(s) || s < kMinSize || s > kMaxSize) {
      throw ApiError(400, "invalid_parameter", "size: an integer in [8, 4096], with format=png");
    }
    r.size = static_cast<int>(s);
  }
  if (auto it = q.find("exposure"); it != q.end()) {
    const double e = parse_number(it->second, "exposure");
    if (!png || std::abs(e) > kMaxExposure) {
      throw ApiError(400, "invalid_parameter", "exposure: EV in [-20, 20], with format=png");
    }
    r.exposure = std::round(e * 4.0) / 4.0;
  }
  if (auto it = q.find("range"); it != q.end()) {
    const auto comma = it->second.find(',');
    const LayerView view = layer_view(r.layer);
    if (!png || view.colour || comma == std::string::npos) {
      throw ApiError(400, "invalid_parameter",
                     "range: lo,hi for format=png of alpha, variance, mixvariance, sure or error");
    }
    const double lo = parse_number(it->second.substr(0, comma), "range");
    const double hi = parse_number(it->second.substr(comma + 1), "range");
    if (!(lo < hi) || (view.scale == Scale::log && lo <= 0.0)) {
      throw ApiError(400, "invalid_parameter", "range: lo < hi (and lo > 0 on a log scale)");
    }
    r.range = {lo, hi};
  }
  return r;
}

PreviewCache::File PreviewCache::get(const fs::path& cache_dir, const fs::path& exr, long frame,
                                     std::uint64_t version, const Request& req) {
  check_request(req.format, req.layer);
  if (req.format == "exr" && req.layer.empty()) {
    // Weak: the version's values never change, but its bytes do once the daemon compresses a
    // version published uncompressed (docs/api.md, output.compression auto).
    return {exr, "image/x-exr", "W/\"v" + std::to_string(version) + "\"", {}};
  }
  const std::string l = req.layer.empty() ? "result" : req.layer;
  const bool png = req.format == "png";
  const LayerView view = layer_view(l);
  const bool mapped = png && !view.colour;
  // Every parameter is in the name, so a name is made once; the stem clears old versions.
  const std::string stem = std::to_string(frame) + "." + l + ".";
  std::string variant = "v" + std::to_string(version);
  if (req.size) variant += ".s" + std::to_string(req.size);
  if (png && view.colour && req.exposure != 0.0) variant += ".e" + fmt(req.exposure);
  if (req.range) variant += ".r" + fmt(req.range->first) + "_" + fmt(req.range->second);
  const fs::path out = cache_dir / (stem + variant + "." + req.format);
  const fs::path meta = cache_dir / (stem + variant + ".json");
  File file{out, png ? "image/png" : "image/x-exr", "\"" + variant + "\"", {}};
  const auto add_headers = [&](const ScalarRange& r) {
    file.headers = {{"X-Proden-Colormap", std::string(name(view.map))},
                    {"X-Proden-Scale", std::string(name(r.scale))},
                    {"X-Proden-Range", fmt(r.lo) + " " + fmt(r.hi)}};
  };

  std::lock_guard lock(mu_);
  std::error_code ec;
  if (fs::exists(out, ec)) {
    if (!mapped) return file;
    if (auto m = read_file(meta, 4096)) {
      try {
        const auto j = nlohmann::json::parse(m->begin(), m->end());
        add_headers({j.at("lo").get<double>(), j.at("hi").get<double>(), view.scale});
        return file;
      } catch (const std::exception&) {  // remade below
      }
    }
  }
  Image img;
  try {
    img = l == "error" ? read_error_layer(exr.string())
                       : std::move(io::read_layers(exr.string(), {l}).front());
  } catch (const std::exception& e) {
    throw ApiError(500, "internal", e.what());
  }
  if (img.empty()) {
    throw ApiError(404, "layer_not_available", "layer " + l + " is not in the published frame");
  }
  fs::create_directories(cache_dir, ec);
  for (fs::directory_iterator it(cache_dir, ec), end; !ec && it != end; it.increment(ec)) {
    // Older versions' renditions go; this version's other variants (sizes, exposures) and newer
    // versions' stay (an older version asked for with ?version=K must not take the latest's).
    const std::string f = it->path().filename().string();
    if (f.rfind(stem + "v", 0) != 0) continue;
    const std::uint64_t v = std::strtoull(f.c_str() + stem.size() + 1, nullptr, 10);
    if (v < version) fs::remove(it->path(), ec);
  }
  if (req.size) img = downscale(img, req.size);
  if (!png) {
    std::vector<io::NamedChannel> ch;
    io::add_layer(ch, "", img);
    io::write_image(out.string(), img.width(), img.height(), ch);
    return file;
  }
  Rgb8 rgb;
  if (view.colour) {
    rgb = tone_map(img, req.exposure);
  } else {
    const std::vector<float> v = channel_mean(img);
    ScalarRange r =
        view.scale == Scale::log ? auto_log_range(v) : ScalarRange{0.0, 1.0, view.scale};
    if (req.range) r = {req.range->first, req.range->second, view.scale};
    rgb = apply_colour_map(v, img.width(), img.height(), view.map, r);
    write_file_atomic(meta, nlohmann::json{{"lo", r.lo}, {"hi", r.hi}}.dump());
    add_headers(r);
  }
  write_png(out.string(), rgb);
  return file;
}

}  // namespace proden::daemon

#include "daemon/preview_cache.hpp"

#include "daemon/processor.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/protocol/api.hpp"

namespace proden::daemon {

namespace fs = std::filesystem;
using protocol::ApiError;

void PreviewCache::check_request(const std::string& format, const std::string& layer) {
  if (format != "exr" && format != "png") {
    throw ApiError(400, "invalid_parameter", "format must be exr or png");
  }
  if (!layer.empty() && !known_layer(layer)) {
    throw ApiError(400, "invalid_parameter", "layer must be one of " + known_layers());
  }
}

PreviewCache::File PreviewCache::get(const fs::path& cache_dir, const fs::path& exr, long frame,
                                     std::uint64_t version, const std::string& format,
                                     const std::string& layer) {
  check_request(format, layer);
  if (format == "exr" && layer.empty()) return {exr, "image/x-exr"};
  const std::string l = layer.empty() ? "result" : layer;
  const std::string stem = std::to_string(frame) + "." + l + ".";
  const fs::path out = cache_dir / (stem + "v" + std::to_string(version) + "." + format);
  std::lock_guard lock(mu_);
  std::error_code ec;
  if (fs::exists(out, ec)) return {out, format == "png" ? "image/png" : "image/x-exr"};
  Image img;
  try {
    img = read_layer(exr.string(), l);
  } catch (const std::exception& e) {
    throw ApiError(500, "internal", e.what());
  }
  if (img.empty()) {
    throw ApiError(404, "layer_not_available", "layer " + l + " is not in the published frame");
  }
  fs::create_directories(cache_dir, ec);
  for (fs::directory_iterator it(cache_dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->path().filename().string().rfind(stem, 0) == 0) fs::remove(it->path(), ec);
  }
  if (format == "png") {
    write_png_preview(out.string(), img);
    return {out, "image/png"};
  }
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "", img);
  io::write_image(out.string(), img.width(), img.height(), ch);
  return {out, "image/x-exr"};
}

}  // namespace proden::daemon

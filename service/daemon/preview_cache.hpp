// PreviewCache: renditions of one layer of a published frame served by GET .../frames/{frame}/image
// (docs/api.md): PNGs for viewing (colour layers tone-mapped with an exposure, alpha and the errors
// colour-mapped, optionally reduced to a thumbnail) and single-layer EXRs, made on first request
// and kept per (frame, layer, version, parameters) in the job's cache directory; a new version
// replaces the old ones. The image math is in colour_map.hpp.
#pragma once

#include <cstdint>
#include <filesystem>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace proden::daemon {

class PreviewCache {
 public:
  // What is asked for (the image endpoint's query parameters).
  struct Request {
    std::string format = "exr";  // exr | png
    std::string layer;           // "" = the whole published EXR (exr) or the result (png)
    int size = 0;                // png: longest side in pixels (0 = full size)
    double exposure = 0.0;       // png colour layers: EV, in steps of 1/4
    std::optional<std::pair<double, double>> range;  // png alpha/error layers: the map's range
    // Validates the query (format, layer, size, exposure, range); throws protocol::ApiError 400.
    static Request from_query(const std::map<std::string, std::string>& query);
  };
  struct File {
    std::filesystem::path path;
    std::string content_type;
    std::string etag;  // changes with the version and the parameters
    // X-Proden-Colormap, X-Proden-Scale, X-Proden-Range for colour-mapped layers.
    std::vector<std::pair<std::string, std::string>> headers;
  };
  // Throws protocol::ApiError 400 for an unknown format or layer.
  static void check_request(const std::string& format, const std::string& layer);

  // The file to serve for `request` of version `version` of a frame published as `exr`. Throws
  // protocol::ApiError: 404 layer_not_available when the frame has no such layer, 500 when the
  // EXR cannot be read.
  File get(const std::filesystem::path& cache_dir, const std::filesystem::path& exr, long frame,
           std::uint64_t version, const Request& request);
  File get(const std::filesystem::path& cache_dir, const std::filesystem::path& exr, long frame,
           std::uint64_t version, const std::string& format, const std::string& layer) {
    Request r;
    r.format = format;
    r.layer = layer;
    return get(cache_dir, exr, frame, version, r);
  }

 private:
  std::mutex mu_;  // one writer at a time (the image writer's temp name is per process)
};

}  // namespace proden::daemon

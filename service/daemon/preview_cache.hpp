// PreviewCache: renditions of one layer of a published frame (PNG tone-mapped for viewing, or a
// single-layer EXR) served by GET .../frames/{frame}/image, made on first request and kept per
// (frame, layer, version) in the job's cache directory; a new version replaces the old ones.
#pragma once

#include <cstdint>
#include <filesystem>
#include <mutex>
#include <string>

namespace proden::daemon {

class PreviewCache {
 public:
  struct File {
    std::filesystem::path path;
    std::string content_type;
  };
  // Throws protocol::ApiError 400 for an unknown format or layer.
  static void check_request(const std::string& format, const std::string& layer);

  // The file to serve for `layer` ("" = the whole published EXR, for format exr) in `format` of
  // version `version` of a frame published as `exr`. Throws protocol::ApiError: 404
  // layer_not_available when the frame has no such layer, 500 when the EXR cannot be read.
  File get(const std::filesystem::path& cache_dir, const std::filesystem::path& exr, long frame,
           std::uint64_t version, const std::string& format, const std::string& layer);

 private:
  std::mutex mu_;  // one writer at a time (the image writer's temp name is per process)
};

}  // namespace proden::daemon

// Writes named float channels to an image file (EXR multi-layer by dotted names, or any format
// OIIO writes), atomically: temp file in the target directory, fsync, rename.
#pragma once

#include <span>
#include <string>
#include <utility>
#include <vector>

#include "proden/aov.hpp"
#include "proden/image.hpp"

namespace proden::io {

struct NamedChannel {
  std::string name;             // "R", "render.G", "ViewLayer.Combined.B", ...
  std::span<const float> data;  // width*height values
};

struct WriteOptions {
  bool half = false;  // store as 16-bit half (EXR) instead of 32-bit float
  std::string compression = "zip";
  std::vector<std::pair<std::string, std::string>> attributes;  // string header attributes
};

// Throws std::runtime_error naming the path on failure; never leaves a partial file at `path`.
void write_image(const std::string& path, int width, int height,
                 std::span<const NamedChannel> channels, const WriteOptions& options = {});

// Appends `prefix + suffix[c]` channels for each plane of `image` ("render." + "R", ...).
void add_layer(std::vector<NamedChannel>& out, const std::string& prefix, const Image& image,
               std::string_view suffixes = "RGB");

// Appends renderer AOVs (AovAccumulator::result(); they must outlive `out`) under their own
// names ("A", "Depth.Z", "CryptoObject00.r", ...), beside the result (docs/api.md).
void add_aovs(std::vector<NamedChannel>& out, const std::vector<AovChannel>& aovs);

}  // namespace proden::io

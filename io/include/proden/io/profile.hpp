// Renderer profiles: how a renderer names a pass's channels and header attributes, and the
// auto-detection that picks a profile for a file (Blender Cycles multilayer EXR, POV-Ray, generic).
#pragma once

#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "proden/io/image_header.hpp"

namespace proden::io {

enum class Renderer { automatic, cycles, povray, generic };

std::string_view to_string(Renderer r);
// Parses "auto", "cycles", "povray", "generic"; nullopt otherwise.
std::optional<Renderer> parse_renderer(std::string_view s);

// Channel names a profile maps to proden's inputs; alternatives are tried in order.
struct ChannelMap {
  Renderer renderer = Renderer::generic;
  std::string layer;                // e.g. Blender's view layer "ViewLayer" (empty for generic)
  std::vector<std::string> layers;  // every Cycles view layer the file has, sorted
  bool single_layer = false;        // Cycles colour as plain R,G,B (Blender's OPEN_EXR format)
  std::vector<std::vector<std::string>> colour, albedo, normal, depth, variance;  // per channel
  std::string spp_attribute;          // header attribute carrying samples per pixel, if any
  std::string render_time_attribute;  // header attribute carrying render time, if any
};

// The file formats a renderer's passes come in, checked by magic bytes before decoding: Cycles
// writes OpenEXR; POV-Ray writes OpenEXR or Radiance HDR; generic and auto take both. Anything
// else (PNG, TIFF, ...: 8-bit display images) is refused, whatever the file is called.
std::span<const FileFormat> accepted_formats(Renderer r);
bool accepts(Renderer r, FileFormat f);

// Picks the profile for a file with these channel names and header-attribute values.
// `forced` != automatic selects a profile explicitly. Returns nullopt if the colour channels of
// the (detected or forced) profile are absent. Cycles: multilayer files are recognised by a
// `<layer>.Combined.R` channel, single-layer OPEN_EXR files (plain R,G,B) by a
// `cycles.<layer>.samples` header attribute (`attribute_names`); the view layer is `view_layer`
// if given (the caller checks it exists: ChannelMap::layers), else the alphabetically first.
std::optional<ChannelMap> detect_profile(std::span<const std::string> channels,
                                         std::span<const std::string> attribute_values,
                                         Renderer forced,
                                         std::span<const std::string> attribute_names = {},
                                         std::string_view view_layer = {});

// A renderer AOV of a file: the channel it is read from and the name it is written under.
struct AovSource {
  std::string channel;  // e.g. "ViewLayer.Depth.Z"
  std::string name;     // e.g. "Depth.Z"; Combined.A (or a plain A) becomes "A"
};
// The channels of `channels` that are neither the profile's colour nor any of its feature or
// variance channels, nor another view layer's: the AOVs (docs/api.md, "Renderer AOVs").
std::vector<AovSource> aov_sources(const ChannelMap& map, std::span<const std::string> channels);
// Header attributes travelling with the AOVs `sources`: Cryptomatte's `cryptomatte/<id>/*` of
// the layers written, with `name` pointed at the channels as written (view layer removed).
std::vector<std::pair<std::string, std::string>> aov_attributes(
    const ChannelMap& map, std::span<const std::pair<std::string, std::string>> attributes,
    std::span<const AovSource> sources);

}  // namespace proden::io

// Reads one pass of a frame from disk (OpenEXR single/multi-part, Radiance HDR, anything OIIO
// reads) into planar buffers, through a renderer profile. Bad files raise proden::InputError
// naming the file and the reason; nothing is returned half-read.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "proden/aov.hpp"
#include "proden/io/profile.hpp"
#include "proden/pass.hpp"

namespace proden::io {

struct ReadOptions {
  Renderer renderer = Renderer::automatic;
  std::optional<double> spp;  // used when the file does not carry its sample count
  bool features = true;       // load albedo/normal/depth when present
  bool variance = true;       // load renderer variance when present
  std::string view_layer;     // Cycles view layer to read ("" = the alphabetically first)
};

enum class SppSource { header, option, assumed };
std::string_view to_string(SppSource s);

// What was detected in a pass file.
struct PassInfo {
  std::string path;
  std::string format;  // OIIO format name: "openexr", "hdr", ...
  Renderer renderer = Renderer::generic;
  std::string layer;                // Blender view layer read, if any
  std::vector<std::string> layers;  // every Cycles view layer in the file, sorted
  int width = 0;
  int height = 0;
  int subimages = 1;
  std::vector<std::string> channels;  // all channel names in the file
  std::string pixel_type;             // of the colour channels: "half", "float", ...
  double spp = 1.0;
  SppSource spp_source = SppSource::assumed;
  Layout layout;                      // which features were found (and loaded)
  std::optional<double> render_time;  // seconds, if the header says
  std::vector<std::string> aovs;      // renderer AOVs as they would be written (aov_sources)
  std::vector<std::pair<std::string, std::string>> aov_attributes;  // e.g. Cryptomatte's
  std::string to_string() const;
};

// Header-only inspection (does not read pixels).
PassInfo probe_pass(const std::string& path, const ReadOptions& options = {});

// Reads and validates the whole file; with `aovs`, also its renderer AOVs (PassInfo::aovs).
Pass read_pass(const std::string& path, const ReadOptions& options = {}, PassInfo* info = nullptr,
               std::vector<AovChannel>* aovs = nullptr);

// Reads the RGB colour of any image proden reads or writes (passes, references, outputs).
Image read_rgb(const std::string& path, const ReadOptions& options = {});

// Reads the RGB channels "<layer>.{R,G,B}" (e.g. proden's "render", "denoised" AOVs); "" or
// "result" reads the image's own colour as read_rgb() does.
Image read_layer(const std::string& path, const std::string& layer,
                 const ReadOptions& options = {});

}  // namespace proden::io

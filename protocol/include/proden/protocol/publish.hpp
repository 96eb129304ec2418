// The published frame, written the same way by the CLI and the daemon: the result as R,G,B, the
// pipeline's layers as <layer>.R/G/B (PipelineResult::layers(), names in progressive.hpp), the
// `proden:` header fields that say how it was made, and the estimated error's JSON keys.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "proden/accumulator.hpp"
#include "proden/aov.hpp"
#include "proden/progressive.hpp"
#include "proden/protocol/compression.hpp"

namespace proden::protocol {

// Header attribute names (EXR string attributes) of a published frame.
namespace header {
inline constexpr std::string_view software = "Software";
inline constexpr std::string_view passes = "proden:passes";
inline constexpr std::string_view spp = "proden:spp";
inline constexpr std::string_view inputs = "proden:inputs";
inline constexpr std::string_view denoiser = "proden:denoiser";
inline constexpr std::string_view mixer = "proden:mixer";
inline constexpr std::string_view mixer_weights = "proden:mixer_weights";
inline constexpr std::string_view divergence = "proden:divergence";
inline constexpr std::string_view t_test = "proden:t_test";
inline constexpr std::string_view variance_source = "proden:variance_source";
inline constexpr std::string_view low_confidence = "proden:low_confidence";
inline constexpr std::string_view estimated_mse = "proden:estimated_mse";
inline constexpr std::string_view estimated_mse_source = "proden:estimated_mse_source";
inline constexpr std::string_view estimated_error = "proden:estimated_error";  // the object, JSON
}  // namespace header

using Attributes = std::vector<std::pair<std::string, std::string>>;

// What the header says about the frame the result came from.
struct FrameProvenance {
  int passes = 0;
  double spp = 0.0;
  VarianceSource variance_source = VarianceSource::between_passes;
  bool low_confidence = false;
};
FrameProvenance provenance_of(const FrameAccumulator& frame, const FrameEstimate& estimate);

// "proden <version>".
std::string software();

// Every header field above, in that order, for this frame and run.
Attributes header_attributes(const FrameProvenance& frame, const PipelineResult& run);

// How a published frame is stored.
struct FrameFormat {
  bool layers = true;  // every layer of the run besides the result
  bool half = false;   // 16-bit halves instead of 32-bit floats
  // One of kFrameCompressions; `auto` is written as PIZ (the daemon resolves it first).
  std::string compression = std::string(kDefaultFrameCompression);
};

// Writes `path` atomically: R,G,B = the result and, with `format.layers`, every layer of the run,
// and the renderer AOVs `aovs` accumulated beside it (their own header entries, e.g.
// Cryptomatte's, added), with `attributes` in the header. Throws std::runtime_error naming the
// path.
void write_frame(const std::string& path, const PipelineResult& run, const Attributes& attributes,
                 const FrameFormat& format, const AovAccumulator* aovs = nullptr);

// The estimated error as the daemon's frame status and `proden denoise --json` report it:
// protocol/estimate.hpp's put_estimated_error ("estimated_mse", "estimated_mse_source" and the
// "estimated_error" object).

}  // namespace proden::protocol

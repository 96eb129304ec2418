// FrameProcessor: the one place where an accumulated frame becomes published images: runs the
// progressive pipeline (proden::run_pipeline) and names its layers (result, render, variance,
// denoised, alpha, sure) and its error estimate; with denoiser "none" it publishes the render.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "proden/accumulator.hpp"
#include "proden/aov.hpp"
#include "proden/error_estimate.hpp"
#include "proden/image.hpp"
#include "proden/protocol/api.hpp"

namespace proden::daemon {

struct ProcessedFrame {
  Image result;                                       // RGB
  std::vector<std::pair<std::string, Image>> layers;  // "render", "variance", later "denoised"...
  double estimated_mse = 0.0;                         // the pipeline's own error estimate
  std::string estimated_mse_source = "variance";      // "variance" until SURE is available
  EstimatedError error;  // the estimated_error object (estimate_error(); mse = estimated_mse)
  std::vector<std::pair<std::string, double>> stage_seconds;
};

class FrameProcessor {
 public:
  // Whether the job's pipeline options name things this build has (why = the reason if not).
  static bool supports(const protocol::PipelineSpec& spec, std::string& why);
  static ProcessedFrame process(const FrameEstimate& estimate, const protocol::PipelineSpec& spec,
                                const ErrorContext& error_context);

  // Writes <base>.exr (R,G,B + each layer as layer.R/G/B + the renderer AOVs, if any, with
  // their header attributes) and, if png, <base>.png (tone-mapped result), atomically. Returns
  // the paths written, the EXR first.
  static std::vector<std::string> publish(
      const ProcessedFrame& frame, const std::string& base, bool png,
      const std::vector<std::pair<std::string, std::string>>& attributes,
      const AovAccumulator* aovs = nullptr);
};

// Names of layers a client may request: result, render, variance, denoised, alpha, sure.
bool known_layer(const std::string& layer);

// Reads layer `layer` ("result" = R,G,B) of a published EXR; empty Image if absent.
Image read_layer(const std::string& exr_path, const std::string& layer);

// Tone-maps linear RGB for viewing (Reinhard x/(1+x) per channel, then sRGB) and writes a PNG.
void write_png_preview(const std::string& path, const Image& rgb);

}  // namespace proden::daemon

// FrameProcessor: the one place where the daemon turns an accumulated frame into published images:
// runs the job's pipeline (proden::Pipeline, committed once per worker thread and options, so its
// stages and scratch are reused frame after frame) and publishes it the way the CLI does
// (protocol/publish.hpp: the same layers and `proden:` header fields, plus a PNG preview).
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "proden/accumulator.hpp"
#include "proden/aov.hpp"
#include "proden/error_estimate.hpp"
#include "proden/image.hpp"
#include "proden/progressive.hpp"
#include "proden/protocol/api.hpp"
#include "proden/protocol/publish.hpp"

namespace proden::daemon {

struct ProcessedFrame {
  PipelineResult run;               // the result, its layers and its estimated error
  protocol::Attributes attributes;  // the published EXR's header fields
  double estimated_mse = 0.0;       // = run.estimated_error, as the frame status reports it
  std::string estimated_mse_source;
  double render_mse = 0.0;  // the plain render's own error estimate: mean Var[x] (the baseline)
  std::vector<std::pair<std::string, double>> stage_seconds;
};

class FrameProcessor {
 public:
  // Whether the job's pipeline builds here: its options commit (why = the error, naming
  // pipeline.<key>, if not).
  static bool supports(const protocol::PipelineSpec& spec, std::string& why);
  // What the job's pipeline needs of the accumulated frame (FrameAccumulator::estimate).
  static EstimateOptions estimate_options(const protocol::PipelineSpec& spec);
  // `error_context`: what the error estimate needs besides the images (docs/error_estimate.md).
  static ProcessedFrame process(const FrameAccumulator& frame, const FrameEstimate& estimate,
                                const protocol::PipelineSpec& spec,
                                const ErrorContext& error_context);

  // Writes <base>.exr (R,G,B + every layer as <layer>.R/G/B + the renderer AOVs, with the header
  // fields plus `extra`, compressed as output.compression says) and, if output.png, <base>.png
  // (tone-mapped result), atomically. Returns the paths written, the EXR first.
  static std::vector<std::string> publish(const ProcessedFrame& frame, const std::string& base,
                                          const protocol::OutputSpec& output,
                                          const protocol::Attributes& extra = {},
                                          const AovAccumulator* aovs = nullptr);
};

// Names of layers a client may request (proden::layer_names()), and them as a list for messages.
bool known_layer(const std::string& layer);
std::string known_layers();

// Writes an 8-bit sRGB image as a PNG, atomically.
struct Rgb8;
void write_png(const std::string& path, const Rgb8& image);

// Tone-maps linear RGB for viewing (colour_map.hpp's tone_map at exposure 0: Reinhard x/(1+x)
// per channel, then sRGB) and writes a PNG.
void write_png_preview(const std::string& path, const Image& rgb);

}  // namespace proden::daemon

#include "daemon/processor.hpp"

#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <stdexcept>

#include "daemon/colour_map.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/protocol/pipeline_spec.hpp"

namespace proden::daemon {
namespace {

// This worker thread's committed pipeline for the options it last ran: consecutive frames with the
// same options reuse its stages and scratch; other options rebuild it (cheap: the built-in
// network is parsed once per process). One per thread, so one execute() at a time on each.
Pipeline& pipeline_for(const PipelineOptions& options) {
  thread_local std::unique_ptr<Pipeline> pipeline;
  thread_local std::string key;
  std::string k = protocol::settings_json(options).dump();
  if (!pipeline || k != key) {
    auto p = std::make_unique<Pipeline>(options);
    p->commit();
    pipeline = std::move(p);
    key = std::move(k);
  }
  return *pipeline;
}

}  // namespace

bool FrameProcessor::supports(const protocol::PipelineSpec& spec, std::string& why) {
  try {
    Pipeline(spec.options).commit();
  } catch (const PipelineError& e) {
    why = "pipeline." + e.key() + ": " + e.message();
    return false;
  }
  return true;
}

EstimateOptions FrameProcessor::estimate_options(const protocol::PipelineSpec& spec) {
  return pipeline_for(spec.options).estimate_options();
}

ProcessedFrame FrameProcessor::process(const FrameAccumulator& frame, const FrameEstimate& estimate,
                                       const protocol::PipelineSpec& spec,
                                       const ErrorContext& error_context) {
  ProcessedFrame out;
  out.run = pipeline_for(spec.options).execute(estimate, error_context);
  out.attributes = protocol::header_attributes(protocol::provenance_of(frame, estimate), out.run);
  out.estimated_mse = out.run.estimated_error.mse;
  out.estimated_mse_source = std::string(out.run.estimated_error.source);
  double var_sum = 0.0;
  for (float v : estimate.variance.data()) var_sum += static_cast<double>(v);
  const std::size_t n = estimate.variance.data().size();
  out.render_mse = n ? var_sum / static_cast<double>(n) : 0.0;
  if (!out.run.denoised.empty()) {
    const StageTimings& t = out.run.timings;
    out.stage_seconds = {{"denoise", t.denoise}, {"sure", t.sure},       {"mix", t.mixer},
                         {"ttest", t.ttest},     {"compose", t.compose}, {"pipeline", t.wall}};
    // Only where it ran (halves present): a 0 for every 1-pass frame would skew the histogram.
    if (t.cross_validation > 0)
      out.stage_seconds.emplace_back("cross_validation", t.cross_validation);
  }
  return out;
}

std::vector<std::string> FrameProcessor::publish(const ProcessedFrame& frame,
                                                 const std::string& base,
                                                 const protocol::OutputSpec& output,
                                                 const protocol::Attributes& extra,
                                                 const AovAccumulator* aovs) {
  std::vector<std::string> written;
  protocol::Attributes attributes = frame.attributes;
  attributes.insert(attributes.end(), extra.begin(), extra.end());
  protocol::FrameFormat format;
  format.compression = output.compression;
  protocol::write_frame(base + ".exr", frame.run, attributes, format, aovs);
  written.push_back(base + ".exr");
  if (output.png) {
    write_png_preview(base + ".png", frame.run.result);
    written.push_back(base + ".png");
  }
  return written;
}

bool known_layer(const std::string& layer) {
  const auto names = layer_names();
  return std::find(names.begin(), names.end(), layer) != names.end();
}

std::string known_layers() {
  std::string s;
  for (const auto name : layer_names()) s += (s.empty() ? "" : ", ") + std::string(name);
  return s;
}

void write_png(const std::string& path, const Rgb8& image) {
  Image planar(image.width, image.height, 3);
  const std::size_t n = planar.pixels();
  for (int c = 0; c < 3; ++c) {
    auto dst = planar.plane(c);
    for (std::size_t p = 0; p < n; ++p) {
      dst[p] = static_cast<float>(image.data[p * 3 + static_cast<std::size_t>(c)]) / 255.0f;
    }
  }
  std::vector<io::NamedChannel> channels;
  io::add_layer(channels, "", planar);
  io::WriteOptions w;
  w.compression = "";
  io::write_image(path, planar.width(), planar.height(), channels, w);
}

void write_png_preview(const std::string& path, const Image& rgb) {
  write_png(path, tone_map(rgb, 0.0));
}

}  // namespace proden::daemon

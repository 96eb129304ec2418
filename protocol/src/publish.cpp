#include "proden/protocol/publish.hpp"

#include <algorithm>
#include <sstream>

#include "proden/io/image_writer.hpp"
#include "proden/protocol/estimate.hpp"
#include "proden/protocol/json.hpp"

#ifndef PRODEN_VERSION
#define PRODEN_VERSION "dev"
#endif

namespace proden::protocol {

FrameProvenance provenance_of(const FrameAccumulator& frame, const FrameEstimate& estimate) {
  return {frame.passes(), frame.total_spp(), estimate.variance_source, estimate.low_confidence()};
}

std::string software() {
  return std::string("proden ") + PRODEN_VERSION;
}

Attributes header_attributes(const FrameProvenance& frame, const PipelineResult& run) {
  std::ostringstream mse;
  mse.precision(17);  // round-trips the double
  mse << run.estimated_error.mse;
  const auto s = [](std::string_view v) { return std::string(v); };
  return {
      {s(header::software), software()},
      {s(header::passes), std::to_string(frame.passes)},
      {s(header::spp), std::to_string(frame.spp)},
      {s(header::inputs), run.inputs.to_string()},
      {s(header::denoiser), run.denoiser},
      {s(header::mixer), run.mixer},
      {s(header::mixer_weights), run.mixer_weights},
      {s(header::divergence), run.divergence},
      {s(header::t_test), run.t_test ? "on" : "off"},
      {s(header::variance_source), s(to_string(frame.variance_source))},
      {s(header::low_confidence), frame.low_confidence ? "true" : "false"},
      {s(header::estimated_mse), mse.str()},
      {s(header::estimated_mse_source), s(run.estimated_error.source)},
      {s(header::estimated_error), to_json(run.estimated_error).dump()},
  };
}

bool is_frame_compression(std::string_view name) {
  return std::find(kFrameCompressions.begin(), kFrameCompressions.end(), name) !=
         kFrameCompressions.end();
}

std::string frame_compressions() {
  std::string s;
  for (const auto c : kFrameCompressions) s += (s.empty() ? "" : ", ") + std::string(c);
  return s;
}

std::string_view resolve_frame_compression(std::string_view name) {
  if (!is_frame_compression(name)) {
    throw std::invalid_argument("compression '" + std::string(name) + "' is not one of " +
                                frame_compressions());
  }
  if (name != "auto") return name;
  return "piz";
}

void write_frame(const std::string& path, const PipelineResult& run, const Attributes& attributes,
                 const FrameFormat& format, const AovAccumulator* aovs) {
  if (!is_frame_compression(format.compression)) {
    throw std::runtime_error(path + ": compression '" + format.compression + "' is not one of " +
                             frame_compressions());
  }
  std::vector<io::NamedChannel> channels;
  io::add_layer(channels, "", run.result);
  if (format.layers) {
    for (const auto& [name, image] : run.layers()) {
      io::add_layer(channels, std::string(name) + ".", *image);
    }
  }
  const std::vector<AovChannel> aov_planes = aovs ? aovs->result() : std::vector<AovChannel>{};
  io::add_aovs(channels, aov_planes);
  io::WriteOptions w;
  w.half = format.half;
  w.compression = std::string(resolve_frame_compression(format.compression));
  w.attributes = attributes;
  if (aovs) {
    w.attributes.insert(w.attributes.end(), aovs->attributes().begin(), aovs->attributes().end());
  }
  io::write_image(path, run.result.width(), run.result.height(), channels, w);
}

}  // namespace proden::protocol

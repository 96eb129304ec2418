#include "proden/protocol/publish.hpp"

#include <sstream>

#include "proden/io/image_writer.hpp"
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
  };
}

void write_frame(const std::string& path, const PipelineResult& run, const Attributes& attributes,
                 bool layers, bool half) {
  std::vector<io::NamedChannel> channels;
  io::add_layer(channels, "", run.result);
  if (layers) {
    for (const auto& [name, image] : run.layers()) {
      io::add_layer(channels, std::string(name) + ".", *image);
    }
  }
  io::WriteOptions w;
  w.half = half;
  w.attributes = attributes;
  io::write_image(path, run.result.width(), run.result.height(), channels, w);
}

void put_estimated_error(nlohmann::json& j, double mse, std::string_view source) {
  j["estimated_mse"] = mse;
  j["estimated_mse_source"] = source;
  j["estimated_error"] = {{"mse", mse}, {"source", source}};
}

}  // namespace proden::protocol

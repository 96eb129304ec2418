#include "proden/protocol/json.hpp"

namespace proden::protocol {

using nlohmann::json;

std::string_view to_string(VarianceSource s) {
  switch (s) {
    case VarianceSource::between_passes:
      return "between_passes";
    case VarianceSource::renderer:
      return "renderer";
    case VarianceSource::spatial:
      return "spatial";
  }
  return "?";
}

json to_json(const Layout& l) {
  return {{"name", l.to_string()},
          {"albedo", l.albedo},
          {"normal", l.normal},
          {"depth", l.depth},
          {"variance", l.variance}};
}

json to_json(const io::PassInfo& i) {
  json j = {{"path", i.path},
            {"format", i.format},
            {"renderer", io::to_string(i.renderer)},
            {"width", i.width},
            {"height", i.height},
            {"subimages", i.subimages},
            {"channels", i.channels},
            {"pixel_type", i.pixel_type},
            {"spp", i.spp},
            {"spp_source", io::to_string(i.spp_source)},
            {"layout", to_json(i.layout)}};
  if (!i.layer.empty()) j["layer"] = i.layer;
  if (!i.layers.empty()) j["layers"] = i.layers;
  j["aovs"] = i.aovs;
  j["render_time_seconds"] = i.render_time ? json(*i.render_time) : json(nullptr);
  return j;
}

json to_json(const ErrorMetrics& m) {
  return {{"rmse", m.rmse},   {"mse", m.mse},       {"relmse", m.relmse},
          {"smape", m.smape}, {"values", m.values}, {"nonfinite", m.nonfinite}};
}

json frame_summary(const FrameAccumulator& frame, const FrameEstimate& e) {
  json passes = json::array();
  for (const auto& r : frame.history()) {
    passes.push_back({{"name", r.name},
                      {"spp", r.spp},
                      {"half", r.half == 0 ? "A" : "B"},
                      {"dropped_pixels", r.dropped_pixels},
                      {"sanitized_features", r.sanitized_features}});
  }
  return {{"width", frame.width()},
          {"height", frame.height()},
          {"layout", to_json(frame.layout())},
          {"passes", passes},
          {"pass_count", frame.passes()},
          {"spp", frame.total_spp()},
          {"dropped_samples", frame.dropped_samples()},
          {"variance_source", to_string(e.variance_source)},
          {"spatial_variance_pixels", e.spatial_pixels},
          {"hole_pixels", e.hole_pixels},
          {"low_confidence", e.low_confidence()},
          {"state_bytes", frame.state_bytes()},
          {"state_bytes_per_pixel",
           FrameAccumulator::bytes_per_pixel(frame.layout(), frame.quarters())}};
}

json error_json(std::string_view code, const std::string& message, const std::string& subject) {
  json e = {{"code", code}, {"message", message}};
  if (!subject.empty()) e["subject"] = subject;
  return {{"error", e}};
}

}  // namespace proden::protocol

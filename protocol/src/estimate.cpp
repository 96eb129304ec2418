#include "proden/protocol/estimate.hpp"

#include <cmath>

#include "proden/protocol/api.hpp"

namespace proden::protocol {

using nlohmann::json;

namespace {

json num(double v) {
  return std::isfinite(v) ? json(v) : json(nullptr);
}
json num(const std::optional<double>& v) {
  return v ? num(*v) : json(nullptr);
}
double get(const json& j, const char* key, double unbounded) {
  const json& v = j.at(key);
  return v.is_null() ? unbounded : v.get<double>();
}
std::optional<double> get_opt(const json& j, const char* key) {
  if (!j.contains(key) || j.at(key).is_null()) return std::nullopt;
  return j.at(key).get<double>();
}

}  // namespace

json to_json(const EstimatedError& e) {
  return {{"mse", num(e.mse)},
          {"mse_low", num(e.mse_low)},
          {"mse_high", num(e.mse_high)},
          {"relmse", num(e.relmse)},
          {"relmse_low", num(e.relmse_low)},
          {"relmse_high", num(e.relmse_high)},
          {"equivalent_spp", num(e.equivalent_spp)},
          {"equivalent_spp_low", num(e.equivalent_spp_low)},
          {"equivalent_spp_high", num(e.equivalent_spp_high)},
          {"render_relmse", num(e.render_relmse)},
          {"spp", num(e.spp)},
          {"confidence", e.confidence},
          {"dof", num(e.dof)},
          {"sampling_rse", num(e.sampling_rse)},
          {"consistent", e.consistent},
          {"noise_scope", to_string(e.noise_scope)},
          {"source", e.source},
          {"calibration", e.calibration},
          {"model_band", e.model_band}};
}

EstimatedError estimated_error_from_json(const json& j) {
  constexpr double inf = std::numeric_limits<double>::infinity();
  EstimatedError e;
  e.mse = get(j, "mse", inf);
  e.mse_low = get(j, "mse_low", 0.0);
  e.mse_high = get_opt(j, "mse_high");
  e.relmse = get(j, "relmse", inf);
  e.relmse_low = get(j, "relmse_low", 0.0);
  e.relmse_high = get_opt(j, "relmse_high");
  e.equivalent_spp = get(j, "equivalent_spp", inf);
  e.equivalent_spp_low = get(j, "equivalent_spp_low", inf);
  e.equivalent_spp_high = get_opt(j, "equivalent_spp_high");
  e.render_relmse = get(j, "render_relmse", 0.0);
  e.spp = get(j, "spp", 0.0);
  e.confidence = j.at("confidence").get<double>();
  e.dof = get_opt(j, "dof");
  e.sampling_rse = get(j, "sampling_rse", inf);
  e.consistent = j.value("consistent", true);
  e.noise_scope =
      j.at("noise_scope").get<std::string>() == "pixel" ? NoiseScope::pixel : NoiseScope::frame;
  e.source = j.at("source").get<std::string>();
  e.calibration = j.value("calibration", "none");
  e.model_band = j.value("model_band", 1.0);  // states written before the band: none
  return e;
}

void put_estimated_error(json& j, const EstimatedError& e) {
  j["estimated_mse"] = num(e.mse);
  j["estimated_mse_source"] = e.source;
  j["estimated_error"] = to_json(e);
}

json to_json(const Target& t) {
  return {{t.kind == Target::Kind::relmse ? "relmse" : "equivalent_spp", t.value}};
}

Target parse_target(const json& j, const std::string& field) {
  auto bad = [&](const std::string& why) {
    throw ApiError(400, "invalid_field", field + ": " + why);
  };
  if (!j.is_object() || j.size() != 1) {
    bad("must be {\"relmse\": R} or {\"equivalent_spp\": S} (exactly one key)");
  }
  Target t;
  const auto it = j.begin();
  const std::string key = it.key();
  const json& v = it.value();
  if (key == "relmse") {
    t.kind = Target::Kind::relmse;
  } else if (key == "equivalent_spp") {
    t.kind = Target::Kind::equivalent_spp;
  } else {
    bad("unknown key " + key + " (relmse or equivalent_spp)");
  }
  if (!v.is_number() || !std::isfinite(v.get<double>()) || !(v.get<double>() > 0)) {
    bad(key + " must be a positive number");
  }
  t.value = v.get<double>();
  return t;
}

bool target_met(const Target& t, const EstimatedError& e) {
  return t.kind == Target::Kind::relmse ? meets_relmse(e, t.value)
                                        : meets_equivalent_spp(e, t.value);
}

bool target_missed(const Target& t, const EstimatedError& e) {
  return t.kind == Target::Kind::relmse ? misses_relmse(e, t.value)
                                        : misses_equivalent_spp(e, t.value);
}

}  // namespace proden::protocol

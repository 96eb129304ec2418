// JSON forms of the estimated error (docs/error_estimate.md) and of a job's "good enough" target
// (docs/api.md, "Targets and convergence"). Keys are part of the contract: extend, never rename.
#pragma once

#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "proden/error_estimate.hpp"

namespace proden::protocol {

// The `estimated_error` object. Unbounded or infinite values are null.
nlohmann::json to_json(const EstimatedError& e);
// Reads it back (the daemon's persisted records). Throws nlohmann::json::exception when malformed.
EstimatedError estimated_error_from_json(const nlohmann::json& j);
// Adds "estimated_mse" (kept for older clients), "estimated_mse_source" and "estimated_error".
void put_estimated_error(nlohmann::json& j, const EstimatedError& e);

// A job's target: {"relmse": R} or {"equivalent_spp": S}.
struct Target {
  enum class Kind { relmse, equivalent_spp } kind = Kind::relmse;
  double value = 0.0;
};
nlohmann::json to_json(const Target& t);
// Parses `j` (the value of key `field`); throws ApiError 400 invalid_field naming it.
Target parse_target(const nlohmann::json& j, const std::string& field = "target");
// Met / missed with confidence (the interval's conservative end / far end).
bool target_met(const Target& t, const EstimatedError& e);
bool target_missed(const Target& t, const EstimatedError& e);

}  // namespace proden::protocol

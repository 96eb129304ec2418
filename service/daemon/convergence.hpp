// Convergence: a frame's "good enough" state against its job's target (docs/api.md, "Targets and
// convergence"): converged at the first version with min_passes passes, a variance that is not a
// single-pass guess and the target met with confidence; back to rendering only when a later
// version misses the target with confidence (hysteresis between the interval's two ends), and
// every change recorded. Pure logic, persisted in the frame's record.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "proden/error_estimate.hpp"
#include "proden/protocol/estimate.hpp"

namespace proden::daemon {

class Convergence {
 public:
  enum class Transition { none, converged, unconverged };
  static constexpr std::size_t kHistory = 32;  // transitions remembered

  // Applies the rule to a new version of the frame.
  Transition update(const std::optional<protocol::Target>& target, int min_passes, int passes,
                    bool low_confidence, const EstimatedError& e, std::uint64_t version,
                    const std::string& at);

  bool converged() const { return converged_; }
  std::uint64_t since_version() const { return since_version_; }
  // The transition recorded at `version`, if any (events are announced when it is published).
  Transition transition_at(std::uint64_t version) const;

  // The frame status's "convergence" object.
  nlohmann::json to_api(const std::optional<protocol::Target>& target, int min_passes) const;
  // Persisted form (the frame record) and back; a missing/null record is the initial state.
  nlohmann::json persist() const;
  static Convergence restore(const nlohmann::json& j);

 private:
  bool converged_ = false;
  std::uint64_t since_version_ = 0;
  std::string converged_at_;
  bool target_met_ = false, target_missed_ = false;
  std::vector<nlohmann::json> history_;  // {"version", "event", "at"}
};

}  // namespace proden::daemon

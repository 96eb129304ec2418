#include "daemon/convergence.hpp"

namespace proden::daemon {

using nlohmann::json;

Convergence::Transition Convergence::update(const std::optional<protocol::Target>& target,
                                            int min_passes, int passes, bool low_confidence,
                                            const EstimatedError& e, std::uint64_t version,
                                            const std::string& at) {
  if (!target) {
    target_met_ = target_missed_ = false;
    return Transition::none;
  }
  target_met_ = passes >= min_passes && !low_confidence && protocol::target_met(*target, e);
  target_missed_ = protocol::target_missed(*target, e);
  Transition t = Transition::none;
  if (!converged_ && target_met_) {
    converged_ = true;
    since_version_ = version;
    converged_at_ = at;
    t = Transition::converged;
  } else if (converged_ && target_missed_) {
    converged_ = false;
    since_version_ = 0;
    converged_at_.clear();
    t = Transition::unconverged;
  }
  if (t != Transition::none) {
    history_.push_back({{"version", version},
                        {"event", t == Transition::converged ? "converged" : "unconverged"},
                        {"at", at}});
    if (history_.size() > kHistory) history_.erase(history_.begin());
  }
  return t;
}

Convergence::Transition Convergence::transition_at(std::uint64_t version) const {
  if (history_.empty() || history_.back().at("version").get<std::uint64_t>() != version) {
    return Transition::none;
  }
  return history_.back().at("event") == "converged" ? Transition::converged
                                                    : Transition::unconverged;
}

json Convergence::to_api(const std::optional<protocol::Target>& target, int min_passes) const {
  return {{"state", !target      ? "no_target"
                    : converged_ ? "converged"
                                 : "rendering"},
          {"target", target ? protocol::to_json(*target) : json()},
          {"min_passes", min_passes},
          {"since_version", converged_ ? json(since_version_) : json()},
          {"converged_at", converged_ ? json(converged_at_) : json()},
          {"target_met", target ? json(target_met_) : json()},
          {"target_missed", target ? json(target_missed_) : json()},
          {"history", history_}};
}

json Convergence::persist() const {
  return {{"converged", converged_},         {"since_version", since_version_},
          {"converged_at", converged_at_},   {"target_met", target_met_},
          {"target_missed", target_missed_}, {"history", history_}};
}

Convergence Convergence::restore(const json& j) {
  Convergence c;
  if (j.is_null()) return c;
  c.converged_ = j.at("converged").get<bool>();
  c.since_version_ = j.at("since_version").get<std::uint64_t>();
  c.converged_at_ = j.at("converged_at").get<std::string>();
  c.target_met_ = j.at("target_met").get<bool>();
  c.target_missed_ = j.at("target_missed").get<bool>();
  for (const auto& h : j.at("history")) c.history_.push_back(h);
  return c;
}

}  // namespace proden::daemon

// Helpers for the daemon's unit tests: an event collector, pass files on disk, a job spec.
#pragma once

#include <filesystem>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "daemon/events.hpp"
#include "daemon/job_store.hpp"
#include "proden/protocol/api.hpp"
#include "test_support.hpp"

namespace proden::test {

// Collects the events of an EventHub (type and data), in order.
class EventLog : public daemon::EventSink {
 public:
  void deliver(std::shared_ptr<const std::string> wire) override {
    std::lock_guard lock(mu_);
    wires_.push_back(*wire);
  }
  struct Event {
    std::string type;
    nlohmann::json data;
  };
  std::vector<Event> events() const;
  std::vector<Event> of_type(const std::string& type) const;

 private:
  mutable std::mutex mu_;
  std::vector<std::string> wires_;
};

// Subscribes a fresh EventLog to `hub`.
std::shared_ptr<EventLog> listen(daemon::EventHub& hub);

// Writes a synthetic pass (w x h, `spp`, seed) as an EXR at `path`; returns the pending entry.
daemon::PendingPass write_pass(const std::filesystem::path& path, const std::string& pass,
                               std::uint64_t seed, bool upload = false, int w = 16, int h = 12);

// A job spec with output in `root`/out (denoiser `none` unless given).
protocol::JobSpec job_spec(const std::filesystem::path& root, const std::string& id,
                           const std::string& denoiser = "none");

}  // namespace proden::test

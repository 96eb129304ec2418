// Helpers for the daemon's unit tests: an event collector, pass files on disk, a job spec.
#pragma once

#include <atomic>
#include <chrono>
#include <filesystem>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "daemon/clock.hpp"
#include "daemon/engine.hpp"
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

// A clock that moves only when told to.
class FakeClock : public daemon::Clock {
 public:
  time_point now() const override { return base_ + std::chrono::nanoseconds(offset_.load()); }
  void advance(std::chrono::milliseconds d) { offset_ += std::chrono::nanoseconds(d).count(); }

 private:
  time_point base_ = std::chrono::steady_clock::now();
  std::atomic<std::int64_t> offset_{0};
};

// Polls `pred` every 10 ms for up to `timeout_ms`; returns its last value.
bool eventually(const std::function<bool()>& pred, int timeout_ms = 20000);

std::string read_all(const std::filesystem::path& p);

// Flips one bit of the byte at `offset` from the file's end (negative) or start.
void flip_byte(const std::filesystem::path& p, std::int64_t offset);

// An Engine on a temp state directory and allowed root, with fast polling (no inotify), a fake
// retry clock and an optional fault hook; restartable.
struct EngineRig {
  TempDir t;
  daemon::Config config;
  daemon::Roots roots;
  daemon::Metrics metrics;
  daemon::EventHub hub{10000};
  std::shared_ptr<EventLog> events = listen(hub);
  FakeClock clock;
  std::function<void(const std::string&, const std::filesystem::path&)> fault;
  std::unique_ptr<daemon::Engine> engine;

  EngineRig();
  ~EngineRig();
  std::filesystem::path allowed() const { return t.path() / "allowed"; }
  void start();
  void restart();
  // A job (denoiser none, 4 spp per pass) writing to allowed/<name>_out unless `out` is given.
  protocol::JobSpec create(const std::string& name, std::optional<protocol::WatchSpec> watch = {},
                           const std::string& out = {});
  // The bytes of a synthetic pass file.
  std::string pass_bytes(std::uint64_t seed, int w = 16, int h = 12);
  // A metric's value as rendered (0 if absent).
  double metric(const std::string& sample);
};

}  // namespace proden::test

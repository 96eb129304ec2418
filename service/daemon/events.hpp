// EventHub: fan-out of daemon events (frame, job, error) to Server-Sent Events clients, with a
// bounded history so a client reconnecting with Last-Event-ID receives what it missed.
// Event ids increase strictly; they start at the daemon's start time in microseconds, so ids from
// before a restart still compare lower than new ones.
#pragma once

#include <cstdint>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace proden::daemon {

// A connected client. deliver() must be cheap and thread-safe (it queues the text for writing).
class EventSink {
 public:
  virtual ~EventSink() = default;
  virtual void deliver(std::shared_ptr<const std::string> wire) = 0;
};

class EventHub {
 public:
  explicit EventHub(std::size_t history);
  // Formats "id: N\nevent: TYPE\ndata: JSON\n\n", keeps it in the history and delivers it.
  std::uint64_t publish(const std::string& type, const nlohmann::json& data);
  // Delivers the history after `last_id` (all of it if last_id is absent or too old), then live
  // events, in order.
  void subscribe(const std::shared_ptr<EventSink>& sink, std::optional<std::uint64_t> last_id);
  void unsubscribe(const EventSink* sink);
  std::size_t clients() const;

 private:
  struct Entry {
    std::uint64_t id;
    std::shared_ptr<const std::string> wire;
  };
  mutable std::mutex mu_;
  std::size_t limit_;
  std::uint64_t next_id_;
  std::deque<Entry> history_;
  std::vector<std::weak_ptr<EventSink>> sinks_;
};

}  // namespace proden::daemon

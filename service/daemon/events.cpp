#include "daemon/events.hpp"

#include <algorithm>
#include <chrono>

namespace proden::daemon {

EventHub::EventHub(std::size_t history)
    : limit_(std::max<std::size_t>(history, 1)),
      next_id_(static_cast<std::uint64_t>(std::chrono::duration_cast<std::chrono::microseconds>(
                                              std::chrono::system_clock::now().time_since_epoch())
                                              .count())) {}

std::uint64_t EventHub::publish(const std::string& type, const nlohmann::json& data) {
  std::lock_guard lock(mu_);
  const std::uint64_t id = next_id_++;
  // Event data is UTF-8 by construction (pass-reader text is io::printable); `replace` keeps a
  // missed byte from ever throwing here, on a worker thread, with a frame half-reported.
  const std::string text = data.dump(-1, ' ', false, nlohmann::json::error_handler_t::replace);
  auto wire = std::make_shared<const std::string>("id: " + std::to_string(id) + "\nevent: " + type +
                                                  "\ndata: " + text + "\n\n");
  history_.push_back({id, wire});
  while (history_.size() > limit_) history_.pop_front();
  // Deliver under the lock so every sink sees events in id order (deliver only queues).
  std::erase_if(sinks_, [](const auto& w) { return w.expired(); });
  for (const auto& w : sinks_) {
    if (auto s = w.lock()) s->deliver(wire);
  }
  return id;
}

void EventHub::subscribe(const std::shared_ptr<EventSink>& sink,
                         std::optional<std::uint64_t> last_id) {
  std::lock_guard lock(mu_);
  for (const auto& e : history_) {
    if (!last_id || e.id > *last_id) sink->deliver(e.wire);
  }
  sinks_.push_back(sink);
}

void EventHub::unsubscribe(const EventSink* sink) {
  std::lock_guard lock(mu_);
  std::erase_if(sinks_, [sink](const auto& w) {
    auto s = w.lock();
    return !s || s.get() == sink;
  });
}

std::size_t EventHub::clients() const {
  std::lock_guard lock(mu_);
  std::size_t n = 0;
  for (const auto& w : sinks_) n += w.expired() ? 0 : 1;
  return n;
}

}  // namespace proden::daemon

// Clock: the time source of the daemon's retry back-off (the steady clock; tests substitute a
// fake one they advance by hand).
#pragma once

#include <chrono>

namespace proden::daemon {

class Clock {
 public:
  using time_point = std::chrono::steady_clock::time_point;
  virtual ~Clock() = default;
  virtual time_point now() const = 0;
};

class SteadyClock : public Clock {
 public:
  time_point now() const override { return std::chrono::steady_clock::now(); }
};

// The process's steady clock.
const Clock& steady_clock();

}  // namespace proden::daemon

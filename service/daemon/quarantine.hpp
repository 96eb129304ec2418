// Quarantine: the pass files a job refuses to read again, with why (persisted as the job's
// quarantine.json, listed in a frame's `quarantined`), and the retry policy that decides, for a
// pass that failed to read, whether it is retried (after a back-off) or quarantined
// (docs/api.md, "Ingestion rules"): only bad input is ever quarantined; a transient fault of the
// machine (out of memory, an I/O error) or an internal error is retried.
#pragma once

#include <chrono>
#include <cstdint>
#include <exception>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

namespace proden::daemon {

// What kind of fault a failure is: the pass itself is bad (bad_input), the machine had a
// passing fault (transient: out of memory, an I/O error), or proden failed (internal).
enum class ErrorClass { bad_input, transient, internal };

// Why reading a pass failed: its class, the error kind reported in events and metrics, and its
// message.
struct Failure {
  ErrorClass cls = ErrorClass::internal;
  std::string kind;  // unreadable, size_mismatch, ... (docs/api.md, error event kinds)
  std::string message;
};

// Classifies the exception being handled (call inside a catch block): proden::InputError is
// bad_input (its kind); std::bad_alloc, std::system_error (file-system errors included) and
// stream failures are transient; anything else is internal.
Failure classify_current_exception();

struct QuarantineRecord {
  std::string path, kind, message, time;
  std::uint64_t size = 0;
  std::int64_t mtime_ns = 0;
};

// One job's quarantined files, keyed by (frame, pass). Not thread-safe: the engine's lock guards
// it.
class Quarantine {
 public:
  using Key = std::pair<long, std::string>;

  // Whether this very file (same size and mtime) is quarantined for (frame, pass).
  bool blocks(long frame, const std::string& pass, std::uint64_t size, std::int64_t mtime_ns) const;
  // A file offered for (frame, pass): false if blocked; a changed file clears its record (it
  // gets a new chance) and is admitted.
  bool admit(long frame, const std::string& pass, std::uint64_t size, std::int64_t mtime_ns);
  bool contains(long frame, const std::string& pass) const;
  void add(long frame, const std::string& pass, QuarantineRecord record);
  void erase(long frame, const std::string& pass);
  // The records of one frame as reported by the API (pass, path, kind, message, time).
  std::vector<nlohmann::json> of_frame(long frame) const;

  nlohmann::json to_json() const;
  static Quarantine from_json(const nlohmann::json& j);

 private:
  std::map<Key, QuarantineRecord> records_;
};

// What to do with a pass whose read failed, and when to try again.
struct RetryPolicy {
  int max_attempts = 3;  // failed reads of an unreadable watched file before it is quarantined
  std::chrono::milliseconds base{1000};   // the first retry's delay
  std::chrono::milliseconds cap{300000};  // the longest delay
  enum class Action { retry, quarantine };
  // `attempts` counts this failure; `upload`: the pass is a stored upload (complete when stored,
  // so an unreadable upload is final).
  Action decide(const Failure& failure, int attempts, bool upload) const;
  // Delay before the retry after `attempts` failures: base * 2^(attempts-1), at most cap.
  std::chrono::milliseconds backoff(int attempts) const;
};

}  // namespace proden::daemon

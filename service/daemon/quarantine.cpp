#include "daemon/quarantine.hpp"

#include <spdlog/spdlog.h>

#include <new>
#include <system_error>

#include "proden/error.hpp"

namespace proden::daemon {

using nlohmann::json;

Failure classify_current_exception() {
  try {
    throw;
  } catch (const InputError& e) {
    return {ErrorClass::bad_input, std::string(to_string(e.kind())), e.reason()};
  } catch (const std::bad_alloc&) {
    return {ErrorClass::transient, "transient", "out of memory"};
  } catch (const std::system_error& e) {  // also std::filesystem_error, std::ios_base::failure
    return {ErrorClass::transient, "transient", e.what()};
  } catch (const std::exception& e) {
    return {ErrorClass::internal, "internal", e.what()};
  } catch (...) {
    return {ErrorClass::internal, "internal", "unknown exception"};
  }
}

bool Quarantine::blocks(long frame, const std::string& pass, std::uint64_t size,
                        std::int64_t mtime_ns) const {
  auto it = records_.find({frame, pass});
  return it != records_.end() && it->second.size == size && it->second.mtime_ns == mtime_ns;
}

bool Quarantine::admit(long frame, const std::string& pass, std::uint64_t size,
                       std::int64_t mtime_ns) {
  if (blocks(frame, pass, size, mtime_ns)) return false;
  records_.erase({frame, pass});
  return true;
}

bool Quarantine::contains(long frame, const std::string& pass) const {
  return records_.count({frame, pass}) > 0;
}

void Quarantine::add(long frame, const std::string& pass, QuarantineRecord record) {
  records_[{frame, pass}] = std::move(record);
}

void Quarantine::erase(long frame, const std::string& pass) {
  records_.erase({frame, pass});
}

std::vector<json> Quarantine::of_frame(long frame) const {
  std::vector<json> out;
  for (const auto& [key, q] : records_) {
    if (key.first != frame) continue;
    out.push_back({{"pass", key.second},
                   {"path", q.path},
                   {"kind", q.kind},
                   {"message", q.message},
                   {"time", q.time}});
  }
  return out;
}

json Quarantine::to_json() const {
  json all = json::array();
  for (const auto& [key, q] : records_) {
    all.push_back({{"frame", key.first},
                   {"pass", key.second},
                   {"path", q.path},
                   {"size", q.size},
                   {"mtime_ns", q.mtime_ns},
                   {"kind", q.kind},
                   {"message", q.message},
                   {"time", q.time}});
  }
  return all;
}

Quarantine Quarantine::from_json(const json& j) {
  Quarantine q;
  if (!j.is_array()) {
    spdlog::warn("state: quarantine records are not a list; dropped (their files are retried)");
    return q;
  }
  // A record only remembers that a file failed: a damaged one is dropped, so its file is tried
  // again (and quarantined again while it is still bad); it never costs the job.
  for (const auto& e : j) {
    try {
      QuarantineRecord r{e.at("path"), e.at("kind"), e.at("message"),
                         e.at("time"), e.at("size"), e.at("mtime_ns")};
      q.records_[{e.at("frame").get<long>(), e.at("pass").get<std::string>()}] = std::move(r);
    } catch (const json::exception& ex) {
      spdlog::warn("state: a damaged quarantine record dropped (its file is retried): {}",
                   ex.what());
    }
  }
  return q;
}

RetryPolicy::Action RetryPolicy::decide(const Failure& failure, int attempts, bool upload) const {
  if (failure.cls != ErrorClass::bad_input) return Action::retry;  // not the file's fault
  if (failure.kind == "unreadable" && !upload && attempts < max_attempts) return Action::retry;
  return Action::quarantine;
}

std::chrono::milliseconds RetryPolicy::backoff(int attempts) const {
  auto d = base;
  for (int i = 1; i < attempts && d < cap; ++i) d *= 2;
  return std::min(d, cap);
}

}  // namespace proden::daemon

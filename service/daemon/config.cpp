#include "daemon/config.hpp"

#include <fstream>
#include <stdexcept>

#include <boost/asio/ip/address.hpp>

namespace proden::daemon {

using nlohmann::json;

namespace {

template <class T>
void take(const json& j, const char* key, T& out, const std::string& where) {
  if (!j.contains(key)) return;
  try {
    out = j.at(key).get<T>();
  } catch (const json::exception&) {
    throw std::runtime_error("config: " + where + key + " has the wrong type");
  }
}

void check_keys(const json& j, std::initializer_list<const char*> keys, const std::string& where) {
  if (!j.is_object()) throw std::runtime_error("config: " + where + " must be an object");
  for (const auto& [k, v] : j.items()) {
    bool known = false;
    for (const char* key : keys) known = known || k == key;
    if (!known) throw std::runtime_error("config: unknown key " + where + k);
  }
}

}  // namespace

void apply_json(Config& c, const json& j) {
  check_keys(
      j,
      {"bind", "port", "state_dir", "allowed_roots", "token_file", "open_reads", "dashboard",
       "worker_threads", "io_threads", "max_resident_frames", "log_level", "limits", "watch"},
      "");
  take(j, "bind", c.bind, "");
  take(j, "port", c.port, "");
  take(j, "state_dir", c.state_dir, "");
  take(j, "allowed_roots", c.allowed_roots, "");
  take(j, "token_file", c.token_file, "");
  take(j, "open_reads", c.open_reads, "");
  take(j, "dashboard", c.dashboard, "");
  take(j, "worker_threads", c.worker_threads, "");
  take(j, "io_threads", c.io_threads, "");
  take(j, "max_resident_frames", c.max_resident_frames, "");
  take(j, "log_level", c.log_level, "");
  if (j.contains("limits")) {
    const json& l = j["limits"];
    check_keys(l,
               {"max_body_bytes", "max_upload_bytes", "max_header_bytes", "request_timeout_ms",
                "upload_timeout_ms", "idle_timeout_ms", "max_connections", "sse_history",
                "sse_keepalive_ms", "sse_queue_limit"},
               "limits.");
    take(l, "max_body_bytes", c.limits.max_body_bytes, "limits.");
    take(l, "max_upload_bytes", c.limits.max_upload_bytes, "limits.");
    take(l, "max_header_bytes", c.limits.max_header_bytes, "limits.");
    take(l, "request_timeout_ms", c.limits.request_timeout_ms, "limits.");
    take(l, "upload_timeout_ms", c.limits.upload_timeout_ms, "limits.");
    take(l, "idle_timeout_ms", c.limits.idle_timeout_ms, "limits.");
    take(l, "max_connections", c.limits.max_connections, "limits.");
    take(l, "sse_history", c.limits.sse_history, "limits.");
    take(l, "sse_keepalive_ms", c.limits.sse_keepalive_ms, "limits.");
    take(l, "sse_queue_limit", c.limits.sse_queue_limit, "limits.");
  }
  if (j.contains("watch")) {
    const json& w = j["watch"];
    check_keys(w,
               {"poll_interval_ms", "settle_ms", "tick_ms", "max_attempts", "max_depth", "inotify"},
               "watch.");
    take(w, "poll_interval_ms", c.watch.poll_interval_ms, "watch.");
    take(w, "settle_ms", c.watch.settle_ms, "watch.");
    take(w, "tick_ms", c.watch.tick_ms, "watch.");
    take(w, "max_attempts", c.watch.max_attempts, "watch.");
    take(w, "max_depth", c.watch.max_depth, "watch.");
    take(w, "inotify", c.watch.inotify, "watch.");
  }
}

void load_config_file(Config& c, const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("config: cannot open " + path);
  json j;
  try {
    in >> j;
  } catch (const json::exception& e) {
    throw std::runtime_error("config: " + path + ": " + e.what());
  }
  apply_json(c, j);
}

json to_json(const Config& c) {
  return {{"bind", c.bind},
          {"port", c.port},
          {"state_dir", c.state_dir},
          {"allowed_roots", c.allowed_roots},
          {"token_file", c.token_file},
          {"open_reads", c.open_reads},
          {"dashboard", c.dashboard},
          {"worker_threads", c.worker_threads},
          {"io_threads", c.io_threads},
          {"max_resident_frames", c.max_resident_frames},
          {"log_level", c.log_level},
          {"limits",
           {{"max_body_bytes", c.limits.max_body_bytes},
            {"max_upload_bytes", c.limits.max_upload_bytes},
            {"max_header_bytes", c.limits.max_header_bytes},
            {"request_timeout_ms", c.limits.request_timeout_ms},
            {"upload_timeout_ms", c.limits.upload_timeout_ms},
            {"idle_timeout_ms", c.limits.idle_timeout_ms},
            {"max_connections", c.limits.max_connections},
            {"sse_history", c.limits.sse_history},
            {"sse_keepalive_ms", c.limits.sse_keepalive_ms},
            {"sse_queue_limit", c.limits.sse_queue_limit}}},
          {"watch",
           {{"poll_interval_ms", c.watch.poll_interval_ms},
            {"settle_ms", c.watch.settle_ms},
            {"tick_ms", c.watch.tick_ms},
            {"max_attempts", c.watch.max_attempts},
            {"max_depth", c.watch.max_depth},
            {"inotify", c.watch.inotify}}}};
}

bool is_loopback_address(const std::string& host) {
  if (host == "localhost") return true;
  boost::system::error_code ec;
  const auto a = boost::asio::ip::make_address(host, ec);
  return !ec && a.is_loopback();
}

}  // namespace proden::daemon

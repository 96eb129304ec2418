#include "daemon/config.hpp"

#include <fstream>
#include <stdexcept>

#include <boost/asio/ip/address.hpp>

#include "proden/protocol/json.hpp"

namespace proden::daemon {

using nlohmann::json;

namespace {

template <class T>
void take(const json& j, const char* key, T& out, const std::string& where) {
  if (!j.contains(key)) return;
  if constexpr (std::is_arithmetic_v<T> && !std::is_same_v<T, bool>) {
    // Checked: 1e20 as an int, or -1 as a byte count, is refused, not cast.
    try {
      out = protocol::checked_number<T>(j.at(key), "config: " + where + key);
    } catch (const std::out_of_range& e) {
      throw std::runtime_error(e.what());
    }
    return;
  }
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

void apply_hostile_input_json(Config& c, const json& j);
json hostile_input_json(const Config& c);

}  // namespace

void apply_json(Config& c, const json& j) {
  check_keys(j,
             {"bind", "port", "state_dir", "allowed_roots", "token_file", "worker_threads",
              "io_threads", "max_resident_frames", "log_level", "limits", "watch",
              /* hostile input (issue 11): */ "input", "handler_threads"},
             "");
  take(j, "bind", c.bind, "");
  take(j, "port", c.port, "");
  take(j, "state_dir", c.state_dir, "");
  take(j, "allowed_roots", c.allowed_roots, "");
  take(j, "token_file", c.token_file, "");
  take(j, "worker_threads", c.worker_threads, "");
  take(j, "io_threads", c.io_threads, "");
  take(j, "max_resident_frames", c.max_resident_frames, "");
  take(j, "log_level", c.log_level, "");
  if (j.contains("limits")) {
    const json& l = j["limits"];
    check_keys(l,
               {"max_body_bytes", "max_upload_bytes", "max_header_bytes", "request_timeout_ms",
                "upload_timeout_ms", "idle_timeout_ms", "max_connections", "sse_history",
                "sse_keepalive_ms", "sse_queue_limit",
                /* hostile clients (issue 11): */ "max_sse_streams", "max_sse_per_client",
                "reserved_connections"},
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
  apply_hostile_input_json(c, j);
}

// ---- hostile input (issue 11): its keys, kept together ----
namespace {

void apply_hostile_input_json(Config& c, const json& j) {
  take(j, "handler_threads", c.handler_threads, "");
  if (j.contains("limits")) {
    const json& l = j["limits"];
    take(l, "max_sse_streams", c.limits.max_sse_streams, "limits.");
    take(l, "max_sse_per_client", c.limits.max_sse_per_client, "limits.");
    take(l, "reserved_connections", c.limits.reserved_connections, "limits.");
  }
  if (j.contains("input")) {
    const json& in = j["input"];
    check_keys(in, {"max_pixels", "max_channels", "max_file_bytes", "max_read_bytes"}, "input.");
    take(in, "max_pixels", c.input.max_pixels, "input.");
    take(in, "max_channels", c.input.max_channels, "input.");
    take(in, "max_file_bytes", c.input.max_file_bytes, "input.");
    take(in, "max_read_bytes", c.input.max_read_bytes, "input.");
  }
  auto positive = [](long long v, const char* key) {
    if (v < 1) throw std::runtime_error(std::string("config: ") + key + " must be at least 1");
  };
  positive(c.handler_threads, "handler_threads");
  positive(c.limits.max_sse_streams, "limits.max_sse_streams");
  positive(c.limits.max_sse_per_client, "limits.max_sse_per_client");
  positive(static_cast<long long>(c.input.max_pixels), "input.max_pixels");
  positive(c.input.max_channels, "input.max_channels");
  if (c.limits.reserved_connections < 0) {
    throw std::runtime_error("config: limits.reserved_connections must not be negative");
  }
}

json hostile_input_json(const Config& c) {
  return {{"max_pixels", c.input.max_pixels},
          {"max_channels", c.input.max_channels},
          {"max_file_bytes", c.input.max_file_bytes},
          {"max_read_bytes", c.input.max_read_bytes}};
}

}  // namespace

io::ReadLimits read_limits(const InputLimits& in, std::uint64_t max_file_bytes) {
  io::ReadLimits r;
  r.max_pixels = in.max_pixels;
  r.max_channels = in.max_channels;
  r.max_file_bytes = max_file_bytes;
  r.max_memory_bytes = in.max_read_bytes;
  return r;
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
            {"sse_queue_limit", c.limits.sse_queue_limit},
            {"max_sse_streams", c.limits.max_sse_streams},
            {"max_sse_per_client", c.limits.max_sse_per_client},
            {"reserved_connections", c.limits.reserved_connections}}},
          {"input", hostile_input_json(c)},
          {"handler_threads", c.handler_threads},
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

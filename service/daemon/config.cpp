#include "daemon/config.hpp"

#include <cmath>
#include <cstdio>
#include <fstream>
#include <stdexcept>
#include <type_traits>

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

void apply_hostile_input_json(Config& c, const json& j);
json hostile_input_json(const Config& c);

}  // namespace

namespace {

// Every number of the config with its bounds (docs: deploy/proden.example.json). `f` is called
// as f(key, field, min, max) for each.
template <class C, class F>
void each_number(C& c, F&& f) {
  constexpr double kDay = 86400000.0, kHour = 3600000.0;
  f("port", c.port, 0.0, 65535.0);
  f("worker_threads", c.worker_threads, 1.0, 256.0);
  f("io_threads", c.io_threads, 1.0, 256.0);
  f("max_resident_frames", c.max_resident_frames, 0.0, 4096.0);
  f("max_resident_bytes", c.max_resident_bytes, 0.0, 70368744177664.0);
  f("pipeline_threads", c.pipeline_threads, 0.0, 1024.0);
  f("limits.max_body_bytes", c.limits.max_body_bytes, 1.0, 1073741824.0);
  f("limits.max_upload_bytes", c.limits.max_upload_bytes, 1.0, 68719476736.0);
  f("limits.max_header_bytes", c.limits.max_header_bytes, 1024.0, 1048576.0);
  f("limits.request_timeout_ms", c.limits.request_timeout_ms, 100.0, kHour);
  f("limits.upload_timeout_ms", c.limits.upload_timeout_ms, 100.0, kDay);
  f("limits.idle_timeout_ms", c.limits.idle_timeout_ms, 100.0, kDay);
  f("limits.max_connections", c.limits.max_connections, 1.0, 1000000.0);
  f("limits.sse_history", c.limits.sse_history, 0.0, 1000000.0);
  f("limits.sse_keepalive_ms", c.limits.sse_keepalive_ms, 100.0, kHour);
  f("limits.sse_queue_limit", c.limits.sse_queue_limit, 1.0, 1000000.0);
  f("watch.poll_interval_ms", c.watch.poll_interval_ms, 10.0, kDay);
  f("watch.settle_ms", c.watch.settle_ms, 0.0, kHour);
  f("watch.tick_ms", c.watch.tick_ms, 1.0, 60000.0);
  f("watch.max_attempts", c.watch.max_attempts, 1.0, 1000.0);
  f("watch.max_depth", c.watch.max_depth, 0.0, 64.0);
  // hostile input and clients (issue 11; docs/api.md "Security and limits")
  f("handler_threads", c.handler_threads, 1.0, 256.0);
  f("limits.max_sse_streams", c.limits.max_sse_streams, 1.0, 1000000.0);
  f("limits.max_sse_per_client", c.limits.max_sse_per_client, 1.0, 1000000.0);
  f("limits.reserved_connections", c.limits.reserved_connections, 0.0, 1000000.0);
  f("input.max_pixels", c.input.max_pixels, 1.0, 1099511627776.0);
  f("input.max_channels", c.input.max_channels, 1.0, 65536.0);
  f("input.max_file_bytes", c.input.max_file_bytes, 1.0, 70368744177664.0);
  f("input.max_read_bytes", c.input.max_read_bytes, 1.0, 70368744177664.0);
}

[[noreturn]] void out_of_range(const std::string& key, double lo, double hi) {
  char buf[128];
  std::snprintf(buf, sizeof buf, " must be an integer in [%.0f, %.0f]", lo, hi);
  throw std::runtime_error("config: " + key + buf);
}

// The JSON value at a dotted key, or null.
const json* find(const json& j, const std::string& key) {
  const json* at = &j;
  std::size_t start = 0;
  for (;;) {
    const auto dot = key.find('.', start);
    const std::string part = key.substr(start, dot == std::string::npos ? dot : dot - start);
    if (!at->is_object() || !at->contains(part)) return nullptr;
    at = &(*at)[part];
    if (dot == std::string::npos) return at;
    start = dot + 1;
  }
}

}  // namespace

void apply_json(Config& c, const json& j) {
  check_keys(j,
             {"bind", "port", "state_dir", "allowed_roots", "token_file", "open_reads", "dashboard",
              "worker_threads", "io_threads", "max_resident_frames", "max_resident_bytes",
              "pipeline_threads", "log_level", "limits", "watch",
              /* hostile input (issue 11): */ "input", "handler_threads"},
             "");
  take(j, "bind", c.bind, "");
  take(j, "state_dir", c.state_dir, "");
  take(j, "allowed_roots", c.allowed_roots, "");
  take(j, "token_file", c.token_file, "");
  take(j, "open_reads", c.open_reads, "");
  take(j, "dashboard", c.dashboard, "");
  take(j, "log_level", c.log_level, "");
  if (j.contains("limits")) {
    check_keys(j["limits"],
               {"max_body_bytes", "max_upload_bytes", "max_header_bytes", "request_timeout_ms",
                "upload_timeout_ms", "idle_timeout_ms", "max_connections", "sse_history",
                "sse_keepalive_ms", "sse_queue_limit",
                /* hostile clients (issue 11): */ "max_sse_streams", "max_sse_per_client",
                "reserved_connections"},
               "limits.");
  }
  if (j.contains("watch")) {
    const json& w = j["watch"];
    check_keys(w,
               {"poll_interval_ms", "settle_ms", "tick_ms", "max_attempts", "max_depth", "inotify"},
               "watch.");
    take(w, "inotify", c.watch.inotify, "watch.");
  }
  // Numbers: integers within their bounds, checked before any conversion.
  each_number(c, [&j](const std::string& key, auto& field, double lo, double hi) {
    const json* v = find(j, key);
    if (!v) return;
    if (!v->is_number()) throw std::runtime_error("config: " + key + " has the wrong type");
    const double d = v->get<double>();
    if (!std::isfinite(d) || d != std::floor(d) || d < lo || d > hi) out_of_range(key, lo, hi);
    field = static_cast<std::remove_reference_t<decltype(field)>>(d);
  });
  apply_hostile_input_json(c, j);
}

void validate(const Config& c) {
  each_number(c, [](const std::string& key, const auto& field, double lo, double hi) {
    const auto v = static_cast<double>(field);
    if (v < lo || v > hi) out_of_range(key, lo, hi);
  });
}

// ---- hostile input (issue 11): its keys, kept together ----
namespace {

void apply_hostile_input_json(Config&, const json& j) {  // their numbers: each_number
  if (j.contains("input")) {
    check_keys(j["input"], {"max_pixels", "max_channels", "max_file_bytes", "max_read_bytes"},
               "input.");
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
          {"open_reads", c.open_reads},
          {"dashboard", c.dashboard},
          {"worker_threads", c.worker_threads},
          {"io_threads", c.io_threads},
          {"max_resident_frames", c.max_resident_frames},
          {"max_resident_bytes", c.max_resident_bytes},
          {"pipeline_threads", c.pipeline_threads},
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

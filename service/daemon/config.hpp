// Configuration of `proden serve`: defaults embedded here, overridden by a JSON config file and
// then by command-line flags (see deploy/proden.example.json for every key).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace proden::daemon {

struct Limits {
  std::size_t max_body_bytes = 1 << 20;                 // JSON requests
  std::size_t max_upload_bytes = std::size_t{1} << 30;  // PUT .../passes/{pass}
  std::size_t max_header_bytes = 16 * 1024;
  int request_timeout_ms = 30000;  // reading one request (headers + JSON body), writing a reply
  int upload_timeout_ms = 600000;  // reading an upload body
  int idle_timeout_ms = 60000;     // keep-alive wait for the next request
  int max_connections = 4096;
  std::size_t sse_history = 1024;  // events kept for Last-Event-ID resumption
  int sse_keepalive_ms = 15000;
  std::size_t sse_queue_limit = 4096;  // pending events per client before it is dropped
};

struct WatchConfig {
  int poll_interval_ms = 2000;  // full directory scan (fallback for NFS)
  int settle_ms = 1000;         // size+mtime unchanged for this long before a file is read
  int tick_ms = 200;            // stability checks
  int max_attempts = 3;         // failed reads of a stable file before it is quarantined
  int max_depth = 8;            // subdirectory levels watched below watch.dir
  bool inotify = true;          // false: polling only (e.g. everything on NFS)
};

struct Config {
  std::string bind = "127.0.0.1";
  int port = 8080;
  std::string state_dir = "proden-state";
  std::vector<std::string> allowed_roots;
  std::string token_file;
  // With a token file, reads (GET /api/v1/..., /metrics) need the token too unless this is set;
  // /livez, /readyz and the dashboard's static files are always open.
  bool open_reads = false;
  bool dashboard = true;        // serve the dashboard from / (docs/dashboard.md)
  int worker_threads = 2;       // frames processed concurrently
  int io_threads = 2;           // HTTP threads
  int max_resident_frames = 2;  // accumulators cached in memory (others reload from state)
  std::string log_level = "info";
  Limits limits;
  WatchConfig watch;
};

// Applies the keys present in `j` over `c` (throws std::runtime_error on unknown keys or types).
void apply_json(Config& c, const nlohmann::json& j);
void load_config_file(Config& c, const std::string& path);
nlohmann::json to_json(const Config& c);

bool is_loopback_address(const std::string& host);

}  // namespace proden::daemon

// Configuration of `proden serve`: defaults embedded here, overridden by a JSON config file and
// then by command-line flags (see deploy/proden.example.json for every key).
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "proden/io/image_header.hpp"

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

  // ---- hostile clients (issue 11; docs/api.md "Security and limits") ----
  int max_sse_streams = 1024;     // event streams open at once (of max_connections)
  int max_sse_per_client = 256;   // event streams per source address
  int reserved_connections = 64;  // the last connections: health checks and tokens only
                                  // (at most max_connections / 4)
};

// ---- hostile pass files (issue 11; docs/api.md "Security and limits"): bounds checked from a
// pass's header before it is decoded (io::ReadLimits). ----
struct InputLimits {
  std::uint64_t max_pixels = 7680ull * 4320;  // width * height (8K UHD)
  int max_channels = 1024;                    // all parts of one file
  std::uint64_t max_file_bytes = 1ull << 30;  // a pass file (uploads: limits.max_upload_bytes)
  std::uint64_t max_read_bytes = 1ull << 30;  // estimated peak memory of reading one pass
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
  bool dashboard = true;   // serve the dashboard from / (docs/dashboard.md)
  int worker_threads = 2;  // frames processed concurrently
  int io_threads = 2;      // HTTP threads
  // Frames whose accumulated state stays in memory between updates (the least recently updated
  // beyond either bound are dropped and reload from their state file at their next update).
  int max_resident_frames = 64;
  std::uint64_t max_resident_bytes = 0;  // 0 = a quarter of usable_memory_bytes()
  int pipeline_threads = 0;              // threads of one frame's pipeline (TBB); 0 = one per core
  std::string log_level = "info";
  Limits limits;
  WatchConfig watch;
  // ---- hostile input (issue 11) ----
  InputLimits input;
  int handler_threads = 2;  // HTTP handlers that validate uploads and encode images
};

// Applies the keys present in `j` over `c` (throws std::runtime_error on unknown keys or types).
void apply_json(Config& c, const nlohmann::json& j);
void load_config_file(Config& c, const std::string& path);
// Checks every number against its bounds (throws std::runtime_error naming the key).
void validate(const Config& c);
nlohmann::json to_json(const Config& c);

bool is_loopback_address(const std::string& host);

// ---- hostile input (issue 11) ----
// The pass reader's bounds from the config; `max_file_bytes`: input.max_file_bytes for watched
// files, limits.max_upload_bytes for uploads.
io::ReadLimits read_limits(const InputLimits& in, std::uint64_t max_file_bytes);

}  // namespace proden::daemon

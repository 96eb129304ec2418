// Watcher: finds pass files of jobs' watched directories (inotify close-write/moved-to,
// recursively, plus a periodic full scan for network file systems where inotify misses remote
// writes) and hands a file to the engine only once it is stable: non-empty, not a temp name, and
// size+mtime unchanged across checks at least `settle_ms` apart.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "daemon/config.hpp"
#include "daemon/files.hpp"
#include "daemon/pass_pattern.hpp"

namespace proden::daemon {

// True for names the watcher never reads: dot files, *.tmp, *.partial*, *~.
bool is_temp_name(const std::string& filename);

struct FoundFile {
  std::string job;
  long frame;
  std::string pass;
  std::filesystem::path path;
  std::uint64_t size;
  std::int64_t mtime_ns;
};

class Watcher {
 public:
  struct Callbacks {
    // Does the engine still want this (job, frame, pass) with this size+mtime?
    std::function<bool(const FoundFile&)> wanted;
    // A stable file.
    std::function<void(const FoundFile&)> offer;
    // A file refused for safety (e.g. a symlink resolving outside the allowed roots).
    std::function<void(const FoundFile&, const std::string& why)> refused;
  };
  Watcher(const WatchConfig& config, const Roots& roots, Callbacks callbacks);
  ~Watcher();
  Watcher(const Watcher&) = delete;
  Watcher& operator=(const Watcher&) = delete;

  void start();
  void stop();
  // False (logged) when `pattern` is not a valid watch pattern: nothing is watched for the job.
  bool add_job(const std::string& id, const std::filesystem::path& dir, const std::string& pattern);
  void remove_job(const std::string& id);
  void rescan();  // schedule a full scan soon (e.g. after a resume)

 private:
  struct Job {
    std::filesystem::path dir;
    PassPattern pattern;
  };
  struct Candidate {
    FoundFile file;
    std::chrono::steady_clock::time_point changed;
  };
  void run();
  void scan_job(const std::string& id, const Job& job);
  void scan_dir(const std::string& id, const Job& job, const std::filesystem::path& dir, int depth);
  void consider(const std::string& id, const Job& job, const std::filesystem::path& path);
  void watch_dir(const std::string& id, const std::filesystem::path& dir, int depth);
  void read_inotify();
  void check_candidates();

  WatchConfig config_;
  const Roots& roots_;
  Callbacks cb_;
  int inotify_fd_ = -1;
  int wake_fd_ = -1;  // eventfd to interrupt poll()
  std::thread thread_;
  std::atomic<bool> stop_{false};
  std::atomic<bool> rescan_{true};

  std::mutex mu_;
  std::map<std::string, Job> jobs_;
  struct WatchRef {
    std::string job;
    std::filesystem::path dir;
    int depth;
  };
  std::map<int, std::vector<WatchRef>> watches_;                         // inotify wd -> users
  std::map<std::pair<std::string, std::string>, Candidate> candidates_;  // (job, path)
  std::set<std::pair<std::string, std::string>> refused_;
};

}  // namespace proden::daemon

// Engine: the daemon's jobs and frames. Owns the job store (state_dir/jobs/<id>/), takes stable
// pass files from the Watcher and uploads, and runs frames on a bounded worker pool shared
// fairly (round-robin) by all jobs: read passes -> accumulate -> persist (exactly once) ->
// process -> publish a new version -> event. Passes arriving while a frame runs coalesce into its
// next run. Thread-safe; HTTP handlers call it directly.
#pragma once

#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <nlohmann/json.hpp>

#include "daemon/config.hpp"
#include "daemon/events.hpp"
#include "daemon/files.hpp"
#include "daemon/frame_state.hpp"
#include "daemon/metrics.hpp"
#include "daemon/watcher.hpp"
#include "proden/accumulator.hpp"
#include "proden/protocol/api.hpp"

namespace proden::daemon {

class Engine {
 public:
  Engine(const Config& config, const Roots& roots, Metrics& metrics, EventHub& events);
  ~Engine();
  Engine(const Engine&) = delete;
  Engine& operator=(const Engine&) = delete;

  void start();  // loads the state directory, resumes jobs, starts watcher and workers
  void stop();   // stops taking work, finishes in-flight frames (state is persisted per run)
  bool ready() const { return ready_; }

  // API operations; failures throw protocol::ApiError.
  protocol::JobSpec create_job(protocol::JobSpec spec);
  std::vector<protocol::JobSpec> jobs() const;
  protocol::JobSpec job(const std::string& id) const;
  void delete_job(const std::string& id);
  protocol::JobSpec set_paused(const std::string& id, bool paused);
  // Checks an upload's target before its body is read (404/400/409).
  void check_upload(const std::string& id, const std::string& frame, const std::string& pass) const;
  nlohmann::json upload(const std::string& id, const std::string& frame, const std::string& pass,
                        const std::string& body);
  std::vector<protocol::FrameStatus> frames(const std::string& id) const;
  protocol::FrameStatus frame(const std::string& id, long frame) const;
  struct ImageFile {
    std::filesystem::path path;
    std::string content_type;
  };
  ImageFile image(const std::string& id, long frame, const std::string& format,
                  const std::string& layer);
  // Blocks until no frame is queued or running (tests, benchmarks); false on timeout.
  bool wait_idle(int timeout_ms);

 private:
  struct Pending {
    std::string pass;
    std::filesystem::path path;
    std::uint64_t size = 0;
    std::int64_t mtime_ns = 0;
    bool upload = false;
  };
  struct Frame {
    FrameRecord rec;
    bool has_state = false;
    std::uint64_t published_version = 0;
    std::vector<std::string> outputs;
    std::map<std::string, Pending> pending;
    std::set<std::string> ingested, inflight;
    std::map<std::string, int> attempts;
    bool queued = false, running = false;
    std::shared_ptr<FrameAccumulator> acc;  // resident state (LRU-bounded)
    std::uint64_t last_used = 0;
  };
  struct Quarantined {
    std::string path, kind, message, time;
    std::uint64_t size = 0;
    std::int64_t mtime_ns = 0;
  };
  struct Job {
    protocol::JobSpec spec;
    std::filesystem::path dir;  // state_dir/jobs/<id>
    std::map<long, Frame> frames;
    std::deque<long> ready;
    bool in_rotation = false;
    bool deleted = false;
    std::map<std::pair<long, std::string>, Quarantined> quarantine;
  };

  void load_state();
  void load_job(const std::filesystem::path& dir);
  void worker();
  void run_frame(const std::shared_ptr<Job>& job, long frame_no);
  void enqueue(const std::shared_ptr<Job>& job, long frame_no, Frame& fr);  // mu_ held
  void quarantine(const std::shared_ptr<Job>& job, long frame, const Pending& p,
                  const std::string& kind, const std::string& message);
  void save_job(const Job& job);
  void save_quarantine(const std::shared_ptr<Job>& job);
  void update_gauges();  // mu_ held
  void evict();          // mu_ held
  void error_event(const std::string& job, long frame, const std::string& pass,
                   const std::string& path, const std::string& kind, const std::string& message,
                   bool quarantined);
  bool wanted(const FoundFile& f);
  void offer(const FoundFile& f);
  std::shared_ptr<Job> find(const std::string& id) const;  // mu_ held; 404 if absent
  protocol::FrameStatus status(const Job& job, const Frame& fr) const;
  std::filesystem::path output_base(const Job& job, long frame) const;
  std::filesystem::path state_path(const Job& job, long frame) const;

  Config config_;
  const Roots& roots_;
  Metrics& metrics_;
  EventHub& events_;
  std::unique_ptr<Watcher> watcher_;

  mutable std::mutex mu_;
  std::condition_variable cv_, idle_cv_;
  std::map<std::string, std::shared_ptr<Job>> jobs_;
  std::deque<std::string> rotation_;  // jobs with ready frames, served round-robin
  std::vector<std::thread> workers_;
  bool stopping_ = false;
  int running_ = 0;
  std::uint64_t use_clock_ = 0;
  std::atomic<bool> ready_{false};
};

}  // namespace proden::daemon

// Engine: the daemon's front over its jobs and frames. It keeps the in-memory table of jobs and
// frames (which passes each frame has, waits for or is reading), answers the API, takes stable
// files from the Watcher and uploads, and hands frames to the Scheduler, which runs them as
// FrameRuns; JobStore keeps the state on disk, Quarantine the refused files, PreviewCache the
// image renditions. Thread-safe; HTTP handlers call it directly.
//
// Locks, in this order: a job's save lock (orders writes of job.json), the engine's lock, then
// the Scheduler's, the EventHub's or Metrics' own. The engine never calls the Watcher with its
// lock held (the Watcher calls back into the engine).
//
// Its own published frames (any job's <output.dir>/<name>_<frame>.exr|.png, also reached through
// a symlink) are never taken as passes, so an output directory may lie inside a watch directory.
#pragma once

#include <atomic>
#include <cstdint>
#include <filesystem>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <vector>

#include <tbb/global_control.h>
#include <nlohmann/json.hpp>

#include "daemon/clock.hpp"
#include "daemon/config.hpp"
#include "daemon/events.hpp"
#include "daemon/files.hpp"
#include "daemon/frame_run.hpp"
#include "daemon/frame_state.hpp"
#include "daemon/job_store.hpp"
#include "daemon/metrics.hpp"
#include "daemon/preview_cache.hpp"
#include "daemon/quarantine.hpp"
#include "daemon/scheduler.hpp"
#include "daemon/watcher.hpp"
#include "proden/accumulator.hpp"
#include "proden/protocol/api.hpp"

namespace proden::daemon {

// Test seams of the Engine: faults injected into file operations, the clock of the retry back-off.
struct EngineTestHooks {
  FsHook fs;
  const Clock* clock = nullptr;  // null: the steady clock
};

class Engine {
 public:
  Engine(const Config& config, const Roots& roots, Metrics& metrics, EventHub& events,
         EngineTestHooks hooks = EngineTestHooks());
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
  // Checks an upload's target before its body is read (404/400).
  void check_upload(const std::string& id, const std::string& frame, const std::string& pass) const;
  // Stores an upload (docs/api.md): {"status":"queued"} (202) when stored or already waiting with
  // the same bytes, {"status":"ingested"} (200) when the frame holds the pass with the same
  // bytes; 409 when (frame, pass) has other bytes.
  nlohmann::json upload(const std::string& id, const std::string& frame, const std::string& pass,
                        const std::string& body);
  // Where the HTTP layer streams an upload's body (checks the target first, like check_upload).
  std::filesystem::path upload_spool(const std::string& id, const std::string& frame,
                                     const std::string& pass);
  // An upload whose body was streamed to `spooled` (taken over: moved into place or removed).
  nlohmann::json upload_spooled(const std::string& id, const std::string& frame,
                                const std::string& pass, const std::filesystem::path& spooled);
  std::vector<protocol::FrameStatus> frames(const std::string& id) const;
  protocol::FrameStatus frame(const std::string& id, long frame) const;
  struct ImageFile : PreviewCache::File {
    std::uint64_t version = 0;  // the version served
  };
  // The latest version, or `version` if given (404 version_not_available when its image is not
  // kept, docs/api.md).
  ImageFile image(const std::string& id, long frame, const std::string& format,
                  const std::string& layer);
  ImageFile image(const std::string& id, long frame, const PreviewCache::Request& request,
                  std::optional<std::uint64_t> version = {});
  // The frame's published versions (FrameHistory); 404 for an unknown job or frame.
  nlohmann::json history(const std::string& id, long frame) const;
  // Every frame's published versions: [{"frame", "versions"}], in frame order.
  nlohmann::json job_history(const std::string& id) const;
  // Every quarantined file of the job (frame, pass, path, kind, message, time).
  nlohmann::json quarantined(const std::string& id) const;
  // Blocks until no frame is queued or running (tests, benchmarks); false on timeout.
  bool wait_idle(int timeout_ms);

 private:
  struct Retry {
    PendingPass pass;
    Clock::time_point due;
  };
  struct Frame {
    FrameRecord rec;
    bool has_state = false;
    std::uint64_t published_version = 0;
    std::vector<std::string> outputs;
    std::map<std::string, PendingPass> pending;   // to read at the next run
    std::map<std::string, Retry> retry;           // to read again once due (back-off)
    std::map<std::string, PendingPass> inflight;  // being read by the running run
    std::set<std::string> ingested;
    std::map<std::string, int> attempts;    // failed reads per pass
    int failures = 0;                       // consecutive failed runs (persist/publish)
    std::shared_ptr<FrameAccumulator> acc;  // resident state (LRU-bounded)
    std::shared_ptr<AovAccumulator> aovs;   // its renderer AOVs (resident with acc)
    std::uint64_t last_used = 0;
    // Versions whose kept EXR may still be uncompressed (output.compression auto), compressed
    // when the daemon is idle (compress_idle).
    std::set<std::uint64_t> to_compress;
    bool has(const std::string& pass) const {
      return ingested.count(pass) || pending.count(pass) || retry.count(pass) ||
             inflight.count(pass);
    }
  };
  struct Job {
    protocol::JobSpec spec;
    std::map<long, Frame> frames;
    Quarantine quarantine;
    bool deleted = false;
    std::mutex save_mu;  // orders job.json writes (taken before the engine's lock)
  };
  // What an upload of (frame, pass) with these bytes is, given what the frame has.
  enum class UploadFit { fresh, queued, ingested, conflict };
  UploadFit fit(const Frame& fr, const std::string& pass, std::uint64_t hash) const;

  void load_state();
  void load_job(const std::filesystem::path& dir);
  void run_frame(const std::string& job_id, long frame_no);
  // From the scheduler's idle hook: compresses kept versions that `auto` wrote uncompressed, newest
  // first, while the scheduler stays idle: at most one file rewritten per call (the hook comes
  // back after the next idle second), so work that lands waits for one file at most.
  void compress_idle();
  // Rewrites version `version` of the frame with its final compression; false if nothing was to do.
  bool compress_version(const protocol::JobSpec& spec, long frame, std::uint64_t version,
                        bool latest);
  void enqueue(const Job& job, long frame_no);  // mu_ held
  void retry_later(Job& job, long frame_no, Frame& fr, const PendingPass& p,
                   std::chrono::milliseconds delay);  // mu_ held
  void on_failed(const std::shared_ptr<Job>& job, long frame, const PendingPass& p,
                 const Failure& f);
  void on_damaged(const std::string& job, long frame, const std::string& message);
  bool own_output(const std::filesystem::path& path) const;  // mu_ held
  void quarantine(const std::shared_ptr<Job>& job, long frame, const PendingPass& p,
                  const std::string& kind, const std::string& message);
  void save_quarantine(const std::shared_ptr<Job>& job);
  void evict();  // mu_ held
  bool wanted(const FoundFile& f);
  void offer(const FoundFile& f);
  std::shared_ptr<Job> find(const std::string& id) const;  // mu_ held; 404 if absent
  protocol::FrameStatus status(const Job& job, const Frame& fr) const;

  Config config_;
  const Roots& roots_;
  Metrics& metrics_;
  EventHub& events_;
  const Clock& clock_;
  JobStore store_;
  RetryPolicy retry_;
  PreviewCache previews_;
  std::unique_ptr<Watcher> watcher_;
  std::unique_ptr<Scheduler> scheduler_;
  std::unique_ptr<tbb::global_control> pipeline_threads_;  // config.pipeline_threads > 0

  mutable std::mutex mu_;
  std::map<std::string, std::shared_ptr<Job>> jobs_;
  std::uint64_t use_clock_ = 0;
  std::uint64_t resident_budget_ = 0;  // config_.max_resident_bytes, or its default (start())
  std::atomic<bool> ready_{false};
};

}  // namespace proden::daemon

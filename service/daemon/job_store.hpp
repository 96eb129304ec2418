// JobStore: the daemon's state directory on disk (layout in docs/api.md, "State directory"):
// one directory per job with job.json, quarantine.json, frames/<n>.state (+ <n>.pub, the version
// last published, and <n>.history, the versions published), uploads/<n>/<pass>.exr and cache/.
// It saves atomically and durably and recovers what a previous process left (start-up). It holds
// no in-memory job state; the engine orders calls on one job.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "daemon/frame_state.hpp"
#include "proden/accumulator.hpp"
#include "proden/protocol/api.hpp"

namespace proden::daemon {

// Test hook on the store's writes: called with the operation's name and path before it happens
// ("job", "quarantine", "state", "published", "upload", "fsync_dir"); throwing from it simulates
// the fault (disk full, I/O error) at that point.
using FsHook = std::function<void(const std::string& op, const std::filesystem::path& path)>;

// A pass file waiting to be read into its frame: a watched file (identified by path, size and
// mtime at discovery) or a stored upload.
struct PendingPass {
  std::string pass;
  std::filesystem::path path;
  std::uint64_t size = 0;
  std::int64_t mtime_ns = 0;
  bool upload = false;
};

class JobStore {
 public:
  explicit JobStore(std::filesystem::path state_dir, FsHook hook = {});

  const std::filesystem::path& jobs_dir() const { return jobs_; }
  std::filesystem::path job_dir(const std::string& id) const;
  std::filesystem::path state_path(const std::string& id, long frame) const;
  std::filesystem::path published_path(const std::string& id, long frame) const;
  std::filesystem::path history_path(const std::string& id, long frame) const;  // FrameHistory
  std::filesystem::path upload_dir(const std::string& id, long frame) const;
  std::filesystem::path cache_dir(const std::string& id) const;

  // ---- jobs ----
  void create_job(const protocol::JobSpec& spec);  // directories + job.json
  void save_job(const std::string& id, const std::string& job_json);
  void save_quarantine(const std::string& id, const std::string& quarantine_json);
  void remove_job(const std::string& id);  // the job's state only (outputs stay)

  // What a previous process left of one job.
  struct LoadedFrame {
    FrameRecord record;
    std::uint64_t published_version = 0;
  };
  struct LoadedJob {
    protocol::JobSpec spec;
    nlohmann::json quarantine = nlohmann::json::array();
    std::vector<LoadedFrame> frames;
    std::vector<std::pair<long, PendingPass>> uploads;  // stored, not yet accumulated
  };
  // Loads one job directory: its spec, quarantine records, frame records (a frame whose state
  // cannot be read is moved aside as <n>.corrupt and reported through `corrupt`), stored uploads;
  // removes temp files left by an interrupted write. nullopt: no job there (an interrupted
  // creation, removed). Throws when the job cannot be loaded.
  std::optional<LoadedJob> load_job(const std::filesystem::path& dir,
                                    const std::function<void(const std::string&)>& corrupt);

  // ---- frames ----
  void save_frame(const std::string& id, const FrameRecord& record, const FrameAccumulator& acc,
                  const AovAccumulator& aovs = {});
  FrameAccumulator load_frame(const std::string& id, long frame,
                              AovAccumulator* aovs = nullptr) const;
  void save_published(const std::string& id, long frame, std::uint64_t version);

  // ---- uploads ----
  // Stores an upload body under a temp name in the frame's upload directory (for checking).
  std::filesystem::path spool_upload(const std::string& id, long frame, const std::string& pass,
                                     const std::string& body);
  // Moves a checked spooled upload to its final name; returns the final path.
  std::filesystem::path commit_upload(const std::filesystem::path& spooled, const std::string& id,
                                      long frame, const std::string& pass);
  void remove_file(const std::filesystem::path& path) const;

 private:
  void hook(const std::string& op, const std::filesystem::path& path) const {
    if (hook_) hook_(op, path);
  }
  std::filesystem::path jobs_;
  FsHook hook_;
};

// Removes files of `dir` named <prefix>...tmp... (leftovers of interrupted atomic writes).
void remove_temp_files(const std::filesystem::path& dir, const std::string& prefix);

}  // namespace proden::daemon

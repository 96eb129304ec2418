// JobStore: the daemon's state directory on disk (layout in docs/api.md, "State directory"):
// one directory per job with job.json, quarantine.json, frames/<n>.state (the frame's state),
// frames/<n>.prev (the state before it: the last good state should <n>.state be damaged),
// frames/<n>.kept/ (the uploads accumulated by the latest state, kept until the next one so that
// falling back to <n>.prev loses nothing), frames/<n>.pub (the version last published),
// frames/<n>.history (the versions published), uploads/<n>/<pass>.exr and cache/. It saves
// atomically and durably and recovers what a previous process left (start-up). It holds no
// in-memory job state; the engine orders calls on one job.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "daemon/frame_state.hpp"
#include "proden/accumulator.hpp"
#include "proden/protocol/api.hpp"

namespace proden::daemon {

// Test hook on the daemon's file operations: called with the operation's name and path before it
// happens ("job", "open_job", "quarantine", "state", "published", "upload", "spooled",
// "fsync_dir", "read", "publish"); throwing from it simulates the fault (disk full, I/O error)
// at that point.
using FsHook = std::function<void(const std::string& op, const std::filesystem::path& path)>;

// A pass file waiting to be read into its frame: a watched file (identified by path, size and
// mtime at discovery) or a stored upload (identified by its content hash).
struct PendingPass {
  std::string pass;
  std::filesystem::path path;
  std::uint64_t size = 0;
  std::int64_t mtime_ns = 0;
  bool upload = false;
  std::uint64_t content_hash = 0;  // uploads: hash_bytes of the body (0: not known)
};

class JobStore {
 public:
  explicit JobStore(std::filesystem::path state_dir, FsHook hook = {});

  const std::filesystem::path& jobs_dir() const { return jobs_; }
  std::filesystem::path job_dir(const std::string& id) const;
  std::filesystem::path state_path(const std::string& id, long frame) const;
  std::filesystem::path prev_path(const std::string& id, long frame) const;
  std::filesystem::path kept_dir(const std::string& id, long frame) const;
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
  // Loads one job directory: its spec, quarantine records, frame records (a damaged state falls
  // back to the last good one; what happened is reported through `damaged(frame, message)`),
  // stored uploads; removes temp files left by an interrupted write. nullopt: an interrupted job
  // creation (no job.json and no state), removed. Throws when the job cannot be loaded (the
  // directory is left as it is).
  std::optional<LoadedJob> load_job(
      const std::filesystem::path& dir,
      const std::function<void(long frame, const std::string& message)>& damaged);

  // ---- frames ----
  // The commit point of a frame run, in two steps: begin_frame_save starts writing the
  // statistics (a frame run does so before its pipeline, which they overlap); commit_frame keeps
  // the current state as <n>.prev, then commits the new one with its record, atomically.
  // save_frame does both at once.
  std::unique_ptr<FrameStateWriter> begin_frame_save(const std::string& id, long frame,
                                                     const FrameAccumulator& acc,
                                                     const AovAccumulator& aovs);
  void commit_frame(const std::string& id, FrameStateWriter& writer, const FrameRecord& record);
  void save_frame(const std::string& id, const FrameRecord& record, const FrameAccumulator& acc,
                  const AovAccumulator& aovs = {});
  struct LoadedState {
    FrameAccumulator acc;
    FrameRecord record;
    AovAccumulator aovs;  // the renderer AOVs (issue 13)
    std::string damage;   // non-empty: <n>.state was damaged (moved aside); this is <n>.prev
  };
  // Loads the frame's state, falling back to the last good one; throws when neither loads.
  LoadedState load_frame(const std::string& id, long frame) const;
  // Moves a frame's unloadable state files aside (<n>.corrupt) so that it starts over.
  void set_aside(const std::string& id, long frame) const;
  // After a fall-back to `good`: the kept uploads it does not hold go back to uploads/ (to be
  // read again); returns them.
  std::vector<PendingPass> restore_kept(const std::string& id, long frame, const FrameRecord& good);
  // After a commit: the accumulated uploads `accepted` become the frame's kept uploads (moved
  // from uploads/), replacing the previous ones.
  void keep_uploads(const std::string& id, long frame, const std::vector<PendingPass>& accepted);
  void save_published(const std::string& id, long frame, std::uint64_t version);

  // ---- uploads ----
  // A unique temp path in the frame's upload directory (created, and made durable) for a body
  // streamed there.
  std::filesystem::path spool_path(const std::string& id, long frame, const std::string& pass);
  // Writes an upload body to a unique temp path (spool_path) and returns it.
  std::filesystem::path spool_upload(const std::string& id, long frame, const std::string& pass,
                                     const std::string& body);
  // Moves a checked spooled upload to its final name, durably; returns the final path.
  std::filesystem::path commit_upload(const std::filesystem::path& spooled, const std::string& id,
                                      long frame, const std::string& pass);
  void remove_file(const std::filesystem::path& path) const;

  // Calls the FsHook (if any) for an operation about to happen.
  void fault_point(const std::string& op, const std::filesystem::path& path) const {
    if (hook_) hook_(op, path);
  }

 private:
  void sync_dir(const std::filesystem::path& dir) const;
  std::filesystem::path jobs_;
  FsHook hook_;
};

// Removes files of `dir` named <prefix>...tmp... (leftovers of interrupted atomic writes).
void remove_temp_files(const std::filesystem::path& dir, const std::string& prefix);

}  // namespace proden::daemon

// FrameRun: one run of one frame, and the exactly-once protocol in one place (docs/api.md,
// "Ingestion rules"): read the batch's passes (each identified by path, size, mtime and content
// hash), accumulate them, persist the statistics and the pass identities together in one atomic
// file (the commit point), keep the accumulated uploads aside (until the next commit: they back
// the last good state), publish the new version, record it as published and announce it. A crash
// before the commit loses nothing (the passes are found again); after it, the version is
// re-published on restart, as itself, before new passes make the next one. A damaged state falls
// back to the last good one (an error event says so); nothing non-finite is ever committed.
#pragma once

#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "daemon/events.hpp"
#include "daemon/files.hpp"
#include "daemon/frame_state.hpp"
#include "daemon/job_store.hpp"
#include "daemon/metrics.hpp"
#include "daemon/quarantine.hpp"
#include "proden/accumulator.hpp"
#include "proden/aov.hpp"
#include "proden/io/image_header.hpp"
#include "proden/protocol/api.hpp"

namespace proden::daemon {

// <output.dir>/<output.name expanded>: the published files are this plus .exr (and .png).
std::filesystem::path output_base(const protocol::JobSpec& spec, long frame);

// Natural order of pass names: numbers numerically, then names (the order passes accumulate in).
bool pass_less(const std::string& a, const std::string& b);

// Publishes an `error` event (docs/api.md, "Events").
void publish_error(EventHub& events, const std::string& job, long frame, const std::string& pass,
                   const std::string& path, const std::string& kind, const std::string& message,
                   bool quarantined);

class FrameRun {
 public:
  // What the run reports as it goes (called from the worker thread, without locks held).
  struct Hooks {
    // A pass of the batch could not be read or accumulated.
    std::function<void(const PendingPass&, const Failure&)> failed;
    // The new state is persisted: `record` (with the accepted passes) is the frame's state now.
    std::function<void(const FrameRecord& record,
                       const std::vector<protocol::PassIdentity>& accepted)>
        committed;
    // Version `version` is published as `outputs`; `compress_later`: its EXR was written
    // uncompressed for output.compression `auto`, to be compressed when the daemon is idle.
    std::function<void(std::uint64_t version, const std::vector<std::string>& outputs,
                       bool compress_later)>
        published;
    // The persisted state was damaged and `record` (the last good state) replaced it: passes
    // that are not in it must be read again.
    std::function<void(const FrameRecord& record)> recovered;
  };
  FrameRun(JobStore& store, Metrics& metrics, EventHub& events, Hooks hooks);

  struct Input {
    protocol::JobSpec spec;
    long frame = 0;
    FrameRecord record;  // the frame's persisted state
    bool has_state = false;
    bool republish = false;                 // the persisted version is not published yet
    std::shared_ptr<FrameAccumulator> acc;  // resident state, or null (loaded from the store)
    std::shared_ptr<AovAccumulator> aovs;   // its renderer AOVs (resident with acc)
    std::vector<PendingPass> batch;         // passes to read, any order
    // Watched passes are read, and outputs written, beneath these roots (null: no confinement,
    // for tests of runs that read only stored uploads); reads are bounded by `limits`.
    const Roots* roots = nullptr;
    io::ReadLimits limits;
  };
  enum class Result {
    done,              // ran to the end (some passes may have failed)
    state_unreadable,  // neither the state nor the last good one could be loaded; nothing read
    failed,            // persisting or publishing failed; the resident state must be dropped
  };
  struct Outcome {
    Result result = Result::done;
    std::shared_ptr<FrameAccumulator> acc;  // the state to keep resident (when done)
    std::shared_ptr<AovAccumulator> aovs;
    bool committed = false;  // a new state was persisted
    std::string error;       // why it failed
  };
  Outcome run(Input in);

 private:
  Outcome commit_and_publish(const protocol::JobSpec& spec, long frame_no, FrameRecord& rec,
                             const std::shared_ptr<FrameAccumulator>& acc,
                             const std::shared_ptr<AovAccumulator>& aovs,
                             const std::vector<protocol::PassIdentity>& accepted,
                             const std::vector<PendingPass>& accepted_passes,
                             std::uint64_t accepted_bytes, const Roots* roots);
  JobStore& store_;
  Metrics& metrics_;
  EventHub& events_;
  Hooks hooks_;
};

}  // namespace proden::daemon

// Persistence of one frame: its accumulated statistics and the identities of the passes they
// contain, in ONE file written atomically (temp + fsync + rename), so that after a crash a pass
// is either in both or in neither: counted exactly once.
//
// File (version 4): "PRDNFRS4", u64 m, m bytes of blob: the accumulator
// (FrameAccumulator::serialize) then the renderer AOVs (AovAccumulator::serialize; the record's
// "accumulator_bytes" says where they start), u64 hash of every byte before it; then n bytes of
// JSON record, u64 n, u64 hash(JSON). The hashes, the blobs' checksums and the record's digest
// are XXH3 (checksum_bytes, proden/hash.hpp). Version 3 files ("PRDNFRS3", the same layout with
// hash_bytes throughout, their blobs and digest included) still load. The statistics come first so
// that they can be written and made durable while the pipeline runs, before the record (which holds
// the version's estimate) is known (FrameStateWriter). Every byte is covered: the two hashes, and
// the sizes, which must add up to the file's. The record can be read from the end without the rest
// (start-up). Version 2 files ("PRDNFRS2", u64 n, n bytes of JSON, u64 hash(JSON), u64 m, m bytes
// of blob, u64 hash of every byte before it) and version 1 ("PRDNFRS1": no m, no whole-file hash;
// the blob carries its own checksum) still load. Non-finite numbers are never written (JSON would
// turn them into null).
#pragma once

#include <cstdint>
#include <exception>
#include <filesystem>
#include <future>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "daemon/convergence.hpp"
#include "proden/accumulator.hpp"
#include "proden/aov.hpp"
#include "proden/protocol/api.hpp"

namespace proden::daemon {

struct FrameRecord {
  long frame = 0;
  std::uint64_t version = 0;
  std::string updated;
  double estimated_mse = 0.0;
  std::string estimated_mse_source = "variance";
  int passes = 0;
  double spp = 0.0;
  int width = 0, height = 0;
  std::string inputs, variance_source;
  bool low_confidence = false;
  std::uint64_t digest = 0;
  std::vector<protocol::PassIdentity> ingested;
  // Issue 13: the latest version's estimated_error object, what the passes were read as, the
  // renderer AOVs accumulated, the convergence state and the versions kept.
  nlohmann::json estimated_error;
  std::string renderer, view_layer;
  std::vector<std::string> view_layers;
  nlohmann::json aovs = nlohmann::json::array();  // [{"name", "mode"}]
  Convergence convergence;
  std::vector<std::uint64_t> versions;  // the versions whose images are kept, ascending
};

nlohmann::json to_json(const FrameRecord& r);
FrameRecord frame_record_from_json(const nlohmann::json& j);

// A state file written in two steps. The constructor starts writing the statistics to a temp
// file beside `path` on a thread of its own and makes them durable (fdatasync); commit() adds the
// record, syncs it and renames the file into place. `frame` is read by that thread: it must
// outlive the writer and not change meanwhile. Destroyed without a commit, it waits for the
// thread and removes the temp file.
class FrameStateWriter {
 public:
  FrameStateWriter(std::filesystem::path path, const FrameAccumulator& frame,
                   const AovAccumulator& aovs);
  FrameStateWriter(std::filesystem::path, FrameAccumulator&&, const AovAccumulator&) = delete;
  FrameStateWriter(const FrameStateWriter&) = delete;
  FrameStateWriter& operator=(const FrameStateWriter&) = delete;
  ~FrameStateWriter();
  // The digest of the statistics written (FrameAccumulator::state_digest), once they are.
  std::uint64_t digest();
  // Waits for the statistics, appends `record` (whose digest must be digest()), fsyncs and
  // renames over `path`, then syncs the directory. Throws (naming the file) on any failure;
  // `path` is then untouched (the destructor removes the temp file).
  void commit(const FrameRecord& record);
  const std::filesystem::path& path() const { return path_; }

 private:
  struct Written {
    std::uint64_t digest = 0;
    std::size_t accumulator_bytes = 0;
  };
  Written wait();
  std::filesystem::path path_, tmp_;
  int fd_ = -1;
  std::future<Written> blob_;
  std::optional<Written> written_;
  std::exception_ptr failed_;
};

void save_frame_state(const std::filesystem::path& path, const FrameRecord& record,
                      const FrameAccumulator& frame, const AovAccumulator& aovs = {});
// The file's bytes, and the inverse (both used by the functions above; bytes in, bytes out for
// the fuzz target fuzz/frame_state_fuzz.cpp). `name` names the file in errors. Throws on a corrupt
// or inconsistent state; a non-finite number in the record or the statistics is corrupt.
std::vector<std::uint8_t> frame_state_bytes(const FrameRecord& record,
                                            const FrameAccumulator& frame,
                                            const AovAccumulator& aovs = {});
FrameAccumulator parse_frame_state(std::span<const std::uint8_t> bytes, const std::string& name,
                                   FrameRecord* record, AovAccumulator* aovs = nullptr);
// Reads only the JSON record (fast). Throws std::runtime_error on a corrupt file.
FrameRecord load_frame_record(const std::filesystem::path& path);
// Reads the record and the accumulator (and, if `aovs`, the renderer AOVs). Throws on a corrupt
// file.
FrameAccumulator load_frame_accumulator(const std::filesystem::path& path, FrameRecord* record,
                                        AovAccumulator* aovs = nullptr);

}  // namespace proden::daemon

// FrameHistory: the versions a frame has published (time, passes, spp, the result's estimated
// error and the plain render's), one JSON line per version appended to
// state/jobs/<id>/frames/<n>.history; served by GET .../frames/{frame}/history for the
// dashboard's accuracy-over-time chart (docs/api.md). A record of what was published, not state:
// the frame's .state file stays the truth, so a line lost in a crash costs a chart point only.
#pragma once

#include <filesystem>

#include <nlohmann/json.hpp>

namespace proden::daemon {

class FrameHistory {
 public:
  // Appends `entry` (an object with a "version") as one line, in one write (O_APPEND).
  // Throws std::runtime_error naming the file.
  static void append(const std::filesystem::path& file, const nlohmann::json& entry);
  // The entries in version order, one per version (a version published again after a restart
  // keeps its last line); lines a crash left torn are skipped. Missing file: empty array.
  static nlohmann::json load(const std::filesystem::path& file);
};

}  // namespace proden::daemon

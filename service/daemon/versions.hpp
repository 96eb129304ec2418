// Version history of a published frame (docs/api.md, "Versions"): besides the latest
// <output.dir>/<name>.exr, every published version is kept as
// <output.dir>/versions/<name>.v<version, 4+ digits>.exr (a hard link to the published file where
// the file system allows, else a copy), and the frame's record lists the kept versions with a
// summary; the oldest beyond output.history are removed.
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "proden/protocol/api.hpp"

namespace proden::daemon {

struct VersionEntry {
  std::uint64_t version = 0;
  int passes = 0;
  double spp = 0.0;
  std::string updated;
  bool converged = false;
  nlohmann::json estimated_error;
};
nlohmann::json to_json(const VersionEntry& v);
VersionEntry version_entry_from_json(const nlohmann::json& j);

// <output.dir>/versions/<base name>.v<version>.exr
std::filesystem::path version_file(const protocol::JobSpec& spec, long frame,
                                   std::uint64_t version);

// Appends `entry` (the newest) to `list` and removes from it the entries beyond the latest plus
// `history` older ones; returns the removed ones (whose files the caller deletes).
std::vector<VersionEntry> add_version(std::vector<VersionEntry>& list, VersionEntry entry,
                                      int history);

// Makes `dest` a copy of the just-published `published` (hard link, else copy), atomically.
// Throws std::runtime_error naming the paths.
void keep_version(const std::filesystem::path& published, const std::filesystem::path& dest);

}  // namespace proden::daemon

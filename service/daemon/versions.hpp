// The images of older versions (docs/api.md, "History and older versions"): besides the latest
// <output.dir>/<name>.exr, every published version is kept as
// <output.dir>/versions/<name>.v<version, 4+ digits>.exr (a hard link to the published file where
// the file system allows, else a copy); the frame's record lists the version numbers kept, and
// the oldest beyond output.history are removed. What each version was worth is FrameHistory's.
#pragma once

#include <cstdint>
#include <filesystem>
#include <vector>

#include "proden/protocol/api.hpp"

namespace proden::daemon {

// <output.dir>/versions/<base name>.v<version>.exr
std::filesystem::path version_file(const protocol::JobSpec& spec, long frame,
                                   std::uint64_t version);

// Appends `version` (the newest) to `kept` (ascending) and removes from it the versions beyond the
// latest plus `history` older ones; returns the removed ones (whose files the caller deletes).
std::vector<std::uint64_t> add_version(std::vector<std::uint64_t>& kept, std::uint64_t version,
                                       int history);

// Makes `dest` a copy of the just-published `published` (hard link, else copy), atomically.
// Throws std::runtime_error naming the paths.
void keep_version(const std::filesystem::path& published, const std::filesystem::path& dest);

}  // namespace proden::daemon

// Reading a pass the engine is about to accumulate, at the moment of use: the file is opened once
// (a watched file beneath its allowed root's descriptor, a stored upload without following a
// symlink), and its size, mtime, content hash and pixels all come from that one descriptor's
// bytes, decoded from memory within the read limits (issue 11, classes 2 and 4).
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "daemon/files.hpp"
#include "daemon/job_store.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/pass.hpp"

namespace proden::daemon {

struct SourcedPass {
  std::uint64_t size = 0;
  std::int64_t mtime_ns = 0;
  std::uint64_t content_hash = 0;  // hash_bytes of the file
  Pass pass;
  io::PassInfo info;             // what the reader detected (renderer, view layers, AOVs)
  std::vector<AovChannel> aovs;  // the renderer AOVs, when asked for (issue 13)
};

// nullopt: the file is gone, or (a watched file) its size or mtime changed since it was found,
// so there is nothing to count now (the watcher offers it again once it settles). Throws
// proden::InputError: path_escape when its path leads out of the roots, too_large above
// `options.limits.max_file_bytes`, unreadable when it cannot be read, and whatever the pass reader
// refuses. `roots` may be null only where no watched files exist (stored uploads).
std::optional<SourcedPass> read_pending_pass(const PendingPass& p, const Roots* roots,
                                             const io::ReadOptions& options, bool aovs = false);

}  // namespace proden::daemon

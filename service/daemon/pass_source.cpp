#include "daemon/pass_source.hpp"

#include <fcntl.h>

#include <cerrno>
#include <cstring>

#include "proden/error.hpp"
#include "proden/hash.hpp"

namespace proden::daemon {

std::optional<SourcedPass> read_pending_pass(const PendingPass& p, const Roots* roots,
                                             const io::ReadOptions& options, bool aovs) {
  const std::string name = p.path.string();
  FileError err = FileError::none;
  std::string why;
  UniqueFd fd;
  if (p.upload || !roots) {
    const int f = open_regular_nofollow(p.path);
    if (f == -ENOENT) return std::nullopt;
    if (f < 0) throw InputError(InputErrorKind::unreadable, name, "cannot open the stored upload");
    fd = UniqueFd(f);
  } else {
    fd = roots->open(p.path, O_RDONLY | O_NOCTTY | O_NONBLOCK, err, why);
    if (!fd) {
      if (err == FileError::not_found) return std::nullopt;
      if (err == FileError::escape) throw InputError(InputErrorKind::path_escape, name, why);
      throw InputError(InputErrorKind::unreadable, name, why);
    }
  }
  auto file = read_fd(fd.get(), options.limits.max_file_bytes, err, why);
  if (!file) {
    if (err == FileError::too_large) throw InputError(InputErrorKind::too_large, name, why);
    throw InputError(InputErrorKind::unreadable, name, why);
  }
  if (!p.upload && (file->size != p.size || file->mtime_ns != p.mtime_ns)) return std::nullopt;
  SourcedPass out;
  out.size = file->size;
  out.mtime_ns = file->mtime_ns;
  out.content_hash = hash_bytes(std::span<const unsigned char>(file->bytes));
  out.pass = io::read_pass(io::MemorySource(file->bytes), name, options, &out.info,
                           aovs ? &out.aovs : nullptr);
  return out;
}

}  // namespace proden::daemon

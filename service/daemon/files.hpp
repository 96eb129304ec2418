// File-system helpers of the daemon: atomic writes (temp + fsync + rename + directory fsync),
// whole-file reads, and confinement of user-supplied paths to the configured allowed roots.
// Confinement is checked when a path is used, not only when it is accepted: every open below an
// allowed root is resolved relative to a descriptor held on that root, component by component,
// so a symlink or rename swapped in later cannot lead outside it (docs/api.md, "Security").
#pragma once

#include <sys/types.h>

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace proden::daemon {

// Writes `data` to `path` atomically; throws std::runtime_error naming the path.
void write_file_atomic(const std::filesystem::path& path, std::span<const std::uint8_t> data);
// The same for a file given in pieces, written in order (no copy of them into one buffer).
void write_file_atomic(const std::filesystem::path& path,
                       std::span<const std::span<const std::uint8_t>> pieces);
void write_file_atomic(const std::filesystem::path& path, const std::string& text);
// Makes the directory's entries (a rename or creation in it) durable.
void fsync_dir(const std::filesystem::path& dir);
// The temp name write_file_atomic writes `path` under (beside it, unique to this thread); the
// start-up clean-up removes such leftovers.
std::filesystem::path temp_path_for(const std::filesystem::path& path);
// Writes all of `data` to `fd`, retrying short writes; false (errno set) on failure.
bool write_all(int fd, std::span<const std::uint8_t> data);

// Reads a whole file; nullopt when it cannot be opened or read to the end.
std::optional<std::vector<std::uint8_t>> read_file(const std::filesystem::path& path,
                                                   std::uint64_t max_bytes = UINT64_MAX);

// A descriptor owned by its holder.
class UniqueFd {
 public:
  UniqueFd() = default;
  explicit UniqueFd(int fd) : fd_(fd) {}
  ~UniqueFd() { reset(); }
  UniqueFd(UniqueFd&& o) noexcept : fd_(o.release()) {}
  UniqueFd& operator=(UniqueFd&& o) noexcept {
    if (this != &o) reset(o.release());
    return *this;
  }
  UniqueFd(const UniqueFd&) = delete;
  UniqueFd& operator=(const UniqueFd&) = delete;
  int get() const { return fd_; }
  explicit operator bool() const { return fd_ >= 0; }
  int release() {
    const int f = fd_;
    fd_ = -1;
    return f;
  }
  void reset(int fd = -1);

 private:
  int fd_ = -1;
};

// ---- resolution beneath a directory descriptor ----------------------------------------------

// How open_beneath resolves: the kernel's openat2(RESOLVE_BENEATH) where it exists (probed once
// at run time), else a walk of openat(O_NOFOLLOW) per component. `walk` forces the walk (tests).
enum class Resolve { automatic, walk };

// True once openat2 was found to work on this kernel (after the first open_beneath).
bool kernel_has_openat2();

// Opens `relative` beneath the directory `root_fd`. Every component is resolved inside it: ".."
// may not climb above it; a relative symlink is followed while it stays inside; an absolute
// symlink is followed only if its target lies lexically under `root_path` (then re-anchored at
// `root_fd`); anything else fails with EXDEV. `flags` apply to the last component (add
// O_NOFOLLOW to refuse a symlink there). Returns the descriptor, or -errno.
int open_beneath(int root_fd, const std::filesystem::path& root_path, std::string_view relative,
                 int flags, mode_t mode = 0, Resolve how = Resolve::automatic);

// ---- allowed roots ----------------------------------------------------------------------------

// What a use of a path inside the roots may fail with.
enum class FileError { none, not_found, escape, not_regular, too_large, io };

struct FileBytes {
  std::vector<std::uint8_t> bytes;
  std::uint64_t size = 0;
  std::int64_t mtime_ns = 0;  // of the descriptor the bytes were read from
};

// Resolved allowed roots (absolute, symlinks resolved; each must exist), each with a descriptor
// held open for the daemon's lifetime.
class Roots {
 public:
  Roots() = default;
  explicit Roots(const std::vector<std::string>& roots);
  // Resolves `p` (must be absolute) to its real path and checks it lies inside a root. Refuses
  // `..` components before resolution. Returns nullopt with `why` set on refusal. (Accepting a
  // path; every later use goes through the descriptor-based functions below.)
  std::optional<std::filesystem::path> confine(const std::string& p, std::string& why) const;
  bool contains(const std::filesystem::path& real) const;
  const std::vector<std::filesystem::path>& list() const { return roots_; }

  // Opens `p` (absolute, lexically inside a root) beneath that root's descriptor at the moment
  // of use. On failure the descriptor is empty, `error` and `why` say why.
  UniqueFd open(const std::filesystem::path& p, int flags, FileError& error, std::string& why,
                Resolve how = Resolve::automatic) const;
  // A directory, for *at() calls (O_PATH would not allow fsync or reading entries).
  UniqueFd open_dir(const std::filesystem::path& p, FileError& error, std::string& why) const;
  // Creates the missing directories of `p` one by one with mkdirat beneath its root (never
  // following a symlink out), and returns the last one open.
  UniqueFd make_dirs(const std::filesystem::path& p, FileError& error, std::string& why) const;
  // Reads the regular file `p` through a descriptor opened beneath its root: bytes, size and
  // mtime all from that one descriptor. Never blocks on a FIFO or device.
  std::optional<FileBytes> read(const std::filesystem::path& p, std::uint64_t max_bytes,
                                FileError& error, std::string& why) const;

 private:
  // The root lexically containing `p` and the path below it.
  bool locate(const std::filesystem::path& p, std::size_t& root, std::string& relative) const;
  // The same, setting `error` (escape) and `why` when `p` is in no root.
  bool locate(const std::filesystem::path& p, std::size_t& root, std::string& relative,
              FileError& error, std::string& why) const;
  std::vector<std::filesystem::path> roots_;
  std::vector<std::shared_ptr<UniqueFd>> fds_;
};

// Reads the regular file open at `fd` (any position) to the end: bytes, size and mtime from the
// descriptor. nullopt with `error`/`why` on failure.
std::optional<FileBytes> read_fd(int fd, std::uint64_t max_bytes, FileError& error,
                                 std::string& why);

// Opens a regular file (not under the roots: the state directory) without following a symlink in
// the last component or blocking on a FIFO; -errno on failure.
int open_regular_nofollow(const std::filesystem::path& p);

// hash_bytes (proden/hash.hpp) of the first `size` bytes of an open file, read in chunks (never
// all in memory); nullopt when it cannot be read to `size`.
std::optional<std::uint64_t> hash_fd(int fd, std::uint64_t size);

std::int64_t mtime_ns(const std::filesystem::path& p, std::error_code& ec);

}  // namespace proden::daemon

// File-system helpers of the daemon: atomic writes (temp + fsync + rename + directory fsync),
// whole-file reads, and confinement of user-supplied paths to the configured allowed roots.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <span>
#include <string>
#include <vector>

namespace proden::daemon {

// Writes `data` to `path` atomically; throws std::runtime_error naming the path.
void write_file_atomic(const std::filesystem::path& path, std::span<const std::uint8_t> data);
void write_file_atomic(const std::filesystem::path& path, const std::string& text);
// Makes the directory's entries (a rename or creation in it) durable.
void fsync_dir(const std::filesystem::path& dir);

// Reads a whole file; nullopt when it cannot be opened or read to the end.
std::optional<std::vector<std::uint8_t>> read_file(const std::filesystem::path& path,
                                                   std::uint64_t max_bytes = UINT64_MAX);

// Resolved allowed roots (absolute, symlinks resolved; each must exist).
class Roots {
 public:
  Roots() = default;
  explicit Roots(const std::vector<std::string>& roots);
  // Resolves `p` (must be absolute) to its real path and checks it lies inside a root. Refuses
  // `..` components before resolution. Returns nullopt with `why` set on refusal.
  std::optional<std::filesystem::path> confine(const std::string& p, std::string& why) const;
  bool contains(const std::filesystem::path& real) const;
  const std::vector<std::filesystem::path>& list() const { return roots_; }

 private:
  std::vector<std::filesystem::path> roots_;
};

std::int64_t mtime_ns(const std::filesystem::path& p, std::error_code& ec);

}  // namespace proden::daemon

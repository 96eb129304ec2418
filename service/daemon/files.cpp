#include "daemon/files.hpp"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>

namespace proden::daemon {

namespace fs = std::filesystem;

void fsync_dir(const fs::path& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

void write_file_atomic(const fs::path& path, std::span<const std::uint8_t> data) {
  const fs::path dir = path.parent_path();
  fs::path tmp = dir / ("." + path.filename().string() + ".tmp" + std::to_string(::getpid()) + "." +
                        std::to_string(::gettid()));
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw std::runtime_error(path.string() + ": cannot create: " + std::strerror(errno));
  std::size_t done = 0;
  while (done < data.size()) {
    const ssize_t n = ::write(fd, data.data() + done, data.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const std::string why = std::strerror(errno);
      ::close(fd);
      ::unlink(tmp.c_str());
      throw std::runtime_error(path.string() + ": write failed: " + why);
    }
    done += static_cast<std::size_t>(n);
  }
  if (::fsync(fd) != 0 || ::close(fd) != 0) {
    ::unlink(tmp.c_str());
    throw std::runtime_error(path.string() + ": fsync failed");
  }
  if (::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string why = std::strerror(errno);
    ::unlink(tmp.c_str());
    throw std::runtime_error(path.string() + ": rename failed: " + why);
  }
  fsync_dir(dir);
}

void write_file_atomic(const fs::path& path, const std::string& text) {
  write_file_atomic(path, std::span<const std::uint8_t>(
                              reinterpret_cast<const std::uint8_t*>(text.data()), text.size()));
}

std::optional<std::vector<std::uint8_t>> read_file(const fs::path& path, std::uint64_t max_bytes) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return std::nullopt;
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode) ||
      static_cast<std::uint64_t>(st.st_size) > max_bytes) {
    ::close(fd);
    return std::nullopt;
  }
  std::vector<std::uint8_t> out(static_cast<std::size_t>(st.st_size));
  std::size_t done = 0;
  while (done < out.size()) {
    const ssize_t n = ::read(fd, out.data() + done, out.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {  // error, or the file shrank under us
      ::close(fd);
      return std::nullopt;
    }
    done += static_cast<std::size_t>(n);
  }
  ::close(fd);
  return out;
}

Roots::Roots(const std::vector<std::string>& roots) {
  for (const auto& r : roots) {
    std::error_code ec;
    fs::path real = fs::canonical(fs::absolute(r), ec);
    if (ec) throw std::runtime_error("allowed root " + r + ": " + ec.message());
    if (!fs::is_directory(real))
      throw std::runtime_error("allowed root " + r + ": not a directory");
    roots_.push_back(real);
  }
}

bool Roots::contains(const fs::path& real) const {
  for (const auto& root : roots_) {
    auto r = root.begin();
    auto p = real.begin();
    for (; r != root.end() && p != real.end(); ++r, ++p) {
      if (*r != *p) break;
    }
    if (r == root.end()) return true;
  }
  return false;
}

std::optional<fs::path> Roots::confine(const std::string& p, std::string& why) const {
  const fs::path path(p);
  if (p.empty() || !path.is_absolute()) {
    why = "must be an absolute path";
    return std::nullopt;
  }
  for (const auto& part : path) {
    if (part == "..") {
      why = "'..' components are not allowed";
      return std::nullopt;
    }
  }
  std::error_code ec;
  // weakly_canonical resolves every symlink of the existing prefix, so a link pointing outside a
  // root is seen at its real location.
  fs::path real = fs::weakly_canonical(path, ec);
  if (ec) {
    why = "cannot resolve: " + ec.message();
    return std::nullopt;
  }
  if (!contains(real)) {
    why = "resolves to " + real.string() + ", outside the allowed roots";
    return std::nullopt;
  }
  return real;
}

std::int64_t mtime_ns(const fs::path& p, std::error_code& ec) {
  struct stat st {};
  if (::stat(p.c_str(), &st) != 0) {
    ec = std::error_code(errno, std::generic_category());
    return 0;
  }
  ec.clear();
  return static_cast<std::int64_t>(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
}

}  // namespace proden::daemon

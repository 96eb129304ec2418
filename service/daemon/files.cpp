#include "daemon/files.hpp"

#include <fcntl.h>
#include <linux/openat2.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <climits>
#include <cstring>
#include <deque>
#include <stdexcept>
#include <vector>

#include "proden/hash.hpp"

namespace proden::daemon {

namespace fs = std::filesystem;

void fsync_dir(const fs::path& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY);
  if (fd < 0) return;
  ::fsync(fd);
  ::close(fd);
}

void write_file_atomic(const fs::path& path, std::span<const std::uint8_t> data) {
  const std::span<const std::uint8_t> one[] = {data};
  write_file_atomic(path, one);
}

fs::path temp_path_for(const fs::path& path) {
  return path.parent_path() / ("." + path.filename().string() + ".tmp" +
                               std::to_string(::getpid()) + "." + std::to_string(::gettid()));
}

bool write_all(int fd, std::span<const std::uint8_t> data) {
  std::size_t done = 0;
  while (done < data.size()) {
    const ssize_t n = ::write(fd, data.data() + done, data.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      if (n == 0) errno = EIO;
      return false;
    }
    done += static_cast<std::size_t>(n);
  }
  return true;
}

void write_file_atomic(const fs::path& path,
                       std::span<const std::span<const std::uint8_t>> pieces) {
  const fs::path dir = path.parent_path();
  const fs::path tmp = temp_path_for(path);
  const int fd = ::open(tmp.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) throw std::runtime_error(path.string() + ": cannot create: " + std::strerror(errno));
  for (const auto& data : pieces) {
    if (!write_all(fd, data)) {
      const std::string why = std::strerror(errno);
      ::close(fd);
      ::unlink(tmp.c_str());
      throw std::runtime_error(path.string() + ": write failed: " + why);
    }
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

void UniqueFd::reset(int fd) {
  if (fd_ >= 0) ::close(fd_);
  fd_ = fd;
}

// ---- resolution beneath a directory descriptor ----------------------------------------------

namespace {

// -1: not probed yet, 0: no openat2 (ENOSYS, or refused by a sandbox), 1: works.
std::atomic<int> g_openat2{-1};

// Path components, without empty ones and ".".
std::deque<std::string> components(std::string_view p) {
  std::deque<std::string> out;
  std::size_t start = 0;
  while (start <= p.size()) {
    const std::size_t end = std::min(p.find('/', start), p.size());
    const std::string_view c = p.substr(start, end - start);
    if (!c.empty() && c != ".") out.emplace_back(c);
    start = end + 1;
  }
  return out;
}

int try_openat2(int dirfd, const char* path, int flags, mode_t mode) {
  open_how how{};
  how.flags = static_cast<std::uint64_t>(flags | O_CLOEXEC);
  how.mode = (flags & O_CREAT) ? mode : 0;
  how.resolve = RESOLVE_BENEATH | RESOLVE_NO_MAGICLINKS;
  for (int attempt = 0; attempt < 3; ++attempt) {
    const long r = ::syscall(SYS_openat2, dirfd, path, &how, sizeof how);
    if (r >= 0) return static_cast<int>(r);
    if (errno != EAGAIN && errno != EINTR) return -errno;  // EAGAIN: a rename raced; retry
  }
  return -EAGAIN;
}

// The userspace form of RESOLVE_BENEATH (also what decides cases openat2 refuses outright, such
// as an absolute symlink that names a place inside the root): a stack of directory descriptors
// below the root, each component opened with O_NOFOLLOW relative to the one above it.
int walk_beneath(int root_fd, const fs::path& root_path, std::string_view relative, int flags,
                 mode_t mode) {
  std::vector<UniqueFd> stack;
  const auto cur = [&] { return stack.empty() ? root_fd : stack.back().get(); };
  std::deque<std::string> todo = components(relative);
  if (todo.empty()) {
    const int fd = ::openat(root_fd, ".", (flags & ~(O_CREAT | O_EXCL | O_NOFOLLOW)) | O_CLOEXEC);
    return fd >= 0 ? fd : -errno;
  }
  int links = 0;
  while (!todo.empty()) {
    const std::string name = std::move(todo.front());
    todo.pop_front();
    const bool last = todo.empty();
    if (name == "..") {
      if (stack.empty()) return -EXDEV;  // above the root
      stack.pop_back();
      if (last) {
        const int fd = ::openat(cur(), ".", (flags & ~(O_CREAT | O_EXCL | O_NOFOLLOW)) | O_CLOEXEC);
        return fd >= 0 ? fd : -errno;
      }
      continue;
    }
    const int f =
        last ? (flags | O_NOFOLLOW | O_CLOEXEC) : (O_PATH | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
    int err = 0;
    const int fd = ::openat(cur(), name.c_str(), f, mode);
    if (fd >= 0) {
      struct stat st {};
      // O_PATH|O_NOFOLLOW opens a symlink itself: only return it if the caller asked for that.
      if (last && (flags & O_PATH) && !(flags & O_NOFOLLOW) && ::fstat(fd, &st) == 0 &&
          S_ISLNK(st.st_mode)) {
        ::close(fd);
        err = ELOOP;
      } else if (last) {
        return fd;
      } else {
        stack.emplace_back(fd);
        continue;
      }
    } else {
      err = errno;
    }
    if (err != ELOOP && err != ENOTDIR && err != EEXIST) return -err;
    // Refused because it is a symlink? Then follow it by hand, still beneath the root.
    char buf[PATH_MAX];
    const ssize_t n = ::readlinkat(cur(), name.c_str(), buf, sizeof buf);
    if (n < 0) return -err;  // not a symlink: the open's own error stands
    if (static_cast<std::size_t>(n) >= sizeof buf) return -ENAMETOOLONG;
    if (last && (flags & O_NOFOLLOW)) return -ELOOP;
    if (last && (flags & O_CREAT) && (flags & O_EXCL)) return -EEXIST;
    if (++links > 40) return -ELOOP;
    const std::string_view target(buf, static_cast<std::size_t>(n));
    std::deque<std::string> parts = components(target);
    if (!target.empty() && target.front() == '/') {
      // Absolute: only a target lexically under the root's own path, re-anchored at the root.
      auto r = components(root_path.string());
      for (const auto& rc : r) {
        if (parts.empty() || parts.front() != rc) return -EXDEV;
        parts.pop_front();
      }
      stack.clear();
    }
    todo.insert(todo.begin(), parts.begin(), parts.end());
    if (todo.empty()) {  // a link to the root itself
      const int rfd = ::openat(cur(), ".", (flags & ~(O_CREAT | O_EXCL | O_NOFOLLOW)) | O_CLOEXEC);
      return rfd >= 0 ? rfd : -errno;
    }
  }
  return -ENOENT;
}

}  // namespace

bool kernel_has_openat2() {
  return g_openat2.load() == 1;
}

int open_beneath(int root_fd, const fs::path& root_path, std::string_view relative, int flags,
                 mode_t mode, Resolve how) {
  if (how == Resolve::automatic && g_openat2.load() != 0) {
    const std::string rel = relative.empty() ? std::string(".") : std::string(relative);
    const int fd = try_openat2(root_fd, rel.c_str(), flags, mode);
    if (g_openat2.load() < 0) {
      // ENOSYS: old kernel; EPERM: a seccomp filter; E2BIG/EINVAL: a struct it does not know.
      const bool missing = fd == -ENOSYS || fd == -EPERM || fd == -E2BIG;
      g_openat2.store(missing ? 0 : 1);
      if (missing) return walk_beneath(root_fd, root_path, relative, flags, mode);
    }
    // EXDEV/ELOOP: a ".." or a symlink leaving the root, or an absolute symlink; EAGAIN: renames
    // kept racing. The walk gives the answer (it accepts only absolute links inside the root).
    if (fd != -EXDEV && fd != -ELOOP && fd != -EAGAIN) return fd;
  }
  return walk_beneath(root_fd, root_path, relative, flags, mode);
}

// ---- allowed roots ----------------------------------------------------------------------------

Roots::Roots(const std::vector<std::string>& roots) {
  for (const auto& r : roots) {
    std::error_code ec;
    fs::path real = fs::canonical(fs::absolute(r), ec);
    if (ec) throw std::runtime_error("allowed root " + r + ": " + ec.message());
    if (!fs::is_directory(real))
      throw std::runtime_error("allowed root " + r + ": not a directory");
    const int fd = ::open(real.c_str(), O_PATH | O_DIRECTORY | O_CLOEXEC);
    if (fd < 0) throw std::runtime_error("allowed root " + r + ": " + std::strerror(errno));
    roots_.push_back(real);
    fds_.push_back(std::make_shared<UniqueFd>(fd));
  }
}

bool Roots::locate(const fs::path& p, std::size_t& root, std::string& relative, FileError& error,
                   std::string& why) const {
  if (locate(p, root, relative)) return true;
  error = FileError::escape;
  why = p.string() + " is not inside the allowed roots";
  return false;
}

bool Roots::locate(const fs::path& p, std::size_t& root, std::string& relative) const {
  if (!p.is_absolute()) return false;
  std::size_t best_len = 0;
  bool found = false;
  for (std::size_t i = 0; i < roots_.size(); ++i) {
    auto r = roots_[i].begin();
    auto q = p.begin();
    std::size_t n = 0;
    for (; r != roots_[i].end() && q != p.end(); ++r, ++q, ++n) {
      if (*r != *q) break;
    }
    if (r == roots_[i].end() && (!found || n > best_len)) {
      found = true;
      best_len = n;
      root = i;
      relative.clear();
      for (; q != p.end(); ++q) {
        if (*q == "..") return false;
        if (q->empty() || *q == ".") continue;
        if (!relative.empty()) relative += '/';
        relative += q->string();
      }
    }
  }
  return found;
}

UniqueFd Roots::open(const fs::path& p, int flags, FileError& error, std::string& why,
                     Resolve how) const {
  std::size_t root = 0;
  std::string rel;
  if (!locate(p, root, rel, error, why)) return {};
  const int fd = open_beneath(fds_[root]->get(), roots_[root], rel, flags, 0644, how);
  if (fd >= 0) {
    error = FileError::none;
    return UniqueFd(fd);
  }
  switch (-fd) {
    case ENOENT:
    case ENOTDIR:
      error = FileError::not_found;
      why = p.string() + ": no such file or directory";
      break;
    case EXDEV:
      error = FileError::escape;
      why = p.string() + ": a symlink or '..' leads outside the allowed root " +
            roots_[root].string();
      break;
    case ELOOP:
      error = FileError::escape;
      why = p.string() + ": too many symlinks, or a symlink where none is allowed";
      break;
    default:
      error = FileError::io;
      why = p.string() + ": " + std::strerror(-fd);
  }
  return {};
}

UniqueFd Roots::open_dir(const fs::path& p, FileError& error, std::string& why) const {
  return open(p, O_RDONLY | O_DIRECTORY, error, why);
}

UniqueFd Roots::make_dirs(const fs::path& p, FileError& error, std::string& why) const {
  std::size_t root = 0;
  std::string rel;
  if (!locate(p, root, rel, error, why)) return {};
  const auto parts = components(rel);
  UniqueFd dir(::openat(fds_[root]->get(), ".", O_RDONLY | O_DIRECTORY | O_CLOEXEC));
  std::string prefix;
  for (const auto& part : parts) {
    prefix += (prefix.empty() ? "" : "/") + part;
    int fd = open_beneath(fds_[root]->get(), roots_[root], prefix, O_RDONLY | O_DIRECTORY);
    if (fd == -ENOENT) {
      // Create it inside the directory already resolved, then open exactly that entry.
      if (::mkdirat(dir.get(), part.c_str(), 0755) != 0 && errno != EEXIST) {
        error = FileError::io;
        why = p.string() + ": cannot create " + prefix + ": " + std::strerror(errno);
        return {};
      }
      fd = ::openat(dir.get(), part.c_str(), O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
      if (fd < 0) fd = -errno;
    }
    if (fd < 0) {
      error = (fd == -EXDEV || fd == -ELOOP) ? FileError::escape : FileError::io;
      why = p.string() + ": " + prefix + ": " +
            (fd == -EXDEV ? std::string("leads outside the allowed root") : std::strerror(-fd));
      return {};
    }
    dir.reset(fd);
  }
  error = FileError::none;
  return dir;
}

std::optional<FileBytes> read_fd(int fd, std::uint64_t max_bytes, FileError& error,
                                 std::string& why) {
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    error = FileError::io;
    why = std::string("cannot stat: ") + std::strerror(errno);
    return std::nullopt;
  }
  if (!S_ISREG(st.st_mode)) {
    error = FileError::not_regular;
    why = "not a regular file";
    return std::nullopt;
  }
  const auto size = static_cast<std::uint64_t>(st.st_size);
  if (size > max_bytes) {
    error = FileError::too_large;
    why = "file of " + std::to_string(size) + " bytes is above the limit of " +
          std::to_string(max_bytes);
    return std::nullopt;
  }
  FileBytes out;
  out.size = size;
  out.mtime_ns = static_cast<std::int64_t>(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec;
  out.bytes.resize(static_cast<std::size_t>(size));
  std::size_t done = 0;
  while (done < out.bytes.size()) {
    const ssize_t n =
        ::pread(fd, out.bytes.data() + done, out.bytes.size() - done, static_cast<off_t>(done));
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      error = FileError::io;
      why = n < 0 ? std::string("read failed: ") + std::strerror(errno)
                  : "the file shrank while it was read";
      return std::nullopt;
    }
    done += static_cast<std::size_t>(n);
  }
  error = FileError::none;
  return out;
}

std::optional<FileBytes> Roots::read(const fs::path& p, std::uint64_t max_bytes, FileError& error,
                                     std::string& why) const {
  const UniqueFd fd = open(p, O_RDONLY | O_NOCTTY | O_NONBLOCK, error, why);
  if (!fd) return std::nullopt;
  auto r = read_fd(fd.get(), max_bytes, error, why);
  if (!r) why = p.string() + ": " + why;
  return r;
}

int open_regular_nofollow(const fs::path& p) {
  const int fd = ::open(p.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_NOCTTY | O_CLOEXEC);
  if (fd < 0) return -errno;
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    ::close(fd);
    return -EINVAL;
  }
  return fd;
}

std::optional<std::uint64_t> hash_fd(int fd, std::uint64_t size) {
  ByteHasher h(size);
  std::vector<unsigned char> buf(std::size_t{1} << 20);
  for (std::uint64_t at = 0; at < size;) {
    const std::size_t want =
        static_cast<std::size_t>(std::min<std::uint64_t>(buf.size(), size - at));
    const ssize_t got = ::pread(fd, buf.data(), want, static_cast<off_t>(at));
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0) return std::nullopt;
    h.update({buf.data(), static_cast<std::size_t>(got)});
    at += static_cast<std::uint64_t>(got);
  }
  return h.finish();
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

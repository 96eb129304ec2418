#include "daemon/watcher.hpp"

#include <poll.h>
#include <spdlog/spdlog.h>
#include <sys/eventfd.h>
#include <sys/inotify.h>
#include <unistd.h>

#include <cstring>

namespace proden::daemon {

namespace fs = std::filesystem;
using Steady = std::chrono::steady_clock;

bool is_temp_name(const std::string& name) {
  if (name.empty() || name.front() == '.' || name.back() == '~') return true;
  if (name.size() >= 4 && name.compare(name.size() - 4, 4, ".tmp") == 0) return true;
  return name.find(".partial") != std::string::npos;
}

Watcher::Watcher(const WatchConfig& config, const Roots& roots, Callbacks callbacks)
    : config_(config), roots_(roots), cb_(std::move(callbacks)) {
  inotify_fd_ = config_.inotify ? ::inotify_init1(IN_NONBLOCK | IN_CLOEXEC) : -1;
  if (config_.inotify && inotify_fd_ < 0) {
    spdlog::warn("inotify unavailable ({}); relying on polling every {} ms", std::strerror(errno),
                 config_.poll_interval_ms);
  }
  wake_fd_ = ::eventfd(0, EFD_NONBLOCK | EFD_CLOEXEC);
}

Watcher::~Watcher() {
  stop();
  if (inotify_fd_ >= 0) ::close(inotify_fd_);
  if (wake_fd_ >= 0) ::close(wake_fd_);
}

void Watcher::start() {
  thread_ = std::thread([this] { run(); });
}

void Watcher::stop() {
  stop_ = true;
  const std::uint64_t one = 1;
  if (wake_fd_ >= 0) [[maybe_unused]]
    auto n = ::write(wake_fd_, &one, sizeof one);
  if (thread_.joinable()) thread_.join();
}

void Watcher::rescan() {
  rescan_ = true;
  const std::uint64_t one = 1;
  if (wake_fd_ >= 0) [[maybe_unused]]
    auto n = ::write(wake_fd_, &one, sizeof one);
}

bool Watcher::add_job(const std::string& id, const fs::path& dir, const std::string& pattern) {
  std::string why;
  auto compiled = PassPattern::parse(pattern, why);
  if (!compiled) {  // e.g. a job persisted before the pattern grammar was bounded
    spdlog::error("job {}: watch.pattern '{}' is not watched: {}", id, pattern, why);
    return false;
  }
  {
    std::lock_guard lock(mu_);
    jobs_.erase(id);
    jobs_.emplace(id, Job{dir, std::move(*compiled)});
    watch_dir(id, dir, 0);
  }
  rescan();
  return true;
}

void Watcher::remove_job(const std::string& id) {
  std::lock_guard lock(mu_);
  jobs_.erase(id);
  for (auto it = watches_.begin(); it != watches_.end();) {
    std::erase_if(it->second, [&](const WatchRef& r) { return r.job == id; });
    if (it->second.empty()) {
      if (inotify_fd_ >= 0) ::inotify_rm_watch(inotify_fd_, it->first);
      it = watches_.erase(it);
    } else {
      ++it;
    }
  }
  std::erase_if(candidates_, [&](const auto& kv) { return kv.first.first == id; });
}

void Watcher::watch_dir(const std::string& id, const fs::path& dir, int depth) {
  auto job = jobs_.find(id);
  if (job == jobs_.end()) return;
  if (inotify_fd_ >= 0) {
    const int wd =
        ::inotify_add_watch(inotify_fd_, dir.c_str(),
                            IN_CLOSE_WRITE | IN_MOVED_TO | IN_CREATE | IN_MOVE_SELF | IN_ONLYDIR);
    if (wd >= 0) {
      auto& refs = watches_[wd];
      bool have = false;
      for (const auto& r : refs) have = have || (r.job == id && r.dir == dir);
      if (!have) refs.push_back({id, dir, depth});
    }
  }
  if (depth >= job->second.pattern.depth() || depth >= config_.max_depth) return;
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->is_directory(ec) && !it->is_symlink(ec)) watch_dir(id, it->path(), depth + 1);
  }
}

void Watcher::run() {
  auto last_scan = Steady::now() - std::chrono::hours(1);
  while (!stop_) {
    pollfd fds[2] = {{inotify_fd_, POLLIN, 0}, {wake_fd_, POLLIN, 0}};
    ::poll(fds, 2, config_.tick_ms);
    if (stop_) break;
    if (fds[1].revents & POLLIN) {
      std::uint64_t v;
      [[maybe_unused]] auto n = ::read(wake_fd_, &v, sizeof v);
    }
    std::lock_guard lock(mu_);
    try {
      if (inotify_fd_ >= 0 && (fds[0].revents & POLLIN)) read_inotify();
      const auto now = Steady::now();
      if (rescan_.exchange(false) ||
          now - last_scan >= std::chrono::milliseconds(config_.poll_interval_ms)) {
        for (const auto& [id, job] : jobs_) scan_job(id, job);
        last_scan = now;
      }
      check_candidates();
    } catch (const std::exception& e) {
      spdlog::error("watcher: {}", e.what());
    }
  }
}

void Watcher::read_inotify() {
  alignas(inotify_event) char buf[64 * 1024];
  for (;;) {
    const ssize_t len = ::read(inotify_fd_, buf, sizeof buf);
    if (len <= 0) break;
    for (ssize_t off = 0; off < len;) {
      inotify_event ev;
      std::memcpy(&ev, buf + off, sizeof ev);
      const std::string name = ev.len > 0 ? std::string(buf + off + sizeof(inotify_event)) : "";
      off += static_cast<ssize_t>(sizeof(inotify_event) + ev.len);
      if (ev.mask & IN_Q_OVERFLOW) {
        rescan_ = true;
        continue;
      }
      auto it = watches_.find(ev.wd);
      if (it == watches_.end()) continue;
      if (ev.mask & IN_IGNORED) {
        watches_.erase(it);
        continue;
      }
      if (ev.mask & IN_MOVE_SELF) {
        // A watched directory moved (perhaps out of the roots): its events would be reported
        // under its old path. Drop the watch; the next scan watches whatever is there now.
        ::inotify_rm_watch(inotify_fd_, ev.wd);
        watches_.erase(it);
        rescan_ = true;
        continue;
      }
      const auto refs = it->second;
      for (const auto& ref : refs) {
        auto job = jobs_.find(ref.job);
        if (job == jobs_.end() || name.empty()) continue;
        const fs::path path = ref.dir / name;
        if (ev.mask & IN_ISDIR) {
          if ((ev.mask & (IN_CREATE | IN_MOVED_TO)) && ref.depth < job->second.pattern.depth()) {
            watch_dir(ref.job, path, ref.depth + 1);
            scan_dir(ref.job, job->second, path, ref.depth + 1);  // files that beat the watch
          }
        } else if (ev.mask & (IN_CLOSE_WRITE | IN_MOVED_TO)) {
          consider(ref.job, job->second, path);
        }
      }
    }
  }
}

void Watcher::scan_job(const std::string& id, const Job& job) {
  watch_dir(id, job.dir, 0);  // picks up directories inotify may have missed
  scan_dir(id, job, job.dir, 0);
}

void Watcher::scan_dir(const std::string& id, const Job& job, const fs::path& dir, int depth) {
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code e2;
    if (it->is_directory(e2) && !it->is_symlink(e2)) {
      if (depth < job.pattern.depth() && depth < config_.max_depth) {
        scan_dir(id, job, it->path(), depth + 1);
      }
    } else {
      consider(id, job, it->path());
    }
  }
}

void Watcher::consider(const std::string& id, const Job& job, const fs::path& path) {
  if (is_temp_name(path.filename().string())) return;
  const auto m = job.pattern.match(path.lexically_relative(job.dir).generic_string());
  if (!m) return;
  const auto key = std::make_pair(id, path.string());
  if (candidates_.count(key)) return;
  std::error_code ec;
  const auto st = fs::symlink_status(path, ec);
  if (ec) return;
  FoundFile f{id, m->frame, m->pass, path, 0, 0};
  if (fs::is_symlink(st)) {
    const fs::path real = fs::canonical(path, ec);
    if (ec || !roots_.contains(real)) {
      if (refused_.insert(key).second) {
        cb_.refused(f, ec ? "dangling symlink" : "symlink resolves outside the allowed roots");
      }
      return;
    }
  }
  if (!fs::is_regular_file(path, ec)) return;
  f.size = fs::file_size(path, ec);
  if (ec) return;
  f.mtime_ns = mtime_ns(path, ec);
  if (ec) return;
  if (!cb_.wanted(f)) return;
  candidates_.emplace(key, Candidate{f, Steady::now()});
}

void Watcher::check_candidates() {
  const auto now = Steady::now();
  const auto settle = std::chrono::milliseconds(config_.settle_ms);
  for (auto it = candidates_.begin(); it != candidates_.end();) {
    Candidate& c = it->second;
    std::error_code ec;
    const std::uint64_t size = fs::file_size(c.file.path, ec);
    const std::int64_t mt = ec ? 0 : mtime_ns(c.file.path, ec);
    if (ec) {  // gone (e.g. a temp file renamed away)
      it = candidates_.erase(it);
      continue;
    }
    if (size != c.file.size || mt != c.file.mtime_ns) {
      c.file.size = size;
      c.file.mtime_ns = mt;
      c.changed = now;
      ++it;
      continue;
    }
    if (size == 0 || now - c.changed < settle) {  // placeholder, or not settled yet
      ++it;
      continue;
    }
    if (cb_.wanted(c.file)) cb_.offer(c.file);
    it = candidates_.erase(it);
  }
}

}  // namespace proden::daemon

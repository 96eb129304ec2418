#include "daemon/job_store.hpp"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <fstream>
#include <map>
#include <set>
#include <system_error>

#include "daemon/files.hpp"
#include "proden/hash.hpp"

namespace proden::daemon {

namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// Whether `dir` holds any file (at any depth).
bool holds_files(const fs::path& dir) {
  std::error_code ec;
  for (fs::recursive_directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (!it->is_directory(ec)) return true;
  }
  return false;
}

std::optional<long> frame_number(const std::string& s) {
  if (s.empty() || s.size() > 9 || !std::all_of(s.begin(), s.end(), ::isdigit)) {
    return std::nullopt;
  }
  return std::stol(s);
}

// hash_bytes of a stored upload's content (0 when unreadable): its identity for idempotent
// re-uploads.
std::uint64_t content_hash(const fs::path& p) {
  const auto bytes = read_file(p);
  return bytes ? hash_bytes(std::span<const unsigned char>(*bytes)) : 0;
}

bool has_pass(const FrameRecord& r, const std::string& pass) {
  return std::any_of(r.ingested.begin(), r.ingested.end(),
                     [&](const auto& i) { return i.pass == pass; });
}

}  // namespace

void remove_temp_files(const fs::path& dir, const std::string& prefix) {
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string n = it->path().filename().string();
    if (n.rfind(prefix, 0) == 0 && n.find(".tmp") != std::string::npos) fs::remove(it->path(), ec);
  }
}

JobStore::JobStore(fs::path state_dir, FsHook hook)
    : jobs_(std::move(state_dir) / "jobs"), hook_(std::move(hook)) {}

fs::path JobStore::job_dir(const std::string& id) const {
  return jobs_ / id;
}

fs::path JobStore::state_path(const std::string& id, long frame) const {
  return job_dir(id) / "frames" / (std::to_string(frame) + ".state");
}

fs::path JobStore::prev_path(const std::string& id, long frame) const {
  return job_dir(id) / "frames" / (std::to_string(frame) + ".prev");
}

fs::path JobStore::kept_dir(const std::string& id, long frame) const {
  return job_dir(id) / "frames" / (std::to_string(frame) + ".kept");
}

fs::path JobStore::published_path(const std::string& id, long frame) const {
  return job_dir(id) / "frames" / (std::to_string(frame) + ".pub");
}

fs::path JobStore::history_path(const std::string& id, long frame) const {
  return job_dir(id) / "frames" / (std::to_string(frame) + ".history");
}

fs::path JobStore::upload_dir(const std::string& id, long frame) const {
  return job_dir(id) / "uploads" / std::to_string(frame);
}

fs::path JobStore::cache_dir(const std::string& id) const {
  return job_dir(id) / "cache";
}

void JobStore::sync_dir(const fs::path& dir) const {
  fault_point("fsync_dir", dir);
  fsync_dir(dir);
}

// ---- jobs ------------------------------------------------------------------------------------

void JobStore::create_job(const protocol::JobSpec& spec) {
  fs::create_directories(job_dir(spec.id) / "frames");
  fs::create_directories(job_dir(spec.id) / "uploads");
  save_job(spec.id, protocol::to_json(spec).dump(2, ' ', false, json::error_handler_t::replace));
  sync_dir(jobs_);
}

void JobStore::save_job(const std::string& id, const std::string& job_json) {
  const fs::path p = job_dir(id) / "job.json";
  fault_point("job", p);
  write_file_atomic(p, job_json);
}

void JobStore::save_quarantine(const std::string& id, const std::string& quarantine_json) {
  const fs::path p = job_dir(id) / "quarantine.json";
  fault_point("quarantine", p);
  write_file_atomic(p, quarantine_json);
}

void JobStore::remove_job(const std::string& id) {
  std::error_code ec;
  fs::remove_all(job_dir(id), ec);
}

std::optional<JobStore::LoadedJob> JobStore::load_job(
    const fs::path& dir, const std::function<void(long, const std::string&)>& damaged) {
  LoadedJob job;
  {
    const fs::path jp = dir / "job.json";
    fault_point("open_job", jp);
    const int fd = ::open(jp.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) {
      const int err = errno;
      // Only a creation interrupted before job.json (nothing but empty directories) is removed;
      // anything else is left for the operator.
      if (err == ENOENT && !holds_files(dir)) {
        spdlog::warn("state: {} has no job.json and no state (interrupted creation); removing",
                     dir.string());
        std::error_code ec;
        fs::remove_all(dir, ec);
        return std::nullopt;
      }
      throw std::runtime_error(jp.string() + ": cannot open (" + std::strerror(err) +
                               "); the job is not loaded and its state is left in place");
    }
    ::close(fd);
    std::ifstream in(jp);
    job.spec = protocol::job_from_json(json::parse(in));
  }
  if (std::ifstream q(dir / "quarantine.json"); q) {
    // Unparseable records are dropped, not the job: their files are simply tried again.
    job.quarantine = json::parse(q, nullptr, /*allow_exceptions=*/false);
    if (job.quarantine.is_discarded()) {
      spdlog::warn("state: {} is damaged; its records are dropped and those files retried",
                   (dir / "quarantine.json").string());
      job.quarantine = json::array();
    }
  }
  const std::string& id = job.spec.id;
  // Frames: records only (the accumulators load when a frame next runs).
  const fs::path frames = dir / "frames";
  fs::create_directories(frames);
  remove_temp_files(frames, ".");
  std::set<long> numbers;
  std::error_code ec;
  for (fs::directory_iterator it(frames, ec), end; !ec && it != end; it.increment(ec)) {
    const auto ext = it->path().extension();
    if (ext != ".state" && ext != ".prev") continue;
    if (auto n = frame_number(it->path().stem().string())) numbers.insert(*n);
  }
  for (const long n : numbers) {
    const fs::path cur = frames / (std::to_string(n) + ".state");
    const fs::path prev = frames / (std::to_string(n) + ".prev");
    LoadedFrame f;
    std::ifstream pub(frames / (std::to_string(n) + ".pub"));
    pub >> f.published_version;
    std::string damage;
    try {
      f.record = load_frame_record(fs::exists(cur) ? cur : prev);
    } catch (const std::exception& e) {
      damage = e.what();
    }
    if (!damage.empty() && fs::exists(cur) && fs::exists(prev)) {
      try {
        f.record = load_frame_record(prev);
        fs::rename(cur, frames / (std::to_string(n) + ".corrupt"), ec);
        // Versions only increase: the next one follows the newest known.
        f.record.version = std::max(f.record.version, f.published_version);
        damaged(n, damage + "; recovered the last good state (version " +
                       std::to_string(f.record.version) + ", " + std::to_string(f.record.passes) +
                       " passes); the passes after it are read again");
        damage.clear();
      } catch (const std::exception& e) {
        damage += "; " + std::string(e.what());
      }
    }
    if (!damage.empty()) {
      spdlog::error("state: {}; moved aside, frame restarts", damage);
      set_aside(id, n);
      damaged(n, damage + "; the frame restarts from its passes");
      continue;
    }
    f.record.frame = n;
    job.frames.push_back(std::move(f));
  }
  // Output temp files of an interrupted publish (and of a kept version).
  const std::string& tmpl = job.spec.output.name;
  const std::string stem = tmpl.substr(0, std::min(tmpl.find('#'), tmpl.find("{frame}")));
  remove_temp_files(job.spec.output.dir,
                    "." + protocol::expand_output_name(stem, job.spec.name, 0));
  remove_temp_files(fs::path(job.spec.output.dir) / "versions", ".");
  auto ingested = [&](long frame, const std::string& pass) {
    return std::any_of(job.frames.begin(), job.frames.end(), [&](const LoadedFrame& f) {
      return f.record.frame == frame && has_pass(f.record, pass);
    });
  };
  // Kept uploads the frame's (recovered) state does not hold go back to uploads/: read again.
  for (const long n : numbers) {
    FrameRecord none;
    const FrameRecord* good = &none;
    for (const auto& f : job.frames) {
      if (f.record.frame == n) good = &f.record;
    }
    restore_kept(id, n, *good);
  }
  // Stored uploads not yet accumulated.
  for (fs::recursive_directory_iterator it(dir / "uploads", ec), end; !ec && it != end;
       it.increment(ec)) {
    if (!it->is_regular_file()) continue;
    const fs::path p = it->path();
    if (p.filename().string().front() == '.') {
      fs::remove(p, ec);  // an upload interrupted before it was acknowledged
      continue;
    }
    const auto frame = frame_number(p.parent_path().filename().string());
    if (!frame) continue;
    const std::string pass = p.stem().string();
    if (ingested(*frame, pass)) {
      fs::remove(p, ec);  // accumulated before the crash, only the clean-up was lost
      continue;
    }
    std::error_code e2;
    PendingPass pd{pass, p, fs::file_size(p, e2), mtime_ns(p, e2), true, content_hash(p)};
    job.uploads.emplace_back(*frame, std::move(pd));
  }
  return job;
}

// ---- frames ----------------------------------------------------------------------------------

std::unique_ptr<FrameStateWriter> JobStore::begin_frame_save(const std::string& id, long frame,
                                                             const FrameAccumulator& acc,
                                                             const AovAccumulator& aovs) {
  return std::make_unique<FrameStateWriter>(state_path(id, frame), acc, aovs);
}

void JobStore::commit_frame(const std::string& id, FrameStateWriter& writer,
                            const FrameRecord& record) {
  const fs::path p = state_path(id, record.frame);
  if (writer.path() != p) throw std::logic_error(p.string() + ": a writer for another frame");
  fault_point("state", p);
  if (fs::exists(p)) {
    // Keep the current state as the last good one: a hard link (no window without a state),
    // renamed over the previous one; the commit's directory sync makes both durable.
    const fs::path tmp = p.parent_path() / ("." + std::to_string(record.frame) + ".prev.tmp" +
                                            std::to_string(::getpid()));
    std::error_code ec;
    fs::remove(tmp, ec);
    fs::create_hard_link(p, tmp);
    fs::rename(tmp, prev_path(id, record.frame));
  }
  writer.commit(record);
}

void JobStore::save_frame(const std::string& id, const FrameRecord& record,
                          const FrameAccumulator& acc, const AovAccumulator& aovs) {
  const auto writer = begin_frame_save(id, record.frame, acc, aovs);
  commit_frame(id, *writer, record);
}

JobStore::LoadedState JobStore::load_frame(const std::string& id, long frame) const {
  const fs::path cur = state_path(id, frame), prev = prev_path(id, frame);
  LoadedState out;
  std::string damage;
  if (fs::exists(cur) || !fs::exists(prev)) {
    try {
      out.acc = load_frame_accumulator(cur, &out.record, &out.aovs);
      return out;
    } catch (const std::exception& e) {
      if (!fs::exists(prev)) throw;
      damage = e.what();
    }
  }
  try {
    out.acc = load_frame_accumulator(prev, &out.record, &out.aovs);
  } catch (const std::exception& e) {
    if (damage.empty()) throw;
    throw std::runtime_error(damage + "; and the last good state: " + e.what());
  }
  if (!damage.empty()) {
    std::error_code ec;
    fs::rename(cur, fs::path(cur).replace_extension(".corrupt"), ec);
    out.damage = damage;
  }
  return out;
}

void JobStore::set_aside(const std::string& id, long frame) const {
  std::error_code ec;
  for (const fs::path& p : {state_path(id, frame), prev_path(id, frame)}) {
    if (fs::exists(p, ec)) fs::rename(p, p.string() + ".corrupt", ec);
  }
}

std::vector<PendingPass> JobStore::restore_kept(const std::string& id, long frame,
                                                const FrameRecord& good) {
  std::vector<PendingPass> out;
  const fs::path dir = upload_dir(id, frame);
  std::error_code ec;
  for (fs::directory_iterator it(kept_dir(id, frame), ec), end; !ec && it != end;
       it.increment(ec)) {
    const fs::path p = it->path();
    const std::string pass = p.stem().string();
    if (!it->is_regular_file() || pass.empty() || pass.front() == '.' || has_pass(good, pass)) {
      continue;
    }
    fs::create_directories(dir);
    const fs::path to = dir / (pass + ".exr");
    std::error_code e2;
    if (fs::exists(to, e2)) continue;  // stored again since: that one counts
    fs::rename(p, to);
    out.push_back({pass, to, fs::file_size(to, e2), mtime_ns(to, e2), true, content_hash(to)});
  }
  if (!out.empty()) {
    sync_dir(dir);
    sync_dir(kept_dir(id, frame));
  }
  return out;
}

void JobStore::keep_uploads(const std::string& id, long frame,
                            const std::vector<PendingPass>& accepted) {
  const fs::path dir = kept_dir(id, frame);
  fs::create_directories(dir);
  std::set<fs::path> keep;
  for (const auto& p : accepted) {
    const fs::path to = dir / (p.pass + ".exr");
    keep.insert(to);
    if (p.path != to) fs::rename(p.path, to);
  }
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (!keep.count(it->path())) fs::remove(it->path(), ec);
  }
  sync_dir(dir);
  if (!accepted.empty()) sync_dir(upload_dir(id, frame));
}

void JobStore::save_published(const std::string& id, long frame, std::uint64_t version) {
  const fs::path p = published_path(id, frame);
  fault_point("published", p);
  write_file_atomic(p, std::to_string(version));
}

// ---- uploads ---------------------------------------------------------------------------------

fs::path JobStore::spool_path(const std::string& id, long frame, const std::string& pass) {
  static std::atomic<std::uint64_t> counter{0};
  const fs::path dir = upload_dir(id, frame);
  if (fs::create_directories(dir)) sync_dir(dir.parent_path());
  return dir / (".upload." + pass + "." + std::to_string(::getpid()) + "." +
                std::to_string(++counter) + ".tmp");
}

fs::path JobStore::spool_upload(const std::string& id, long frame, const std::string& pass,
                                const std::string& body) {
  const fs::path tmp = spool_path(id, frame, pass);
  write_file_atomic(tmp, body);
  fault_point("spooled", tmp);
  return tmp;
}

fs::path JobStore::commit_upload(const fs::path& spooled, const std::string& id, long frame,
                                 const std::string& pass) {
  const fs::path path = upload_dir(id, frame) / (pass + ".exr");
  fault_point("upload", path);
  fs::rename(spooled, path);
  sync_dir(path.parent_path());  // acknowledged only once the name is durable
  return path;
}

void JobStore::remove_file(const fs::path& path) const {
  std::error_code ec;
  fs::remove(path, ec);
}

}  // namespace proden::daemon

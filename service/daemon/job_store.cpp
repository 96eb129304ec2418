#include "daemon/job_store.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <fstream>

#include "daemon/files.hpp"

namespace proden::daemon {

namespace fs = std::filesystem;
using nlohmann::json;

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

// ---- jobs ------------------------------------------------------------------------------------

void JobStore::create_job(const protocol::JobSpec& spec) {
  fs::create_directories(job_dir(spec.id) / "frames");
  fs::create_directories(job_dir(spec.id) / "uploads");
  save_job(spec.id, protocol::to_json(spec).dump(2));
}

void JobStore::save_job(const std::string& id, const std::string& job_json) {
  const fs::path p = job_dir(id) / "job.json";
  hook("job", p);
  write_file_atomic(p, job_json);
}

void JobStore::save_quarantine(const std::string& id, const std::string& quarantine_json) {
  const fs::path p = job_dir(id) / "quarantine.json";
  hook("quarantine", p);
  write_file_atomic(p, quarantine_json);
}

void JobStore::remove_job(const std::string& id) {
  std::error_code ec;
  fs::remove_all(job_dir(id), ec);
}

std::optional<JobStore::LoadedJob> JobStore::load_job(
    const fs::path& dir, const std::function<void(const std::string&)>& corrupt) {
  LoadedJob job;
  {
    std::ifstream in(dir / "job.json");
    if (!in) {  // a job whose creation was interrupted before job.json: drop it
      spdlog::warn("state: {} has no job.json; removing", dir.string());
      fs::remove_all(dir);
      return std::nullopt;
    }
    job.spec = protocol::job_from_json(json::parse(in));
  }
  if (std::ifstream q(dir / "quarantine.json"); q) job.quarantine = json::parse(q);
  // Frames: records only (the accumulators load when a frame next runs).
  const fs::path frames = dir / "frames";
  fs::create_directories(frames);
  remove_temp_files(frames, ".");
  std::error_code ec;
  for (fs::directory_iterator it(frames, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->path().extension() != ".state") continue;
    try {
      LoadedFrame f;
      f.record = load_frame_record(it->path());
      std::ifstream pub(fs::path(it->path()).replace_extension(".pub"));
      pub >> f.published_version;
      job.frames.push_back(std::move(f));
    } catch (const std::exception& e) {
      // Atomic writes make this a disk fault; start the frame over (its passes are re-read).
      spdlog::error("state: {}; moved aside, frame restarts", e.what());
      fs::rename(it->path(), fs::path(it->path()).replace_extension(".corrupt"), ec);
      corrupt(e.what());
    }
  }
  // Output temp files of an interrupted publish (and of a kept version).
  const std::string& tmpl = job.spec.output.name;
  const std::string stem = tmpl.substr(0, std::min(tmpl.find('#'), tmpl.find("{frame}")));
  remove_temp_files(job.spec.output.dir,
                    "." + protocol::expand_output_name(stem, job.spec.name, 0));
  remove_temp_files(fs::path(job.spec.output.dir) / "versions", ".");
  // Stored uploads not yet accumulated.
  for (fs::recursive_directory_iterator it(dir / "uploads", ec), end; !ec && it != end;
       it.increment(ec)) {
    if (!it->is_regular_file()) continue;
    const fs::path p = it->path();
    if (p.filename().string().front() == '.') {
      fs::remove(p, ec);
      continue;
    }
    long frame = 0;
    try {
      frame = std::stol(p.parent_path().filename().string());
    } catch (...) {
      continue;
    }
    const std::string pass = p.stem().string();
    const bool ingested = std::any_of(job.frames.begin(), job.frames.end(), [&](const auto& f) {
      return f.record.frame == frame &&
             std::any_of(f.record.ingested.begin(), f.record.ingested.end(),
                         [&](const auto& i) { return i.pass == pass; });
    });
    if (ingested) {
      fs::remove(p, ec);  // accumulated before the crash, only the clean-up was lost
      continue;
    }
    std::error_code e2;
    PendingPass pd{pass, p, fs::file_size(p, e2), mtime_ns(p, e2), true};
    job.uploads.emplace_back(frame, std::move(pd));
  }
  return job;
}

// ---- frames ----------------------------------------------------------------------------------

void JobStore::save_frame(const std::string& id, const FrameRecord& record,
                          const FrameAccumulator& acc, const AovAccumulator& aovs) {
  const fs::path p = state_path(id, record.frame);
  hook("state", p);
  save_frame_state(p, record, acc, aovs);
}

FrameAccumulator JobStore::load_frame(const std::string& id, long frame,
                                      AovAccumulator* aovs) const {
  return load_frame_accumulator(state_path(id, frame), nullptr, aovs);
}

void JobStore::save_published(const std::string& id, long frame, std::uint64_t version) {
  const fs::path p = published_path(id, frame);
  hook("published", p);
  write_file_atomic(p, std::to_string(version));
}

// ---- uploads ---------------------------------------------------------------------------------

fs::path JobStore::spool_upload(const std::string& id, long frame, const std::string& pass,
                                const std::string& body) {
  const fs::path dir = upload_dir(id, frame);
  fs::create_directories(dir);
  const fs::path tmp = dir / (".check." + pass + ".exr");
  write_file_atomic(tmp, body);
  return tmp;
}

fs::path JobStore::commit_upload(const fs::path& spooled, const std::string& id, long frame,
                                 const std::string& pass) {
  const fs::path path = upload_dir(id, frame) / (pass + ".exr");
  hook("upload", path);
  fs::rename(spooled, path);
  return path;
}

void JobStore::remove_file(const fs::path& path) const {
  std::error_code ec;
  fs::remove(path, ec);
}

}  // namespace proden::daemon

#include "daemon/engine.hpp"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <random>

#include "daemon/frame_history.hpp"
#include "daemon/memory.hpp"
#include "daemon/processor.hpp"
#include "daemon/request_parse.hpp"
#include "daemon/versions.hpp"
#include "proden/hash.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"

namespace proden::daemon {

namespace fs = std::filesystem;
using nlohmann::json;
using protocol::ApiError;

namespace {

std::string new_id() {
  std::random_device rd;
  std::uniform_int_distribution<std::uint64_t> d;
  char buf[24];
  std::snprintf(buf, sizeof buf, "j%012llx",
                static_cast<unsigned long long>(d(rd) & 0xffffffffffffULL));
  return buf;
}

std::string hex64(std::uint64_t v) {
  char buf[20];
  std::snprintf(buf, sizeof buf, "%016llx", static_cast<unsigned long long>(v));
  return buf;
}

bool valid_pass_name(const std::string& p) {
  return !p.empty() && p.size() <= 64 && std::all_of(p.begin(), p.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-';
  });
}

long parse_frame(const std::string& s) {
  const auto frame = parse_frame_number(s);
  if (!frame) {
    throw ApiError(400, "invalid_frame", "frame must be a non-negative integer (<= 9 digits)");
  }
  return *frame;
}

}  // namespace

Engine::Engine(const Config& config, const Roots& roots, Metrics& metrics, EventHub& events,
               EngineTestHooks hooks)
    : config_(config),
      roots_(roots),
      metrics_(metrics),
      events_(events),
      clock_(hooks.clock ? *hooks.clock : steady_clock()),
      store_(config_.state_dir, std::move(hooks.fs)) {
  retry_.max_attempts = config_.watch.max_attempts;
  Watcher::Callbacks cb;
  cb.wanted = [this](const FoundFile& f) { return wanted(f); };
  cb.offer = [this](const FoundFile& f) { offer(f); };
  cb.refused = [this](const FoundFile& f, const std::string& why) {
    spdlog::warn("{}: refused: {}", f.path.string(), why);
    metrics_.inc("proden_errors_total", "path_escape");
    publish_error(events_, f.job, f.frame, f.pass, f.path.string(), "path_escape", why, false);
  };
  watcher_ = std::make_unique<Watcher>(config_.watch, roots_, std::move(cb));
  scheduler_ = std::make_unique<Scheduler>(
      config_.worker_threads, [this](const std::string& job, long frame) { run_frame(job, frame); },
      &metrics_, clock_);
  // Runs' temporaries (decoded passes, the estimate, the pipeline's planes) are freed into the
  // heap, where the next run reuses their pages while the farm keeps the daemon busy; once it has
  // been idle for a second they go back to the system, so an idle daemon's resident memory
  // follows what it holds (daemon/memory.hpp). First, versions published uncompressed are
  // compressed (output.compression auto), one file per idle second.
  scheduler_->on_idle(
      [this] {
        compress_idle();
        release_free_memory();
      },
      std::chrono::seconds(1));
}

Engine::~Engine() {
  stop();
}

void Engine::start() {
  validate(config_);
  resident_budget_ =
      config_.max_resident_bytes > 0 ? config_.max_resident_bytes : usable_memory_bytes() / 4;
  if (resident_budget_ == 0) resident_budget_ = std::uint64_t{1} << 30;  // nothing readable
  metrics_.set("proden_resident_budget_bytes", static_cast<double>(resident_budget_));
  if (config_.pipeline_threads > 0) {
    pipeline_threads_ =
        std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                              static_cast<std::size_t>(config_.pipeline_threads));
  }
  fs::create_directories(store_.jobs_dir());
  load_state();
  watcher_->start();
  scheduler_->start();
  ready_ = true;
}

void Engine::stop() {
  ready_ = false;
  if (watcher_) watcher_->stop();
  if (scheduler_) scheduler_->stop();
}

// ---- state directory -------------------------------------------------------------------------

void Engine::load_state() {
  std::error_code ec;
  for (fs::directory_iterator it(store_.jobs_dir(), ec), end; !ec && it != end; it.increment(ec)) {
    if (!it->is_directory()) continue;
    try {
      load_job(it->path());
    } catch (const std::exception& e) {
      spdlog::error("state: job {} not loaded: {}", it->path().string(), e.what());
      metrics_.inc("proden_errors_total", "corrupt_state");
    }
  }
  std::lock_guard lock(mu_);
  metrics_.set("proden_jobs", static_cast<double>(jobs_.size()));
}

void Engine::load_job(const fs::path& dir) {
  std::vector<std::pair<long, std::string>> damaged;
  auto loaded = store_.load_job(
      dir, [&](long frame, const std::string& msg) { damaged.emplace_back(frame, msg); });
  if (!loaded) return;
  auto job = std::make_shared<Job>();
  job->spec = std::move(loaded->spec);
  job->quarantine = Quarantine::from_json(loaded->quarantine);
  for (auto& lf : loaded->frames) {
    Frame& fr = job->frames[lf.record.frame];
    for (const auto& p : lf.record.ingested) fr.ingested.insert(p.pass);
    fr.rec = std::move(lf.record);
    fr.has_state = true;
    fr.published_version = lf.published_version;
    // Kept versions an earlier process may have left uncompressed (killed before it was idle):
    // compress_idle checks each file and rewrites only uncompressed ones.
    if (job->spec.output.compression == "auto") {
      for (const auto v : fr.rec.versions) {
        if (v <= fr.published_version) fr.to_compress.insert(v);
      }
    }
  }
  const std::string id = job->spec.id;
  for (const auto& [frame, msg] : damaged) on_damaged(id, frame, msg);
  {
    std::lock_guard lock(mu_);
    jobs_[id] = job;
    scheduler_->set_paused(id, job->spec.paused);
    for (auto& [frame, pd] : loaded->uploads) {
      if (job->quarantine.contains(frame, pd.pass)) continue;
      Frame& fr = job->frames[frame];
      fr.rec.frame = frame;
      fr.pending[pd.pass] = pd;
    }
    for (auto& [no, fr] : job->frames) {
      fr.rec.frame = no;
      if (!fr.pending.empty() || fr.published_version < fr.rec.version) enqueue(*job, no);
    }
  }
  // Not under the engine's lock: the watcher calls back into the engine under its own.
  if (job->spec.watch) {
    std::string why;
    if (roots_.confine(job->spec.watch->dir, why)) {
      watcher_->add_job(id, job->spec.watch->dir, job->spec.watch->pattern);
    } else {
      spdlog::error("job {}: watch dir {} not watched: {}", id, job->spec.watch->dir, why);
    }
  }
  spdlog::info("resumed job {} ({}): {} frame(s)", id, job->spec.name, job->frames.size());
}

void Engine::on_damaged(const std::string& job, long frame, const std::string& message) {
  spdlog::error("job {} frame {}: {}", job, frame, message);
  metrics_.inc("proden_errors_total", "corrupt_state");
  publish_error(events_, job, frame, "", store_.state_path(job, frame).string(), "corrupt_state",
                message, false);
}

void Engine::save_quarantine(const std::shared_ptr<Job>& job) {
  std::string text;
  {
    std::lock_guard lock(mu_);
    text = job->quarantine.to_json().dump(1, ' ', false, json::error_handler_t::replace);
  }
  try {
    store_.save_quarantine(job->spec.id, text);
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
  }
}

// ---- running frames --------------------------------------------------------------------------

void Engine::enqueue(const Job& job, long frame_no) {
  if (job.deleted) return;
  scheduler_->enqueue(job.spec.id, frame_no);
}

// Drops the least recently updated resident states until at most max_resident_frames remain and
// they hold at most the memory budget; a dropped frame reloads its state file at its next update.
void Engine::evict() {
  struct Resident {
    std::uint64_t last_used;
    std::size_t bytes;
    Frame* frame;
  };
  std::vector<Resident> resident;
  std::uint64_t bytes = 0;
  for (auto& [id, j] : jobs_) {
    for (auto& [no, fr] : j->frames) {
      if (!fr.acc) continue;  // not resident, or running (its state is lent out)
      const std::size_t b = fr.acc->state_bytes() + (fr.aovs ? fr.aovs->state_bytes() : 0);
      resident.push_back({fr.last_used, b, &fr});
      bytes += b;
    }
  }
  const std::size_t limit = static_cast<std::size_t>(std::max(0, config_.max_resident_frames));
  std::sort(resident.begin(), resident.end(),
            [](const auto& a, const auto& b) { return a.last_used < b.last_used; });
  std::size_t kept = resident.size();
  for (const auto& r : resident) {
    if (kept <= limit && bytes <= resident_budget_) break;
    r.frame->acc.reset();
    r.frame->aovs.reset();
    bytes -= r.bytes;
    --kept;
    metrics_.inc("proden_evictions_total");
  }
  metrics_.set("proden_resident_frames", static_cast<double>(kept));
  metrics_.set("proden_resident_bytes", static_cast<double>(bytes));
}

bool Engine::wait_idle(int timeout_ms) {
  return scheduler_->wait_idle(timeout_ms);
}

void Engine::retry_later(Job& job, long frame_no, Frame& fr, const PendingPass& p,
                         std::chrono::milliseconds delay) {
  fr.retry[p.pass] = Retry{p, clock_.now() + delay};
  if (!job.deleted) scheduler_->enqueue(job.spec.id, frame_no, delay);
}

void Engine::run_frame(const std::string& job_id, long frame_no) {
  std::shared_ptr<Job> job;
  FrameRun::Input in;
  {
    std::lock_guard lock(mu_);
    auto it = jobs_.find(job_id);
    if (it == jobs_.end() || it->second->deleted) return;
    job = it->second;
    Frame& fr = job->frames[frame_no];
    const auto now = clock_.now();
    for (auto r = fr.retry.begin(); r != fr.retry.end();) {  // retries that are due join
      if (r->second.due <= now) {
        fr.pending.emplace(r->first, r->second.pass);
        r = fr.retry.erase(r);
      } else {
        ++r;
      }
    }
    for (auto& [pass, p] : fr.pending) {
      if (!fr.ingested.count(pass)) {
        fr.inflight[pass] = p;
        in.batch.push_back(p);
      }
    }
    fr.pending.clear();
    in.acc = std::move(fr.acc);
    in.aovs = std::move(fr.aovs);
    fr.acc.reset();
    fr.aovs.reset();
    in.record = fr.rec;
    in.has_state = fr.has_state;
    in.republish = fr.published_version < fr.rec.version;
    in.spec = job->spec;
    in.frame = frame_no;
  }
  in.roots = &roots_;
  in.limits = read_limits(config_.input, config_.input.max_file_bytes);
  const std::vector<PendingPass> batch = in.batch;

  FrameRun::Hooks hooks;
  hooks.failed = [&](const PendingPass& p, const Failure& f) { on_failed(job, frame_no, p, f); };
  hooks.committed = [&](const FrameRecord& rec,
                        const std::vector<protocol::PassIdentity>& accepted) {
    std::lock_guard lock(mu_);
    Frame& fr = job->frames[frame_no];
    fr.rec = rec;
    fr.has_state = true;
    for (const auto& a : accepted) {
      fr.ingested.insert(a.pass);
      fr.attempts.erase(a.pass);
      fr.inflight.erase(a.pass);
    }
  };
  hooks.published = [&](std::uint64_t version, const std::vector<std::string>& outputs,
                        bool compress_later) {
    std::lock_guard lock(mu_);
    Frame& fr = job->frames[frame_no];
    fr.published_version = version;
    fr.outputs = outputs;
    if (compress_later) fr.to_compress.insert(version);
  };
  hooks.recovered = [&](const FrameRecord& good) {
    // Passes after the last good state: watched files are offered again by the watcher (they
    // are no longer ingested); kept uploads are read again.
    const auto kept = store_.restore_kept(job_id, frame_no, good);
    std::lock_guard lock(mu_);
    Frame& fr = job->frames[frame_no];
    fr.rec = good;
    fr.ingested.clear();
    for (const auto& p : good.ingested) fr.ingested.insert(p.pass);
    for (const auto& p : kept) {
      if (!fr.has(p.pass)) fr.pending[p.pass] = p;
    }
  };
  FrameRun::Outcome out;
  try {
    FrameRun run(store_, metrics_, events_, std::move(hooks));
    out = run.run(std::move(in));
  } catch (...) {
    // Nothing escapes without putting the batch back: it is retried after a back-off (the
    // scheduler logs the exception and runs the frame again).
    std::lock_guard lock(mu_);
    Frame& fr = job->frames[frame_no];
    for (const auto& p : batch) {
      if (fr.inflight.erase(p.pass)) fr.retry[p.pass] = Retry{p, clock_.now()};
    }
    throw;
  }

  if (out.result == FrameRun::Result::state_unreadable) {
    // Neither the state nor the last good one loads: the frame starts over from its passes.
    store_.set_aside(job_id, frame_no);
    on_damaged(job_id, frame_no,
               out.error +
                   "; the frame restarts from its passes (watched files and kept "
                   "uploads are read again)");
  }
  const auto kept = out.result == FrameRun::Result::state_unreadable
                        ? store_.restore_kept(job_id, frame_no, FrameRecord{})
                        : std::vector<PendingPass>{};
  std::lock_guard lock(mu_);
  Frame& fr = job->frames[frame_no];
  std::vector<PendingPass> unfinished;  // read by this run, neither committed nor failed
  for (const auto& p : batch) {
    auto it = fr.inflight.find(p.pass);
    if (it == fr.inflight.end()) continue;
    fr.inflight.erase(it);
    if (!fr.has(p.pass) && !job->quarantine.contains(frame_no, p.pass)) unfinished.push_back(p);
  }
  switch (out.result) {
    case FrameRun::Result::state_unreadable: {
      FrameRecord fresh;
      fresh.frame = frame_no;
      fresh.version = std::max(fr.rec.version, fr.published_version);  // versions only increase
      fr.rec = std::move(fresh);
    }
      fr.has_state = false;
      fr.ingested.clear();
      for (const auto& p : unfinished) fr.pending[p.pass] = p;
      for (const auto& p : kept) {
        if (!fr.has(p.pass)) fr.pending[p.pass] = p;
      }
      break;
    case FrameRun::Result::failed: {
      // Persisting or publishing failed (disk full, I/O error): try again after a back-off, the
      // passes of the batch (uploads included) or the publish of the committed version.
      const auto delay = retry_.backoff(++fr.failures);
      for (const auto& p : unfinished) {
        if (p.upload || !out.committed) retry_later(*job, frame_no, fr, p, delay);
      }
      if (out.committed) scheduler_->enqueue(job_id, frame_no, delay);
      break;
    }
    case FrameRun::Result::done:
      fr.failures = 0;
      fr.acc = out.acc;
      fr.aovs = out.aovs;
      fr.last_used = ++use_clock_;
      break;
  }
  if (!fr.pending.empty()) enqueue(*job, frame_no);
  evict();
}

void Engine::compress_idle() {
  for (;;) {
    std::string job_id;
    long frame_no = 0;
    std::uint64_t version = 0;
    protocol::JobSpec spec;
    {
      std::lock_guard lock(mu_);
      for (auto& [id, job] : jobs_) {
        if (job->deleted) continue;
        for (auto& [no, frame] : job->frames) {
          Frame& fr = frame;  // a name the lambda below may capture (clang 14: not a binding)
          // Versions no longer kept (removed beyond output.history) have no file to compress.
          std::erase_if(fr.to_compress, [&](std::uint64_t v) {
            return v > fr.published_version ||
                   std::find(fr.rec.versions.begin(), fr.rec.versions.end(), v) ==
                       fr.rec.versions.end();
          });
          if (fr.to_compress.empty()) continue;
          if (job_id.empty() || *fr.to_compress.rbegin() > version) {
            job_id = id;
            frame_no = no;
            version = *fr.to_compress.rbegin();
            spec = job->spec;
          }
        }
      }
    }
    // Nothing left, or work waits (or this frame is queued): the next idle time goes on.
    if (job_id.empty() || !scheduler_->claim(job_id, frame_no)) return;
    // Who owns frame_no now (null: the job was deleted meanwhile); mu_ held.
    const auto frame_of = [&]() -> Frame* {
      const auto j = jobs_.find(job_id);
      if (j == jobs_.end()) return nullptr;
      const auto f = j->second->frames.find(frame_no);
      return f == j->second->frames.end() ? nullptr : &f->second;
    };
    bool rewritten = false;
    bool latest = false;
    {
      std::lock_guard lock(mu_);
      const Frame* fr = frame_of();
      latest = fr && fr->published_version == version;
    }
    try {
      rewritten = compress_version(spec, frame_no, version, latest);
      if (rewritten) metrics_.inc("proden_publish_compressed_later_total");
    } catch (const std::exception& e) {  // the file stays as it was: uncompressed, same values
      spdlog::warn("job {} frame {}: compressing version {}: {}", job_id, frame_no, version,
                   e.what());
      metrics_.inc("proden_errors_total", "compress");
    }
    {
      std::lock_guard lock(mu_);
      if (Frame* fr = frame_of()) fr->to_compress.erase(version);
    }
    scheduler_->release(job_id, frame_no);
    if (rewritten) return;
  }
}

bool Engine::compress_version(const protocol::JobSpec& spec, long frame, std::uint64_t version,
                              bool latest) {
  // The latest is the published file, whose versions/ copy is then made that file again (a hard
  // link); an older version is its versions/ file alone.
  const fs::path kept = version_file(spec, frame, version);
  const fs::path file = latest ? fs::path(output_base(spec, frame).string() + ".exr") : kept;
  FileError fe = FileError::none;
  std::string why;
  const UniqueFd dir = roots_.open_dir(file.parent_path(), fe, why);
  if (!dir) throw std::runtime_error(why);
  const bool rewritten = io::compress_image_at(
      dir.get(), file.filename().string(),
      std::string(protocol::resolve_frame_compression(spec.output.compression)), file.string());
  std::error_code ec;
  if (latest && !fs::equivalent(file, kept, ec)) keep_version(file, kept);
  return rewritten;
}

void Engine::on_failed(const std::shared_ptr<Job>& job, long frame, const PendingPass& p,
                       const Failure& f) {
  int attempts = 0;
  {
    std::lock_guard lock(mu_);
    attempts = ++job->frames[frame].attempts[p.pass];
  }
  if (retry_.decide(f, attempts, p.upload) == RetryPolicy::Action::retry) {
    const auto delay = retry_.backoff(attempts);
    if (f.cls == ErrorClass::bad_input) {
      spdlog::info("{}: {} (attempt {}/{}): {}", p.path.string(), f.kind, attempts,
                   retry_.max_attempts, f.message);
      metrics_.inc("proden_errors_total", "read_retry");
    } else {
      spdlog::error("{}: {} error (attempt {}, retried in {} ms): {}", p.path.string(), f.kind,
                    attempts, delay.count(), f.message);
      metrics_.inc("proden_errors_total", f.kind);
      publish_error(events_, job->spec.id, frame, p.pass, p.path.string(), f.kind, f.message,
                    false);
    }
    std::lock_guard lock(mu_);
    Frame& fr = job->frames[frame];
    fr.inflight.erase(p.pass);
    retry_later(*job, frame, fr, p, delay);
    return;
  }
  quarantine(job, frame, p, f.kind, f.message);
}

void Engine::quarantine(const std::shared_ptr<Job>& job, long frame, const PendingPass& p,
                        const std::string& kind, const std::string& message) {
  spdlog::warn("{}: quarantined ({}): {}", p.path.string(), kind, message);
  {
    std::lock_guard lock(mu_);
    job->quarantine.add(frame, p.pass,
                        QuarantineRecord{p.path.string(), kind, message, protocol::now_rfc3339(),
                                         p.size, p.mtime_ns});
    job->frames[frame].inflight.erase(p.pass);
  }
  save_quarantine(job);
  metrics_.inc("proden_errors_total", kind);
  publish_error(events_, job->spec.id, frame, p.pass, p.path.string(), kind, message, true);
}

// ---- watcher callbacks -----------------------------------------------------------------------

namespace {

// Whether `name` is <job name>_<4+ digits>.exr or .png: a published frame's file name.
bool published_name(const std::string& name, const std::string& job_name) {
  if (name.size() <= job_name.size() + 1 || name.compare(0, job_name.size(), job_name) != 0 ||
      name[job_name.size()] != '_') {
    return false;
  }
  const std::string rest = name.substr(job_name.size() + 1);
  const auto dot = rest.find('.');
  if (dot == std::string::npos || dot < 4) return false;
  const std::string ext = rest.substr(dot);
  return (ext == ".exr" || ext == ".png") &&
         std::all_of(rest.begin(), rest.begin() + static_cast<long>(dot), ::isdigit);
}

// The file itself and, for a symlink, what it resolves to.
std::vector<fs::path> identities(const fs::path& path) {
  std::vector<fs::path> out{path};
  std::error_code ec;
  if (fs::is_symlink(fs::symlink_status(path, ec))) {
    const fs::path real = fs::canonical(path, ec);
    if (!ec) out.push_back(real);
  }
  return out;
}

}  // namespace

bool Engine::own_output(const fs::path& path) const {
  const fs::path dir = path.parent_path();
  const std::string name = path.filename().string();
  for (const auto& [id, j] : jobs_) {
    if (fs::path(j->spec.output.dir) == dir && published_name(name, j->spec.name)) return true;
  }
  return false;
}

bool Engine::wanted(const FoundFile& f) {
  const auto ids = identities(f.path);
  std::lock_guard lock(mu_);
  auto it = jobs_.find(f.job);
  if (it == jobs_.end() || it->second->deleted) return false;
  for (const auto& p : ids) {
    if (own_output(p)) return false;  // a frame the daemon published: never a pass
  }
  const Job& job = *it->second;
  if (job.quarantine.blocks(f.frame, f.pass, f.size, f.mtime_ns)) return false;
  auto fr = job.frames.find(f.frame);
  return fr == job.frames.end() || !fr->second.has(f.pass);
}

void Engine::offer(const FoundFile& f) {
  const auto ids = identities(f.path);
  std::lock_guard lock(mu_);
  auto it = jobs_.find(f.job);
  if (it == jobs_.end() || it->second->deleted) return;
  for (const auto& p : ids) {
    if (own_output(p)) return;
  }
  auto& job = it->second;
  if (!job->quarantine.admit(f.frame, f.pass, f.size, f.mtime_ns)) return;
  Frame& fr = job->frames[f.frame];
  fr.rec.frame = f.frame;
  if (fr.has(f.pass)) return;
  fr.pending[f.pass] = PendingPass{f.pass, f.path, f.size, f.mtime_ns, false, 0};
  enqueue(*job, f.frame);
}

// ---- API -------------------------------------------------------------------------------------

std::shared_ptr<Engine::Job> Engine::find(const std::string& id) const {
  auto it = jobs_.find(id);
  if (it == jobs_.end()) throw ApiError(404, "not_found", "no job " + id);
  return it->second;
}

protocol::JobSpec Engine::create_job(protocol::JobSpec spec) {
  auto confine = [this](const std::string& p, const char* field) {
    std::string why;
    if (p.empty() || p.front() != '/') {
      throw ApiError(400, "invalid_path", std::string(field) + ": must be an absolute path");
    }
    for (const auto& part : fs::path(p)) {
      if (part == "..") {
        throw ApiError(400, "invalid_path", std::string(field) + ": '..' components are refused");
      }
    }
    auto real = roots_.confine(p, why);
    if (!real) throw ApiError(403, "path_forbidden", std::string(field) + ": " + why);
    // Created one directory at a time beneath the root: a symlink swapped in meanwhile is refused.
    FileError fe = FileError::none;
    if (!roots_.make_dirs(*real, fe, why)) {
      if (fe == FileError::escape) {
        throw ApiError(403, "path_forbidden", std::string(field) + ": " + why);
      }
      throw ApiError(400, "invalid_path",
                     std::string(field) + ": cannot create directory " + real->string());
    }
    std::error_code ec;
    // Re-check after creation: a symlink may have appeared in the meantime.
    const fs::path again = fs::canonical(*real, ec);
    if (ec || !roots_.contains(again)) {
      throw ApiError(403, "path_forbidden", std::string(field) + ": outside the allowed roots");
    }
    return again.string();
  };
  protocol::validate_job_spec(spec);
  if (std::string why; !FrameProcessor::supports(spec.pipeline, why)) {
    throw ApiError(400, "invalid_field", why);
  }
  if (spec.watch) spec.watch->dir = confine(spec.watch->dir, "watch.dir");
  spec.output.dir = confine(spec.output.dir, "output.dir");
  spec.created = protocol::now_rfc3339();
  auto job = std::make_shared<Job>();
  std::unique_lock save(job->save_mu);  // before the engine's lock
  {
    std::lock_guard lock(mu_);
    if (!ready_) throw ApiError(503, "unavailable", "the daemon is shutting down");
    for (const auto& [id, j] : jobs_) {
      if (j->spec.name == spec.name) {
        throw ApiError(409, "conflict", "a job named " + spec.name + " exists: " + id);
      }
    }
    do {
      spec.id = new_id();
    } while (jobs_.count(spec.id));
    job->spec = spec;
    jobs_[spec.id] = job;
    scheduler_->set_paused(spec.id, spec.paused);
    metrics_.set("proden_jobs", static_cast<double>(jobs_.size()));
  }
  try {
    store_.create_job(spec);
  } catch (const std::exception& e) {
    std::lock_guard lock(mu_);
    jobs_.erase(spec.id);
    scheduler_->remove_job(spec.id);
    throw ApiError(500, "internal", std::string("cannot persist the job: ") + e.what());
  }
  save.unlock();
  if (spec.watch) watcher_->add_job(spec.id, spec.watch->dir, spec.watch->pattern);
  events_.publish("job", {{"job", spec.id}, {"name", spec.name}, {"state", "created"}});
  spdlog::info("job {} ({}) created", spec.id, spec.name);
  return spec;
}

std::vector<protocol::JobSpec> Engine::jobs() const {
  std::lock_guard lock(mu_);
  std::vector<protocol::JobSpec> out;
  for (const auto& [id, j] : jobs_) out.push_back(j->spec);
  return out;
}

protocol::JobSpec Engine::job(const std::string& id) const {
  std::lock_guard lock(mu_);
  return find(id)->spec;
}

void Engine::delete_job(const std::string& id) {
  std::shared_ptr<Job> job;
  {
    std::lock_guard lock(mu_);
    job = find(id);
  }
  std::lock_guard save(job->save_mu);  // no job.json write is in flight
  {
    std::lock_guard lock(mu_);
    if (job->deleted) throw ApiError(404, "not_found", "no job " + id);
    job->deleted = true;
    jobs_.erase(id);
    scheduler_->remove_job(id);
    metrics_.set("proden_jobs", static_cast<double>(jobs_.size()));
  }
  watcher_->remove_job(id);
  store_.remove_job(id);  // state only; published outputs stay
  events_.publish("job", {{"job", id}, {"name", job->spec.name}, {"state", "deleted"}});
  spdlog::info("job {} deleted", id);
}

protocol::JobSpec Engine::set_paused(const std::string& id, bool paused) {
  std::shared_ptr<Job> job;
  {
    std::lock_guard lock(mu_);
    job = find(id);
  }
  // The save lock orders the writes of job.json as the changes are ordered in memory; the spec
  // is serialised under the engine's lock.
  std::lock_guard save(job->save_mu);
  protocol::JobSpec spec;
  std::string text;
  {
    std::lock_guard lock(mu_);
    if (job->deleted) throw ApiError(404, "not_found", "no job " + id);
    job->spec.paused = paused;
    scheduler_->set_paused(id, paused);
    spec = job->spec;
    text = protocol::to_json(spec).dump(2, ' ', false, json::error_handler_t::replace);
  }
  store_.save_job(id, text);
  events_.publish("job",
                  {{"job", id}, {"name", spec.name}, {"state", paused ? "paused" : "resumed"}});
  return spec;
}

void Engine::check_upload(const std::string& id, const std::string& frame,
                          const std::string& pass) const {
  parse_frame(frame);
  if (!valid_pass_name(pass)) {
    throw ApiError(400, "invalid_pass", "pass must be 1-64 characters of A-Z a-z 0-9 _ -");
  }
  std::lock_guard lock(mu_);
  find(id);
}

Engine::UploadFit Engine::fit(const Frame& fr, const std::string& pass, std::uint64_t hash) const {
  if (fr.ingested.count(pass)) {
    for (const auto& i : fr.rec.ingested) {
      if (i.pass == pass) return i.content_hash == hash ? UploadFit::ingested : UploadFit::conflict;
    }
    return UploadFit::conflict;
  }
  const PendingPass* p = nullptr;
  if (auto it = fr.pending.find(pass); it != fr.pending.end()) p = &it->second;
  if (auto it = fr.retry.find(pass); it != fr.retry.end()) p = &it->second.pass;
  if (auto it = fr.inflight.find(pass); it != fr.inflight.end()) p = &it->second;
  if (!p) return UploadFit::fresh;
  // Waiting or being read: the same bytes uploaded again are the same request (idempotent);
  // a watched file, an upload being stored (hash 0) or other bytes are a conflict.
  return p->upload && p->content_hash != 0 && p->content_hash == hash ? UploadFit::queued
                                                                      : UploadFit::conflict;
}

json Engine::upload(const std::string& id, const std::string& frame, const std::string& pass,
                    const std::string& body) {
  check_upload(id, frame, pass);
  if (body.empty()) throw ApiError(400, "invalid_pass", "empty body");
  return upload_spooled(id, frame, pass, store_.spool_upload(id, parse_frame(frame), pass, body));
}

fs::path Engine::upload_spool(const std::string& id, const std::string& frame,
                              const std::string& pass) {
  check_upload(id, frame, pass);
  return store_.spool_path(id, parse_frame(frame), pass);
}

json Engine::upload_spooled(const std::string& id, const std::string& frame,
                            const std::string& pass, const fs::path& spooled) {
  struct Spool {  // removed unless it became the stored upload
    const JobStore& store;
    fs::path path;
    ~Spool() {
      if (!path.empty()) store.remove_file(path);
    }
  } tmp{store_, spooled};
  check_upload(id, frame, pass);
  const long f = parse_frame(frame);
  std::string renderer;
  {
    std::lock_guard lock(mu_);
    renderer = find(id)->spec.renderer;
  }
  // The body is never read into memory: its size, content hash and header all come through one
  // descriptor (within the read limits), so a client sending garbage hears about it now.
  const UniqueFd fd(open_regular_nofollow(spooled));
  struct stat st {};
  if (!fd || ::fstat(fd.get(), &st) != 0) {
    throw ApiError(500, "internal", "the stored upload cannot be read back");
  }
  const auto size = static_cast<std::uint64_t>(st.st_size);
  if (size == 0) throw ApiError(400, "invalid_pass", "empty body");
  const std::optional<std::uint64_t> hash = hash_fd(fd.get(), size);
  if (!hash) throw ApiError(500, "internal", "the stored upload cannot be read back");
  auto answer = [&](const char* status) {
    return json{{"job", id}, {"frame", f}, {"pass", pass}, {"bytes", size}, {"status", status}};
  };
  auto settled = [&](UploadFit fit) -> std::optional<json> {
    if (fit == UploadFit::conflict) {
      throw ApiError(409, "conflict",
                     "frame " + frame + " already has pass " + pass + " with other content");
    }
    if (fit == UploadFit::ingested) return answer("ingested");
    if (fit == UploadFit::queued) return answer("queued");
    return std::nullopt;
  };
  {
    std::lock_guard lock(mu_);
    auto job = find(id);
    if (auto fr = job->frames.find(f); fr != job->frames.end()) {
      if (auto done = settled(fit(fr->second, pass, *hash))) return *done;
    }
  }
  try {
    ::fsync(fd.get());
    io::ReadOptions ro;
    ro.renderer = io::parse_renderer(renderer).value_or(io::Renderer::automatic);
    ro.limits = read_limits(config_.input, config_.limits.max_upload_bytes);
    io::probe_pass(io::FdSource(fd.get(), size), spooled.string(), ro);
  } catch (const std::exception& e) {
    throw ApiError(400, "invalid_pass", std::string("not a readable pass: ") + e.what());
  }
  // Claim (frame, pass) under the lock, store it durably without the lock, then queue it.
  std::shared_ptr<Job> job;
  PendingPass claim{pass, {}, size, 0, true, 0};  // hash 0 while being stored: a conflict
  {
    std::lock_guard lock(mu_);
    job = find(id);
    Frame& fr = job->frames[f];
    fr.rec.frame = f;
    if (auto done = settled(fit(fr, pass, *hash))) return *done;
    fr.inflight[pass] = claim;
  }
  fs::path path;
  try {
    path = store_.commit_upload(spooled, id, f, pass);
    tmp.path.clear();
  } catch (const std::exception& e) {
    std::lock_guard lock(mu_);
    job->frames[f].inflight.erase(pass);
    throw ApiError(500, "internal", std::string("cannot store the upload: ") + e.what());
  }
  std::error_code ec;
  const std::int64_t mt = mtime_ns(path, ec);
  {
    std::lock_guard lock(mu_);
    Frame& fr = job->frames[f];
    fr.inflight.erase(pass);
    fr.pending[pass] = PendingPass{pass, path, size, mt, true, *hash};
    job->quarantine.erase(f, pass);
    enqueue(*job, f);
  }
  metrics_.inc("proden_uploads_total");
  return answer("queued");
}

protocol::FrameStatus Engine::status(const Job& job, const Frame& fr) const {
  protocol::FrameStatus s;
  s.job = job.spec.id;
  s.frame = fr.rec.frame;
  s.passes = fr.rec.passes;
  s.spp = fr.rec.spp;
  s.version = fr.published_version;
  s.updated = fr.rec.updated;
  s.estimated_mse = fr.rec.estimated_mse;
  s.estimated_mse_source = fr.rec.estimated_mse_source;
  s.width = fr.rec.width;
  s.height = fr.rec.height;
  s.inputs = fr.rec.inputs;
  s.variance_source = fr.rec.variance_source;
  s.low_confidence = fr.rec.low_confidence;
  s.state_digest = hex64(fr.rec.digest);
  s.pass_list = fr.rec.ingested;
  s.quarantined = job.quarantine.of_frame(fr.rec.frame);
  s.outputs = fr.outputs;
  if (s.outputs.empty() && fr.published_version > 0) {
    const std::string base = output_base(job.spec, fr.rec.frame).string();
    s.outputs.push_back(base + ".exr");
    if (job.spec.output.png) s.outputs.push_back(base + ".png");
  }
  s.pending =
      scheduler_->busy(job.spec.id, fr.rec.frame) || !fr.pending.empty() || !fr.retry.empty();
  s.estimated_error = fr.rec.estimated_error;
  s.converged = fr.rec.convergence.converged();
  s.convergence = fr.rec.convergence.to_api(job.spec.target, job.spec.min_passes);
  s.renderer = fr.rec.renderer;
  s.view_layer = fr.rec.view_layer;
  s.view_layers = fr.rec.view_layers;
  s.aovs = fr.rec.aovs;
  for (auto it = fr.rec.versions.rbegin(); it != fr.rec.versions.rend(); ++it) {
    if (*it <= fr.published_version) s.versions.push_back(*it);
  }
  return s;
}

std::vector<protocol::FrameStatus> Engine::frames(const std::string& id) const {
  std::lock_guard lock(mu_);
  auto job = find(id);
  std::vector<protocol::FrameStatus> out;
  for (const auto& [no, fr] : job->frames) {
    if (fr.has_state || !fr.pending.empty() || !fr.retry.empty() || scheduler_->busy(id, no)) {
      out.push_back(status(*job, fr));
    }
  }
  return out;
}

protocol::FrameStatus Engine::frame(const std::string& id, long frame) const {
  std::lock_guard lock(mu_);
  auto job = find(id);
  auto it = job->frames.find(frame);
  if (it == job->frames.end()) {
    throw ApiError(404, "not_found", "job " + id + " has no frame " + std::to_string(frame));
  }
  return status(*job, it->second);
}

Engine::ImageFile Engine::image(const std::string& id, long frame, const std::string& format,
                                const std::string& layer) {
  PreviewCache::Request r;
  r.format = format;
  r.layer = layer;
  return image(id, frame, r);
}

json Engine::history(const std::string& id, long frame) const {
  {
    std::lock_guard lock(mu_);
    auto job = find(id);
    if (!job->frames.count(frame)) {
      throw ApiError(404, "not_found", "job " + id + " has no frame " + std::to_string(frame));
    }
  }
  return FrameHistory::load(store_.history_path(id, frame));
}

json Engine::job_history(const std::string& id) const {
  std::vector<long> frames;
  {
    std::lock_guard lock(mu_);
    for (const auto& [no, fr] : find(id)->frames) {
      if (fr.published_version > 0) frames.push_back(no);
    }
  }
  json out = json::array();
  for (long f : frames) {
    out.push_back({{"frame", f}, {"versions", FrameHistory::load(store_.history_path(id, f))}});
  }
  return out;
}

json Engine::quarantined(const std::string& id) const {
  std::lock_guard lock(mu_);
  json all = find(id)->quarantine.to_json();
  for (auto& q : all) {  // the API's form (as in a frame's `quarantined`)
    q.erase("size");
    q.erase("mtime_ns");
  }
  return all;
}

Engine::ImageFile Engine::image(const std::string& id, long frame,
                                const PreviewCache::Request& request,
                                std::optional<std::uint64_t> wanted) {
  PreviewCache::check_request(request.format, request.layer);
  fs::path exr;
  std::uint64_t version = 0;
  {
    std::lock_guard lock(mu_);
    auto job = find(id);
    auto it = job->frames.find(frame);
    if (it == job->frames.end() || it->second.published_version == 0) {
      throw ApiError(404, "not_found", "frame " + std::to_string(frame) + " has no version yet");
    }
    const Frame& fr = it->second;
    version = fr.published_version;
    exr = output_base(job->spec, frame).string() + ".exr";
    if (wanted && *wanted != version) {
      const bool kept =
          *wanted < version && std::find(fr.rec.versions.begin(), fr.rec.versions.end(), *wanted) !=
                                   fr.rec.versions.end();
      if (!kept) {
        std::string have;
        for (auto v = fr.rec.versions.rbegin(); v != fr.rec.versions.rend(); ++v) {
          if (*v <= version) have += (have.empty() ? "" : ", ") + std::to_string(*v);
        }
        throw ApiError(404, "version_not_available",
                       "frame " + std::to_string(frame) + " has no version " +
                           std::to_string(*wanted) + " (kept: " + have + ")");
      }
      version = *wanted;
      exr = version_file(job->spec, frame, version);
    }
  }
  if (request.format == "exr" && request.layer.empty()) {  // the API opens it confined
    ImageFile f;
    static_cast<PreviewCache::File&>(f) =
        previews_.get(store_.cache_dir(id), exr, frame, version, request);
    f.version = version;
    return f;
  }
  // A rendition decodes the published EXR: open it beneath its root now, check its header within
  // the read limits, and let the decoder read exactly that descriptor (/proc/self/fd/N names it).
  FileError fe = FileError::none;
  std::string why;
  const UniqueFd fd = roots_.open(exr, O_RDONLY | O_NONBLOCK | O_NOCTTY, fe, why);
  if (!fd) {
    if (fe == FileError::escape) throw ApiError(403, "path_forbidden", why);
    throw ApiError(404, "not_found", "the published image is not readable");
  }
  struct stat st {};
  if (::fstat(fd.get(), &st) != 0 || !S_ISREG(st.st_mode)) {
    throw ApiError(404, "not_found", "the published image is not a file");
  }
  try {
    io::inspect_header(io::FdSource(fd.get(), static_cast<std::uint64_t>(st.st_size)), exr.string(),
                       read_limits(config_.input, config_.input.max_file_bytes));
  } catch (const std::exception& e) {
    throw ApiError(500, "internal", e.what());
  }
  ImageFile f;
  static_cast<PreviewCache::File&>(f) = previews_.get(
      store_.cache_dir(id), "/proc/self/fd/" + std::to_string(fd.get()), frame, version, request);
  f.version = version;
  return f;
}

}  // namespace proden::daemon

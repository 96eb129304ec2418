#include "daemon/engine.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <random>

#include "daemon/processor.hpp"
#include "proden/error.hpp"
#include "proden/hash.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/protocol/json.hpp"

#ifndef PRODEN_VERSION
#define PRODEN_VERSION "dev"
#endif

namespace proden::daemon {

namespace fs = std::filesystem;
using nlohmann::json;
using protocol::ApiError;
using Clock = std::chrono::steady_clock;

namespace {

double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Natural order of pass names: numbers numerically, then names.
bool pass_less(const std::string& a, const std::string& b) {
  const bool na = !a.empty() && a.size() < 19 && std::all_of(a.begin(), a.end(), ::isdigit);
  const bool nb = !b.empty() && b.size() < 19 && std::all_of(b.begin(), b.end(), ::isdigit);
  if (na && nb) {
    const long long x = std::stoll(a), y = std::stoll(b);
    return x != y ? x < y : a < b;
  }
  if (na != nb) return na;
  return a < b;
}

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
  if (s.empty() || s.size() > 9 || !std::all_of(s.begin(), s.end(), ::isdigit)) {
    throw ApiError(400, "invalid_frame", "frame must be a non-negative integer (<= 9 digits)");
  }
  return std::stol(s);
}

void remove_temp_files(const fs::path& dir, const std::string& prefix) {
  std::error_code ec;
  for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string n = it->path().filename().string();
    if (n.rfind(prefix, 0) == 0 && n.find(".tmp") != std::string::npos) fs::remove(it->path(), ec);
  }
}

}  // namespace

Engine::Engine(const Config& config, const Roots& roots, Metrics& metrics, EventHub& events)
    : config_(config), roots_(roots), metrics_(metrics), events_(events) {
  Watcher::Callbacks cb;
  cb.wanted = [this](const FoundFile& f) { return wanted(f); };
  cb.offer = [this](const FoundFile& f) { offer(f); };
  cb.refused = [this](const FoundFile& f, const std::string& why) {
    spdlog::warn("{}: refused: {}", f.path.string(), why);
    metrics_.inc("proden_errors_total", "path_escape");
    error_event(f.job, f.frame, f.pass, f.path.string(), "path_escape", why, false);
  };
  watcher_ = std::make_unique<Watcher>(config_.watch, roots_, std::move(cb));
}

Engine::~Engine() {
  stop();
}

void Engine::start() {
  fs::create_directories(fs::path(config_.state_dir) / "jobs");
  load_state();
  watcher_->start();
  const int n = std::max(1, config_.worker_threads);
  for (int i = 0; i < n; ++i) workers_.emplace_back([this] { worker(); });
  ready_ = true;
}

void Engine::stop() {
  ready_ = false;
  if (watcher_) watcher_->stop();
  {
    std::lock_guard lock(mu_);
    stopping_ = true;
  }
  cv_.notify_all();
  for (auto& t : workers_) {
    if (t.joinable()) t.join();
  }
  workers_.clear();
}

// ---- state directory -------------------------------------------------------------------------

void Engine::load_state() {
  std::error_code ec;
  for (fs::directory_iterator it(fs::path(config_.state_dir) / "jobs", ec), end; !ec && it != end;
       it.increment(ec)) {
    if (!it->is_directory()) continue;
    try {
      load_job(it->path());
    } catch (const std::exception& e) {
      spdlog::error("state: job {} not loaded: {}", it->path().string(), e.what());
      metrics_.inc("proden_errors_total", "corrupt_state");
    }
  }
  std::lock_guard lock(mu_);
  update_gauges();
}

void Engine::load_job(const fs::path& dir) {
  auto job = std::make_shared<Job>();
  job->dir = dir;
  {
    std::ifstream in(dir / "job.json");
    if (!in) {  // a job whose creation was interrupted before job.json: drop it
      spdlog::warn("state: {} has no job.json; removing", dir.string());
      fs::remove_all(dir);
      return;
    }
    job->spec = protocol::job_from_json(json::parse(in));
  }
  const std::string& id = job->spec.id;
  // Quarantined files.
  if (std::ifstream q(dir / "quarantine.json"); q) {
    for (const auto& e : json::parse(q)) {
      Quarantined r{e.at("path"), e.at("kind"), e.at("message"),
                    e.at("time"), e.at("size"), e.at("mtime_ns")};
      job->quarantine[{e.at("frame").get<long>(), e.at("pass").get<std::string>()}] = r;
    }
  }
  // Frames: records only (the accumulators load when a frame next runs).
  const fs::path frames = dir / "frames";
  fs::create_directories(frames);
  remove_temp_files(frames, ".");
  std::error_code ec;
  for (fs::directory_iterator it(frames, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->path().extension() != ".state") continue;
    try {
      FrameRecord rec = load_frame_record(it->path());
      Frame& fr = job->frames[rec.frame];
      for (const auto& p : rec.ingested) fr.ingested.insert(p.pass);
      fr.rec = std::move(rec);
      fr.has_state = true;
      std::ifstream pub(fs::path(it->path()).replace_extension(".pub"));
      pub >> fr.published_version;
    } catch (const std::exception& e) {
      // Atomic writes make this a disk fault; start the frame over (its passes are re-read).
      spdlog::error("state: {}; moved aside, frame restarts", e.what());
      fs::rename(it->path(), fs::path(it->path()).replace_extension(".corrupt"), ec);
      metrics_.inc("proden_errors_total", "corrupt_state");
    }
  }
  // Output temp files of an interrupted publish.
  remove_temp_files(job->spec.output.dir, "." + job->spec.name + "_");
  // Stored uploads not yet accumulated.
  std::vector<std::pair<long, Pending>> uploads;
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
    auto f = job->frames.find(frame);
    if (f != job->frames.end() && f->second.ingested.count(pass)) {
      fs::remove(p, ec);  // accumulated before the crash, only the clean-up was lost
      continue;
    }
    if (job->quarantine.count({frame, pass})) continue;
    std::error_code e2;
    Pending pd{pass, p, fs::file_size(p, e2), mtime_ns(p, e2), true};
    uploads.emplace_back(frame, pd);
  }
  std::lock_guard lock(mu_);
  jobs_[id] = job;
  for (auto& [frame, pd] : uploads) {
    Frame& fr = job->frames[frame];
    fr.rec.frame = frame;
    fr.pending[pd.pass] = pd;
  }
  for (auto& [no, fr] : job->frames) {
    fr.rec.frame = no;
    if (!fr.pending.empty() || fr.published_version < fr.rec.version) enqueue(job, no, fr);
  }
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

void Engine::save_job(const Job& job) {
  write_file_atomic(job.dir / "job.json", protocol::to_json(job.spec).dump(2));
}

void Engine::save_quarantine(const std::shared_ptr<Job>& job) {
  json all = json::array();
  {
    std::lock_guard lock(mu_);
    for (const auto& [key, q] : job->quarantine) {
      all.push_back({{"frame", key.first},
                     {"pass", key.second},
                     {"path", q.path},
                     {"size", q.size},
                     {"mtime_ns", q.mtime_ns},
                     {"kind", q.kind},
                     {"message", q.message},
                     {"time", q.time}});
    }
  }
  try {
    write_file_atomic(job->dir / "quarantine.json", all.dump(1));
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
  }
}

// ---- scheduling ------------------------------------------------------------------------------

void Engine::enqueue(const std::shared_ptr<Job>& job, long frame_no, Frame& fr) {
  if (fr.queued || fr.running || job->deleted) return;
  fr.queued = true;
  job->ready.push_back(frame_no);
  if (!job->in_rotation && !job->spec.paused) {
    job->in_rotation = true;
    rotation_.push_back(job->spec.id);
  }
  update_gauges();
  cv_.notify_one();
}

void Engine::update_gauges() {
  std::size_t queued = 0;
  for (const auto& [id, j] : jobs_) queued += j->ready.size();
  metrics_.set("proden_queue_depth", static_cast<double>(queued));
  metrics_.set("proden_frames_in_progress", running_);
  metrics_.set("proden_jobs", static_cast<double>(jobs_.size()));
}

void Engine::worker() {
  for (;;) {
    std::shared_ptr<Job> job;
    long frame_no = 0;
    {
      std::unique_lock lock(mu_);
      cv_.wait(lock, [this] { return stopping_ || !rotation_.empty(); });
      if (stopping_) return;
      const std::string id = rotation_.front();
      rotation_.pop_front();
      auto it = jobs_.find(id);
      if (it == jobs_.end()) continue;
      job = it->second;
      job->in_rotation = false;
      if (job->spec.paused || job->deleted || job->ready.empty()) continue;
      frame_no = job->ready.front();
      job->ready.pop_front();
      if (!job->ready.empty()) {  // round-robin: back of the line
        job->in_rotation = true;
        rotation_.push_back(id);
      }
      Frame& fr = job->frames[frame_no];
      fr.queued = false;
      fr.running = true;
      ++running_;
      update_gauges();
    }
    run_frame(job, frame_no);
    {
      std::lock_guard lock(mu_);
      --running_;
      Frame& fr = job->frames[frame_no];
      fr.running = false;
      if (!fr.pending.empty()) enqueue(job, frame_no, fr);
      evict();
      update_gauges();
    }
    idle_cv_.notify_all();
  }
}

void Engine::evict() {
  std::vector<std::pair<std::uint64_t, Frame*>> resident;
  for (auto& [id, j] : jobs_) {
    for (auto& [no, fr] : j->frames) {
      if (fr.acc && !fr.running) resident.emplace_back(fr.last_used, &fr);
    }
  }
  const std::size_t limit = static_cast<std::size_t>(std::max(0, config_.max_resident_frames));
  if (resident.size() <= limit) return;
  std::sort(resident.begin(), resident.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  for (std::size_t i = 0; i + limit < resident.size(); ++i) resident[i].second->acc.reset();
}

bool Engine::wait_idle(int timeout_ms) {
  std::unique_lock lock(mu_);
  return idle_cv_.wait_for(lock, std::chrono::milliseconds(timeout_ms),
                           [this] { return running_ == 0 && rotation_.empty(); });
}

void Engine::run_frame(const std::shared_ptr<Job>& job, long frame_no) {
  std::vector<Pending> batch;
  std::shared_ptr<FrameAccumulator> acc;
  FrameRecord rec;
  bool has_state = false, republish = false;
  protocol::JobSpec spec;
  {
    std::lock_guard lock(mu_);
    Frame& fr = job->frames[frame_no];
    for (auto& [pass, p] : fr.pending) {
      if (!fr.ingested.count(pass)) {
        fr.inflight.insert(pass);
        batch.push_back(std::move(p));
      }
    }
    fr.pending.clear();
    std::sort(batch.begin(), batch.end(),
              [](const Pending& a, const Pending& b) { return pass_less(a.pass, b.pass); });
    acc = fr.acc;
    fr.acc.reset();
    rec = fr.rec;
    has_state = fr.has_state;
    republish = fr.published_version < fr.rec.version;
    spec = job->spec;
  }
  auto finish = [&](bool keep_acc) {
    std::lock_guard lock(mu_);
    Frame& fr = job->frames[frame_no];
    for (const auto& p : batch) fr.inflight.erase(p.pass);
    if (keep_acc) {
      fr.acc = acc;
      fr.last_used = ++use_clock_;
    }
  };
  const std::string job_id = spec.id;
  const fs::path state_file = state_path(*job, frame_no);
  try {
    if (!acc) {
      if (has_state) {
        const auto t0 = Clock::now();
        acc = std::make_shared<FrameAccumulator>(load_frame_accumulator(state_file, nullptr));
        metrics_.observe("proden_stage_duration_seconds", "load", seconds_since(t0));
      } else {
        acc = std::make_shared<FrameAccumulator>();
      }
    }
  } catch (const std::exception& e) {
    spdlog::error("job {} frame {}: cannot load state: {}", job_id, frame_no, e.what());
    metrics_.inc("proden_errors_total", "corrupt_state");
    error_event(job_id, frame_no, "", state_file.string(), "corrupt_state", e.what(), false);
    std::lock_guard lock(mu_);
    Frame& fr = job->frames[frame_no];
    for (auto& p : batch) {
      fr.inflight.erase(p.pass);
      if (p.upload) fr.pending[p.pass] = p;  // keep stored uploads for a later run
    }
    return;
  }

  io::ReadOptions ro;
  ro.renderer = io::parse_renderer(spec.renderer).value_or(io::Renderer::automatic);
  ro.spp = spec.spp;
  std::vector<protocol::PassIdentity> accepted;
  std::uint64_t accepted_bytes = 0;
  for (const auto& p : batch) {
    try {
      auto t0 = Clock::now();
      std::error_code ec;
      const std::uint64_t size = fs::file_size(p.path, ec);
      const std::int64_t mt = ec ? 0 : mtime_ns(p.path, ec);
      if (ec) continue;  // gone: nothing to count (the watcher re-discovers a re-created file)
      if (!p.upload && (size != p.size || mt != p.mtime_ns)) continue;  // changed: re-settles
      auto bytes = read_file(p.path);
      if (!bytes || bytes->size() != size) {
        throw InputError(InputErrorKind::unreadable, p.path.string(), "cannot be read to the end");
      }
      protocol::PassIdentity id{p.pass, p.path.string(), size, mt,
                                hash_bytes(std::span<const unsigned char>(*bytes))};
      bytes.reset();
      const Pass pass = io::read_pass(p.path.string(), ro);
      metrics_.observe("proden_stage_duration_seconds", "read", seconds_since(t0));
      t0 = Clock::now();
      const AddResult r = acc->add(pass, p.pass);
      metrics_.observe("proden_stage_duration_seconds", "accumulate", seconds_since(t0));
      if (r.dropped_pixels > 0) {
        spdlog::warn("{}: {} non-finite pixel(s) dropped", p.path.string(), r.dropped_pixels);
      }
      accepted.push_back(id);
      accepted_bytes += size;
    } catch (const InputError& e) {
      const std::string kind(to_string(e.kind()));
      int attempts = 0;
      {
        std::lock_guard lock(mu_);
        attempts = ++job->frames[frame_no].attempts[p.pass];
      }
      if (e.kind() == InputErrorKind::unreadable && !p.upload &&
          attempts < config_.watch.max_attempts) {
        spdlog::info("{}: unreadable (attempt {}/{}): {}", p.path.string(), attempts,
                     config_.watch.max_attempts, e.reason());
        metrics_.inc("proden_errors_total", "read_retry");
        continue;  // the watcher's next scan offers it again
      }
      quarantine(job, frame_no, p, kind, e.reason());
    } catch (const std::exception& e) {
      quarantine(job, frame_no, p, "unreadable", e.what());
    }
  }

  if (accepted.empty() && !republish) {
    finish(true);
    return;
  }
  try {
    auto t0 = Clock::now();
    const FrameEstimate est = acc->estimate(FrameProcessor::estimate_options(spec.pipeline));
    metrics_.observe("proden_stage_duration_seconds", "estimate", seconds_since(t0));
    const ProcessedFrame out = FrameProcessor::process(*acc, est, spec.pipeline);
    for (const auto& [stage, s] : out.stage_seconds) {
      metrics_.observe("proden_stage_duration_seconds", stage, s);
    }
    if (!accepted.empty()) {
      rec.frame = frame_no;
      rec.version += 1;
      rec.updated = protocol::now_rfc3339();
      rec.estimated_mse = out.estimated_mse;
      rec.estimated_mse_source = out.estimated_mse_source;
      rec.passes = acc->passes();
      rec.spp = acc->total_spp();
      rec.width = acc->width();
      rec.height = acc->height();
      rec.inputs = acc->layout().to_string();
      rec.variance_source = std::string(protocol::to_string(est.variance_source));
      rec.low_confidence = est.low_confidence();
      rec.digest = acc->state_digest();
      rec.ingested.insert(rec.ingested.end(), accepted.begin(), accepted.end());
      t0 = Clock::now();
      // The commit point: statistics and pass identities together, atomically.
      save_frame_state(state_file, rec, *acc);
      metrics_.observe("proden_stage_duration_seconds", "persist", seconds_since(t0));
      {
        std::lock_guard lock(mu_);
        Frame& fr = job->frames[frame_no];
        fr.rec = rec;
        fr.has_state = true;
        for (const auto& a : accepted) {
          fr.ingested.insert(a.pass);
          fr.attempts.erase(a.pass);
        }
      }
      metrics_.inc("proden_passes_ingested_total", {}, static_cast<double>(accepted.size()));
      metrics_.inc("proden_ingested_bytes_total", {}, static_cast<double>(accepted_bytes));
      for (const auto& p : batch) {
        std::error_code ec;
        if (p.upload && std::any_of(accepted.begin(), accepted.end(),
                                    [&](const auto& a) { return a.pass == p.pass; })) {
          fs::remove(p.path, ec);
        }
      }
    }
    t0 = Clock::now();
    fs::create_directories(spec.output.dir);
    const auto outputs =
        FrameProcessor::publish(out, output_base(*job, frame_no).string(), spec.output.png);
    write_file_atomic(fs::path(state_file).replace_extension(".pub"), std::to_string(rec.version));
    metrics_.observe("proden_stage_duration_seconds", "publish", seconds_since(t0));
    {
      std::lock_guard lock(mu_);
      Frame& fr = job->frames[frame_no];
      fr.published_version = rec.version;
      fr.outputs = outputs;
    }
    metrics_.inc("proden_frame_updates_total");
    json data = {{"job", job_id},
                 {"name", spec.name},
                 {"frame", frame_no},
                 {"version", rec.version},
                 {"passes", rec.passes},
                 {"spp", rec.spp},
                 {"new_passes", accepted.size()},
                 {"estimated_mse", rec.estimated_mse},
                 {"updated", rec.updated},
                 {"outputs", outputs}};
    events_.publish("frame", data);
    spdlog::info("job {} frame {}: version {} ({} pass(es), {} spp)", job_id, frame_no, rec.version,
                 rec.passes, rec.spp);
    finish(true);
  } catch (const std::exception& e) {
    // Persist or publish failed (disk full, permissions): drop the resident state so the next
    // run reloads what is on disk; passes not persisted are offered again by the watcher.
    spdlog::error("job {} frame {}: {}", job_id, frame_no, e.what());
    metrics_.inc("proden_errors_total", "publish");
    error_event(job_id, frame_no, "", "", "publish", e.what(), false);
    finish(false);
  }
}

void Engine::quarantine(const std::shared_ptr<Job>& job, long frame, const Pending& p,
                        const std::string& kind, const std::string& message) {
  spdlog::warn("{}: quarantined ({}): {}", p.path.string(), kind, message);
  {
    std::lock_guard lock(mu_);
    job->quarantine[{frame, p.pass}] =
        Quarantined{p.path.string(), kind, message, protocol::now_rfc3339(), p.size, p.mtime_ns};
  }
  save_quarantine(job);
  metrics_.inc("proden_errors_total", kind);
  error_event(job->spec.id, frame, p.pass, p.path.string(), kind, message, true);
}

void Engine::error_event(const std::string& job, long frame, const std::string& pass,
                         const std::string& path, const std::string& kind,
                         const std::string& message, bool quarantined) {
  events_.publish("error", {{"job", job},
                            {"frame", frame},
                            {"pass", pass},
                            {"path", path},
                            {"kind", kind},
                            {"message", message},
                            {"quarantined", quarantined}});
}

// ---- watcher callbacks -----------------------------------------------------------------------

bool Engine::wanted(const FoundFile& f) {
  std::lock_guard lock(mu_);
  auto it = jobs_.find(f.job);
  if (it == jobs_.end() || it->second->deleted) return false;
  const Job& job = *it->second;
  auto q = job.quarantine.find({f.frame, f.pass});
  if (q != job.quarantine.end() && q->second.size == f.size && q->second.mtime_ns == f.mtime_ns) {
    return false;
  }
  auto fr = job.frames.find(f.frame);
  if (fr == job.frames.end()) return true;
  return !fr->second.ingested.count(f.pass) && !fr->second.pending.count(f.pass) &&
         !fr->second.inflight.count(f.pass);
}

void Engine::offer(const FoundFile& f) {
  std::lock_guard lock(mu_);
  auto it = jobs_.find(f.job);
  if (it == jobs_.end() || it->second->deleted) return;
  auto& job = it->second;
  auto q = job->quarantine.find({f.frame, f.pass});
  if (q != job->quarantine.end()) {
    if (q->second.size == f.size && q->second.mtime_ns == f.mtime_ns) return;
    job->quarantine.erase(q);  // replaced by a new file: give it its chance
  }
  Frame& fr = job->frames[f.frame];
  fr.rec.frame = f.frame;
  if (fr.ingested.count(f.pass) || fr.pending.count(f.pass) || fr.inflight.count(f.pass)) return;
  fr.pending[f.pass] = Pending{f.pass, f.path, f.size, f.mtime_ns, false};
  enqueue(job, f.frame, fr);
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
    std::error_code ec;
    fs::create_directories(*real, ec);
    if (ec || !fs::is_directory(*real)) {
      throw ApiError(400, "invalid_path",
                     std::string(field) + ": cannot create directory " + real->string());
    }
    // Re-check after creation: a symlink may have appeared in the meantime.
    const fs::path again = fs::canonical(*real, ec);
    if (ec || !roots_.contains(again)) {
      throw ApiError(403, "path_forbidden", std::string(field) + ": outside the allowed roots");
    }
    return again.string();
  };
  if (std::string why; !FrameProcessor::supports(spec.pipeline, why)) {
    throw ApiError(400, "invalid_field", why);
  }
  if (spec.watch) spec.watch->dir = confine(spec.watch->dir, "watch.dir");
  spec.output.dir = confine(spec.output.dir, "output.dir");
  spec.created = protocol::now_rfc3339();
  auto job = std::make_shared<Job>();
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
    job->dir = fs::path(config_.state_dir) / "jobs" / spec.id;
    jobs_[spec.id] = job;
    update_gauges();
  }
  try {
    fs::create_directories(job->dir / "frames");
    fs::create_directories(job->dir / "uploads");
    save_job(*job);
  } catch (const std::exception& e) {
    std::lock_guard lock(mu_);
    jobs_.erase(spec.id);
    throw ApiError(500, "internal", std::string("cannot persist the job: ") + e.what());
  }
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
    job->deleted = true;
    jobs_.erase(id);
    update_gauges();
  }
  watcher_->remove_job(id);
  std::error_code ec;
  fs::remove_all(job->dir, ec);  // state only; published outputs stay
  events_.publish("job", {{"job", id}, {"name", job->spec.name}, {"state", "deleted"}});
  spdlog::info("job {} deleted", id);
}

protocol::JobSpec Engine::set_paused(const std::string& id, bool paused) {
  protocol::JobSpec spec;
  std::shared_ptr<Job> job;
  {
    std::lock_guard lock(mu_);
    job = find(id);
    job->spec.paused = paused;
    if (!paused && !job->ready.empty() && !job->in_rotation) {
      job->in_rotation = true;
      rotation_.push_back(id);
      cv_.notify_one();
    }
    spec = job->spec;
  }
  save_job(*job);
  events_.publish("job",
                  {{"job", id}, {"name", spec.name}, {"state", paused ? "paused" : "resumed"}});
  return spec;
}

void Engine::check_upload(const std::string& id, const std::string& frame,
                          const std::string& pass) const {
  const long f = parse_frame(frame);
  if (!valid_pass_name(pass)) {
    throw ApiError(400, "invalid_pass", "pass must be 1-64 characters of A-Z a-z 0-9 _ -");
  }
  std::lock_guard lock(mu_);
  const auto job = find(id);
  auto fr = job->frames.find(f);
  if (fr != job->frames.end() &&
      (fr->second.ingested.count(pass) || fr->second.pending.count(pass) ||
       fr->second.inflight.count(pass))) {
    throw ApiError(409, "conflict", "frame " + frame + " already has pass " + pass);
  }
}

json Engine::upload(const std::string& id, const std::string& frame, const std::string& pass,
                    const std::string& body) {
  check_upload(id, frame, pass);
  const long f = parse_frame(frame);
  if (body.empty()) throw ApiError(400, "invalid_pass", "empty body");
  fs::path dir, path;
  {
    std::lock_guard lock(mu_);
    dir = find(id)->dir / "uploads" / std::to_string(f);
  }
  fs::create_directories(dir);
  path = dir / (pass + ".exr");
  const fs::path tmp = dir / (".check." + pass + ".exr");
  write_file_atomic(tmp, body);
  try {  // header check now, so a client sending garbage hears about it
    io::ReadOptions ro;
    io::probe_pass(tmp.string(), ro);
  } catch (const std::exception& e) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw ApiError(400, "invalid_pass", std::string("not a readable pass: ") + e.what());
  }
  std::lock_guard lock(mu_);
  auto job = find(id);
  Frame& fr = job->frames[f];
  fr.rec.frame = f;
  if (fr.ingested.count(pass) || fr.pending.count(pass) || fr.inflight.count(pass)) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw ApiError(409, "conflict", "frame " + frame + " already has pass " + pass);
  }
  fs::rename(tmp, path);
  std::error_code ec;
  fr.pending[pass] = Pending{pass, path, fs::file_size(path, ec), mtime_ns(path, ec), true};
  job->quarantine.erase({f, pass});
  enqueue(job, f, fr);
  metrics_.inc("proden_uploads_total");
  return {{"job", id}, {"frame", f}, {"pass", pass}, {"bytes", body.size()}, {"status", "queued"}};
}

std::filesystem::path Engine::output_base(const Job& job, long frame) const {
  char buf[32];
  std::snprintf(buf, sizeof buf, "_%04ld", frame);
  return fs::path(job.spec.output.dir) / (job.spec.name + buf);
}

std::filesystem::path Engine::state_path(const Job& job, long frame) const {
  return job.dir / "frames" / (std::to_string(frame) + ".state");
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
  for (const auto& [key, q] : job.quarantine) {
    if (key.first != fr.rec.frame) continue;
    s.quarantined.push_back({{"pass", key.second},
                             {"path", q.path},
                             {"kind", q.kind},
                             {"message", q.message},
                             {"time", q.time}});
  }
  s.outputs = fr.outputs;
  if (s.outputs.empty() && fr.published_version > 0) {
    s.outputs.push_back(output_base(job, fr.rec.frame).string() + ".exr");
    if (job.spec.output.png) s.outputs.push_back(output_base(job, fr.rec.frame).string() + ".png");
  }
  s.pending = fr.queued || fr.running || !fr.pending.empty();
  return s;
}

std::vector<protocol::FrameStatus> Engine::frames(const std::string& id) const {
  std::lock_guard lock(mu_);
  auto job = find(id);
  std::vector<protocol::FrameStatus> out;
  for (const auto& [no, fr] : job->frames) {
    if (fr.has_state || fr.queued || fr.running || !fr.pending.empty()) {
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
  if (format != "exr" && format != "png") {
    throw ApiError(400, "invalid_parameter", "format must be exr or png");
  }
  if (!layer.empty() && !known_layer(layer)) {
    throw ApiError(400, "invalid_parameter", "layer must be one of " + known_layers());
  }
  fs::path exr, cache;
  std::uint64_t version = 0;
  {
    std::lock_guard lock(mu_);
    auto job = find(id);
    auto it = job->frames.find(frame);
    if (it == job->frames.end() || it->second.published_version == 0) {
      throw ApiError(404, "not_found", "frame " + std::to_string(frame) + " has no version yet");
    }
    version = it->second.published_version;
    exr = output_base(*job, frame).string() + ".exr";
    cache = job->dir / "cache";
  }
  if (format == "exr" && layer.empty()) return {exr, "image/x-exr"};
  const std::string l = layer.empty() ? "result" : layer;
  const std::string stem = std::to_string(frame) + "." + l + ".";
  const fs::path out = cache / (stem + "v" + std::to_string(version) + "." + format);
  static std::mutex cache_mu;  // one writer at a time (the writer's temp name is per process)
  std::lock_guard cache_lock(cache_mu);
  std::error_code ec;
  if (fs::exists(out, ec)) return {out, format == "png" ? "image/png" : "image/x-exr"};
  Image img;
  try {
    img = read_layer(exr.string(), l);
  } catch (const std::exception& e) {
    throw ApiError(500, "internal", e.what());
  }
  if (img.empty()) {
    throw ApiError(404, "layer_not_available", "layer " + l + " is not in the published frame");
  }
  fs::create_directories(cache, ec);
  for (fs::directory_iterator it(cache, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->path().filename().string().rfind(stem, 0) == 0) fs::remove(it->path(), ec);
  }
  if (format == "png") {
    write_png_preview(out.string(), img);
    return {out, "image/png"};
  }
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "", img);
  io::write_image(out.string(), img.width(), img.height(), ch);
  return {out, "image/x-exr"};
}

}  // namespace proden::daemon

#include "daemon/engine.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <random>

#include "daemon/frame_history.hpp"
#include "daemon/processor.hpp"
#include "daemon/versions.hpp"
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
  if (s.empty() || s.size() > 9 || !std::all_of(s.begin(), s.end(), ::isdigit)) {
    throw ApiError(400, "invalid_frame", "frame must be a non-negative integer (<= 9 digits)");
  }
  return std::stol(s);
}

}  // namespace

Engine::Engine(const Config& config, const Roots& roots, Metrics& metrics, EventHub& events,
               FsHook fs_hook)
    : config_(config),
      roots_(roots),
      metrics_(metrics),
      events_(events),
      store_(config_.state_dir, std::move(fs_hook)) {
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
      &metrics_);
}

Engine::~Engine() {
  stop();
}

void Engine::start() {
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
  auto loaded = store_.load_job(
      dir, [this](const std::string&) { metrics_.inc("proden_errors_total", "corrupt_state"); });
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
  }
  const std::string id = job->spec.id;
  std::lock_guard lock(mu_);
  {
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

void Engine::save_quarantine(const std::shared_ptr<Job>& job) {
  std::string text;
  {
    std::lock_guard lock(mu_);
    text = job->quarantine.to_json().dump(1);
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

void Engine::evict() {
  std::vector<std::pair<std::uint64_t, Frame*>> resident;
  for (auto& [id, j] : jobs_) {
    for (auto& [no, fr] : j->frames) {
      if (fr.acc) resident.emplace_back(fr.last_used, &fr);  // a running frame's is lent out
    }
  }
  const std::size_t limit = static_cast<std::size_t>(std::max(0, config_.max_resident_frames));
  if (resident.size() <= limit) return;
  std::sort(resident.begin(), resident.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  for (std::size_t i = 0; i + limit < resident.size(); ++i) {
    resident[i].second->acc.reset();
    resident[i].second->aovs.reset();
  }
}

bool Engine::wait_idle(int timeout_ms) {
  return scheduler_->wait_idle(timeout_ms);
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
    for (auto& [pass, p] : fr.pending) {
      if (!fr.ingested.count(pass)) {
        fr.inflight.insert(pass);
        in.batch.push_back(std::move(p));
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
    }
  };
  hooks.published = [&](std::uint64_t version, const std::vector<std::string>& outputs) {
    std::lock_guard lock(mu_);
    Frame& fr = job->frames[frame_no];
    fr.published_version = version;
    fr.outputs = outputs;
  };
  FrameRun run(store_, metrics_, events_, std::move(hooks));
  const FrameRun::Outcome out = run.run(std::move(in));

  std::lock_guard lock(mu_);
  Frame& fr = job->frames[frame_no];
  for (const auto& p : batch) fr.inflight.erase(p.pass);
  if (out.result == FrameRun::Result::state_unreadable) {
    for (const auto& p : batch) {
      if (p.upload) fr.pending[p.pass] = p;  // keep stored uploads for a later run
    }
  } else if (out.result == FrameRun::Result::done) {
    fr.acc = out.acc;
    fr.aovs = out.aovs;
    fr.last_used = ++use_clock_;
  }
  if (!fr.pending.empty()) enqueue(*job, frame_no);
  evict();
}

void Engine::on_failed(const std::shared_ptr<Job>& job, long frame, const PendingPass& p,
                       const Failure& f) {
  int attempts = 0;
  {
    std::lock_guard lock(mu_);
    attempts = ++job->frames[frame].attempts[p.pass];
  }
  if (retry_.decide(f, attempts, p.upload) == RetryPolicy::Action::retry) {
    spdlog::info("{}: {} (attempt {}/{}): {}", p.path.string(), f.kind, attempts,
                 retry_.max_attempts, f.message);
    metrics_.inc("proden_errors_total", "read_retry");
    return;  // the watcher's next scan offers it again
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
  }
  save_quarantine(job);
  metrics_.inc("proden_errors_total", kind);
  publish_error(events_, job->spec.id, frame, p.pass, p.path.string(), kind, message, true);
}

// ---- watcher callbacks -----------------------------------------------------------------------

bool Engine::wanted(const FoundFile& f) {
  std::lock_guard lock(mu_);
  auto it = jobs_.find(f.job);
  if (it == jobs_.end() || it->second->deleted) return false;
  const Job& job = *it->second;
  if (job.quarantine.blocks(f.frame, f.pass, f.size, f.mtime_ns)) return false;
  auto fr = job.frames.find(f.frame);
  return fr == job.frames.end() || !fr->second.has(f.pass);
}

void Engine::offer(const FoundFile& f) {
  std::lock_guard lock(mu_);
  auto it = jobs_.find(f.job);
  if (it == jobs_.end() || it->second->deleted) return;
  auto& job = it->second;
  if (!job->quarantine.admit(f.frame, f.pass, f.size, f.mtime_ns)) return;
  Frame& fr = job->frames[f.frame];
  fr.rec.frame = f.frame;
  if (fr.has(f.pass)) return;
  fr.pending[f.pass] = PendingPass{f.pass, f.path, f.size, f.mtime_ns, false};
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
    jobs_[spec.id] = job;
    scheduler_->set_paused(spec.id, spec.paused);
    metrics_.set("proden_jobs", static_cast<double>(jobs_.size()));
  }
  try {
    store_.create_job(spec);
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
    scheduler_->remove_job(id);
    metrics_.set("proden_jobs", static_cast<double>(jobs_.size()));
  }
  watcher_->remove_job(id);
  store_.remove_job(id);  // state only; published outputs stay
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
    scheduler_->set_paused(id, paused);
    spec = job->spec;
  }
  store_.save_job(id, protocol::to_json(job->spec).dump(2));
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
  if (fr != job->frames.end() && fr->second.has(pass)) {
    throw ApiError(409, "conflict", "frame " + frame + " already has pass " + pass);
  }
}

json Engine::upload(const std::string& id, const std::string& frame, const std::string& pass,
                    const std::string& body) {
  check_upload(id, frame, pass);
  const long f = parse_frame(frame);
  if (body.empty()) throw ApiError(400, "invalid_pass", "empty body");
  const fs::path tmp = store_.spool_upload(id, f, pass, body);
  try {  // header check now, so a client sending garbage hears about it
    io::ReadOptions ro;
    io::probe_pass(tmp.string(), ro);
  } catch (const std::exception& e) {
    store_.remove_file(tmp);
    throw ApiError(400, "invalid_pass", std::string("not a readable pass: ") + e.what());
  }
  std::lock_guard lock(mu_);
  auto job = find(id);
  Frame& fr = job->frames[f];
  fr.rec.frame = f;
  if (fr.has(pass)) {
    store_.remove_file(tmp);
    throw ApiError(409, "conflict", "frame " + frame + " already has pass " + pass);
  }
  const fs::path path = store_.commit_upload(tmp, id, f, pass);
  std::error_code ec;
  fr.pending[pass] = PendingPass{pass, path, fs::file_size(path, ec), mtime_ns(path, ec), true};
  job->quarantine.erase(f, pass);
  enqueue(*job, f);
  metrics_.inc("proden_uploads_total");
  return {{"job", id}, {"frame", f}, {"pass", pass}, {"bytes", body.size()}, {"status", "queued"}};
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
  s.pending = scheduler_->busy(job.spec.id, fr.rec.frame) || !fr.pending.empty();
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
    if (fr.has_state || !fr.pending.empty() || scheduler_->busy(id, no)) {
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
  ImageFile f;
  static_cast<PreviewCache::File&>(f) =
      previews_.get(store_.cache_dir(id), exr, frame, version, request);
  f.version = version;
  return f;
}

}  // namespace proden::daemon

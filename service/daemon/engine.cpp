#include "daemon/engine.hpp"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <random>

#include "daemon/processor.hpp"
#include "daemon/request_parse.hpp"
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
  for (std::size_t i = 0; i + limit < resident.size(); ++i) resident[i].second->acc.reset();
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
    fr.acc.reset();
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
  std::uint64_t size = 0;
  try {  // header check now (through the descriptor, within the limits), so a client sending
         // garbage hears about it; the body is never read into memory here
    const UniqueFd fd(open_regular_nofollow(spooled));
    struct stat st {};
    if (!fd || ::fstat(fd.get(), &st) != 0) {
      throw ApiError(500, "internal", "the stored upload cannot be read back");
    }
    size = static_cast<std::uint64_t>(st.st_size);
    if (size == 0) throw ApiError(400, "invalid_pass", "empty body");
    ::fsync(fd.get());
    io::ReadOptions ro;
    ro.renderer = io::parse_renderer(renderer).value_or(io::Renderer::automatic);
    ro.limits = read_limits(config_.input, config_.limits.max_upload_bytes);
    io::probe_pass(io::FdSource(fd.get(), size), spooled.string(), ro);
  } catch (const ApiError&) {
    throw;
  } catch (const std::exception& e) {
    throw ApiError(400, "invalid_pass", std::string("not a readable pass: ") + e.what());
  }
  std::lock_guard lock(mu_);
  auto job = find(id);
  Frame& fr = job->frames[f];
  fr.rec.frame = f;
  if (fr.has(pass)) {
    throw ApiError(409, "conflict", "frame " + frame + " already has pass " + pass);
  }
  const fs::path path = store_.commit_upload(spooled, id, f, pass);
  tmp.path.clear();
  std::error_code ec;
  fr.pending[pass] = PendingPass{pass, path, size, mtime_ns(path, ec), true};
  job->quarantine.erase(f, pass);
  enqueue(*job, f);
  metrics_.inc("proden_uploads_total");
  return {{"job", id}, {"frame", f}, {"pass", pass}, {"bytes", size}, {"status", "queued"}};
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
  PreviewCache::check_request(format, layer);
  fs::path exr;
  std::uint64_t version = 0;
  {
    std::lock_guard lock(mu_);
    auto job = find(id);
    auto it = job->frames.find(frame);
    if (it == job->frames.end() || it->second.published_version == 0) {
      throw ApiError(404, "not_found", "frame " + std::to_string(frame) + " has no version yet");
    }
    version = it->second.published_version;
    exr = output_base(job->spec, frame).string() + ".exr";
  }
  if (format == "exr" && layer.empty()) return {exr, "image/x-exr"};  // the API opens it confined
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
  return previews_.get(store_.cache_dir(id), "/proc/self/fd/" + std::to_string(fd.get()), frame,
                       version, format, layer);
}

}  // namespace proden::daemon

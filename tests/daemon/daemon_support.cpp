#include "daemon_support.hpp"

#include <fstream>
#include <sstream>
#include <thread>

#include "daemon/files.hpp"

namespace proden::test {

namespace fs = std::filesystem;

std::vector<EventLog::Event> EventLog::events() const {
  std::lock_guard lock(mu_);
  std::vector<Event> out;
  for (const auto& w : wires_) {
    Event e;
    std::size_t pos = 0;
    while (pos < w.size()) {
      const auto end = w.find('\n', pos);
      const std::string line = w.substr(pos, end - pos);
      if (line.rfind("event: ", 0) == 0) e.type = line.substr(7);
      if (line.rfind("data: ", 0) == 0) e.data = nlohmann::json::parse(line.substr(6));
      if (end == std::string::npos) break;
      pos = end + 1;
    }
    out.push_back(std::move(e));
  }
  return out;
}

std::vector<EventLog::Event> EventLog::of_type(const std::string& type) const {
  std::vector<Event> out;
  for (auto& e : events()) {
    if (e.type == type) out.push_back(std::move(e));
  }
  return out;
}

std::shared_ptr<EventLog> listen(daemon::EventHub& hub) {
  auto log = std::make_shared<EventLog>();
  hub.subscribe(log, std::nullopt);
  return log;
}

daemon::PendingPass write_pass(const fs::path& path, const std::string& pass, std::uint64_t seed,
                               bool upload, int w, int h) {
  fs::create_directories(path.parent_path());
  write_generic_exr(path.string(), make_pass(w, h, 4.0, seed));
  std::error_code ec;
  return {pass, path, fs::file_size(path), daemon::mtime_ns(path, ec), upload};
}

protocol::JobSpec job_spec(const fs::path& root, const std::string& id,
                           const std::string& denoiser) {
  protocol::JobSpec s;
  s.id = id;
  s.name = "shot";
  s.output.dir = (root / "out").string();
  s.pipeline = protocol::PipelineSpec::from_json({{"denoiser", denoiser}});
  s.spp = 4.0;  // the synthetic files do not say
  s.created = "2026-01-01T00:00:00.000Z";
  return s;
}

bool eventually(const std::function<bool()>& pred, int timeout_ms) {
  const auto end = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  for (;;) {
    if (pred()) return true;
    if (std::chrono::steady_clock::now() > end) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

std::string read_all(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void flip_byte(const fs::path& p, std::int64_t offset) {
  std::fstream f(p, std::ios::in | std::ios::out | std::ios::binary);
  f.seekg(offset, offset < 0 ? std::ios::end : std::ios::beg);
  const auto pos = f.tellg();
  char c = 0;
  f.read(&c, 1);
  f.seekp(pos);
  f.put(static_cast<char>(c ^ 0x10));
}

EngineRig::EngineRig() {
  fs::create_directories(allowed());
  config.state_dir = (t.path() / "state").string();
  config.allowed_roots = {allowed().string()};
  config.worker_threads = 2;
  config.watch.inotify = false;
  config.watch.poll_interval_ms = 100;
  config.watch.settle_ms = 50;
  config.watch.tick_ms = 20;
  roots = daemon::Roots(config.allowed_roots);
  start();
}

EngineRig::~EngineRig() {
  if (engine) engine->stop();
}

void EngineRig::start() {
  daemon::EngineTestHooks hooks;
  hooks.fs = [this](const std::string& op, const fs::path& p) {
    if (fault) fault(op, p);
  };
  hooks.clock = &clock;
  engine = std::make_unique<daemon::Engine>(config, roots, metrics, hub, hooks);
  engine->start();
}

void EngineRig::restart() {
  engine->stop();
  engine.reset();
  start();
}

protocol::JobSpec EngineRig::create(const std::string& name,
                                    std::optional<protocol::WatchSpec> watch,
                                    const std::string& out) {
  protocol::JobSpec s;
  s.name = name;
  s.output.dir = out.empty() ? (allowed() / (name + "_out")).string() : out;
  s.pipeline = protocol::PipelineSpec::from_json({{"denoiser", "none"}});
  s.spp = 4.0;  // the synthetic files do not say
  s.watch = std::move(watch);
  return engine->create_job(s);
}

std::string EngineRig::pass_bytes(std::uint64_t seed, int w, int h) {
  const fs::path p = t.path() / ("p" + std::to_string(seed) + ".exr");
  write_pass(p, "x", seed, false, w, h);
  return read_all(p);
}

double EngineRig::metric(const std::string& sample) {
  std::istringstream in(metrics.render());
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(sample + " ", 0) == 0) return std::stod(line.substr(sample.size() + 1));
  }
  return 0.0;
}

}  // namespace proden::test

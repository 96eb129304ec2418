#include "daemon_support.hpp"

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

}  // namespace proden::test

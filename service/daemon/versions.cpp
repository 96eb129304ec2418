#include "daemon/versions.hpp"

#include <cstdio>
#include <stdexcept>

#include "daemon/frame_run.hpp"

namespace proden::daemon {

namespace fs = std::filesystem;
using nlohmann::json;

json to_json(const VersionEntry& v) {
  return {
      {"version", v.version}, {"passes", v.passes},       {"spp", v.spp},
      {"updated", v.updated}, {"converged", v.converged}, {"estimated_error", v.estimated_error}};
}

VersionEntry version_entry_from_json(const json& j) {
  VersionEntry v;
  v.version = j.at("version").get<std::uint64_t>();
  v.passes = j.at("passes").get<int>();
  v.spp = j.at("spp").get<double>();
  v.updated = j.at("updated").get<std::string>();
  v.converged = j.at("converged").get<bool>();
  v.estimated_error = j.at("estimated_error");
  return v;
}

fs::path version_file(const protocol::JobSpec& spec, long frame, std::uint64_t version) {
  const fs::path base = output_base(spec, frame);
  char v[32];
  std::snprintf(v, sizeof v, ".v%04llu.exr", static_cast<unsigned long long>(version));
  return base.parent_path() / "versions" / (base.filename().string() + v);
}

std::vector<VersionEntry> add_version(std::vector<VersionEntry>& list, VersionEntry entry,
                                      int history) {
  std::erase_if(list, [&](const VersionEntry& e) { return e.version == entry.version; });
  list.push_back(std::move(entry));
  std::vector<VersionEntry> dropped;
  const std::size_t keep = static_cast<std::size_t>(std::max(0, history)) + 1;
  while (list.size() > keep) {
    dropped.push_back(std::move(list.front()));
    list.erase(list.begin());
  }
  return dropped;
}

void keep_version(const fs::path& published, const fs::path& dest) {
  std::error_code ec;
  fs::create_directories(dest.parent_path(), ec);
  const fs::path tmp = dest.parent_path() / ("." + dest.filename().string() + ".tmp");
  fs::remove(tmp, ec);
  fs::create_hard_link(published, tmp, ec);
  if (ec) {  // another file system, or links not supported: copy
    ec.clear();
    fs::copy_file(published, tmp, fs::copy_options::overwrite_existing, ec);
    if (ec) {
      throw std::runtime_error("cannot keep " + published.string() + " as " + dest.string() + ": " +
                               ec.message());
    }
  }
  fs::rename(tmp, dest, ec);
  if (ec) {
    fs::remove(tmp, ec);
    throw std::runtime_error("cannot rename the kept version to " + dest.string());
  }
}

}  // namespace proden::daemon

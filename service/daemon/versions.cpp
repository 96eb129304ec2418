#include "daemon/versions.hpp"

#include <cstdio>
#include <stdexcept>

#include "daemon/frame_run.hpp"

namespace proden::daemon {

namespace fs = std::filesystem;

fs::path version_file(const protocol::JobSpec& spec, long frame, std::uint64_t version) {
  const fs::path base = output_base(spec, frame);
  char v[32];
  std::snprintf(v, sizeof v, ".v%04llu.exr", static_cast<unsigned long long>(version));
  return base.parent_path() / "versions" / (base.filename().string() + v);
}

std::vector<std::uint64_t> add_version(std::vector<std::uint64_t>& list, std::uint64_t version,
                                       int history) {
  std::erase(list, version);
  list.push_back(version);
  std::vector<std::uint64_t> dropped;
  const std::size_t keep = static_cast<std::size_t>(std::max(0, history)) + 1;
  while (list.size() > keep) {
    dropped.push_back(list.front());
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

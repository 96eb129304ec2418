#include "daemon/frame_history.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <fstream>
#include <map>
#include <stdexcept>
#include <string>

namespace proden::daemon {

void FrameHistory::append(const std::filesystem::path& file, const nlohmann::json& entry) {
  const std::string line = entry.dump() + "\n";
  const int fd = ::open(file.c_str(), O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (fd < 0) throw std::runtime_error(file.string() + ": " + std::strerror(errno));
  const ssize_t n = ::write(fd, line.data(), line.size());
  const int err = errno;
  ::close(fd);
  if (n != static_cast<ssize_t>(line.size())) {
    throw std::runtime_error(file.string() + ": short write: " + std::strerror(err));
  }
}

nlohmann::json FrameHistory::load(const std::filesystem::path& file) {
  std::map<std::uint64_t, nlohmann::json> by_version;
  std::ifstream in(file);
  std::string line;
  while (std::getline(in, line)) {
    try {
      auto j = nlohmann::json::parse(line);
      const auto version = j.at("version").get<std::uint64_t>();  // before j is moved from
      by_version[version] = std::move(j);
    } catch (const std::exception&) {  // a torn last line (crash mid-append): skip it
    }
  }
  nlohmann::json out = nlohmann::json::array();
  for (auto& [v, j] : by_version) out.push_back(std::move(j));
  return out;
}

}  // namespace proden::daemon

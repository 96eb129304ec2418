#include "proden/io/image_writer.hpp"

#include <OpenImageIO/imageio.h>
#include <fcntl.h>
#include <unistd.h>

#include <filesystem>
#include <stdexcept>

namespace proden::io {
namespace {

namespace fs = std::filesystem;

void fsync_path(const std::string& path, int flags) {
  const int fd = ::open(path.c_str(), flags);
  if (fd < 0) return;  // best effort (e.g. directories on some file systems)
  ::fsync(fd);
  ::close(fd);
}

}  // namespace

void add_layer(std::vector<NamedChannel>& out, const std::string& prefix, const Image& image,
               std::string_view suffixes) {
  if (static_cast<int>(suffixes.size()) < image.channels()) {
    throw std::invalid_argument("add_layer " + prefix + ": not enough channel suffixes");
  }
  for (int c = 0; c < image.channels(); ++c) {
    out.push_back({prefix + suffixes[static_cast<std::size_t>(c)], image.plane(c)});
  }
}

void write_image(const std::string& path, int width, int height,
                 std::span<const NamedChannel> channels, const WriteOptions& options) {
  const std::size_t n = static_cast<std::size_t>(width) * height;
  if (channels.empty() || n == 0) throw std::runtime_error(path + ": nothing to write");
  for (const auto& ch : channels) {
    if (ch.data.size() != n) {
      throw std::runtime_error(path + ": channel " + ch.name + " has " +
                               std::to_string(ch.data.size()) + " values, expected " +
                               std::to_string(n));
    }
  }
  const fs::path target(path);
  const fs::path dir = target.has_parent_path() ? target.parent_path() : fs::path(".");
  // Same directory (same file system) so rename is atomic; keep the extension for OIIO.
  std::string tmp_name = ".";
  tmp_name += target.stem().string();
  tmp_name += ".tmp";
  tmp_name += std::to_string(::getpid());
  tmp_name += target.extension().string();
  const fs::path tmp = dir / tmp_name;

  auto out = OIIO::ImageOutput::create(tmp.string());
  if (!out) throw std::runtime_error(path + ": cannot create writer: " + OIIO::geterror());
  const int nch = static_cast<int>(channels.size());
  OIIO::ImageSpec spec(width, height, nch,
                       options.half ? OIIO::TypeDesc::HALF : OIIO::TypeDesc::FLOAT);
  spec.channelnames.clear();
  for (const auto& ch : channels) spec.channelnames.push_back(ch.name);
  spec.alpha_channel = -1;
  spec.attribute("compression", options.compression);
  for (const auto& [k, v] : options.attributes) spec.attribute(k, v);

  std::vector<float> interleaved(n * static_cast<std::size_t>(nch));
  for (std::size_t c = 0; c < channels.size(); ++c) {
    const auto d = channels[c].data;
    for (std::size_t p = 0; p < n; ++p) interleaved[p * channels.size() + c] = d[p];
  }
  bool ok =
      out->open(tmp.string(), spec) && out->write_image(OIIO::TypeDesc::FLOAT, interleaved.data());
  std::string err = ok ? "" : out->geterror();
  ok = out->close() && ok;
  if (!ok) {
    std::error_code ec;
    fs::remove(tmp, ec);
    throw std::runtime_error(path + ": write failed: " + (err.empty() ? out->geterror() : err));
  }
  fsync_path(tmp.string(), O_RDONLY);
  std::error_code ec;
  fs::rename(tmp, target, ec);
  if (ec) {
    const std::string why = ec.message();
    fs::remove(tmp, ec);
    throw std::runtime_error(path + ": cannot move into place: " + why);
  }
  fsync_path(dir.string(), O_RDONLY | O_DIRECTORY);
}

void add_aovs(std::vector<NamedChannel>& out, const std::vector<AovChannel>& aovs) {
  for (const auto& a : aovs) out.push_back({a.name, a.plane.data()});
}

}  // namespace proden::io

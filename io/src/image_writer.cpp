#include "proden/io/image_writer.hpp"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <tbb/parallel_for.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <random>
#include <stdexcept>

#include "strips.hpp"

namespace proden::io {
namespace {

namespace fs = std::filesystem;

// OIIO writes through this into a descriptor proden created (never opening a path itself).
class FdWriter final : public OIIO::Filesystem::IOProxy {
 public:
  explicit FdWriter(int fd) : IOProxy("", IOProxy::Write), fd_(fd) {}
  const char* proxytype() const override { return "proden-fd"; }
  bool seek(int64_t offset) override {
    if (offset < 0) return false;
    m_pos = offset;
    return true;
  }
  size_t write(const void* buf, size_t size) override {
    const size_t n = pwrite(buf, size, m_pos);
    m_pos += static_cast<int64_t>(n);
    return n;
  }
  size_t pwrite(const void* buf, size_t size, int64_t offset) override {
    std::size_t done = 0;
    const auto* p = static_cast<const char*>(buf);
    while (done < size) {
      const ssize_t n = ::pwrite(fd_, p + done, size - done,
                                 static_cast<off_t>(offset) + static_cast<off_t>(done));
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        failed_ = errno != 0 ? errno : EIO;
        break;
      }
      done += static_cast<std::size_t>(n);
    }
    return done;
  }
  size_t size() const override {
    struct stat st {};
    return ::fstat(fd_, &st) == 0 ? static_cast<size_t>(st.st_size) : 0;
  }
  int failed() const { return failed_; }

 private:
  int fd_;
  int failed_ = 0;
};

std::string temp_name(const std::string& name) {
  static thread_local std::mt19937_64 rng(std::random_device{}());
  const fs::path target(name);
  // Hidden, unique, and with the target's extension (OIIO picks the format by it).
  return "." + target.stem().string() + ".tmp" + std::to_string(::getpid()) + "." +
         std::to_string(rng() & 0xffffffffu) + target.extension().string();
}

thread_local OutputDirectory* t_bound = nullptr;

// A single entry of the directory (what the *at() calls take), never a path.
void check_file_name(const std::string& name, const std::string& display) {
  if (name.empty() || name.find('/') != std::string::npos || name == "." || name == "..") {
    throw std::runtime_error(display + ": not a file name");
  }
}

}  // namespace

OutputDirectory::OutputDirectory(std::string dir, int dir_fd)
    : dir_(fs::path(std::move(dir)).lexically_normal().string()), fd_(dir_fd), outer_(t_bound) {
  while (dir_.size() > 1 && dir_.back() == '/') dir_.pop_back();
  t_bound = this;
}

OutputDirectory::~OutputDirectory() {
  t_bound = outer_;
}

void add_layer(std::vector<NamedChannel>& out, const std::string& prefix, const Image& image,
               std::string_view suffixes) {
  if (static_cast<int>(suffixes.size()) < image.channels()) {
    throw std::invalid_argument("add_layer " + prefix + ": not enough channel suffixes");
  }
  for (int c = 0; c < image.channels(); ++c) {
    out.push_back({prefix + suffixes[static_cast<std::size_t>(c)], image.plane(c)});
  }
}

void write_image_at(int dir_fd, const std::string& name, int width, int height,
                    std::span<const NamedChannel> channels, const WriteOptions& options,
                    const std::string& display_name) {
  const std::string& display = display_name.empty() ? name : display_name;
  check_file_name(name, display);
  const std::size_t n = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  if (channels.empty() || n == 0) throw std::runtime_error(display + ": nothing to write");
  for (const auto& ch : channels) {
    if (ch.data.size() != n) {
      throw std::runtime_error(display + ": channel " + ch.name + " has " +
                               std::to_string(ch.data.size()) + " values, expected " +
                               std::to_string(n));
    }
  }
  const std::string tmp = temp_name(name);
  const int fd =
      ::openat(dir_fd, tmp.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
  if (fd < 0) {
    throw std::runtime_error(display + ": cannot create a temp file: " + std::strerror(errno));
  }
  auto discard = [&](const std::string& why) {
    ::close(fd);
    ::unlinkat(dir_fd, tmp.c_str(), 0);
    throw std::runtime_error(display + ": " + why);
  };
  FdWriter proxy(fd);
  auto out = OIIO::ImageOutput::create(tmp, &proxy);
  if (!out) discard("cannot create writer: " + OIIO::geterror());
  const int nch = static_cast<int>(channels.size());
  OIIO::ImageSpec spec(width, height, nch,
                       options.half ? OIIO::TypeDesc::HALF : OIIO::TypeDesc::FLOAT);
  spec.channelnames.clear();
  for (const auto& ch : channels) spec.channelnames.push_back(ch.name);
  spec.alpha_channel = -1;
  spec.attribute("compression", options.compression);
  for (const auto& [k, v] : options.attributes) spec.attribute(k, v);

  // Planes to OIIO's interleaved pixels a strip of rows at a time, rows in parallel, each strip
  // then encoded (OpenEXR compresses its chunks on its own threads). A published 1080p frame is 27
  // planes, 224 MB: interleaved whole, it was a fresh mapping above glibc's 32 MiB mmap ceiling
  // that the kernel faulted in and zeroed on every write; a strip stays in the reused heap
  // (bench/RESULTS.md, "Reading and writing in strips").
  const std::size_t stride = channels.size(), w = static_cast<std::size_t>(width);
  const std::uint64_t row_bytes = static_cast<std::uint64_t>(w) * stride * sizeof(float);
  const int rows =
      strip_rows(options.strip_bytes, row_bytes, chunk_rows(options.compression), height);
  std::vector<float> strip;
  strip.resize(static_cast<std::size_t>(rows) * w * stride);
  bool ok = out->set_ioproxy(&proxy) && out->open(tmp, spec);
  for (int y0 = 0; ok && y0 < height; y0 += rows) {
    const int y1 = std::min(y0 + rows, height);
    tbb::parallel_for(y0, y1, [&](int y) {
      const std::size_t first = static_cast<std::size_t>(y) * w;
      float* px = strip.data() + static_cast<std::size_t>(y - y0) * w * stride;
      for (std::size_t p = 0; p < w; ++p, px += stride) {
        for (std::size_t c = 0; c < stride; ++c) px[c] = channels[c].data[first + p];
      }
    });
    ok = out->write_scanlines(y0, y1, 0, OIIO::TypeDesc::FLOAT, strip.data());
  }
  std::string err = ok ? "" : out->geterror();
  ok = out->close() && ok && proxy.failed() == 0;
  if (!ok) {
    if (err.empty()) err = out->geterror();
    if (err.empty() && proxy.failed()) err = std::strerror(proxy.failed());
    discard("write failed: " + err);
  }
  out.reset();
  if (::fsync(fd) != 0) discard(std::string("fsync failed: ") + std::strerror(errno));
  ::close(fd);
  if (::renameat(dir_fd, tmp.c_str(), dir_fd, name.c_str()) != 0) {
    const std::string why = std::strerror(errno);
    ::unlinkat(dir_fd, tmp.c_str(), 0);
    throw std::runtime_error(display + ": cannot move into place: " + why);
  }
  ::fsync(dir_fd);  // the new directory entry is durable before we report the file written
}

void write_image(const std::string& path, int width, int height,
                 std::span<const NamedChannel> channels, const WriteOptions& options) {
  const fs::path target(path);
  const fs::path dir = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::string key = dir.lexically_normal().string();
  while (key.size() > 1 && key.back() == '/') key.pop_back();
  for (const OutputDirectory* b = t_bound; b; b = b->outer_) {
    if (b->dir_ == key) {
      write_image_at(b->fd_, target.filename().string(), width, height, channels, options, path);
      return;
    }
  }
  const int dir_fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (dir_fd < 0) {
    throw std::runtime_error(path + ": cannot open its directory: " + std::strerror(errno));
  }
  try {
    write_image_at(dir_fd, target.filename().string(), width, height, channels, options, path);
  } catch (...) {
    ::close(dir_fd);
    throw;
  }
  ::close(dir_fd);
}

void add_aovs(std::vector<NamedChannel>& out, const std::vector<AovChannel>& aovs) {
  for (const auto& a : aovs) out.push_back({a.name, a.plane.data()});
}

bool compress_image_at(int dir_fd, const std::string& name, const std::string& compression,
                       const std::string& display_name) {
  const std::string& display = display_name.empty() ? name : display_name;
  check_file_name(name, display);
  const int fd = ::openat(dir_fd, name.c_str(), O_RDONLY | O_NOFOLLOW | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) throw std::runtime_error(display + ": cannot open: " + std::strerror(errno));
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) {
    throw std::runtime_error(display + ": not a regular file");
  }
  // The descriptor just opened, by its /proc name: nothing is looked up by path again.
  auto in = OIIO::ImageInput::create("openexr");
  OIIO::ImageSpec spec;
  if (!in || !in->open("/proc/self/fd/" + std::to_string(fd), spec)) return false;  // not EXR
  const OIIO::TypeDesc type = spec.format;
  const bool one_type = spec.channelformats.empty() &&
                        (type == OIIO::TypeDesc::FLOAT || type == OIIO::TypeDesc::HALF);
  const bool plain = spec.tile_width == 0 && !spec.deep && spec.depth == 1 && spec.x == 0 &&
                     spec.y == 0 && spec.z == 0 && spec.full_x == 0 && spec.full_y == 0 &&
                     spec.full_width == spec.width && spec.full_height == spec.height &&
                     spec.width > 0 && spec.height > 0 && spec.nchannels > 0;
  const std::uint64_t pixel_bytes = static_cast<std::uint64_t>(spec.width) *
                                    static_cast<std::uint64_t>(spec.height) *
                                    static_cast<std::uint64_t>(spec.nchannels) * type.size();
  if (spec.get_string_attribute("compression") != "none" || !one_type || !plain ||
      in->seek_subimage(1, 0) || pixel_bytes > static_cast<std::uint64_t>(st.st_size)) {
    return false;
  }
  if (!in->seek_subimage(0, 0)) throw std::runtime_error(display + ": " + in->geterror());
  WriteOptions options;
  options.half = type == OIIO::TypeDesc::HALF;
  options.compression = compression;
  for (const OIIO::ParamValue& p : spec.extra_attribs) {
    const std::string key = p.name().string();
    if (p.type() != OIIO::TypeDesc::STRING || key == "compression" || key.starts_with("oiio:") ||
        key.starts_with("openexr:")) {
      continue;
    }
    options.attributes.emplace_back(key, p.get_string());
  }
  // Planes from strips of interleaved rows (the file's own chunks: 1 row each, uncompressed).
  const std::size_t w = static_cast<std::size_t>(spec.width), n = w * spec.height;
  const std::size_t nch = static_cast<std::size_t>(spec.nchannels);
  std::vector<float> planes(n * nch);
  const int rows = std::max(1, static_cast<int>(options.strip_bytes / (w * nch * sizeof(float))));
  std::vector<float> strip(static_cast<std::size_t>(std::min(rows, spec.height)) * w * nch);
  for (int y0 = 0; y0 < spec.height; y0 += rows) {
    const int y1 = std::min(y0 + rows, spec.height);
    if (!in->read_scanlines(0, 0, y0, y1, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT,
                            strip.data())) {
      throw std::runtime_error(display + ": read failed: " + in->geterror());
    }
    tbb::parallel_for(y0, y1, [&](int y) {
      const float* px = strip.data() + static_cast<std::size_t>(y - y0) * w * nch;
      const std::size_t first = static_cast<std::size_t>(y) * w;
      for (std::size_t p = 0; p < w; ++p, px += nch) {
        for (std::size_t c = 0; c < nch; ++c) planes[c * n + first + p] = px[c];
      }
    });
  }
  in->close();
  std::vector<NamedChannel> channels;
  for (std::size_t c = 0; c < nch; ++c) {
    channels.push_back({spec.channelnames[c], std::span<const float>(planes).subspan(c * n, n)});
  }
  write_image_at(dir_fd, name, spec.width, spec.height, channels, options, display);
  return true;
}

}  // namespace proden::io

#include "proden/io/pass_reader.hpp"

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <sstream>
#include <system_error>

#include "exr_chunks.hpp"
#include "fail.hpp"
#include "proden/error.hpp"
#include "proden/io/text.hpp"
#include "strips.hpp"

namespace proden::io {
namespace {

using detail::fail;

struct ChannelRef {
  int subimage = 0;
  int index = 0;
};

struct Header {
  std::string format;
  int width = 0, height = 0, subimages = 0;
  std::vector<std::string> channels;
  std::map<std::string, ChannelRef> where;
  std::vector<std::string> attribute_values;
  std::map<std::string, std::string> attributes;  // name -> value as string
  std::vector<OIIO::TypeDesc> channel_types;
  // Per subimage: its first scanline's y, and its scanlines per chunk (0: tiled, read whole).
  std::vector<int> part_y;
  std::vector<int> part_chunk_rows;
};

std::string oiio_error(OIIO::ImageInput* in) {
  std::string e = in ? in->geterror() : OIIO::geterror();
  if (e.empty()) e = OIIO::geterror();
  while (!e.empty() && (e.back() == '\n' || e.back() == ' ')) e.pop_back();
  return e.empty() ? "unknown read error" : e;
}

// OIIO reads through this, so it never opens a file by name: the bytes come from the source the
// caller opened (a buffer, or a descriptor opened inside the allowed roots).
class SourceProxy final : public OIIO::Filesystem::IOProxy {
 public:
  explicit SourceProxy(const ByteSource& source) : IOProxy("", IOProxy::Read), src_(source) {}
  const char* proxytype() const override { return "proden"; }
  bool seek(int64_t offset) override {
    if (offset < 0) return false;
    m_pos = offset;
    return true;
  }
  size_t read(void* buf, size_t size) override {
    const size_t n = pread(buf, size, m_pos);
    m_pos += static_cast<int64_t>(n);
    return n;
  }
  size_t pread(void* buf, size_t size, int64_t offset) override {
    if (offset < 0) return 0;
    return src_.read(static_cast<std::uint64_t>(offset), buf, size);
  }
  size_t size() const override { return static_cast<size_t>(src_.size()); }

 private:
  const ByteSource& src_;
};

// A descriptor this file opened (path-based reads of the CLI).
class OwnedFd {
 public:
  explicit OwnedFd(int fd) : fd_(fd) {}
  ~OwnedFd() {
    if (fd_ >= 0) ::close(fd_);
  }
  OwnedFd(const OwnedFd&) = delete;
  OwnedFd& operator=(const OwnedFd&) = delete;
  int get() const { return fd_; }

 private:
  int fd_;
};

// Opens `path` for reading as a pass: a regular file (never blocks on a FIFO or a device).
std::pair<std::unique_ptr<OwnedFd>, std::uint64_t> open_regular(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOCTTY | O_NONBLOCK);
  if (fd < 0) {
    const int e = errno;
    fail(InputErrorKind::unreadable, path,
         e == ENOENT ? std::string("no such file")
                     : "cannot open: " + std::string(std::strerror(e)));
  }
  auto owned = std::make_unique<OwnedFd>(fd);
  struct stat st {};
  if (::fstat(fd, &st) != 0) fail(InputErrorKind::unreadable, path, "cannot stat");
  if (!S_ISREG(st.st_mode)) fail(InputErrorKind::unreadable, path, "not a regular file");
  return {std::move(owned), static_cast<std::uint64_t>(st.st_size)};
}

// The header inspected and bounded, then opened by OIIO through the proxy.
struct Opened {
  HeaderSummary summary;
  std::unique_ptr<SourceProxy> proxy;  // outlives `in`
  std::unique_ptr<OIIO::ImageInput> in;
};

Opened open_source(const ByteSource& src, const std::string& name, const ReadOptions& o) {
  Opened op;
  op.summary = inspect_header(src, name, o.limits);
  const FileFormat format = op.summary.format;
  if (!accepts(o.renderer, format)) {
    fail(InputErrorKind::unsupported_format, name,
         "a " + std::string(format == FileFormat::exr ? "OpenEXR" : "Radiance HDR") +
             " file; the " + std::string(to_string(o.renderer)) + " profile reads OpenEXR only");
  }
  const HeaderPart& first = op.summary.parts.front();
  if (!first.windows_equal) {
    fail(InputErrorKind::unsupported_format, name,
         "data window differs from display window (crop/border renders are not supported)");
  }
  if (o.frame_size &&
      (first.width != o.frame_size->first || first.height != o.frame_size->second)) {
    fail(InputErrorKind::size_mismatch, name,
         std::to_string(first.width) + "x" + std::to_string(first.height) +
             " differs from the frame's " + std::to_string(o.frame_size->first) + "x" +
             std::to_string(o.frame_size->second));
  }
  op.proxy = std::make_unique<SourceProxy>(src);
  // The decoder is the one the magic bytes named, never one guessed from a file name.
  op.in = OIIO::ImageInput::create(to_string(format), false, nullptr, op.proxy.get());
  if (!op.in) fail(InputErrorKind::unreadable, name, "no decoder: " + oiio_error(nullptr));
  OIIO::ImageSpec config;
  OIIO::Filesystem::IOProxy* ptr = op.proxy.get();
  config.attribute("oiio:ioproxy", OIIO::TypeDesc::PTR, &ptr);
  OIIO::ImageSpec spec;
  // The name given to OIIO is not a path: with the proxy it opens nothing itself.
  if (!op.in->open("<proden pass>", spec, config)) {
    fail(InputErrorKind::unreadable, name, "not a readable image: " + oiio_error(op.in.get()));
  }
  return op;
}

Header read_header(OIIO::ImageInput& in, const HeaderSummary& summary, const std::string& path,
                   const ReadLimits& limits) {
  Header h;
  h.format = in.format_name();
  for (int s = 0; in.seek_subimage(s, 0); ++s) {
    const OIIO::ImageSpec& spec = in.spec();
    h.part_y.push_back(spec.y);
    h.part_chunk_rows.push_back(
        spec.tile_width > 0 ? 0 : chunk_rows(spec.get_string_attribute("compression")));
    // The decoder must agree with the bounded header walk.
    if (s >= static_cast<int>(summary.parts.size()) ||
        static_cast<std::uint64_t>(std::max(spec.width, 0)) *
                static_cast<std::uint64_t>(std::max(spec.height, 0)) >
            limits.max_pixels ||
        spec.nchannels > limits.max_channels) {
      fail(InputErrorKind::unreadable, path, "the decoder sees a different header");
    }
    if (s == 0) {
      h.width = spec.width;
      h.height = spec.height;
      if (spec.width != summary.parts[0].width || spec.height != summary.parts[0].height) {
        fail(InputErrorKind::unreadable, path, "the decoder sees a different image size");
      }
      if (spec.x != spec.full_x || spec.y != spec.full_y || spec.width != spec.full_width ||
          spec.height != spec.full_height) {
        fail(InputErrorKind::unsupported_format, path,
             "data window differs from display window (crop/border renders are not supported)");
      }
      for (const auto& a : spec.extra_attribs) {
        const std::string v = a.get_string(1 << 20);
        h.attribute_values.push_back(v);
        h.attributes[a.name().string()] = v;
      }
    } else if (spec.width != h.width || spec.height != h.height) {
      continue;  // parts of other sizes (previews) are not ours
    }
    if (spec.depth > 1) fail(InputErrorKind::unreadable, path, "volume images are not passes");
    for (int c = 0; c < spec.nchannels; ++c) {
      const std::string& name = spec.channelnames[static_cast<std::size_t>(c)];
      if (h.where.count(name)) continue;
      h.where[name] = {s, c};
      h.channels.push_back(name);
      h.channel_types.push_back(spec.channelformat(c));
    }
    h.subimages = s + 1;
  }
  if (h.width <= 0 || h.height <= 0) fail(InputErrorKind::unreadable, path, "image has no pixels");
  return h;
}

// First alternative whose channels all exist, or empty.
std::vector<std::string> pick(const Header& h, const std::vector<std::vector<std::string>>& alts) {
  for (const auto& set : alts) {
    bool all = true;
    for (const auto& n : set) all = all && h.where.count(n) > 0;
    if (all) return set;
  }
  return {};
}

double parse_number(const std::string& s) {
  double v = 0.0;
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), v);
  if (ec != std::errc() || ptr == s.data()) return -1.0;
  return v;
}

// Blender writes render time as "MM:SS.ss" or "HH:MM:SS.ss".
std::optional<double> parse_duration(const std::string& s) {
  if (s.empty()) return std::nullopt;
  double total = 0.0;
  std::stringstream ss(s);
  std::string part;
  while (std::getline(ss, part, ':')) {
    const double v = parse_number(part);
    if (v < 0.0) return std::nullopt;
    total = total * 60.0 + v;
  }
  return total;
}

struct Resolved {
  ChannelMap map;
  std::vector<std::string> colour, albedo, normal, depth, variance;
  std::vector<AovSource> aovs;
};

Resolved resolve(const Header& h, const std::string& path, const ReadOptions& options,
                 PassInfo& info) {
  std::vector<std::string> attribute_names;
  for (const auto& [k, v] : h.attributes) attribute_names.push_back(k);
  auto map = detect_profile(h.channels, h.attribute_values, options.renderer, attribute_names,
                            options.view_layer);
  if (!options.view_layer.empty()) {  // a chosen Cycles view layer must be there
    const auto any =
        detect_profile(h.channels, h.attribute_values, options.renderer, attribute_names);
    if (any && any->renderer == Renderer::cycles &&
        std::find(any->layers.begin(), any->layers.end(), options.view_layer) ==
            any->layers.end()) {
      std::string have;
      for (const auto& l : any->layers) have += (have.empty() ? "" : ", ") + l;
      fail(InputErrorKind::missing_channels, path,
           "no view layer '" + options.view_layer +
               "' (the file has: " + (have.empty() ? "none" : have) + ")");
    }
  }
  if (!map) {
    std::string found;
    for (const auto& c : h.channels) found += (found.empty() ? "" : ", ") + c;
    fail(InputErrorKind::missing_channels, path,
         "no colour channels (expected R,G,B or <ViewLayer>.Combined.{R,G,B} for profile " +
             std::string(to_string(options.renderer)) + "); found: " + found);
  }
  Resolved r{*map, pick(h, map->colour), {}, {}, {}, {}, aov_sources(*map, h.channels)};
  if (options.features) {
    r.albedo = pick(h, map->albedo);
    r.normal = pick(h, map->normal);
    r.depth = pick(h, map->depth);
  }
  if (options.variance) r.variance = pick(h, map->variance);

  info.path = printable(path);
  info.format = h.format;
  info.renderer = map->renderer;
  info.layer = printable(map->layer);
  for (const auto& l : map->layers) info.layers.push_back(printable(l));
  info.aovs.clear();
  for (const auto& a : r.aovs) info.aovs.push_back(printable(a.name));
  {
    const std::vector<std::pair<std::string, std::string>> attrs(h.attributes.begin(),
                                                                 h.attributes.end());
    info.aov_attributes = aov_attributes(*map, attrs, r.aovs);
  }
  info.width = h.width;
  info.height = h.height;
  info.subimages = h.subimages;
  info.channels.clear();
  for (const auto& c : h.channels) info.channels.push_back(printable(c));
  {
    const auto it = std::find(h.channels.begin(), h.channels.end(), r.colour[0]);
    info.pixel_type = h.channel_types[static_cast<std::size_t>(it - h.channels.begin())].c_str();
  }
  info.layout = {!r.albedo.empty(), !r.normal.empty(), !r.depth.empty(), !r.variance.empty()};

  info.spp_source = SppSource::assumed;
  info.spp = 1.0;
  if (const auto it = h.attributes.find(map->spp_attribute);
      !map->spp_attribute.empty() && it != h.attributes.end()) {
    const double spp = parse_number(it->second);
    if (!valid_spp(spp)) {
      fail(InputErrorKind::invalid_value, path,
           "header attribute " + map->spp_attribute + " = '" + it->second.substr(0, 64) +
               "' is not a sample count in (0, " + std::to_string(kMaxSpp) + "]");
    }
    info.spp = spp;
    info.spp_source = SppSource::header;
  } else if (options.spp) {
    if (!valid_spp(*options.spp)) {
      fail(InputErrorKind::invalid_value, path,
           "--spp must be a sample count in (0, " + std::to_string(kMaxSpp) + "]");
    }
    info.spp = *options.spp;
    info.spp_source = SppSource::option;
  }
  if (const auto it = h.attributes.find(map->render_time_attribute);
      !map->render_time_attribute.empty() && it != h.attributes.end()) {
    info.render_time = parse_duration(it->second);
  }
  return r;
}

}  // namespace

bool valid_spp(double spp) {
  return std::isfinite(spp) && spp > 0.0 && spp <= kMaxSpp;
}

std::string_view to_string(SppSource s) {
  switch (s) {
    case SppSource::header:
      return "header";
    case SppSource::option:
      return "option";
    case SppSource::assumed:
      return "assumed";
  }
  return "?";
}

std::string PassInfo::to_string() const {
  std::ostringstream o;
  o << path << ": " << io::to_string(renderer) << " " << format << " " << width << "x" << height
    << " " << pixel_type << ", " << layout.to_string() << ", spp " << spp << " ("
    << io::to_string(spp_source) << ")";
  return o.str();
}

namespace {

// The file's bytes and header walk, for the chunk decoder (none: OpenImageIO decodes).
struct ChunkSource {
  const ByteSource* src = nullptr;
  const HeaderSummary* summary = nullptr;
};

// Reads the named channels (all present in `h`) as planar images, one per requested set. Channels
// are read as runs of neighbouring channel indices of a subimage (OIIO converts half to float),
// one run at a time. A scanline run is decoded in strips of about ReadOptions::strip_bytes (a tiled
// one whole), so the peak is the output planes plus one strip. The strip stays below glibc's mmap
// ceiling (32 MiB), so the daemon's heap reuses it: a whole 1080p run (100 MB for a 12-channel
// Cycles pass) was a fresh mapping that the kernel faulted in and zeroed on every read
// (bench/RESULTS.md, "Reading and writing in strips").
//
// A file the chunk decoder reads (exr_chunks.hpp; `chunks`, when ReadOptions::exr_decoder allows
// it) is decoded by it instead, each chunk once for all sets, straight into the planes.
class ChannelLoader {
 public:
  static constexpr int kMergeGap = 32;
  ChannelLoader(OIIO::ImageInput& in, const Header& h, const std::string& path,
                std::vector<std::vector<std::string>> sets, std::uint64_t strip_bytes,
                ChunkSource chunks = {})
      : in_(in),
        h_(h),
        path_(path),
        sets_(std::move(sets)),
        strip_bytes_(strip_bytes),
        chunks_(chunks) {
    std::map<int, std::set<int>> used;
    for (const auto& set : sets_) {
      for (const auto& n : set) {
        const ChannelRef ref = h_.where.at(n);
        used[ref.subimage].insert(ref.index);
      }
    }
    for (const auto& [s, idx] : used) {
      for (int i : idx) {
        // A chunk holds all of its part's channels, compressed together: every run that reads
        // it decodes it whole again. Channels up to kMergeGap apart share a run, converting the
        // few unused ones between them rather than decoding every chunk twice (a 1080p
        // published frame's 7 error layers, around its mixvariance: 3.5 s as two runs, 1.9-2.2 s
        // as one; bench/RESULTS.md, "Renditions read in strips").
        if (!runs_.empty() && runs_.back().subimage == s && i - runs_.back().end <= kMergeGap) {
          runs_.back().end = i + 1;
        } else {
          runs_.push_back({s, i, i + 1});
        }
      }
    }
  }

  // Estimated peak bytes of load(): `resident` (the file, when in memory) + planes + the largest
  // buffer a run decodes into.
  std::uint64_t peak_bytes(std::uint64_t resident) const {
    const std::uint64_t px = pixels();
    std::uint64_t planes = 0, run = 0;
    for (const auto& set : sets_) planes += px * set.size() * sizeof(float);
    for (const auto& r : runs_) {
      run = std::max(run, static_cast<std::uint64_t>(rows_per_read(r)) *
                              static_cast<std::uint64_t>(h_.width) * row_floats(r) * sizeof(float));
    }
    if (chunk_channels()) {  // each decoding thread's scratch instead
      run = detail::chunk_scratch_bytes(chunks_.summary->parts.front()) *
            static_cast<std::uint64_t>(tbb::this_task_arena::max_concurrency());
    }
    return resident + planes + run;
  }

  std::vector<Image> load() {
    std::vector<Image> out;
    for (const auto& set : sets_) {
      out.push_back(set.empty() ? Image()
                                : Image(h_.width, h_.height, static_cast<int>(set.size())));
    }
    if (chunk_targets(out)) return out;
    std::vector<float> buf;
    for (const auto& r : runs_) {
      const int rows = rows_per_read(r);
      buf.resize(static_cast<std::size_t>(rows) * static_cast<std::size_t>(h_.width) *
                 row_floats(r));
      const bool whole = rows == h_.height;
      const int top = h_.part_y[static_cast<std::size_t>(r.subimage)];
      for (int y0 = 0; y0 < h_.height; y0 += rows) {
        const int y1 = std::min(y0 + rows, h_.height);
        const bool ok =
            whole ? in_.read_image(r.subimage, 0, r.begin, r.end, OIIO::TypeDesc::FLOAT, buf.data())
                  : in_.read_scanlines(r.subimage, 0, top + y0, top + y1, 0, r.begin, r.end,
                                       OIIO::TypeDesc::FLOAT, buf.data());
        if (!ok) {
          fail(InputErrorKind::unreadable, path_,
               "truncated or corrupt pixel data: " + oiio_error(&in_));
        }
        scatter(r, buf, y0, y1, out);
      }
    }
    return out;
  }

 private:
  struct Run {
    int subimage, begin, end;  // channels [begin, end)
  };
  // Decodes with the chunk decoder when it reads the file; false (nothing written) otherwise.
  bool chunk_targets(std::vector<Image>& out) const {
    const auto index = chunk_channels();
    if (!index) return false;
    std::vector<detail::ChunkTarget> targets;
    std::size_t i = 0;
    for (std::size_t k = 0; k < sets_.size(); ++k) {
      for (std::size_t c = 0; c < sets_[k].size(); ++c) {
        targets.push_back({(*index)[i++], out[k].plane(static_cast<int>(c)).data()});
      }
    }
    detail::decode_chunks(*chunks_.src, chunks_.summary->parts.front(), path_, targets);
    return true;
  }
  // When the chunk decoder reads this file and knows every wanted channel by name: each wanted
  // channel's index in the part's channel list, sets in order.
  std::optional<std::vector<int>> chunk_channels() const {
    if (!chunks_.src || !chunks_.summary || !detail::chunk_decodes(*chunks_.summary)) return {};
    const HeaderPart& part = chunks_.summary->parts.front();
    if (part.width != h_.width || part.height != h_.height || h_.subimages != 1) return {};
    std::vector<int> index;
    for (const auto& set : sets_) {
      for (const auto& n : set) {
        const auto it = std::find(part.channels.begin(), part.channels.end(), n);
        if (it == part.channels.end()) return {};
        index.push_back(static_cast<int>(it - part.channels.begin()));
      }
    }
    return index;
  }
  std::uint64_t pixels() const {
    return static_cast<std::uint64_t>(h_.width) * static_cast<std::uint64_t>(h_.height);
  }
  static std::size_t row_floats(const Run& r) { return static_cast<std::size_t>(r.end - r.begin); }
  // Scanlines one read of run `r` decodes: the whole image when tiled, else a strip of whole
  // chunks of about strip_bytes_ (io/src/strips.hpp).
  int rows_per_read(const Run& r) const {
    const int chunk = h_.part_chunk_rows[static_cast<std::size_t>(r.subimage)];
    if (chunk == 0) return h_.height;
    return strip_rows(strip_bytes_,
                      static_cast<std::uint64_t>(h_.width) * row_floats(r) * sizeof(float), chunk,
                      h_.height);
  }
  // Rows [y0, y1) of the run's interleaved buffer into the output planes, rows in parallel.
  void scatter(const Run& r, const std::vector<float>& buf, int y0, int y1,
               std::vector<Image>& out) const {
    const std::size_t n = row_floats(r), w = static_cast<std::size_t>(h_.width);
    for (std::size_t k = 0; k < sets_.size(); ++k) {
      for (std::size_t c = 0; c < sets_[k].size(); ++c) {
        const ChannelRef ref = h_.where.at(sets_[k][c]);
        if (ref.subimage != r.subimage || ref.index < r.begin || ref.index >= r.end) continue;
        const auto off = static_cast<std::size_t>(ref.index - r.begin);
        float* const plane = out[k].plane(static_cast<int>(c)).data();
        tbb::parallel_for(y0, y1, [&](int y) {
          const float* src = buf.data() + static_cast<std::size_t>(y - y0) * w * n + off;
          float* dst = plane + static_cast<std::size_t>(y) * w;
          for (std::size_t p = 0; p < w; ++p) dst[p] = src[p * n];
        });
      }
    }
  }
  OIIO::ImageInput& in_;
  const Header& h_;
  const std::string& path_;
  std::vector<std::vector<std::string>> sets_;
  std::vector<Run> runs_;
  std::uint64_t strip_bytes_;
  ChunkSource chunks_;
};

void check_budget(std::uint64_t need, const std::string& path, const ReadLimits& limits) {
  if (need > limits.max_memory_bytes) {
    fail(InputErrorKind::too_large, path,
         "reading it needs about " + std::to_string(need >> 20) + " MiB, above the per-read " +
             "budget of " + std::to_string(limits.max_memory_bytes >> 20) + " MiB");
  }
}

// What the chunk decoder needs, when the options let it decode.
ChunkSource chunk_route(const ByteSource& src, const Opened& op, const ReadOptions& o) {
  if (o.exr_decoder != ExrDecoder::automatic) return {};
  return {&src, &op.summary};
}

// Opens, walks and resolves `src`; the loader is planned and its budget checked.
struct Prepared {
  Opened op;
  Header h;
  PassInfo info;
  Resolved r;
};

// The channel sets a read loads: colour, albedo, normal, depth, variance, then (with `aovs`) one
// set per renderer AOV.
std::vector<std::vector<std::string>> channel_sets(const Resolved& r, bool aovs) {
  std::vector<std::vector<std::string>> sets = {r.colour, r.albedo, r.normal, r.depth, r.variance};
  if (aovs) {
    for (const auto& a : r.aovs) sets.push_back({a.channel});
  }
  return sets;
}

Prepared prepare(const ByteSource& src, const std::string& name, const ReadOptions& options,
                 bool aovs = false) {
  Prepared p{open_source(src, name, options), {}, {}, {}};
  p.h = read_header(*p.op.in, p.op.summary, name, options.limits);
  p.r = resolve(p.h, name, options, p.info);
  ChannelLoader plan(*p.op.in, p.h, name, channel_sets(p.r, aovs), options.strip_bytes,
                     chunk_route(src, p.op, options));
  // Counted as if the file were in memory: callers reading through a descriptor use less.
  p.info.read_bytes = plan.peak_bytes(src.size());
  check_budget(p.info.read_bytes, name, options.limits);
  return p;
}

}  // namespace

std::size_t FdSource::read(std::uint64_t offset, void* buf, std::size_t n) const {
  std::size_t done = 0;
  auto* out = static_cast<char*>(buf);
  while (done < n && offset + done < size_) {
    const std::size_t want =
        static_cast<std::size_t>(std::min<std::uint64_t>(n - done, size_ - offset - done));
    const ssize_t got = ::pread(fd_, out + done, want, static_cast<off_t>(offset + done));
    if (got < 0 && errno == EINTR) continue;
    if (got <= 0) break;
    done += static_cast<std::size_t>(got);
  }
  return done;
}

PassInfo probe_pass(const ByteSource& source, const std::string& name, const ReadOptions& options) {
  return prepare(source, name, options).info;
}

PassInfo probe_pass(const std::string& path, const ReadOptions& options) {
  const auto [fd, size] = open_regular(path);
  return probe_pass(FdSource(fd->get(), size), path, options);
}

Pass read_pass(const ByteSource& source, const std::string& name, const ReadOptions& options,
               PassInfo* info_out, std::vector<AovChannel>* aovs) {
  Prepared p = prepare(source, name, options, aovs != nullptr);
  auto images = ChannelLoader(*p.op.in, p.h, name, channel_sets(p.r, aovs != nullptr),
                              options.strip_bytes, chunk_route(source, p.op, options))
                    .load();
  Pass pass;
  pass.colour = std::move(images[0]);
  pass.albedo = std::move(images[1]);
  pass.normal = std::move(images[2]);
  pass.depth = std::move(images[3]);
  pass.variance = std::move(images[4]);
  pass.spp = p.info.spp;
  if (aovs) {  // the renderer AOVs, one channel each, after the five sets above
    aovs->clear();
    for (std::size_t k = 0; k < p.r.aovs.size(); ++k) {
      aovs->push_back({p.r.aovs[k].name, std::move(images[5 + k])});
    }
  }
  p.op.in->close();
  if (info_out) *info_out = std::move(p.info);
  return pass;
}

Pass read_pass(const std::string& path, const ReadOptions& options, PassInfo* info_out,
               std::vector<AovChannel>* aovs) {
  const auto [fd, size] = open_regular(path);
  return read_pass(FdSource(fd->get(), size), path, options, info_out, aovs);
}

std::vector<Image> read_layers(const ByteSource& source, const std::string& name,
                               const std::vector<std::string>& layers, const ReadOptions& options) {
  Opened op = open_source(source, name, options);
  const Header h = read_header(*op.in, op.summary, name, options.limits);
  // Per layer, the channels its three planes come from: R, G, B, or a lone Y three times (the
  // loader decodes it once); none when absent.
  std::vector<std::vector<std::string>> sets;
  for (const std::string& layer : layers) {
    const std::string prefix = layer.empty() || layer == "result" ? "" : layer + ".";
    std::vector<std::string> rgb = {prefix + "R", prefix + "G", prefix + "B"};
    if (std::all_of(rgb.begin(), rgb.end(), [&](const auto& n) { return h.where.count(n); })) {
      sets.push_back(std::move(rgb));
    } else if (h.where.count(prefix + "Y")) {
      sets.push_back({prefix + "Y", prefix + "Y", prefix + "Y"});
    } else {
      sets.emplace_back();
    }
  }
  ChannelLoader loader(*op.in, h, name, sets, options.strip_bytes,
                       chunk_route(source, op, options));
  check_budget(loader.peak_bytes(source.size()), name, options.limits);
  return loader.load();
}

std::vector<Image> read_layers(const std::string& path, const std::vector<std::string>& layers,
                               const ReadOptions& options) {
  const auto [fd, size] = open_regular(path);
  return read_layers(FdSource(fd->get(), size), path, layers, options);
}

Image read_layer(const ByteSource& source, const std::string& name, const std::string& layer,
                 const ReadOptions& options) {
  ReadOptions o = options;
  o.features = false;
  o.variance = false;
  if (layer.empty() || layer == "result") return read_pass(source, name, o).colour;
  Image img = std::move(read_layers(source, name, {layer}, o).front());
  if (img.empty()) {
    fail(InputErrorKind::missing_channels, name,
         "no layer '" + layer + "' (channels " + layer + ".R, .G, .B or " + layer + ".Y)");
  }
  return img;
}

Image read_layer(const std::string& path, const std::string& layer, const ReadOptions& options) {
  const auto [fd, size] = open_regular(path);
  return read_layer(FdSource(fd->get(), size), path, layer, options);
}

Image read_rgb(const std::string& path, const ReadOptions& options) {
  return read_layer(path, "", options);
}

}  // namespace proden::io

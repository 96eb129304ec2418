#include "proden/io/image_header.hpp"

#include <algorithm>
#include <array>
#include <cstring>
#include <limits>
#include <map>

#include "fail.hpp"
#include "proden/error.hpp"
#include "proden/io/text.hpp"

namespace proden::io {
namespace {

constexpr std::array<std::uint8_t, 4> kExrMagic = {0x76, 0x2f, 0x31, 0x01};

using detail::fail;

bool starts_with(std::span<const std::uint8_t> head, std::string_view prefix) {
  return head.size() >= prefix.size() &&
         std::memcmp(head.data(), prefix.data(), prefix.size()) == 0;
}

// Reads a source through a window of cached bytes: the header walk asks for bytes one at a time.
class Cursor {
 public:
  Cursor(const ByteSource& src, const std::string& name) : src_(src), name_(name) {}
  std::uint64_t size() const { return src_.size(); }
  std::uint64_t pos = 0;

  bool at_end() const { return pos >= src_.size(); }
  std::uint64_t remaining() const { return pos >= src_.size() ? 0 : src_.size() - pos; }

  std::uint8_t peek() {
    const std::uint8_t b = byte();
    --pos;
    return b;
  }
  std::uint8_t byte() {
    if (pos >= src_.size()) truncated();
    if (pos < base_ || pos >= base_ + window_.size()) load(pos);
    return window_[static_cast<std::size_t>(pos++ - base_)];
  }
  std::uint32_t u32() {
    std::uint32_t v = 0;
    for (int i = 0; i < 4; ++i) v |= static_cast<std::uint32_t>(byte()) << (8 * i);
    return v;
  }
  std::int32_t i32() {
    const std::uint32_t u = u32();
    std::int32_t v;
    std::memcpy(&v, &u, sizeof v);
    return v;
  }
  // A NUL-terminated string of at most `max` bytes before the NUL.
  std::string cstring(std::size_t max, const char* what) {
    std::string s;
    for (;;) {
      const std::uint8_t c = byte();
      if (c == 0) return s;
      if (s.size() >= max) {
        fail(InputErrorKind::unreadable, name_,
             std::string("corrupt header: ") + what + " longer than " + std::to_string(max) +
                 " bytes");
      }
      s += static_cast<char>(c);
    }
  }
  [[noreturn]] void truncated() const {
    fail(InputErrorKind::unreadable, name_,
         "truncated header (file ends at byte " + std::to_string(src_.size()) + ")");
  }

 private:
  void load(std::uint64_t at) {
    const std::size_t n =
        static_cast<std::size_t>(std::min<std::uint64_t>(kWindow, src_.size() - at));
    window_.resize(n);
    const std::size_t got = src_.read(at, window_.data(), n);
    window_.resize(got);
    base_ = at;
    if (got == 0) truncated();
  }
  static constexpr std::uint64_t kWindow = 64 * 1024;
  const ByteSource& src_;
  const std::string& name_;
  std::vector<std::uint8_t> window_;
  std::uint64_t base_ = 0;
};

struct Box {
  std::int32_t xmin = 0, ymin = 0, xmax = -1, ymax = -1;
  bool operator==(const Box&) const = default;
};

// Width or height of [lo, hi], or -1 when empty or wider than an int.
std::int64_t extent(std::int32_t lo, std::int32_t hi) {
  const std::int64_t n = static_cast<std::int64_t>(hi) - lo + 1;
  return n >= 1 && n <= std::numeric_limits<int>::max() ? n : -1;
}

// Scanlines per chunk of each OpenEXR compression (NONE, RLE, ZIPS, ZIP, PIZ, PXR24, B44, B44A,
// DWAA, DWAB): OpenEXR file layout, "Scan Line Based Images".
constexpr std::array<int, 10> kLinesPerChunk = {1, 1, 1, 16, 32, 16, 32, 32, 32, 256};

void check_pixels(std::int64_t w, std::int64_t h, const std::string& name, const ReadLimits& lim,
                  const char* what) {
  const std::uint64_t pixels = static_cast<std::uint64_t>(w) * static_cast<std::uint64_t>(h);
  if (pixels > lim.max_pixels) {
    fail(InputErrorKind::too_large, name,
         std::string(what) + " declares " + std::to_string(w) + "x" + std::to_string(h) + " = " +
             std::to_string(pixels) + " pixels, above the limit of " +
             std::to_string(lim.max_pixels));
  }
}

// Bytes of a value of the OpenEXR attribute types with a fixed layout (OpenEXR "File Layout",
// predefined attribute types), or 0.
int fixed_value_size(const std::string& type) {
  static const std::map<std::string, int, std::less<>> kSizes = {{"box2i", 16},
                                                                 {"box2f", 16},
                                                                 {"chromaticities", 32},
                                                                 {"compression", 1},
                                                                 {"deepImageState", 1},
                                                                 {"double", 8},
                                                                 {"envmap", 1},
                                                                 {"float", 4},
                                                                 {"int", 4},
                                                                 {"keycode", 28},
                                                                 {"lineOrder", 1},
                                                                 {"m33f", 36},
                                                                 {"m33d", 72},
                                                                 {"m44f", 64},
                                                                 {"m44d", 128},
                                                                 {"rational", 8},
                                                                 {"tiledesc", 9},
                                                                 {"timecode", 8},
                                                                 {"v2i", 8},
                                                                 {"v2f", 8},
                                                                 {"v2d", 16},
                                                                 {"v3i", 12},
                                                                 {"v3f", 12},
                                                                 {"v3d", 24}};
  const auto it = kSizes.find(type);
  return it == kSizes.end() ? 0 : it->second;
}

// One part's chunks as its header declares them, for check_chunk_tables.
struct PartChunks {
  std::uint64_t count = 0;  // entries in the part's offset table
  bool tiled = false;
  std::int32_t ymin = 0;  // scanline parts: the data window's first line
  int lines = 1;          // scanline parts: lines per chunk
};

// Every chunk named by the offset tables (which start at `tables`) must start after them, inside
// the file, with the part number (multi-part files), the first scanline its index gives (scanline
// parts) and a data size between 1 byte and the rest of the file. OpenEXR's C++ library decodes a
// chunk read at a wrong offset as zeros without an error (fuzz/findings.md, row 8), and a pass of
// zeros accumulated would darken its frame for good; a half-written file (offsets still 0) is
// refused here the same way, as unreadable, and retried.
// The offsets of a single part go to `keep` when given.
void check_chunk_tables(const ByteSource& src, const std::string& name, std::uint64_t tables,
                        const std::vector<PartChunks>& parts, bool multipart,
                        std::vector<std::uint64_t>* keep) {
  if (keep) keep->reserve(static_cast<std::size_t>(parts.front().count));
  std::uint64_t total = 0;
  for (const PartChunks& p : parts) total += p.count;
  const std::uint64_t end = tables + 8 * total, size = src.size();
  // The tables are read in blocks of 8192 entries (the walk has checked they fit in the file).
  std::vector<std::uint8_t> block;
  std::uint64_t entry = 0, block_begin = 0;
  for (std::size_t k = 0; k < parts.size(); ++k) {
    const PartChunks& p = parts[k];
    for (std::uint64_t i = 0; i < p.count; ++i, ++entry) {
      if (entry == block_begin + block.size() / 8) {
        block_begin = entry;
        block.resize(static_cast<std::size_t>(8 * std::min<std::uint64_t>(total - entry, 8192)));
        if (src.read(tables + 8 * entry, block.data(), block.size()) != block.size()) {
          fail(InputErrorKind::unreadable, name, "truncated chunk offset table");
        }
      }
      const std::uint8_t* b = block.data() + 8 * (entry - block_begin);
      std::uint64_t offset = 0;
      for (int j = 7; j >= 0; --j) offset = (offset << 8) | b[j];
      // Part number (multi-part), then y (scanline) or 4 tile coordinates, then the data size.
      const std::uint64_t head = (multipart ? 4 : 0) + (p.tiled ? 16 : 4) + 4;
      std::uint8_t h[24];
      const auto word = [&h](std::uint64_t at) {
        std::int32_t v;
        std::memcpy(&v, h + at, 4);
        return v;  // little-endian on every machine proden builds for
      };
      bool ok = offset >= end && offset <= size && size - offset >= head &&
                src.read(offset, h, head) == head;
      if (ok && multipart) ok = word(0) == static_cast<std::int32_t>(k);
      if (ok && !p.tiled) {
        const std::int64_t y = static_cast<std::int64_t>(p.ymin) +
                               static_cast<std::int64_t>(i) * static_cast<std::int64_t>(p.lines);
        ok = word(multipart ? 4 : 0) == y;
      }
      if (ok) {
        const std::int32_t bytes = word(head - 4);
        ok = bytes > 0 && static_cast<std::uint64_t>(bytes) <= size - offset - head;
      }
      if (!ok) {
        fail(InputErrorKind::unreadable, name,
             "truncated or corrupt: chunk " + std::to_string(i) +
                 (parts.size() > 1 ? " of part " + std::to_string(k) : "") +
                 " is not where the offset table says (" + std::to_string(offset) + ")");
      }
      if (keep) keep->push_back(offset);
    }
  }
}

HeaderSummary inspect_exr(const ByteSource& src, const std::string& name, const ReadLimits& lim) {
  Cursor c(src, name);
  c.pos = 4;
  const std::uint32_t version = c.u32();
  // A wrong version or unknown flags after the magic number: a corrupt file (retried as
  // unreadable), not a format choice.
  if ((version & 0xFF) != 2) {
    fail(InputErrorKind::unreadable, name,
         "corrupt header: OpenEXR version " + std::to_string(version & 0xFF) + " (only 2 exists)");
  }
  constexpr std::uint32_t kTiled = 0x200, kLongNames = 0x400, kNonImage = 0x800,
                          kMultiPart = 0x1000;
  if (version & ~std::uint32_t{0xFF | kTiled | kLongNames | kNonImage | kMultiPart}) {
    fail(InputErrorKind::unreadable, name, "corrupt header: unknown OpenEXR version flags");
  }
  if (version & kNonImage) {
    fail(InputErrorKind::unsupported_format, name, "deep (non-image) OpenEXR data is not a pass");
  }
  const bool multipart = (version & kMultiPart) != 0;
  const std::size_t max_name = (version & kLongNames) ? 255 : 31;

  HeaderSummary out;
  out.format = FileFormat::exr;
  int channels_total = 0;
  std::uint64_t chunks_total = 0;
  std::vector<PartChunks> part_chunks;
  for (;;) {
    if (static_cast<int>(out.parts.size()) >= lim.max_parts) {
      fail(InputErrorKind::too_large, name,
           "more than " + std::to_string(lim.max_parts) + " parts in one file");
    }
    HeaderPart part;
    std::optional<Box> data, display;
    std::optional<int> compression;
    std::optional<std::pair<std::uint32_t, std::uint32_t>> tiles;
    std::optional<std::int32_t> chunk_count;
    bool tiled = (version & kTiled) != 0, have_channels = false, layout_attribute = false;
    for (int attributes = 0;; ++attributes) {
      if (c.peek() == 0) {  // end of this header
        ++c.pos;
        break;
      }
      const std::string attr = c.cstring(max_name, "attribute name");
      const std::string type = c.cstring(max_name, "attribute type");
      const std::int32_t size = c.i32();
      if (size < 0 || static_cast<std::uint64_t>(size) > lim.max_file_bytes) {
        fail(InputErrorKind::too_large, name,
             "header attribute '" + attr + "' declares " + std::to_string(size) + " bytes");
      }
      if (static_cast<std::uint64_t>(size) > c.remaining()) {
        fail(InputErrorKind::unreadable, name,
             "truncated or corrupt header: attribute '" + attr + "' declares " +
                 std::to_string(size) + " bytes, the file has " + std::to_string(c.remaining()) +
                 " left");
      }
      const std::uint64_t value_end = c.pos + static_cast<std::uint64_t>(size);
      auto expect_size = [&](std::int32_t n) {
        if (size != n) {
          fail(InputErrorKind::unreadable, name,
               "corrupt header: attribute '" + attr + "' of type " + type + " has " +
                   std::to_string(size) + " bytes, expected " + std::to_string(n));
        }
      };
      // OpenEXR reads a value of a type it knows by that type's own layout, not by the declared
      // size: a size that disagrees would make it read other bytes than this walk checked (and
      // allocate what they say). Held to the layout, both read the same header.
      if (const int fixed = fixed_value_size(type); fixed > 0) expect_size(fixed);
      if (type == "preview") {
        if (size < 8) expect_size(8);
        const std::uint64_t at = c.pos;
        const std::uint64_t pw = c.u32(), ph = c.u32();
        c.pos = at;
        const std::uint64_t room = (static_cast<std::uint64_t>(size) - 8) / 4;
        if ((pw != 0 && ph > room / pw) || pw * ph * 4 != static_cast<std::uint64_t>(size) - 8) {
          fail(InputErrorKind::unreadable, name,
               "corrupt header: preview image of " + std::to_string(pw) + "x" + std::to_string(ph) +
                   " pixels in an attribute of " + std::to_string(size) + " bytes");
        }
      }
      if (type == "chlist") {
        have_channels = have_channels || attr == "channels";
        for (;;) {
          if (c.pos >= value_end) {
            fail(InputErrorKind::unreadable, name, "corrupt header: unterminated channel list");
          }
          if (c.byte() == 0) {
            // OpenEXR reads channels up to this terminator, whatever the declared size says.
            if (c.pos != value_end) {
              fail(InputErrorKind::unreadable, name,
                   "corrupt header: channel list '" + attr + "' ends before its declared " +
                       std::to_string(size) + " bytes");
            }
            break;
          }
          --c.pos;
          std::string ch = c.cstring(255, "channel name");
          if (c.pos + 16 > value_end) {
            fail(InputErrorKind::unreadable, name, "corrupt header: channel list overruns");
          }
          const std::int32_t pixel_type = c.i32();
          c.pos += 4;  // pLinear + reserved
          const std::int32_t xs = c.i32(), ys = c.i32();
          if (pixel_type < 0 || pixel_type > 2) {
            fail(InputErrorKind::unsupported_format, name,
                 "channel '" + ch + "' has unknown pixel type " + std::to_string(pixel_type));
          }
          if (xs != 1 || ys != 1) {
            fail(InputErrorKind::unsupported_format, name,
                 "channel '" + ch + "' is subsampled (" + std::to_string(xs) + "x" +
                     std::to_string(ys) + "); passes are full-resolution");
          }
          if (++channels_total > lim.max_channels) {
            fail(InputErrorKind::too_large, name,
                 "more than " + std::to_string(lim.max_channels) + " channels");
          }
          if (attr == "channels") {
            part.channels.push_back(std::move(ch));
            part.pixel_types.push_back(pixel_type);
          }
        }
      } else if ((attr == "dataWindow" || attr == "displayWindow") && type == "box2i") {
        expect_size(16);
        Box b;
        b.xmin = c.i32();
        b.ymin = c.i32();
        b.xmax = c.i32();
        b.ymax = c.i32();
        (attr == "dataWindow" ? data : display) = b;
      } else if (attr == "compression" && type == "compression") {
        expect_size(1);
        compression = c.byte();
      }
      if (attr == "tiles" || attr == "type" || attr == "chunkCount") layout_attribute = true;
      if (attr == "tiles" && type == "tiledesc") {
        expect_size(9);
        const std::uint32_t tx = c.u32(), ty = c.u32();
        tiles = {tx, ty};
      } else if (attr == "type" && type == "string") {
        std::string t;
        for (std::int32_t i = 0; i < size && i < 32; ++i) t += static_cast<char>(c.byte());
        if (t.starts_with("deep")) {
          fail(InputErrorKind::unsupported_format, name, "deep OpenEXR data is not a pass");
        }
        if (t == "tiledimage") tiled = true;
      } else if (attr == "chunkCount" && type == "int") {
        expect_size(4);
        chunk_count = c.i32();
      }
      c.pos = value_end;
      if (attributes > 1'000'000) fail(InputErrorKind::unreadable, name, "corrupt header");
    }
    if (!have_channels || !data || !display || !compression) {
      fail(InputErrorKind::unreadable, name,
           "corrupt header: missing channels, dataWindow, displayWindow or compression");
    }
    if (*compression >= static_cast<int>(kLinesPerChunk.size())) {
      fail(InputErrorKind::unsupported_format, name,
           "unknown OpenEXR compression " + std::to_string(*compression));
    }
    const std::int64_t w = extent(data->xmin, data->xmax), h = extent(data->ymin, data->ymax);
    if (w < 0 || h < 0) fail(InputErrorKind::unreadable, name, "corrupt header: empty data window");
    check_pixels(w, h, name, lim, "the data window");
    if (extent(display->xmin, display->xmax) < 0 || extent(display->ymin, display->ymax) < 0) {
      fail(InputErrorKind::unreadable, name, "corrupt header: empty display window");
    }
    part.width = static_cast<int>(w);
    part.height = static_cast<int>(h);
    part.windows_equal = *data == *display;
    part.compression = *compression;
    part.ymin = data->ymin;
    part.plain_scanline = !multipart && !tiled && !layout_attribute;
    std::uint64_t chunks = 0;
    if (tiled) {
      if (!tiles || tiles->first == 0 || tiles->second == 0) {
        fail(InputErrorKind::unreadable, name, "corrupt header: tiled image without tile size");
      }
      if (static_cast<std::uint64_t>(tiles->first) * tiles->second >
          std::max<std::uint64_t>(lim.max_pixels, 1 << 16)) {
        fail(InputErrorKind::too_large, name,
             "tiles of " + std::to_string(tiles->first) + "x" + std::to_string(tiles->second) +
                 " pixels are above the limit");
      }
      // Level 0 alone: a lower bound on the chunks of mip/rip-mapped files.
      chunks = ((static_cast<std::uint64_t>(w) + tiles->first - 1) / tiles->first) *
               ((static_cast<std::uint64_t>(h) + tiles->second - 1) / tiles->second);
    } else {
      const auto lines = static_cast<std::uint64_t>(kLinesPerChunk[*compression]);
      chunks = (static_cast<std::uint64_t>(h) + lines - 1) / lines;
    }
    if (multipart) {
      if (!chunk_count || *chunk_count < 0 || static_cast<std::uint64_t>(*chunk_count) < chunks) {
        fail(InputErrorKind::unreadable, name, "corrupt header: bad chunkCount");
      }
      chunks = static_cast<std::uint64_t>(*chunk_count);
    }
    chunks_total += chunks;
    part_chunks.push_back({chunks, tiled, data->ymin, tiled ? 1 : kLinesPerChunk[*compression]});
    out.parts.push_back(std::move(part));
    if (!multipart) break;
    if (c.peek() == 0) {  // an empty header ends the list of parts
      ++c.pos;
      break;
    }
  }
  // Every chunk has an 8-byte offset-table entry and at least an 8-byte chunk header: a file too
  // short for them is truncated (and its tables are not worth allocating).
  if (chunks_total > c.remaining() / 16) {
    fail(InputErrorKind::unreadable, name,
         "truncated: " + std::to_string(chunks_total) + " chunks declared, the file has " +
             std::to_string(c.remaining()) + " bytes after the header");
  }
  out.header_bytes = c.pos + 8 * chunks_total;
  check_chunk_tables(src, name, c.pos, part_chunks, multipart,
                     out.parts.front().plain_scanline ? &out.parts.front().chunk_offsets : nullptr);
  return out;
}

// Radiance RGBE (Greg Ward's format as OIIO reads it): "#?RADIANCE" or "#?RGBE", header lines up
// to an empty line, then "-Y <height> +X <width>" (the only orientation OIIO reads).
HeaderSummary inspect_radiance(const ByteSource& src, const std::string& name,
                               const ReadLimits& lim) {
  constexpr std::size_t kMaxHeader = 64 * 1024;
  std::string text(static_cast<std::size_t>(std::min<std::uint64_t>(src.size(), kMaxHeader)), '\0');
  text.resize(src.read(0, text.data(), text.size()));
  std::size_t pos = 0;
  auto line = [&]() -> std::optional<std::string_view> {
    const std::size_t nl = text.find('\n', pos);
    if (nl == std::string::npos) return std::nullopt;
    std::string_view l(text.data() + pos, nl - pos);
    pos = nl + 1;
    if (!l.empty() && l.back() == '\r') l.remove_suffix(1);
    return l;
  };
  auto incomplete = [&] {
    fail(InputErrorKind::unreadable, name,
         "Radiance header truncated or longer than " + std::to_string(kMaxHeader) + " bytes");
  };
  if (!line()) incomplete();  // the "#?" line
  for (;;) {
    const auto l = line();
    if (!l) incomplete();
    if (l->empty()) break;
    if (l->starts_with("FORMAT=") && *l != "FORMAT=32-bit_rle_rgbe") {
      fail(InputErrorKind::unsupported_format, name,
           "Radiance " + std::string(*l) + " (only 32-bit_rle_rgbe is read)");
    }
  }
  const auto res = line();
  if (!res) incomplete();
  auto number = [&](std::string_view s) -> std::int64_t {
    if (s.empty() || s.size() > 9) return -1;
    std::int64_t v = 0;
    for (char ch : s) {
      if (ch < '0' || ch > '9') return -1;
      v = v * 10 + (ch - '0');
    }
    return v;
  };
  std::int64_t w = -1, h = -1;
  if (res->starts_with("-Y ")) {
    const std::string_view rest = res->substr(3);
    const std::size_t sp = rest.find(' ');
    if (sp != std::string_view::npos && rest.substr(sp + 1).starts_with("+X ")) {
      h = number(rest.substr(0, sp));
      w = number(rest.substr(sp + 4));
    }
  }
  if (w < 1 || h < 1) {
    fail(InputErrorKind::unsupported_format, name,
         "Radiance resolution line '" + std::string(res->substr(0, 64)) +
             "' (only '-Y <height> +X <width>' is read)");
  }
  check_pixels(w, h, name, lim, "the resolution line");
  // Smallest scanline: run-length encoded (8 <= width < 32768) it is a 4-byte marker and at
  // least one 2-byte run per 127 values of each of 4 components; otherwise 4 bytes per pixel.
  const auto uw = static_cast<std::uint64_t>(w);
  const std::uint64_t min_line =
      (uw >= 8 && uw < 32768) ? std::min(4 * uw, 4 + 8 * ((uw + 126) / 127)) : 4 * uw;
  const std::uint64_t left = src.size() - pos;
  if (min_line * static_cast<std::uint64_t>(h) > left) {
    fail(InputErrorKind::unreadable, name,
         "truncated: " + std::to_string(w) + "x" + std::to_string(h) + " pixels need at least " +
             std::to_string(min_line * static_cast<std::uint64_t>(h)) + " bytes, the file has " +
             std::to_string(left) + " after the header");
  }
  HeaderSummary out;
  out.format = FileFormat::radiance;
  HeaderPart part;
  part.width = static_cast<int>(w);
  part.height = static_cast<int>(h);
  part.channels = {"R", "G", "B"};
  out.parts.push_back(std::move(part));
  out.header_bytes = pos;
  return out;
}

}  // namespace

std::size_t MemorySource::read(std::uint64_t offset, void* buf, std::size_t n) const {
  if (offset >= bytes_.size()) return 0;
  const std::size_t k =
      static_cast<std::size_t>(std::min<std::uint64_t>(n, bytes_.size() - offset));
  std::memcpy(buf, bytes_.data() + offset, k);
  return k;
}

std::string_view to_string(FileFormat f) {
  return f == FileFormat::exr ? "openexr" : "hdr";
}

std::optional<FileFormat> sniff_format(std::span<const std::uint8_t> head) {
  if (head.size() >= 4 && std::equal(kExrMagic.begin(), kExrMagic.end(), head.begin())) {
    return FileFormat::exr;
  }
  for (std::string_view m : {"#?RADIANCE\n", "#?RADIANCE\r\n", "#?RGBE\n", "#?RGBE\r\n"}) {
    if (starts_with(head, m)) return FileFormat::radiance;
  }
  return std::nullopt;
}

std::string describe_magic(std::span<const std::uint8_t> head) {
  using namespace std::string_view_literals;
  struct Known {
    std::string_view magic, name;
  };
  static constexpr Known known[] = {
      {"\x89PNG\r\n\x1a\n"sv, "PNG"},
      {"\xff\xd8\xff"sv, "JPEG"},
      {"II*\0"sv, "TIFF"},
      {"MM\0*"sv, "TIFF"},
      {"GIF8"sv, "GIF"},
      {"BM"sv, "BMP"},
      {"SDPX"sv, "DPX"},
      {"XPDS"sv, "DPX"},
      {"PF\n"sv, "PFM"},
      {"Pf\n"sv, "PFM"},
      {"8BPS"sv, "Photoshop PSD"},
      {"\0\0\0\x0cjP  "sv, "JPEG 2000"},
      {"RIFF"sv, "RIFF (WebP?)"},
      {"#?"sv, "Radiance-like text with an unknown signature"},
  };
  for (const auto& k : known) {
    if (starts_with(head, k.magic)) return std::string(k.name);
  }
  static constexpr char hex[] = "0123456789abcdef";
  std::string s = "bytes";
  for (std::size_t i = 0; i < std::min<std::size_t>(head.size(), 8); ++i) {
    s += ' ';
    s += hex[head[i] >> 4];
    s += hex[head[i] & 0xF];
  }
  return head.empty() ? "an empty file" : s;
}

HeaderSummary inspect_header(const ByteSource& source, const std::string& name,
                             const ReadLimits& limits) {
  if (source.size() == 0) {
    fail(InputErrorKind::unreadable, name,
         "empty file (0 bytes): a render placeholder or a file still being written");
  }
  if (source.size() > limits.max_file_bytes) {
    fail(InputErrorKind::too_large, name,
         "file of " + std::to_string(source.size()) + " bytes is above the limit of " +
             std::to_string(limits.max_file_bytes));
  }
  std::array<std::uint8_t, 16> head{};
  const std::size_t n = source.read(0, head.data(), head.size());
  const std::span<const std::uint8_t> h(head.data(), n);
  const auto format = sniff_format(h);
  if (!format) {
    fail(InputErrorKind::unsupported_format, name,
         "not a readable image: neither OpenEXR nor Radiance HDR (it looks like " +
             describe_magic(h) + ")");
  }
  return *format == FileFormat::exr ? inspect_exr(source, name, limits)
                                    : inspect_radiance(source, name, limits);
}

}  // namespace proden::io

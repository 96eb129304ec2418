// What a pass file is, decided from its own bytes before any decoder runs: the format by its magic
// number (OpenEXR, Radiance HDR; nothing else is a pass), and the header walked with every size
// checked against the file's length and the read limits, so a few hundred hostile bytes cannot
// make a decoder allocate gigabytes (docs/api.md, "Limits").
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

namespace proden::io {

// The image formats a pass may be in. Which ones a renderer profile accepts: profile.hpp.
enum class FileFormat { exr, radiance };

// OIIO's format names: "openexr", "hdr".
std::string_view to_string(FileFormat f);

// The format named by the file's first bytes (EXR: 76 2f 31 01; Radiance: "#?RADIANCE" or
// "#?RGBE" and a newline), or nullopt.
std::optional<FileFormat> sniff_format(std::span<const std::uint8_t> head);

// A short human description of what the first bytes look like ("PNG", "TIFF", "bytes 00 11 ..."),
// for error messages about files that are not passes.
std::string describe_magic(std::span<const std::uint8_t> head);

// Bounds applied to one read, before anything is allocated from what the file declares.
// The defaults are the CLI's (generous); the daemon sets its own from its config (`input.*`).
struct ReadLimits {
  std::uint64_t max_file_bytes = std::uint64_t{4} << 30;    // the file itself
  std::uint64_t max_pixels = std::uint64_t{1} << 27;        // width * height of any part
  int max_channels = 1024;                                  // all parts together
  int max_parts = 64;                                       // EXR multi-part files
  std::uint64_t max_memory_bytes = std::uint64_t{8} << 30;  // estimated peak of one read
};

struct HeaderPart {
  int width = 0, height = 0;  // data window
  bool windows_equal = true;  // data window == display window
  std::vector<std::string> channels;
  // OpenEXR only: the compression's code (0 NONE, 1 RLE, 2 ZIPS, 3 ZIP, 4 PIZ, ... 9 DWAB), each
  // channel's pixel type (0 UINT, 1 HALF, 2 FLOAT; as `channels`), the data window's first line.
  int compression = 0;
  std::vector<int> pixel_types;
  int ymin = 0;
  // A single-part scanline EXR that declares no `tiles`, `type` or `chunkCount` (what Blender and
  // POV-Ray write): its chunks' offsets, each checked to name its chunk (io/exr_chunks.hpp).
  bool plain_scanline = false;
  std::vector<std::uint64_t> chunk_offsets;
};

struct HeaderSummary {
  FileFormat format = FileFormat::exr;
  std::vector<HeaderPart> parts;
  std::uint64_t header_bytes = 0;  // where the header (and, for EXR, the offset tables) end
};

// Random access to the bytes of a file (a memory buffer or a descriptor).
class ByteSource {
 public:
  virtual ~ByteSource() = default;
  virtual std::uint64_t size() const = 0;
  // Reads up to n bytes at `offset`; returns how many were read (fewer only at the end).
  virtual std::size_t read(std::uint64_t offset, void* buf, std::size_t n) const = 0;
};

class MemorySource final : public ByteSource {
 public:
  explicit MemorySource(std::span<const std::uint8_t> bytes) : bytes_(bytes) {}
  std::uint64_t size() const override { return bytes_.size(); }
  std::size_t read(std::uint64_t offset, void* buf, std::size_t n) const override;

 private:
  std::span<const std::uint8_t> bytes_;
};

// Identifies the format and walks the header of `source` (named `name` in errors) against
// `limits`. Throws proden::InputError: `unsupported_format` for anything but EXR/Radiance,
// `too_large` for a declared size above the limits, `unreadable` for a malformed or truncated
// header. Deep (non-image) EXR, subsampled channels and unknown pixel types are refused.
HeaderSummary inspect_header(const ByteSource& source, const std::string& name,
                             const ReadLimits& limits);

}  // namespace proden::io

// Writes named float channels to an image file (EXR multi-layer by dotted names, or any format
// OIIO writes), atomically: a new temp file in the target directory (O_EXCL|O_NOFOLLOW), written
// through its descriptor, fsync, rename, directory fsync. write_image_at works relative to a
// directory descriptor the caller holds, so the file lands in exactly that directory even if
// its path has been swapped for a symlink meanwhile (the daemon's output confinement).
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "proden/aov.hpp"
#include "proden/image.hpp"

namespace proden::io {

struct NamedChannel {
  std::string name;             // "R", "render.G", "ViewLayer.Combined.B", ...
  std::span<const float> data;  // width*height values
};

struct WriteOptions {
  bool half = false;  // store as 16-bit half (EXR) instead of 32-bit float
  std::string compression = "zip";
  std::vector<std::pair<std::string, std::string>> attributes;  // string header attributes
  // Scanlines are interleaved and handed to the encoder this many bytes at a time (a multiple of
  // 32 rows where it can be: whole compression chunks), so the write holds one strip, not a copy
  // of the image. Below glibc's 32 MiB mmap ceiling; 1080p with 27 channels gets 128 rows, four
  // PIZ chunks per call (24 MiB, three chunks, left one of two threads idle: bench/RESULTS.md).
  std::uint64_t strip_bytes = std::uint64_t{30} << 20;
};

// Throws std::runtime_error naming the path on failure; never leaves a partial file at `path`.
void write_image(const std::string& path, int width, int height,
                 std::span<const NamedChannel> channels, const WriteOptions& options = {});

// The same into the directory open at `dir_fd` (O_RDONLY|O_DIRECTORY), as the single file name
// `name` (the extension picks the format). Errors name `display` (defaults to `name`).
void write_image_at(int dir_fd, const std::string& name, int width, int height,
                    std::span<const NamedChannel> channels, const WriteOptions& options = {},
                    const std::string& display = {});

// Rewrites the uncompressed EXR `name` in the directory open at `dir_fd` with `compression`: the
// same channels, pixel type, size and string header fields, atomically (write_image_at). The
// daemon publishes a version uncompressed and compresses it once it is idle (docs/api.md,
// output.compression `auto`). Returns false and touches nothing when the file is not an
// uncompressed EXR of one pixel type (compressed already, or not proden's); since an uncompressed
// file holds every pixel byte, what it allocates is bounded by the file's size. Never follows a
// symlink at `name`. Throws std::runtime_error naming `display` on a read or write failure, the
// file left as it was.
bool compress_image_at(int dir_fd, const std::string& name, const std::string& compression,
                       const std::string& display = {});

// While alive, write_image() calls on this thread for files directly in `dir` go through the
// directory descriptor `dir_fd` (write_image_at) instead of opening `dir` by path: a caller that
// opened its output directory safely (the daemon, beneath an allowed root) binds it around code
// that writes by path. Bindings nest; the innermost one for a directory wins.
class OutputDirectory {
 public:
  OutputDirectory(std::string dir, int dir_fd);
  ~OutputDirectory();
  OutputDirectory(const OutputDirectory&) = delete;
  OutputDirectory& operator=(const OutputDirectory&) = delete;

 private:
  std::string dir_;
  int fd_;
  OutputDirectory* outer_;
  friend void write_image(const std::string&, int, int, std::span<const NamedChannel>,
                          const WriteOptions&);
};

// Appends `prefix + suffix[c]` channels for each plane of `image` ("render." + "R", ...).
void add_layer(std::vector<NamedChannel>& out, const std::string& prefix, const Image& image,
               std::string_view suffixes = "RGB");

// Appends renderer AOVs (AovAccumulator::result(); they must outlive `out`) under their own
// names ("A", "Depth.Z", "CryptoObject00.r", ...), beside the result (docs/api.md).
void add_aovs(std::vector<NamedChannel>& out, const std::vector<AovChannel>& aovs);

}  // namespace proden::io

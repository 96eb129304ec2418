// Reads one pass of a frame (OpenEXR single/multi-part or Radiance HDR, recognised by their magic
// bytes; nothing else) into planar buffers, through a renderer profile. The header is walked and
// bounded (image_header.hpp) before OpenImageIO decodes anything, and OIIO reads only through an
// IOProxy over bytes proden supplies (a memory buffer or an open descriptor), never by path.
// Bad files raise proden::InputError naming the file and the reason (as printable text);
// nothing is returned half-read.
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "proden/aov.hpp"
#include "proden/io/image_header.hpp"
#include "proden/io/profile.hpp"
#include "proden/pass.hpp"

namespace proden::io {

// Who decodes an OpenEXR file's pixels. `automatic`: proden's chunk decoder (libdeflate, for plain
// single-part scanline NONE/ZIPS/ZIP files with HALF and FLOAT channels: what Blender and POV-Ray
// write) where it applies, OpenImageIO (OpenEXR's C++ library) elsewhere. `library`: OpenImageIO
// for every file, the reference the tests and benchmarks compare against.
enum class ExrDecoder { automatic, library };

struct ReadOptions {
  Renderer renderer = Renderer::automatic;
  std::optional<double> spp;  // used when the file does not carry its sample count
  bool features = true;       // load albedo/normal/depth when present
  bool variance = true;       // load renderer variance when present
  std::string view_layer;     // Cycles view layer to read ("" = the alphabetically first)
  ReadLimits limits;          // bounds checked before decoding (CLI defaults: generous)
  // The frame's size when it is known (its first pass, or the job's declaration): a pass of any
  // other size is refused from its header, before its pixels are decoded.
  std::optional<std::pair<int, int>> frame_size;
  // Scanline files are decoded this many bytes of interleaved channels at a time (whole when
  // tiled): a read's peak memory is its output planes plus one strip.
  std::uint64_t strip_bytes = std::uint64_t{16} << 20;
  ExrDecoder exr_decoder = ExrDecoder::automatic;
};

enum class SppSource { header, option, assumed };

// Samples per pixel of one pass: a finite positive count up to kMaxSpp (2^32: far above any
// render, and sums of many passes stay exact in double). A job's `spp` is held to the same bound.
inline constexpr double kMaxSpp = 4294967296.0;
bool valid_spp(double spp);
std::string_view to_string(SppSource s);

// What was detected in a pass file. Every string is printable text (io::printable): channel
// names and attribute values come from the file and may hold any bytes.
struct PassInfo {
  std::string path;
  std::string format;  // OIIO format name: "openexr" or "hdr"
  Renderer renderer = Renderer::generic;
  std::string layer;                // Blender view layer read, if any
  std::vector<std::string> layers;  // every Cycles view layer in the file, sorted
  int width = 0;
  int height = 0;
  int subimages = 1;
  std::vector<std::string> channels;  // all channel names in the file
  std::string pixel_type;             // of the colour channels: "half", "float", ...
  double spp = 1.0;
  SppSource spp_source = SppSource::assumed;
  Layout layout;                      // which features were found (and loaded)
  std::optional<double> render_time;  // seconds, if the header says
  std::vector<std::string> aovs;      // renderer AOVs as they would be written (aov_sources)
  std::vector<std::pair<std::string, std::string>> aov_attributes;  // e.g. Cryptomatte's
  std::uint64_t read_bytes = 0;  // estimated peak memory of reading the pass
  std::string to_string() const;
};

// A ByteSource over an open descriptor of a regular file (pread; the caller keeps ownership).
class FdSource final : public ByteSource {
 public:
  FdSource(int fd, std::uint64_t size) : fd_(fd), size_(size) {}
  std::uint64_t size() const override { return size_; }
  std::size_t read(std::uint64_t offset, void* buf, std::size_t n) const override;

 private:
  int fd_;
  std::uint64_t size_;
};

// Header-only inspection (does not decode pixels; checks the read would fit the limits).
PassInfo probe_pass(const std::string& path, const ReadOptions& options = {});
PassInfo probe_pass(const ByteSource& source, const std::string& name,
                    const ReadOptions& options = {});

// Reads and validates the whole file. `name` names the source in errors and in PassInfo::path.
// With `aovs`, also its renderer AOVs (PassInfo::aovs).
Pass read_pass(const std::string& path, const ReadOptions& options = {}, PassInfo* info = nullptr,
               std::vector<AovChannel>* aovs = nullptr);
Pass read_pass(const ByteSource& source, const std::string& name, const ReadOptions& options = {},
               PassInfo* info = nullptr, std::vector<AovChannel>* aovs = nullptr);

// Reads the RGB colour of any image proden reads or writes (passes, references, outputs).
Image read_rgb(const std::string& path, const ReadOptions& options = {});

// Reads the RGB channels "<layer>.{R,G,B}" (e.g. proden's "render", "denoised" AOVs), or a lone
// "<layer>.Y" as three equal planes; "" or "result" reads the image's own colour as read_rgb()
// does. A missing layer is an InputError (missing_channels).
Image read_layer(const std::string& path, const std::string& layer,
                 const ReadOptions& options = {});
Image read_layer(const ByteSource& source, const std::string& name, const std::string& layer,
                 const ReadOptions& options = {});

// Several layers of one image, each as read_layer() reads it ("" or "result" here: the channels
// R, G, B or a lone Y themselves, as proden's outputs name them), decoding only their channels, a
// strip at a time: the daemon's renditions of a published frame (docs/api.md). A layer the image
// lacks comes back as an empty Image.
std::vector<Image> read_layers(const std::string& path, const std::vector<std::string>& layers,
                               const ReadOptions& options = {});
std::vector<Image> read_layers(const ByteSource& source, const std::string& name,
                               const std::vector<std::string>& layers,
                               const ReadOptions& options = {});

}  // namespace proden::io

// Fuzz target: a pass file's bytes read exactly as the daemon reads a pass (daemon/pass_source.cpp:
// io::read_pass over an io::MemorySource, OIIO decoding through proden's IOProxy), EXR and
// Radiance HDR. The read limits are the daemon's kind, set small here (1 Mpixel, 64 MiB per read)
// so that `make fuzz` runs with -malloc_limit_mb=256 -rss_limit_mb=1024: any allocation a few
// hostile bytes can force past the header checks is a finding (issue 11, class 4).
//
// Properties: only proden::InputError leaves the reader (io::read_pass, and io::read_layers as
// the daemon's renditions read a published frame), its message is JSON-safe text; a pass
// that is accepted has the header's size within the limits, a finite spp in (0, 2^32], planes of
// the right shape, and every string in its PassInfo JSON-safe. A pass accepted by the default
// route (proden's chunk decoder where it applies) and by OpenImageIO alone
// (ReadOptions::exr_decoder `library`) has the same values in both, bit for bit (NaN as NaN).
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <span>
#include <vector>

#include "fuzz_check.hpp"
#include "proden/error.hpp"
#include "proden/io/pass_reader.hpp"

using namespace proden;

namespace {

io::ReadOptions options(std::uint8_t selector) {
  io::ReadOptions o;
  // The renderer a job names (auto, cycles, povray, generic), picked from the input's length so
  // the file's own bytes stay a real file.
  constexpr io::Renderer kRenderers[] = {io::Renderer::automatic, io::Renderer::cycles,
                                         io::Renderer::povray, io::Renderer::generic};
  o.renderer = kRenderers[selector % 4];
  if (selector & 4) o.spp = 16.0;
  o.limits.max_file_bytes = 1 << 20;
  o.limits.max_pixels = 1 << 20;
  o.limits.max_channels = 256;
  o.limits.max_parts = 16;
  o.limits.max_memory_bytes = 64 << 20;
  return o;
}

void check_same(const Image& a, const Image& b) {
  FUZZ_CHECK(a.same_size(b) && a.channels() == b.channels());
  const auto x = a.data(), y = b.data();
  for (std::size_t i = 0; i < x.size(); ++i) {
    FUZZ_CHECK(std::memcmp(&x[i], &y[i], sizeof(float)) == 0 ||
               (std::isnan(x[i]) && std::isnan(y[i])));
  }
}

void check_plane(const Image& img, const io::PassInfo& info, int channels) {
  if (img.empty()) return;
  FUZZ_CHECK(img.width() == info.width && img.height() == info.height);
  FUZZ_CHECK(img.channels() == channels);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const io::ReadOptions o = options(static_cast<std::uint8_t>(size));
  io::PassInfo info;
  try {
    const Pass pass = io::read_pass(io::MemorySource(std::span<const std::uint8_t>(data, size)),
                                    "fuzz", o, &info);
    FUZZ_CHECK(info.width > 0 && info.height > 0);
    FUZZ_CHECK(static_cast<std::uint64_t>(info.width) * static_cast<std::uint64_t>(info.height) <=
               o.limits.max_pixels);
    FUZZ_CHECK(info.read_bytes <= o.limits.max_memory_bytes);
    FUZZ_CHECK(std::isfinite(pass.spp) && pass.spp > 0.0 && pass.spp <= 4294967296.0);
    FUZZ_CHECK(pass.spp == info.spp);
    FUZZ_CHECK(!pass.colour.empty());
    check_plane(pass.colour, info, 3);
    check_plane(pass.albedo, info, 3);
    check_plane(pass.normal, info, 3);
    check_plane(pass.depth, info, 1);
    check_plane(pass.variance, info, 3);
    fuzz::check_json_safe(info.format);
    fuzz::check_json_safe(info.layer);
    fuzz::check_json_safe(info.pixel_type);
    for (const auto& c : info.channels) fuzz::check_json_safe(c);
    fuzz::check_json_safe(info.to_string());
    // The same bytes through OpenImageIO alone: the header is read the same way by both, so only
    // the pixels' decoding differs, and OpenImageIO refusing pixels the chunk decoder took would
    // be corruption the chunk decoder missed (a finding, like any difference in the values).
    io::ReadOptions library = o;
    library.exr_decoder = io::ExrDecoder::library;
    bool refused = false;
    try {
      const Pass ref = io::read_pass(io::MemorySource(std::span<const std::uint8_t>(data, size)),
                                     "fuzz", library);
      check_same(pass.colour, ref.colour);
      check_same(pass.albedo, ref.albedo);
      check_same(pass.normal, ref.normal);
      check_same(pass.depth, ref.depth);
      check_same(pass.variance, ref.variance);
    } catch (const InputError&) {
      refused = true;
    }
    FUZZ_CHECK(!refused);
  } catch (const InputError& e) {
    fuzz::check_json_safe(e.what());
    fuzz::check_json_safe(e.reason());
  }
  // Half of the inputs (by length) are also read as the daemon reads a published frame's layers
  // for a rendition (io::read_layers): the same walk, fewer channels, a lone Y widened.
  if (size & 8) {
    try {
      const std::vector<Image> layers =
          io::read_layers(io::MemorySource(std::span<const std::uint8_t>(data, size)), "fuzz",
                          {"result", "render", "variance", "alpha"}, o);
      FUZZ_CHECK(layers.size() == 4);
      for (const Image& l : layers) {
        FUZZ_CHECK(l.empty() || l.channels() == 3);
        FUZZ_CHECK(l.empty() || l.same_size(layers[0]) || layers[0].empty());
        FUZZ_CHECK(l.pixels() <= o.limits.max_pixels);
      }
    } catch (const InputError& e) {
      fuzz::check_json_safe(e.what());
    }
  }
  // Anything else (std::bad_alloc, std::length_error, an OIIO exception) escapes and is a finding.
  return 0;
}

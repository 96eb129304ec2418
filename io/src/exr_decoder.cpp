#include "exr_decoder.hpp"

#include <mutex>

#include "proden/io/pass_reader.hpp"

namespace proden::io {

bool core_decodes(int exr_compression) {
  // NONE, RLE, ZIPS, ZIP: the same floats as the C++ library, 1.4-2x less CPU (bench/RESULTS.md,
  // "Decoding passes with OpenEXR Core"). Debian 12's Core library (3.1.5) reads PIZ slower, B44
  // into other values and DWAA not at all, so PXR24 and up stay with the C++ library.
  return exr_compression >= 0 && exr_compression <= 3;
}

bool core_decodes(const HeaderSummary& header) {
  return header.format == FileFormat::exr && header.parts.size() == 1 &&
         header.parts.front().plain_scanline && core_decodes(header.parts.front().compression);
}

namespace detail {

std::unique_ptr<OIIO::ImageInput> create_exr_input(bool core, OIIO::Filesystem::IOProxy* proxy) {
  static std::mutex mutex;
  const std::lock_guard lock(mutex);
  OIIO::attribute("openexr:core", core ? 1 : 0);
  auto in = OIIO::ImageInput::create("openexr", false, nullptr, proxy);
  OIIO::attribute("openexr:core", 0);
  return in;
}

}  // namespace detail
}  // namespace proden::io

// How many scanlines one strip of a read or a write holds (io/pass_reader.cpp,
// io/image_writer.cpp): about a byte budget, in whole compression chunks, so no chunk is decoded
// twice or handed to the encoder in pieces.
#pragma once

#include <algorithm>
#include <cstdint>
#include <string_view>

namespace proden::io {

// Scanlines per chunk of an OpenEXR scanline file with this compression (OIIO's name, optionally
// with ":quality"), per the OpenEXR file layout; 1 for anything else (Radiance HDR, unknown).
inline int chunk_rows(std::string_view compression) {
  const std::string_view c = compression.substr(0, compression.find(':'));
  if (c == "zip" || c == "pxr24") return 16;
  if (c == "piz" || c == "b44" || c == "b44a" || c == "dwaa") return 32;
  if (c == "dwab") return 256;
  return 1;  // none, rle, zips, and formats without chunks
}

// Rows per strip: as many whole chunks as fit in `strip_bytes` (at least one chunk), a multiple
// of 32 rows where that fits too (every lossless chunk height divides it), at most `height`.
inline int strip_rows(std::uint64_t strip_bytes, std::uint64_t row_bytes, int chunk, int height) {
  const std::uint64_t fit = strip_bytes / std::max<std::uint64_t>(row_bytes, 1);
  const std::uint64_t unit = fit >= 32 && 32 % chunk == 0 ? 32 : static_cast<std::uint64_t>(chunk);
  const std::uint64_t rows = std::max(fit - fit % unit, unit);
  return static_cast<int>(std::min<std::uint64_t>(rows, static_cast<std::uint64_t>(height)));
}

}  // namespace proden::io

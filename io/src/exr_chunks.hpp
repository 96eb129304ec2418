// Decodes the pixels of a plain single-part scanline OpenEXR file compressed with NONE, ZIPS or
// ZIP (what Blender and POV-Ray write) straight from its chunks: libdeflate inflates each chunk
// (the inflater OpenEXR itself adopted in 3.2; 2.2x zlib's speed on Cycles passes), ZIP's byte
// predictor and interleave are undone as the OpenEXR file layout specifies, and each wanted
// channel's line is copied into its plane. The same floats as OpenEXR 3.1's C++ library, whose
// conversion of every float by an out-of-line per-byte call was most of a pass read
// (bench/RESULTS.md, "Decoding ZIP chunks with zlib", "Inflating with libdeflate"). The header, the
// offset table and every chunk header were checked by the header walk (image_header.hpp); each
// chunk is checked again here against the bytes it must inflate to.
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "proden/io/image_header.hpp"

namespace proden::io::detail {

// Whether the chunk decoder reads this file: OpenEXR, one plain scanline part (HeaderPart::
// plain_scanline) compressed with NONE, ZIPS or ZIP, channels HALF or FLOAT only, listed in
// strictly increasing order (the order OpenEXR lays them out in a line).
bool chunk_decodes(const HeaderSummary& header);

// The memory one thread decoding the part's chunks holds: a chunk as stored, inflated and
// reordered (each at most the chunk's lines of every channel, wanted or not).
std::uint64_t chunk_scratch_bytes(const HeaderPart& part);

// One wanted channel: its index in HeaderPart::channels, and the plane (width * height floats,
// row-major, the data window's rows) it is written to.
struct ChunkTarget {
  int channel = 0;
  float* plane = nullptr;
};

// Undoes ZIP's two steps on `n` inflated bytes `t` (OpenEXR's file layout, "ZIP compression"):
// each byte was stored as the difference from the one before plus 128 (t is summed in place),
// and the bytes were split into the even-indexed ones followed by the odd-indexed ones (`out`,
// n bytes, gets them back in order). SSE2 where the build has it, the same bytes as the scalar
// loops it ends with.
void undo_zip_predictor(unsigned char* t, std::size_t n, unsigned char* out);

// Decodes every chunk of the file's part into `targets` (a channel may appear more than once),
// chunks in parallel. Throws proden::InputError (unreadable, naming `name`) for a chunk that is
// truncated, does not name its lines, or does not inflate to exactly its lines' bytes.
void decode_chunks(const ByteSource& src, const HeaderPart& part, const std::string& name,
                   std::span<const ChunkTarget> targets);

}  // namespace proden::io::detail

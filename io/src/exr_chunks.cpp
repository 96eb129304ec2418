#include "exr_chunks.hpp"

#include <Imath/half.h>
#include <libdeflate.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <memory>
#include <stdexcept>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include "fail.hpp"

namespace proden::io::detail {
namespace {

static_assert(std::endian::native == std::endian::little,
              "OpenEXR stores little-endian values: the decoder copies them as they are");

constexpr int kNone = 0, kZips = 2, kZip = 3;  // OpenEXR's compression codes
constexpr int kHalf = 1, kFloat = 2;           // and pixel types

int lines_per_chunk(int compression) {
  return compression == kZip ? 16 : 1;
}

// Where each channel starts in a line, and the line's bytes (the last entry).
std::vector<std::size_t> line_layout(const HeaderPart& part) {
  std::vector<std::size_t> at{0};
  for (const int t : part.pixel_types) {
    at.push_back(at.back() + static_cast<std::size_t>(part.width) * (t == kHalf ? 2 : 4));
  }
  return at;
}

struct FreeDecompressor {
  void operator()(libdeflate_decompressor* d) const { libdeflate_free_decompressor(d); }
};

// The scratch of one thread: a chunk as stored, inflated, and reordered, and its decompressor.
struct Scratch {
  std::vector<unsigned char> packed, inflated, bytes;
  std::unique_ptr<libdeflate_decompressor, FreeDecompressor> inflater;
};

const char* inflate_error(libdeflate_result r) {
  switch (r) {
    case LIBDEFLATE_SHORT_OUTPUT:
      return "inflates to fewer bytes than its lines hold";
    case LIBDEFLATE_INSUFFICIENT_SPACE:
      return "inflates to more bytes than its lines hold";
    default:
      return "does not inflate (not a valid zlib stream, or its checksum differs)";
  }
}

}  // namespace

void undo_zip_predictor(unsigned char* t, std::size_t n, unsigned char* out) {
  // The running sum t[i] = t[i-1] + t[i] - 128 (mod 256) from i = 1.
  std::size_t i = 1;
#ifdef __SSE2__
  // 16 bytes at a time: the block's own prefix sum in four shifted adds, plus the byte before
  // the block broadcast to every lane.
  const __m128i bias = _mm_set1_epi8(static_cast<char>(0x80));
  __m128i carry = _mm_set1_epi8(static_cast<char>(n > 0 ? t[0] : 0));
  for (; i + 16 <= n; i += 16) {
    auto* p = reinterpret_cast<__m128i*>(t + i);
    __m128i v = _mm_sub_epi8(_mm_loadu_si128(p), bias);
    v = _mm_add_epi8(v, _mm_slli_si128(v, 1));
    v = _mm_add_epi8(v, _mm_slli_si128(v, 2));
    v = _mm_add_epi8(v, _mm_slli_si128(v, 4));
    v = _mm_add_epi8(v, _mm_slli_si128(v, 8));
    v = _mm_add_epi8(v, carry);
    _mm_storeu_si128(p, v);
    const __m128i hi = _mm_unpackhi_epi8(v, v);  // 8 8 9 9 .. 15 15
    carry = _mm_shuffle_epi32(_mm_unpackhi_epi16(hi, hi), _MM_SHUFFLE(3, 3, 3, 3));  // 15 x16
  }
#endif
  for (; i < n; ++i) t[i] = static_cast<unsigned char>(t[i - 1] + t[i] - 128);
  // The even-indexed bytes were stored first, then the odd-indexed ones.
  const unsigned char* a = t;
  const unsigned char* b = t + (n + 1) / 2;
  std::size_t k = 0;
#ifdef __SSE2__
  for (; k + 32 <= n; k += 32) {
    const __m128i x = _mm_loadu_si128(reinterpret_cast<const __m128i*>(a + k / 2));
    const __m128i y = _mm_loadu_si128(reinterpret_cast<const __m128i*>(b + k / 2));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + k), _mm_unpacklo_epi8(x, y));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + k + 16), _mm_unpackhi_epi8(x, y));
  }
#endif
  for (; k + 1 < n; k += 2) {
    out[k] = a[k / 2];
    out[k + 1] = b[k / 2];
  }
  if (k < n) out[k] = a[k / 2];
}

bool chunk_decodes(const HeaderSummary& header) {
  if (header.format != FileFormat::exr || header.parts.size() != 1) return false;
  const HeaderPart& p = header.parts.front();
  if (!p.plain_scanline || p.chunk_offsets.empty()) return false;
  if (p.compression != kNone && p.compression != kZips && p.compression != kZip) return false;
  if (p.channels.empty() || p.pixel_types.size() != p.channels.size()) return false;
  for (std::size_t c = 0; c < p.channels.size(); ++c) {
    if (p.pixel_types[c] != kHalf && p.pixel_types[c] != kFloat) return false;
    // OpenEXR lays a line's channels out in the order of its (sorted, unique) channel list;
    // a file that lists them otherwise is left to the library's own reading.
    if (c > 0 && std::strcmp(p.channels[c - 1].c_str(), p.channels[c].c_str()) >= 0) return false;
  }
  return true;
}

std::uint64_t chunk_scratch_bytes(const HeaderPart& part) {
  return 3 * static_cast<std::uint64_t>(lines_per_chunk(part.compression)) *
         line_layout(part).back();
}

void decode_chunks(const ByteSource& src, const HeaderPart& part, const std::string& name,
                   std::span<const ChunkTarget> targets) {
  const std::size_t w = static_cast<std::size_t>(part.width);
  const int L = lines_per_chunk(part.compression);
  const std::vector<std::size_t> at = line_layout(part);
  const std::size_t line = at.back();
  for (const ChunkTarget& t : targets) {
    if (t.channel < 0 || static_cast<std::size_t>(t.channel) >= part.channels.size() || !t.plane) {
      throw std::logic_error("decode_chunks: a target names no channel of the part");
    }
  }
  const std::size_t chunks = part.chunk_offsets.size();
  if (chunks != (static_cast<std::size_t>(part.height) + L - 1) / static_cast<std::size_t>(L)) {
    fail(InputErrorKind::unreadable, name, "corrupt: chunk table does not cover the image");
  }
  const std::uint64_t file = src.size();
  tbb::enumerable_thread_specific<Scratch> scratch;
  tbb::parallel_for(std::size_t{0}, chunks, [&](std::size_t k) {
    Scratch& s = scratch.local();
    const int y0 = static_cast<int>(k) * L;
    const int lines = std::min(L, part.height - y0);
    const std::size_t expected = static_cast<std::size_t>(lines) * line;
    const auto corrupt = [&](const std::string& why) {
      fail(InputErrorKind::unreadable, name,
           "truncated or corrupt pixel data: chunk " + std::to_string(k) + " " + why);
    };
    // The chunk header again (the walk checked it; a descriptor's file may have changed since).
    const std::uint64_t offset = part.chunk_offsets[k];
    unsigned char head[8];
    if (offset > file || file - offset < 8 || src.read(offset, head, 8) != 8) corrupt("is cut off");
    std::int32_t y = 0, size = 0;
    std::memcpy(&y, head, 4);
    std::memcpy(&size, head + 4, 4);
    if (static_cast<std::int64_t>(y) != static_cast<std::int64_t>(part.ymin) + y0) {
      corrupt("names line " + std::to_string(y));
    }
    // Stored as is when compressing did not make it smaller (NONE: always).
    if (size <= 0 || static_cast<std::uint64_t>(size) > expected ||
        (part.compression == kNone && static_cast<std::uint64_t>(size) != expected)) {
      corrupt("holds " + std::to_string(size) + " bytes for " + std::to_string(expected));
    }
    if (static_cast<std::uint64_t>(size) > file - offset - 8) corrupt("is cut off");
    s.packed.resize(static_cast<std::size_t>(size));
    if (src.read(offset + 8, s.packed.data(), s.packed.size()) != s.packed.size()) {
      corrupt("is cut off");
    }
    const unsigned char* bytes = s.packed.data();
    if (static_cast<std::size_t>(size) < expected) {
      s.inflated.resize(expected);
      s.bytes.resize(expected);
      if (!s.inflater) {
        s.inflater.reset(libdeflate_alloc_decompressor());
        if (!s.inflater) throw std::bad_alloc();
      }
      // The zlib stream must inflate to exactly the chunk's lines (a NULL actual size makes
      // fewer bytes an error too); its Adler-32 is checked.
      const libdeflate_result r = libdeflate_zlib_decompress(
          s.inflater.get(), s.packed.data(), s.packed.size(), s.inflated.data(), expected, nullptr);
      if (r != LIBDEFLATE_SUCCESS) corrupt(inflate_error(r));
      undo_zip_predictor(s.inflated.data(), expected, s.bytes.data());
      bytes = s.bytes.data();
    }
    for (int l = 0; l < lines; ++l) {
      const unsigned char* in = bytes + static_cast<std::size_t>(l) * line;
      const std::size_t row = static_cast<std::size_t>(y0 + l) * w;
      for (const ChunkTarget& t : targets) {
        const auto c = static_cast<std::size_t>(t.channel);
        const unsigned char* v = in + at[c];
        float* dst = t.plane + row;
        if (part.pixel_types[c] == kFloat) {
          std::memcpy(dst, v, w * sizeof(float));
        } else {
          for (std::size_t x = 0; x < w; ++x) {
            std::uint16_t h;
            std::memcpy(&h, v + 2 * x, 2);
            dst[x] = imath_half_to_float(h);
          }
        }
      }
    }
  });
}

}  // namespace proden::io::detail

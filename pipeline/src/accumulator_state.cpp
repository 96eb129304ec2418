// Binary (de)serialisation of FrameAccumulator, so a daemon can persist a frame's accumulated
// state and resume after a restart or crash with bit-identical statistics.
//
// Layout (host byte order, which is little-endian on every platform proden supports):
//   "PRDNACC" + version byte, u32 width, u32 height, u8 layout flags,
//   per half: vec<f64> weight, vec<u32> count, moments; moments albedo, normal, depth;
//   vec<f64> renderer variance; u64 history size, per record: str name, f64 spp, i32 half,
//   u64 fingerprint, u64 dropped, u64 sanitized; trailing u64 hash of everything before it.
// vec<T> = u64 length + raw values; moments = i32 channels + vec mean + vec m2.
#include <cmath>
#include <cstring>
#include <type_traits>

#include "proden/accumulator.hpp"
#include "proden/error.hpp"
#include "proden/hash.hpp"

namespace proden {
namespace {

constexpr char kMagic[8] = {'P', 'R', 'D', 'N', 'A', 'C', 'C', '\x01'};
constexpr std::uint64_t kSeed = 0x61636373746174;  // "accstat"

class Writer {
 public:
  template <class T>
  void put(const T& v) {
    static_assert(std::is_trivially_copyable_v<T>);
    const auto* p = reinterpret_cast<const std::uint8_t*>(&v);
    out.insert(out.end(), p, p + sizeof(T));
  }
  template <class T>
  void vec(const std::vector<T>& v) {
    put<std::uint64_t>(v.size());
    const auto* p = reinterpret_cast<const std::uint8_t*>(v.data());
    out.insert(out.end(), p, p + v.size() * sizeof(T));
  }
  void str(const std::string& s) {
    put<std::uint64_t>(s.size());
    out.insert(out.end(), s.begin(), s.end());
  }
  std::vector<std::uint8_t> out;
};

class Reader {
 public:
  explicit Reader(std::span<const std::uint8_t> b) : bytes(b) {}
  [[noreturn]] static void fail(const std::string& why) {
    throw InputError(InputErrorKind::unreadable, "frame state", why);
  }
  void need(std::size_t n) const {
    if (n > bytes.size() - pos) fail("truncated frame state");
  }
  template <class T>
  T get() {
    need(sizeof(T));
    T v;
    std::memcpy(&v, bytes.data() + pos, sizeof(T));
    pos += sizeof(T);
    return v;
  }
  template <class T>
  std::vector<T> vec(std::size_t expected) {
    const auto n = get<std::uint64_t>();
    if (n != expected) fail("inconsistent array length in frame state");
    if (n > (bytes.size() - pos) / sizeof(T)) fail("truncated frame state");
    std::vector<T> v(n);
    if (n > 0) std::memcpy(v.data(), bytes.data() + pos, n * sizeof(T));
    pos += n * sizeof(T);
    if constexpr (std::is_floating_point_v<T>) {
      // add() never stores a non-finite statistic; one here is damage, however it got past the
      // checksum (issue 11, class 9: never resume from NaN).
      for (const T x : v) {
        if (!std::isfinite(x)) fail("non-finite statistic in frame state");
      }
    }
    return v;
  }
  std::string str() {
    const auto n = get<std::uint64_t>();
    if (n > 1 << 20) fail("implausible string length in frame state");
    need(n);
    std::string s(reinterpret_cast<const char*>(bytes.data() + pos), n);
    pos += n;
    return s;
  }
  std::span<const std::uint8_t> bytes;
  std::size_t pos = 0;
};

}  // namespace

std::vector<std::uint8_t> FrameAccumulator::serialize() const {
  Writer w;
  w.out.reserve(64 + state_bytes() + history_.size() * 64);
  w.out.insert(w.out.end(), kMagic, kMagic + sizeof(kMagic));
  w.put<std::uint32_t>(static_cast<std::uint32_t>(width_));
  w.put<std::uint32_t>(static_cast<std::uint32_t>(height_));
  const std::uint8_t flags =
      static_cast<std::uint8_t>((layout_.albedo ? 1 : 0) | (layout_.normal ? 2 : 0) |
                                (layout_.depth ? 4 : 0) | (layout_.variance ? 8 : 0));
  w.put(flags);
  auto moments = [&w](const Moments& m) {
    w.put<std::int32_t>(m.channels);
    w.vec(m.mean);
    w.vec(m.m2);
  };
  for (const auto& h : halves_) {
    w.vec(h.weight);
    w.vec(h.count);
    moments(h.colour);
  }
  moments(albedo_);
  moments(normal_);
  moments(depth_);
  w.vec(renderer_variance_);
  w.put<std::uint64_t>(history_.size());
  for (const auto& r : history_) {
    w.str(r.name);
    w.put(r.spp);
    w.put<std::int32_t>(r.half);
    w.put<std::uint64_t>(r.fingerprint);
    w.put<std::uint64_t>(r.dropped_pixels);
    w.put<std::uint64_t>(r.sanitized_features);
  }
  w.put<std::uint64_t>(hash_span(std::span<const std::uint8_t>(w.out), kSeed));
  return std::move(w.out);
}

FrameAccumulator FrameAccumulator::deserialize(std::span<const std::uint8_t> blob) {
  if (blob.size() < sizeof(kMagic) + sizeof(std::uint64_t)) Reader::fail("truncated frame state");
  if (std::memcmp(blob.data(), kMagic, sizeof(kMagic) - 1) != 0) {
    Reader::fail("not a proden frame state (bad magic)");
  }
  if (blob[sizeof(kMagic) - 1] != static_cast<std::uint8_t>(kMagic[sizeof(kMagic) - 1])) {
    Reader::fail("unsupported frame state version " + std::to_string(blob[sizeof(kMagic) - 1]));
  }
  const std::size_t body = blob.size() - sizeof(std::uint64_t);
  std::uint64_t stored = 0;
  std::memcpy(&stored, blob.data() + body, sizeof(stored));
  if (hash_span(blob.first(body), kSeed) != stored) Reader::fail("frame state checksum mismatch");

  Reader r(blob.first(body));
  r.pos = sizeof(kMagic);
  FrameAccumulator a;
  const auto width = r.get<std::uint32_t>();
  const auto height = r.get<std::uint32_t>();
  if (width > (1u << 16) || height > (1u << 16)) Reader::fail("implausible frame size");
  a.width_ = static_cast<int>(width);
  a.height_ = static_cast<int>(height);
  const auto flags = r.get<std::uint8_t>();
  if (flags > 15) Reader::fail("bad layout flags in frame state");
  a.layout_ = {(flags & 1) != 0, (flags & 2) != 0, (flags & 4) != 0, (flags & 8) != 0};
  const std::size_t n = a.pixels();
  auto moments = [&r, n](Moments& m, int expected_channels) {
    m.channels = r.get<std::int32_t>();
    if (m.channels != expected_channels) Reader::fail("inconsistent channels in frame state");
    const std::size_t len = n * static_cast<std::size_t>(m.channels);
    m.mean = r.vec<double>(len);
    m.m2 = r.vec<double>(len);
  };
  for (auto& h : a.halves_) {
    h.weight = r.vec<double>(n);
    h.count = r.vec<std::uint32_t>(n);
    moments(h.colour, n > 0 ? 3 : 0);
  }
  moments(a.albedo_, a.layout_.albedo ? 3 : 0);
  moments(a.normal_, a.layout_.normal ? 3 : 0);
  moments(a.depth_, a.layout_.depth ? 1 : 0);
  a.renderer_variance_ = r.vec<double>(a.layout_.variance ? 3 * n : 0);
  const auto records = r.get<std::uint64_t>();
  if (records > (r.bytes.size() - r.pos) / 44) Reader::fail("truncated frame state history");
  if ((records == 0) != (n == 0)) Reader::fail("inconsistent frame state history");
  a.history_.reserve(records);
  for (std::uint64_t i = 0; i < records; ++i) {
    PassRecord rec;
    rec.name = r.str();
    rec.spp = r.get<double>();
    if (!std::isfinite(rec.spp) || rec.spp <= 0.0) Reader::fail("bad spp in frame state history");
    rec.half = r.get<std::int32_t>();
    if (rec.half != 0 && rec.half != 1) Reader::fail("bad half index in frame state");
    rec.fingerprint = r.get<std::uint64_t>();
    rec.dropped_pixels = r.get<std::uint64_t>();
    rec.sanitized_features = r.get<std::uint64_t>();
    a.history_.push_back(std::move(rec));
  }
  if (r.pos != r.bytes.size()) Reader::fail("trailing bytes in frame state");
  return a;
}

}  // namespace proden

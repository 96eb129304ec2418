// Binary (de)serialisation of FrameAccumulator, so a daemon can persist a frame's accumulated
// state and resume after a restart or crash with bit-identical statistics.
//
// Layout of version 4 (host byte order, which is little-endian on every platform proden supports):
//   "PRDNACC" + version byte, u32 width, u32 height, u8 layout flags, u8 feature halves (0/1),
//   u8 quarters (0/1), per half: vec<f64> weight, vec<u32> count, moments, vec<f64> albedo,
//   normal, depth means; spread albedo, normal, depth; vec<f64> renderer variance; with quarters,
//   per half its sub-half 1: vec<f64> weight, colour, albedo, normal, depth means; u64 history
//   size, per record:
//   str name, f64 spp, i32 half, u64 fingerprint, u64 dropped, u64 sanitized; trailing u64
//   checksum_bytes (XXH3) of everything before it.
// vec<T> = u64 length + raw values; moments = i32 channels + vec mean + vec m2; spread = i32
// channels + vec m2.
// Version 3 (still read) is version 4 with the trailing hash made by hash_bytes (proden/hash.hpp).
// Version 2 (still read) is version 3 without the quarters byte and sub-halves: it loads with
// quarters() false (the frame's earlier passes were not split into sub-halves).
// Version 1 (still read: daemons have such states on disk) had no feature halves byte, no
// per-half feature means, and moments (mean and M2 over all passes) for each feature. It loads
// with both halves' feature means set to that mean (so the full mean is unchanged) and
// feature_halves() false: the frame never reports feature halves (docs/nfor.md, fallback).
#include <cmath>
#include <cstring>
#include <type_traits>

#include "proden/accumulator.hpp"
#include "proden/error.hpp"
#include "proden/hash.hpp"
#include "state_io.hpp"

namespace proden {
namespace {

constexpr char kMagic[8] = {'P', 'R', 'D', 'N', 'A', 'C', 'C', '\x04'};
constexpr std::uint8_t kVersion1 = 1;
constexpr std::uint8_t kVersion2 = 2;
constexpr std::uint8_t kVersion3 = 3;
constexpr std::uint64_t kSeed = 0x61636373746174;  // "accstat"

using detail::Reader;
using detail::Writer;

}  // namespace

template <class W>
void FrameAccumulator::write_state(W& w) const {
  w.bytes({reinterpret_cast<const std::uint8_t*>(kMagic), sizeof(kMagic)});
  w.put(static_cast<std::uint32_t>(width_));
  w.put(static_cast<std::uint32_t>(height_));
  const std::uint8_t flags =
      static_cast<std::uint8_t>((layout_.albedo ? 1 : 0) | (layout_.normal ? 2 : 0) |
                                (layout_.depth ? 4 : 0) | (layout_.variance ? 8 : 0));
  w.put(flags);
  w.put(static_cast<std::uint8_t>(feature_halves_ ? 1 : 0));
  w.put(static_cast<std::uint8_t>(quarters_ ? 1 : 0));
  for (const auto& h : halves_) {
    w.vec(h.weight);
    w.vec(h.count);
    w.put(static_cast<std::int32_t>(h.colour.channels));
    w.vec(h.colour.mean);
    w.vec(h.colour.m2);
    w.vec(h.albedo);
    w.vec(h.normal);
    w.vec(h.depth);
  }
  for (const FeatureSpread* f : {&albedo_, &normal_, &depth_}) {
    w.put(static_cast<std::int32_t>(f->channels));
    w.vec(f->m2);
  }
  w.vec(renderer_variance_);
  if (quarters_) {
    for (const auto& sh : subs_) {
      w.vec(sh.weight);
      w.vec(sh.colour);
      w.vec(sh.albedo);
      w.vec(sh.normal);
      w.vec(sh.depth);
    }
  }
  w.put(static_cast<std::uint64_t>(history_.size()));
  for (const auto& r : history_) {
    w.str(r.name);
    w.put(r.spp);
    w.put(static_cast<std::int32_t>(r.half));
    w.put(static_cast<std::uint64_t>(r.fingerprint));
    w.put(static_cast<std::uint64_t>(r.dropped_pixels));
    w.put(static_cast<std::uint64_t>(r.sanitized_features));
  }
}

std::size_t FrameAccumulator::serialized_size() const {
  detail::SizeCounter c;
  write_state(c);
  return c.n + sizeof(std::uint64_t);
}

std::size_t FrameAccumulator::serialize_to(const ByteSink& sink, Checksum* also) const {
  const std::size_t n = serialized_size();
  detail::StreamWriter w(sink, kSeed, also);
  write_state(w);
  w.finish();
  return n;
}

std::vector<std::uint8_t> FrameAccumulator::serialize() const {
  Writer w;
  w.out.reserve(serialized_size());
  serialize_to([&w](std::span<const std::uint8_t> b) { w.bytes(b); });
  return std::move(w.out);
}

FrameAccumulator FrameAccumulator::deserialize(std::span<const std::uint8_t> blob) {
  if (blob.size() < sizeof(kMagic) + sizeof(std::uint64_t)) Reader::fail("truncated frame state");
  if (std::memcmp(blob.data(), kMagic, sizeof(kMagic) - 1) != 0) {
    Reader::fail("not a proden frame state (bad magic)");
  }
  const std::uint8_t version = blob[sizeof(kMagic) - 1];
  if (version != static_cast<std::uint8_t>(kMagic[sizeof(kMagic) - 1]) && version != kVersion1 &&
      version != kVersion2 && version != kVersion3) {
    Reader::fail("unsupported frame state version " + std::to_string(version));
  }
  const std::size_t body = blob.size() - sizeof(std::uint64_t);
  std::uint64_t stored = 0;
  std::memcpy(&stored, blob.data() + body, sizeof(stored));
  const HashKind kind = version <= kVersion3 ? HashKind::legacy : HashKind::xxh3;
  if (hash_with(kind, blob.first(body), kSeed) != stored) {
    Reader::fail("frame state checksum mismatch");
  }

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
  if (version != kVersion1) {
    const auto halves = r.get<std::uint8_t>();
    if (halves > 1) Reader::fail("bad feature halves flag in frame state");
    a.feature_halves_ = halves == 1;
  }
  if (version != kVersion1 && version != kVersion2) {
    const auto quarters = r.get<std::uint8_t>();
    if (quarters > 1) Reader::fail("bad quarters flag in frame state");
    a.quarters_ = quarters == 1;
  }
  const std::size_t n = a.pixels();
  auto channels = [&r](int expected) {
    const auto c = r.get<std::int32_t>();
    if (c != expected) Reader::fail("inconsistent channels in frame state");
    return c;
  };
  auto moments = [&r, n, &channels](Moments& m, int expected_channels) {
    m.channels = channels(expected_channels);
    const std::size_t len = n * static_cast<std::size_t>(m.channels);
    m.mean = r.vec<double>(len);
    m.m2 = r.vec<double>(len);
  };
  const int alb = a.layout_.albedo ? 3 : 0, nrm = a.layout_.normal ? 3 : 0;
  const int dep = a.layout_.depth ? 1 : 0;
  auto len = [n](int ch) { return n * static_cast<std::size_t>(ch); };
  for (auto& h : a.halves_) {
    h.weight = r.vec<double>(n);
    h.count = r.vec<std::uint32_t>(n);
    moments(h.colour, n > 0 ? 3 : 0);
    if (version != kVersion1) {
      h.albedo = r.vec<double>(len(alb));
      h.normal = r.vec<double>(len(nrm));
      h.depth = r.vec<double>(len(dep));
    }
  }
  if (version == kVersion1) {
    // Features over all passes only: both halves take the full mean, M2 is kept.
    auto v1_feature = [&](FeatureSpread& s, std::vector<double> Half::*mean, int ch) {
      Moments m;
      moments(m, ch);
      s = {m.channels, std::move(m.m2)};
      for (auto& h : a.halves_) h.*mean = m.mean;
    };
    v1_feature(a.albedo_, &Half::albedo, alb);
    v1_feature(a.normal_, &Half::normal, nrm);
    v1_feature(a.depth_, &Half::depth, dep);
    a.feature_halves_ = false;
  } else {
    for (auto [s, ch] : {std::pair{&a.albedo_, alb}, {&a.normal_, nrm}, {&a.depth_, dep}}) {
      s->channels = channels(ch);
      s->m2 = r.vec<double>(len(ch));
    }
  }
  a.renderer_variance_ = r.vec<double>(a.layout_.variance ? 3 * n : 0);
  if (a.quarters_) {
    for (auto& sh : a.subs_) {
      sh.weight = r.vec<double>(n);
      sh.colour = r.vec<double>(len(n > 0 ? 3 : 0));
      sh.albedo = r.vec<double>(len(alb));
      sh.normal = r.vec<double>(len(nrm));
      sh.depth = r.vec<double>(len(dep));
    }
  }
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

// AovAccumulator. Binary layout (host byte order): "PRDNAOV" + version byte, u32 width,
// u32 height, u64 attribute count, per attribute: str name, str value; u64 channel count, per
// channel: str name, u8 mode, then vec<f64> mean + vec<f64> weight (mean) or vec<f32> (first
// pass); trailing u64 checksum_bytes (XXH3) of everything before it. Version 1 (still read) has
// the trailing hash made by hash_bytes (proden/hash.hpp).
#include "proden/aov.hpp"

#include <algorithm>
#include <cmath>
#include <set>
#include <stdexcept>

#include "proden/hash.hpp"
#include "state_io.hpp"

namespace proden {
namespace {

constexpr char kMagic[8] = {'P', 'R', 'D', 'N', 'A', 'O', 'V', '\x02'};
constexpr char kVersion1 = '\x01';
constexpr std::uint64_t kSeed = 0x616f7673746174;  // "aovstat"

}  // namespace

std::string_view to_string(AovMode m) {
  return m == AovMode::mean ? "mean" : "first_pass";
}

AovMode aov_mode(std::string_view name) {
  const std::string_view layer = name.substr(0, name.find('.'));
  if (layer.rfind("Crypto", 0) == 0 || layer == "IndexOB" || layer == "IndexMA") {
    return AovMode::first_pass;
  }
  return AovMode::mean;
}

void AovAccumulator::add(const std::vector<AovChannel>& in, double spp,
                         const std::vector<std::pair<std::string, std::string>>& attributes) {
  if (in.empty()) return;
  if (!(spp > 0) || !std::isfinite(spp)) throw std::invalid_argument("AOVs: spp must be > 0");
  const int w = in.front().plane.width(), h = in.front().plane.height();
  std::set<std::string> names;
  for (const auto& c : in) {
    if (c.plane.channels() != 1 || c.plane.width() != w || c.plane.height() != h) {
      throw std::invalid_argument("AOV " + c.name + ": not one channel of the pass's size");
    }
    if (!names.insert(c.name).second) throw std::invalid_argument("AOV " + c.name + " repeated");
  }
  if (width_ != 0 && (w != width_ || h != height_)) {
    throw std::invalid_argument("AOVs: " + std::to_string(w) + "x" + std::to_string(h) +
                                ", the frame's are " + std::to_string(width_) + "x" +
                                std::to_string(height_));
  }
  // Nothing below throws (except allocation).
  width_ = w;
  height_ = h;
  const std::size_t n = static_cast<std::size_t>(w) * static_cast<std::size_t>(h);
  for (const auto& c : in) {
    auto it = std::lower_bound(channels_.begin(), channels_.end(), c.name,
                               [](const Channel& a, const std::string& b) { return a.name < b; });
    if (it == channels_.end() || it->name != c.name) {
      Channel ch;
      ch.name = c.name;
      ch.mode = aov_mode(c.name);
      if (ch.mode == AovMode::mean) {
        ch.mean.assign(n, 0.0);
        ch.weight.assign(n, 0.0);
      } else {
        ch.first.assign(c.plane.data().begin(), c.plane.data().end());
      }
      it = channels_.insert(it, std::move(ch));
      if (it->mode == AovMode::first_pass) continue;
    }
    if (it->mode != AovMode::mean) continue;  // the first pass's values stay
    const auto src = c.plane.data();
    for (std::size_t p = 0; p < n; ++p) {
      const double x = src[p];
      if (!std::isfinite(x)) continue;
      it->weight[p] += spp;
      it->mean[p] += spp / it->weight[p] * (x - it->mean[p]);
    }
  }
  for (const auto& kv : attributes) {  // not a structured binding: clang 14 cannot capture one
    const bool have = std::any_of(attributes_.begin(), attributes_.end(),
                                  [&](const auto& a) { return a.first == kv.first; });
    if (!have) attributes_.push_back(kv);
  }
}

std::vector<std::pair<std::string, AovMode>> AovAccumulator::channels() const {
  std::vector<std::pair<std::string, AovMode>> out;
  for (const auto& c : channels_) out.emplace_back(c.name, c.mode);
  return out;
}

std::size_t AovAccumulator::state_bytes() const {
  std::size_t b = 0;
  for (const auto& c : channels_) {
    b += (c.mean.size() + c.weight.size()) * sizeof(double) + c.first.size() * sizeof(float);
  }
  return b;
}

std::vector<AovChannel> AovAccumulator::result() const {
  std::vector<AovChannel> out;
  for (const auto& c : channels_) {
    AovChannel a{c.name, Image(width_, height_, 1)};
    auto dst = a.plane.data();
    if (c.mode == AovMode::mean) {
      for (std::size_t p = 0; p < dst.size(); ++p) dst[p] = static_cast<float>(c.mean[p]);
    } else {
      std::copy(c.first.begin(), c.first.end(), dst.begin());
    }
    out.push_back(std::move(a));
  }
  return out;
}

std::vector<std::uint8_t> AovAccumulator::serialize() const {
  if (channels_.empty() && attributes_.empty()) return {};
  detail::Writer w;
  for (const char c : kMagic) w.put(c);  // (a range insert trips GCC 12's -Wstringop-overflow)
  w.put<std::uint32_t>(static_cast<std::uint32_t>(width_));
  w.put<std::uint32_t>(static_cast<std::uint32_t>(height_));
  w.put<std::uint64_t>(attributes_.size());
  for (const auto& [k, v] : attributes_) {
    w.str(k);
    w.str(v);
  }
  w.put<std::uint64_t>(channels_.size());
  for (const auto& c : channels_) {
    w.str(c.name);
    w.put<std::uint8_t>(c.mode == AovMode::mean ? 0 : 1);
    if (c.mode == AovMode::mean) {
      w.vec(c.mean);
      w.vec(c.weight);
    } else {
      w.vec(c.first);
    }
  }
  w.put<std::uint64_t>(checksum_span(std::span<const std::uint8_t>(w.out), kSeed));
  return std::move(w.out);
}

AovAccumulator AovAccumulator::deserialize(std::span<const std::uint8_t> blob) {
  using detail::Reader;
  AovAccumulator a;
  if (blob.empty()) return a;
  if (blob.size() < sizeof(kMagic) + sizeof(std::uint64_t) ||
      std::memcmp(blob.data(), kMagic, sizeof(kMagic) - 1) != 0) {
    Reader::fail("not a proden AOV state");
  }
  const char version = static_cast<char>(blob[sizeof(kMagic) - 1]);
  if (version != kMagic[sizeof(kMagic) - 1] && version != kVersion1) {
    Reader::fail("unsupported AOV state version " + std::to_string(static_cast<int>(version)));
  }
  const std::size_t body = blob.size() - sizeof(std::uint64_t);
  std::uint64_t stored = 0;
  std::memcpy(&stored, blob.data() + body, sizeof stored);
  const HashKind kind = version == kVersion1 ? HashKind::legacy : HashKind::xxh3;
  if (hash_with(kind, blob.first(body), kSeed) != stored) {
    Reader::fail("AOV state checksum mismatch");
  }
  Reader r(blob.first(body));
  r.pos = sizeof(kMagic);
  a.width_ = static_cast<int>(r.get<std::uint32_t>());
  a.height_ = static_cast<int>(r.get<std::uint32_t>());
  if (a.width_ > (1 << 16) || a.height_ > (1 << 16)) Reader::fail("implausible AOV size");
  const std::size_t n = static_cast<std::size_t>(a.width_) * static_cast<std::size_t>(a.height_);
  const auto attrs = r.get<std::uint64_t>();
  if (attrs > 4096) Reader::fail("implausible AOV attribute count");
  for (std::uint64_t i = 0; i < attrs; ++i) {
    std::string k = r.str();
    a.attributes_.emplace_back(std::move(k), r.str());
  }
  const auto count = r.get<std::uint64_t>();
  if (count > 4096) Reader::fail("implausible AOV channel count");
  for (std::uint64_t i = 0; i < count; ++i) {
    Channel c;
    c.name = r.str();
    const auto mode = r.get<std::uint8_t>();
    if (mode > 1) Reader::fail("bad AOV mode");
    c.mode = mode == 0 ? AovMode::mean : AovMode::first_pass;
    if (c.mode == AovMode::mean) {
      c.mean = r.vec<double>(n);
      c.weight = r.vec<double>(n);
    } else {
      c.first = r.vec<float>(n);
    }
    if (!a.channels_.empty() && !(a.channels_.back().name < c.name)) {
      Reader::fail("AOV channels out of order");
    }
    a.channels_.push_back(std::move(c));
  }
  if (r.pos != r.bytes.size()) Reader::fail("trailing bytes in AOV state");
  return a;
}

}  // namespace proden

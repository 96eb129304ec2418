#include "proden/hash.hpp"

#include <algorithm>
#include <cstring>

namespace proden {
namespace {

constexpr std::uint64_t kMul = 0x9E3779B97F4A7C15ull;

std::uint64_t mix(std::uint64_t h) {  // splitmix64 finaliser
  h ^= h >> 30;
  h *= 0xBF58476D1CE4E5B9ull;
  h ^= h >> 27;
  h *= 0x94D049BB133111EBull;
  h ^= h >> 31;
  return h;
}

}  // namespace

ByteHasher::ByteHasher(std::uint64_t total, std::uint64_t seed) : h_(mix(seed ^ (total * kMul))) {}

void ByteHasher::update(std::span<const unsigned char> bytes) {
  std::size_t i = 0;
  while (i < bytes.size()) {
    if (fill_ == 0 && i + 8 <= bytes.size()) {  // whole words straight from the input
      std::uint64_t word;
      std::memcpy(&word, bytes.data() + i, 8);
      h_ = mix(h_ ^ (word * kMul)) + kMul;
      i += 8;
      continue;
    }
    word_[fill_++] = bytes[i++];
    if (fill_ == 8) {
      std::uint64_t word;
      std::memcpy(&word, word_, 8);
      h_ = mix(h_ ^ (word * kMul)) + kMul;
      fill_ = 0;
    }
  }
}

void ByteHasher::update_both(ByteHasher& a, ByteHasher& b, std::span<const unsigned char> bytes) {
  if (a.fill_ != b.fill_) {  // out of step: no common words
    a.update(bytes);
    b.update(bytes);
    return;
  }
  std::size_t i = 0;
  if (a.fill_ != 0) {  // complete both partial words first
    i = std::min<std::size_t>(8 - a.fill_, bytes.size());
    a.update(bytes.first(i));
    b.update(bytes.first(i));
  }
  for (; i + 8 <= bytes.size(); i += 8) {
    std::uint64_t word;
    std::memcpy(&word, bytes.data() + i, 8);
    word *= kMul;
    a.h_ = mix(a.h_ ^ word) + kMul;
    b.h_ = mix(b.h_ ^ word) + kMul;
  }
  a.update(bytes.subspan(i));
  b.update(bytes.subspan(i));
}

std::uint64_t ByteHasher::finish() const {
  std::uint64_t tail = 0;
  std::memcpy(&tail, word_, fill_);
  return mix(h_ ^ tail ^ kMul);
}

std::uint64_t hash_bytes(std::span<const unsigned char> bytes, std::uint64_t seed) {
  ByteHasher h(bytes.size(), seed);
  h.update(bytes);
  return h.finish();
}

}  // namespace proden

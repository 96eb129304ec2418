#include "proden/hash.hpp"

#include <xxhash.h>

#include <cstring>
#include <new>

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

std::uint64_t checksum_bytes(std::span<const unsigned char> bytes, std::uint64_t seed) {
  return XXH3_64bits_withSeed(bytes.data(), bytes.size(), seed);
}

void Checksum::Free::operator()(XXH3_state_s* s) const {
  XXH3_freeState(s);
}

Checksum::Checksum(std::uint64_t seed) : state_(XXH3_createState()) {
  if (!state_) throw std::bad_alloc();
  XXH3_64bits_reset_withSeed(state_.get(), seed);
}

void Checksum::update(std::span<const unsigned char> bytes) {
  XXH3_64bits_update(state_.get(), bytes.data(), bytes.size());
}

std::uint64_t Checksum::finish() const {
  return XXH3_64bits_digest(state_.get());
}

}  // namespace proden

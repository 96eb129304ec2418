// A fast, non-cryptographic 64-bit hash of raw bytes (pass fingerprints for duplicate detection).
#pragma once

#include <cstdint>
#include <span>

namespace proden {

std::uint64_t hash_bytes(std::span<const unsigned char> bytes, std::uint64_t seed = 0);

// hash_bytes of `total` bytes given in pieces of any size (a file read in chunks): the same value.
class ByteHasher {
 public:
  explicit ByteHasher(std::uint64_t total, std::uint64_t seed = 0);
  void update(std::span<const unsigned char> bytes);
  std::uint64_t finish() const;  // after exactly `total` bytes

  // a.update(bytes) and b.update(bytes) in one pass over them. Each hash is a serial chain (one
  // multiply-mix per 8 bytes, bound by its latency); two independent chains overlap in the CPU,
  // so both cost about what one does (the state file's hash and its accumulator's checksum).
  static void update_both(ByteHasher& a, ByteHasher& b, std::span<const unsigned char> bytes);

 private:
  std::uint64_t h_;
  unsigned char word_[8] = {};
  unsigned fill_ = 0;  // bytes of word_ taken
};

template <class T>
std::uint64_t hash_span(std::span<const T> values, std::uint64_t seed = 0) {
  return hash_bytes({reinterpret_cast<const unsigned char*>(values.data()), values.size_bytes()},
                    seed);
}

}  // namespace proden

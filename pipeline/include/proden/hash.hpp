// Fast non-cryptographic 64-bit hashes of raw bytes: the checksums of what proden persists
// (XXH3), and the older serial hash that identifies passes and checks states written before
// frame state format 4.
#pragma once

#include <cstdint>
#include <memory>
#include <span>

struct XXH3_state_s;

namespace proden {

// The older hash: one multiply-mix per 8 bytes in a serial chain (1-2 GB/s). It stays for the
// identities already stored (passes' content hashes in frame records and uploads: a changed
// value would let a re-delivered pass count twice after an upgrade), the SURE probe's seeds, and
// to check states written before format 4.
std::uint64_t hash_bytes(std::span<const unsigned char> bytes, std::uint64_t seed = 0);

// hash_bytes of `total` bytes given in pieces of any size (a file read in chunks): the same value.
class ByteHasher {
 public:
  explicit ByteHasher(std::uint64_t total, std::uint64_t seed = 0);
  void update(std::span<const unsigned char> bytes);
  std::uint64_t finish() const;  // after exactly `total` bytes

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

// The checksum of persisted state from frame state format 4 on (the accumulator's and the AOVs'
// blobs, the state file, FrameAccumulator::state_digest): XXH3-64 with a seed, from Debian's
// libxxhash, ~12 GB/s on one core where hash_bytes ran at 1.1 GB/s (AMD EPYC; bench/RESULTS.md,
// "State checksums"). A 1080p frame's ~600 MB of statistics are hashed three times per update.
std::uint64_t checksum_bytes(std::span<const unsigned char> bytes, std::uint64_t seed = 0);

template <class T>
std::uint64_t checksum_span(std::span<const T> values, std::uint64_t seed = 0) {
  return checksum_bytes(
      {reinterpret_cast<const unsigned char*>(values.data()), values.size_bytes()}, seed);
}

// checksum_bytes of bytes given in pieces of any size: the same value.
class Checksum {
 public:
  explicit Checksum(std::uint64_t seed = 0);
  void update(std::span<const unsigned char> bytes);
  std::uint64_t finish() const;

 private:
  struct Free {
    void operator()(XXH3_state_s* s) const;
  };
  std::unique_ptr<XXH3_state_s, Free> state_;
};

// Which of the two a persisted value was made with: states before format 4 used `legacy`.
enum class HashKind { legacy, xxh3 };

inline std::uint64_t hash_with(HashKind kind, std::span<const unsigned char> bytes,
                               std::uint64_t seed) {
  return kind == HashKind::xxh3 ? checksum_bytes(bytes, seed) : hash_bytes(bytes, seed);
}

}  // namespace proden

// A fast, non-cryptographic 64-bit hash of raw bytes (pass fingerprints for duplicate detection).
#pragma once

#include <cstdint>
#include <span>

namespace proden {

std::uint64_t hash_bytes(std::span<const unsigned char> bytes, std::uint64_t seed = 0);

template <class T>
std::uint64_t hash_span(std::span<const T> values, std::uint64_t seed = 0) {
  return hash_bytes({reinterpret_cast<const unsigned char*>(values.data()), values.size_bytes()},
                    seed);
}

}  // namespace proden

// The learned mixer's weights file (`.pdnw`, docs/mixer_network.md): a versioned, bounds-checked
// container of named float32 tensors. Parsing works on bytes; reading files is the caller's job.
#pragma once

#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

namespace proden::network {

// A corrupt or unusable weights file; the message names the source and the field at fault.
class WeightsError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct Tensor {
  std::string name;        // equals the layer's name, e.g. "res1.conv2.weight"
  std::vector<int> shape;  // PyTorch order (OIHW for convolutions)
  std::vector<float> values;

  std::size_t size() const;
  std::string shape_string() const;  // "[48,18,5,5]"
};

struct WeightsFile {
  static constexpr std::uint16_t kVersion = 1;
  std::string metadata;  // informational JSON text (width, training command, validation numbers)
  std::vector<Tensor> tensors;

  const Tensor* find(const std::string& name) const;
};

// Parses and checks every bound of a `.pdnw` image (magic, version, counts, names, dims, offsets,
// overlap, checksum, finite values). `source` names the file in error messages.
WeightsFile parse_weights(std::span<const unsigned char> bytes, const std::string& source);

// The inverse of parse_weights (tests build corrupt variants from it; training writes its own).
std::vector<unsigned char> serialize_weights(const WeightsFile& file);

// FNV-1a, 64 bit: the file's trailing checksum.
std::uint64_t fnv1a64(std::span<const unsigned char> bytes);

}  // namespace proden::network

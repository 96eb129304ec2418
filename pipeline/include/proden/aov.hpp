// Renderer AOVs of a frame (Combined.A, Depth, Mist, DiffCol, Cryptomatte, ... besides the colour
// and the denoiser's features): spp-weighted per-pixel means where averaging means something,
// the first pass's values where it does not (Cryptomatte ids and coverage, object/material
// indices). docs/api.md, "Renderer AOVs".
#pragma once

#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "proden/image.hpp"

namespace proden {

enum class AovMode {
  mean,        // spp-weighted mean of the passes' finite samples
  first_pass,  // the first pass's values, unchanged (averaging is meaningless)
};
std::string_view to_string(AovMode m);

// One channel of a pass, named as it is written out (e.g. "Depth.Z", "CryptoObject00.r", "A").
struct AovChannel {
  std::string name;
  Image plane;  // 1 channel, the pass's size
};

// The mode a channel's name calls for: Cryptomatte layers ("Crypto...") and object/material
// index passes ("IndexOB", "IndexMA") pass through; everything else is averaged.
AovMode aov_mode(std::string_view channel_name);

class AovAccumulator {
 public:
  // Adds one pass's channels with weight `spp`. The first pass fixes the size; a channel first
  // seen in a later pass starts there (its mean covers the passes that had it). Non-finite
  // samples are skipped per pixel. `attributes` (e.g. Cryptomatte's manifest) are kept from the
  // first pass that brings them. Validates everything before changing anything: throws
  // std::invalid_argument (wrong size, not one channel, spp <= 0, a repeated name).
  void add(const std::vector<AovChannel>& channels, double spp,
           const std::vector<std::pair<std::string, std::string>>& attributes = {});

  bool empty() const { return channels_.empty(); }
  // Names and modes, in name order.
  std::vector<std::pair<std::string, AovMode>> channels() const;
  // The accumulated planes (means as float; pixels no finite sample reached are 0), in name order.
  std::vector<AovChannel> result() const;
  const std::vector<std::pair<std::string, std::string>>& attributes() const { return attributes_; }
  // Bytes of accumulated planes (what keeping it in memory costs).
  std::size_t state_bytes() const;

  // Binary form for the daemon's frame state ("PRDNAOV" + version, checksummed); deserialize()
  // throws InputError (unreadable) on a corrupt blob. An empty accumulator serialises to nothing.
  std::vector<std::uint8_t> serialize() const;
  static AovAccumulator deserialize(std::span<const std::uint8_t> blob);

 private:
  struct Channel {
    std::string name;
    AovMode mode = AovMode::mean;
    std::vector<double> mean, weight;  // mode mean
    std::vector<float> first;          // mode first_pass
  };
  int width_ = 0, height_ = 0;
  std::vector<Channel> channels_;  // sorted by name
  std::vector<std::pair<std::string, std::string>> attributes_;
};

}  // namespace proden

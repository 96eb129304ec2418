// Accumulated state of one frame: the running, spp-weighted statistics of all its passes, from
// which the render x, its variance of the mean Var[x], the half buffers and feature means derive.
//
// Statistics (per pixel and channel, in double): passes alternate into half buffers A and B, each
// keeping a weighted Welford mean and M2 = sum_k n_k (x_k - mean)^2 with weights n_k = spp. The
// full frame is the exact (Chan) combination of the halves, so it costs no extra memory. With K
// passes and N = sum n_k samples at a pixel, sigma^2 = M2 / (K - 1) is the unbiased per-sample
// variance and Var[x] = sigma^2 / N (= s^2 / K for equal spp). Features (albedo, normal, depth)
// keep a weighted mean per half (NFOR's feature prefilter cross-filters them, docs/nfor.md) and
// one M2 over all passes; their full mean is again the Chan combination of the halves. Memory per
// pixel: see bytes_per_pixel().
//
// Quarters (optional, AccumulatorOptions::quarters): pass k also belongs to sub-half (k / 2) % 2 of
// its half k % 2, so each half is itself split the way a frame of only that half's passes would
// be. The error estimate cross-validates a denoiser that reads the halves (NFOR) by running it on
// one half with these sub-halves as its halves (docs/error_estimate.md). Kept: the weight, colour
// and feature means of sub-half 1 of each half; sub-half 0 is the half less sub-half 1.
//
// Non-finite policy: a pass's pixel whose colour (or renderer variance) is NaN/Inf, or whose
// variance is negative, is dropped from that pass (all channels, counted in AddResult and
// dropped_samples()); the pixel then has fewer passes than the frame. Non-finite feature values
// are sanitised (NaN -> 0, +-Inf -> +-1e10, Cycles' background depth) and counted.
#pragma once

#include <array>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "proden/hash.hpp"
#include "proden/image.hpp"
#include "proden/pass.hpp"

namespace proden {

// Where a pixel's Var[x] came from.
enum class VarianceSource {
  between_passes,  // spread between K >= 2 passes
  renderer,        // the passes' own variance channels
  spatial,         // fallback for pixels with a single pass: 3x3 spread of the mean (biased up)
};

struct PassRecord {
  std::string name;
  double spp = 0.0;
  int half = 0;                    // 0 = A, 1 = B
  std::uint64_t fingerprint = 0;   // hash of the colour data, for duplicate detection
  std::size_t dropped_pixels = 0;  // pixels whose sample was dropped (non-finite)
  std::size_t sanitized_features = 0;
};

struct EstimateOptions {
  bool halves = true;
  bool features = true;
  bool quarters = false;  // the half buffers' own halves (needs AccumulatorOptions::quarters)
};

struct AccumulatorOptions {
  bool quarters = false;  // keep each half's sub-halves (header comment)
};

// Float snapshots of the accumulated statistics, ready for the pipeline stages.
struct FrameEstimate {
  Image mean;                          // x: spp-weighted mean, RGB
  Image variance;                      // Var[x]: variance of the mean, RGB
  std::array<Image, 2> half_mean;      // x_A, x_B (empty unless both halves hold passes)
  std::array<Image, 2> half_variance;  // Var[x_A], Var[x_B]
  // Feature means per half (each empty unless half_mean is set, the frame carries the feature and
  // the state has feature halves: a state restored from format v1 has none).
  std::array<Image, 2> half_albedo, half_normal, half_depth;
  Image albedo, normal, depth;  // feature means (empty where the frame has none)
  Image albedo_variance, normal_variance, depth_variance;  // variance of the feature means
  // Quarters, index 2 h + s = sub-half s of half h (empty unless asked for, kept, and every
  // quarter holds a pass: 4 passes or more); features as for the halves.
  std::array<Image, 4> quarter_mean, quarter_variance;
  std::array<Image, 4> quarter_albedo, quarter_normal, quarter_depth;
  Image passes;  // 1 channel: passes that contributed to each pixel
  VarianceSource variance_source = VarianceSource::between_passes;
  std::size_t spatial_pixels = 0;  // pixels whose variance uses the spatial fallback
  std::size_t hole_pixels = 0;     // pixels no pass contributed to (filled from neighbours)
  // True when some variance is a spatial guess (a single pass, or holes): downstream error
  // estimates are then less reliable.
  bool low_confidence() const { return spatial_pixels > 0 || hole_pixels > 0; }
};

struct AddResult {
  int pass_index = 0;
  int half = 0;
  std::size_t dropped_pixels = 0;
  std::size_t sanitized_features = 0;
};

class FrameAccumulator {
 public:
  FrameAccumulator() = default;  // the first pass fixes size and layout
  explicit FrameAccumulator(AccumulatorOptions options) : quarters_(options.quarters) {}

  // Validates `pass` against the frame, changing nothing, and returns its fingerprint (a hash of
  // its colour, PassRecord::fingerprint). Throws InputError (subject = name): size_mismatch,
  // layout_mismatch, duplicate (bit-identical colour to an accepted, non-constant pass),
  // invalid_value (bad spp, malformed planes).
  std::uint64_t check(const Pass& pass, const std::string& name) const;

  // check() then accumulate. Strong guarantee: if it throws, the state is unchanged.
  AddResult add(const Pass& pass, const std::string& name);

  bool empty() const { return history_.empty(); }
  int width() const { return width_; }
  int height() const { return height_; }
  Layout layout() const { return layout_; }
  int passes() const { return static_cast<int>(history_.size()); }
  double total_spp() const;
  const std::vector<PassRecord>& history() const { return history_; }
  std::size_t dropped_samples() const;

  // Bytes of accumulated state per pixel for a layout (the documented memory cost).
  static std::size_t bytes_per_pixel(Layout layout, bool quarters = false);
  std::size_t state_bytes() const;
  // False for a state restored from format v1, which kept features only over all passes: such a
  // frame never gets feature halves (its earlier passes' split is lost).
  bool feature_halves() const { return feature_halves_; }
  // True when the state keeps the halves' sub-halves (AccumulatorOptions::quarters; a state
  // restored from format v1 or v2 has none).
  bool quarters() const { return quarters_; }

  FrameEstimate estimate(const EstimateOptions& options = {}) const;

  // Digest of the whole state (statistics and history): equal digests <=> unchanged state.
  // Frame state files before format 4 stored it made with HashKind::legacy.
  std::uint64_t state_digest(HashKind kind = HashKind::xxh3) const;

  // Binary form of the whole state (statistics and history), for persistence across restarts:
  // versioned magic header, host byte order (little-endian), trailing checksum. deserialize()
  // throws InputError (unreadable) on a corrupt, truncated or inconsistent blob.
  std::vector<std::uint8_t> serialize() const;
  static FrameAccumulator deserialize(std::span<const std::uint8_t> blob);
  // serialize()'s bytes handed to `sink` in order, in pieces (the planes straight from the
  // state, never copied whole: a 1080p state with features is ~600 MB), and their count
  // (serialized_size(), known first). `also`: a checksum to run over the same bytes in the same
  // pass over the pieces (the state file's).
  using ByteSink = std::function<void(std::span<const std::uint8_t>)>;
  std::size_t serialize_to(const ByteSink& sink, Checksum* also = nullptr) const;
  std::size_t serialized_size() const;

 private:
  // Writes everything before the trailing checksum with writer W (detail::Put in state_io.hpp).
  template <class W>
  void write_state(W& w) const;

  struct Moments {  // weighted Welford accumulators, planar [c * pixels + p]
    int channels = 0;
    std::vector<double> mean;
    std::vector<double> m2;
    void reset(int ch, std::size_t pixels);
  };
  struct Half {
    std::vector<double> weight;        // sum of spp per pixel
    std::vector<std::uint32_t> count;  // passes per pixel
    Moments colour;
    std::vector<double> albedo, normal, depth;  // feature means, planar (empty without the feature)
  };
  // Sub-half 1 of a half (its passes k with (k / 2) % 2 == 1): weight and means, planar.
  struct SubHalf {
    std::vector<double> weight, colour, albedo, normal, depth;
  };
  // M2 of a feature over all passes (its mean is the combination of the halves' means).
  struct FeatureSpread {
    int channels = 0;
    std::vector<double> m2;
  };

  void initialise(const Pass& pass);
  std::size_t pixels() const { return static_cast<std::size_t>(width_) * height_; }

  int width_ = 0;
  int height_ = 0;
  Layout layout_;
  std::array<Half, 2> halves_;
  FeatureSpread albedo_, normal_, depth_;
  bool feature_halves_ = true;
  bool quarters_ = false;
  std::array<SubHalf, 2> subs_;            // with quarters_: sub-half 1 of halves A and B
  std::vector<double> renderer_variance_;  // sum_k n_k^2 var_k, planar RGB
  std::vector<PassRecord> history_;
};

}  // namespace proden

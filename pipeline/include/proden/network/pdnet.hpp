// The learned mixing network (Firmino et al. 2022; docs/mixer_network.md):
// PdNet runs the CNN on one region as an independent image; NetworkMixer plugs it into the
// pipeline's tiles with a halo of its receptive radius (7), so tiles equal the whole image.
#pragma once

#include <tbb/enumerable_thread_specific.h>

#include <memory>
#include <string>
#include <vector>

#include "proden/mixer.hpp"
#include "proden/network/weights.hpp"
#include "proden/region.hpp"

namespace proden::network {

// One convolution, repacked for the kernel: weights [ky][kx][cin][cout_pad], bias [cout_pad],
// cout padded to a multiple of 16 with zeros.
struct ConvLayer {
  std::string name;
  int k = 0, cin = 0, cout = 0, cout_pad = 0;
  std::vector<float> weights, bias;
};

// Activation buffers PdNet::infer reuses between calls (one per thread, never shared).
struct InferScratch {
  std::vector<float> buffers[5];
};

class PdNet {
 public:
  static constexpr int kInputs = 18;
  static constexpr int kOutputs = 9;
  static constexpr int kRadius = 7;  // 2 (5x5) + 4 x 1 (residual 3x3) + 1 (output 3x3)

  // Checks the architecture (every tensor present once with the right shape, nothing extra).
  explicit PdNet(const WeightsFile& weights, std::string source = "weights");

  int width() const { return width_; }
  const std::string& source() const { return source_; }
  // Multiply-adds x 2 per pixel of the region the network runs on.
  double flops_per_pixel() const;

  // Runs the network over `region`, reading x, y, var, sure (3 planes each, views covering the
  // region), zero-padded at the region's border; writes alpha (3 planes) and, if given, the raw
  // 9-channel output. Buffers must cover `region`.
  // `scratch` (optional) keeps the buffers between calls.
  void infer(const View& x, const View& y, const View& var, const View& sure, const Rect& region,
             Buffer& alpha, Buffer* raw = nullptr, InferScratch* scratch = nullptr) const;

 private:
  std::string source_;
  int width_ = 0;
  ConvLayer conv_in_, res_[2][2], conv_out_;
};

// He-initialised weights of the architecture's shapes (biases N(0, 0.1 He)), deterministic in
// `seed`: untrained, for tests and benchmarks (inference time does not depend on the values).
WeightsFile random_weights(int width, unsigned seed);

// The 18 input channels at one pixel and channel c (docs/mixer_network.md).
void network_features(float x, float y, float var, float sure, float out[6]);

class NetworkMixer final : public Mixer {
 public:
  explicit NetworkMixer(std::shared_ptr<const PdNet> net) : net_(std::move(net)) {}
  std::string name() const override;
  int radius() const override { return PdNet::kRadius; }
  void mix(const MixInputs& in, const Rect& out, Buffer& alpha) const override;
  const PdNet& net() const { return *net_; }

 private:
  std::shared_ptr<const PdNet> net_;
  mutable tbb::enumerable_thread_specific<InferScratch> scratch_;  // per worker thread
};

}  // namespace proden::network

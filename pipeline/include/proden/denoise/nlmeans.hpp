// Built-in denoiser: feature-guided non-local means after Rousselle, Knaus & Zwicker 2012
// (variance-normalised patch distance) with Rousselle et al. 2013's cross-bilateral feature
// weights. y_p = sum_q w_pq x_q / sum_q w_pq: linear in x once the weights are fixed. It also
// returns the exact Jacobian diagonal dy_p/dx_p, weights' dependence on x included, so SURE needs
// no extra denoiser runs (exact away from the image border; within search+patch radius of it the
// replicated border copies' contribution to the weight derivative is ignored).
#pragma once

#include <string>
#include <vector>

#include "proden/denoise/denoiser.hpp"

namespace proden {

struct NlMeansParams {
  int search_radius = 5;   // r: (2r+1)^2 candidate pixels (Rousselle: 7; 5 is 1.9x faster)
  int patch_radius = 3;    // f: (2f+1)^2 patch
  float k = 1.0f;          // colour damping: larger blurs more (Rousselle: 0.45, see docs)
  float alpha = 1.0f;      // variance cancellation strength
  float epsilon = 1e-10f;  // guards the distance's denominator
  bool use_features = true;
  float k_feature = 0.6f;     // feature damping
  float tau = 1e-3f;          // floor of a feature's variance in its distance
  float depth_scale = 0.02f;  // relative depth difference that counts as one feature "sigma"
  // Kernel build: "" = the best for this CPU, or one of nlmeans_isas_available() (tests and
  // benchmarks force each; they agree within float rounding, docs/pipeline.md).
  std::string isa;
};

// The kernel builds this CPU can run: "baseline" (portable) first, then "avx2", "avx512".
std::vector<std::string> nlmeans_isas_available();

class NlMeansDenoiser final : public Denoiser {
 public:
  explicit NlMeansDenoiser(NlMeansParams params = {});
  std::string name() const override { return "nlmeans"; }
  int radius() const override { return params_.search_radius + params_.patch_radius; }
  bool has_derivative() const override { return true; }
  void denoise(const DenoiseInputs& in, const Rect& out, Buffer& y, Buffer* dydx) const override;
  const NlMeansParams& params() const { return params_; }
  std::string isa() const;  // the kernel build in use

 private:
  // One block of the output (denoise() splits `out` so that the kernel's working set fits L2).
  void denoise_block(const DenoiseInputs& in, const Rect& out, Buffer& y, Buffer* dydx) const;
  NlMeansParams params_;
  int build_ = 0;
};

}  // namespace proden

// NFOR: nonlinearly weighted first-order regression (Bitterli, Rousselle, Moon, Iglesias-Guitián,
// Adler, Mitchell, Jarosz, Novák, "Nonlinearly Weighted First-order Regression for Denoising Monte
// Carlo Renderings", CGF 35(4), 2016), written from the paper: feature prefiltering from the half
// buffers (§5.1), collaborative first-order regression with NL-means weights from the other half
// (§4, §5.2), per-pixel selection between bandwidths by half-buffer MSE estimates (§5.3) and a
// second pass (§5.4). A sequence of whole-image stages (whole_frame()), each parallel over tiles.
// docs/nfor.md has the parameters, the fallbacks (one pass, no features, v1 states) and the
// deviations from the paper.
#pragma once

#include <array>
#include <string>
#include <utility>
#include <vector>

#include "proden/denoise/denoiser.hpp"
#include "proden/image.hpp"

namespace proden {

struct NforParams {
  // §5.1 feature prefilter: NL-means of each feature half weighted on the other half.
  int prefilter_radius = 5;  // r: (2r+1)^2 candidates
  int prefilter_patch = 3;   // f: (2f+1)^2 patch
  float prefilter_k = 0.5f;  // NL-means damping k
  // §4, §5.2 collaborative first-order regression.
  int window_radius = 9;  // 19x19 regression window
  int patch_radius = 3;   // colour patch of the NL-means regression weights
  // §5.3 candidate NL-means bandwidths of the first pass.
  std::array<float, 2> bandwidths = {0.5f, 1.0f};
  // §5.3 smoothing of the MSE estimates and of the selection map: NL-means on the colour.
  int selection_radius = 1;
  int selection_patch = 3;
  float selection_k = 1.0f;
  // §5.4 second pass: the selected result regressed once more, weighted on the colour (docs/nfor.md
  // has its measured effect).
  bool second_pass = true;
  float second_pass_k = 1.0f;
  bool use_features = true;
  // Kernel build of the regression's vectorised loops: "" = the best for this CPU, else
  // "avx512", "avx2" or "baseline" (tests and benchmarks compare them).
  std::string isa;
};

// What a whole-frame NFOR run can report besides y (images over the full frame, empty unless
// asked for).
struct NforExtras {
  bool want_cross_validation = false;
  bool want_hat = false;
  bool want_stages = false;
  // Half-buffer cross-validation estimate of MSE(y) per pixel and channel (docs/nfor.md):
  // the second pass applied to x_A and x_B with y's weights gives F_A, F_B, and
  // a (F_A - x_B)^2 + b (F_B - x_A)^2 - a Var[x_B] - b Var[x_A] - a b (F_A - F_B)^2,
  // a = w_A / w, b = 1 - a. Empty without both halves.
  Image cross_validation;
  // The second pass's hat-matrix diagonal, dy_p/dx_p with its weights held fixed (3 equal
  // channels).
  Image hat;
  // With want_stages: the intermediate images (name, RGB), e.g. "pass1 k=0.5" (the mean of the
  // two halves' first-pass outputs), "selected" (§5.3), for evaluation.
  std::vector<std::pair<std::string, Image>> stages;
  // Which mode ran: "nfor" (halves), "single-buffer" (no halves: one regression, docs/nfor.md).
  std::string mode;
  bool prefiltered_features = false;  // §5.1 ran (the frame had feature halves)
  // Wall seconds per stage of the run.
  struct Timings {
    double load = 0, prefilter = 0, first_pass = 0, selection = 0, second_pass = 0, total = 0;
  } seconds;
};

class NforDenoiser final : public Denoiser {
 public:
  explicit NforDenoiser(NforParams params = {});
  std::string name() const override { return "nfor"; }
  // Footprint of one output pixel on the inputs (prefilter + two regression passes); the
  // pipeline needs no halo for it since NFOR runs whole-frame.
  int radius() const override;
  // The hat-matrix diagonal of the second pass (weights held fixed): SURE's divergence ignores
  // how the weights and the first pass depend on x (docs/nfor.md compares it with the truth).
  bool has_derivative() const override { return true; }
  bool whole_frame() const override { return true; }
  // Runs the whole frame and copies `out` (any region) into y (and dydx).
  void denoise(const DenoiseInputs& in, const Rect& out, Buffer& y, Buffer* dydx) const override;
  // The whole frame: y (3 channels) and, as asked in `extras`, its error estimates.
  Image run(const DenoiseInputs& in, NforExtras* extras = nullptr) const;
  const NforParams& params() const { return params_; }

 private:
  NforParams params_;
};

}  // namespace proden

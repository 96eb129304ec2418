// NFOR's stages (docs/nfor.md), internal to the pipeline library: whole-frame planes with a
// replicated border, NL-means weights of one tile for every offset (shared by the prefilter, the
// regressions and the selection), the NL-means filter, the collaborative regression and its
// vectorised per-chunk kernel (AVX-512, AVX2, portable; run-time dispatch).
#pragma once

#include <array>
#include <cstddef>
#include <string>
#include <vector>

#include "proden/region.hpp"

namespace proden::nfor {

constexpr int kFeatures = 7;                            // albedo RGB, normal XYZ, depth
constexpr int kColumns = 1 + kFeatures;                 // the design [1, f_q - f_p] (§4)
constexpr int kPacked = kColumns * (kColumns + 1) / 2;  // upper triangle of X^T W X
constexpr int kMaxData = 9;      // colour channels regressed at once: y, or y, x_A, x_B (§5.4, CV)
constexpr int kTileWidth = 32;   // tile of output pixels: a multiple of every ISA's lanes
constexpr int kTileHeight = 16;  // ... (the weights of a tile: (2r+1)^2 x 512 floats)

// NL-means distance (Rousselle, Knaus & Zwicker 2012, as NFOR §5.2 uses it):
// d^2 = mean over patch and channels of ((u_p - u_q)^2 - alpha (V_p + min(V_p, V_q))) /
// (k^2 (eps + V_p + V_q)), w = exp(-max(0, d^2)). (Rousselle et al. guard with eps + k^2 (..);
// with eps inside the k^2 factor the weights of two bandwidths differ by a power: w_k =
// w_K^((K/k)^2), so the first pass computes them once per guide, docs/nfor.md.)
constexpr float kVarianceCancellation = 1.0f;  // alpha
constexpr float kDistanceEpsilon = 1e-10f;     // eps
// Weights below this become 0 before they are raised to a power (no denormals).
constexpr float kWeightFlush = 1e-9f;
// Bandwidths that share one weight computation: w_k = w_K^(2^s) with s <= kMaxSquarings.
constexpr int kMaxSquarings = 2;

// Solve (§4): columns are equilibrated (unit diagonal), a column whose weighted spread is below
// kMinColumn x sum(w) is dropped, and so is one whose Schur complement (its variance left after
// the earlier columns) falls below kPivotTolerance: a truncated Cholesky factorisation that
// solves the least-squares problem on the remaining columns, never divides by ~0.
constexpr float kMinColumn = 1e-8f;
constexpr float kPivotTolerance = 1e-2f;

// Whole-frame layout shared by every plane of one run: width x height pixels padded to whole
// tiles, plus a border (replicated edge pixels) wide enough for every stage's radius + patch and
// the vector kernels' overrun past a tile row (kVectorMargin).
constexpr int kVectorMargin = 16;
struct Geometry {
  int width = 0, height = 0;
  int border = 0;
  int tiles_x = 0, tiles_y = 0;
  int stride = 0, rows = 0;
  Geometry() = default;
  Geometry(int w, int h, int border);
  std::size_t plane_size() const {
    return static_cast<std::size_t>(stride) * static_cast<std::size_t>(rows);
  }
  // Offset of pixel (x, y) (image coordinates, may lie in the border) from a plane's origin,
  // pixel (0, 0).
  std::ptrdiff_t offset(int x, int y) const { return static_cast<std::ptrdiff_t>(y) * stride + x; }
  Rect tile(int tx, int ty) const {
    return {tx * kTileWidth, ty * kTileHeight, (tx + 1) * kTileWidth, (ty + 1) * kTileHeight};
  }
};

// `channels` planes of a Geometry.
class Planes {
 public:
  Planes() = default;
  Planes(const Geometry& g, int channels, float fill = 0.0f);
  int channels() const { return channels_; }
  float* plane(int c) { return data_.data() + static_cast<std::size_t>(c) * size_; }
  const float* plane(int c) const { return data_.data() + static_cast<std::size_t>(c) * size_; }
  // Pointer to pixel (0, 0) of plane c: add Geometry::offset(x, y) to it.
  float* origin(int c) { return plane(c) + origin_; }
  const float* origin(int c) const { return plane(c) + origin_; }
  float& at(int x, int y, int c) { return origin(c)[static_cast<std::ptrdiff_t>(y) * stride_ + x]; }
  float at(int x, int y, int c) const {
    return origin(c)[static_cast<std::ptrdiff_t>(y) * stride_ + x];
  }

 private:
  int channels_ = 0;
  std::ptrdiff_t stride_ = 0, origin_ = 0;
  std::size_t size_ = 0;
  std::vector<float> data_;
};

// Copies a view's channels into planes (values clamped to +-limit, NaN -> 0), filling the border
// and the tile padding by replicating the nearest image pixel.
Planes load(const Geometry& g, const View& v, float limit);
// Fills the border and tile padding of every plane from the image pixels (replicate).
void replicate_border(const Geometry& g, Planes& p);
// The image part of planes [c0, c0 + 3) as an Image.
void store_rgb(const Geometry& g, const Planes& p, int c0, float* out_planes[3]);

// Mean of each pixel's (2r+1)^2 neighbourhood clipped to the image, per plane (separable), with
// the border replicated.
Planes box_mean(const Geometry& g, const Planes& p, int r);

// NL-means weights of one tile for every offset (dy, dx) in [-r, r]^2, row-major: weight of
// output pixel p (tile coordinates) and offset o at w[o * tile_area + p]. Zero where p or q = p + o
// lies outside the image, so padding never counts.
struct Kernels;
struct WeightSpec {
  const float* guide[3] = {nullptr, nullptr, nullptr};     // plane origins
  const float* variance[3] = {nullptr, nullptr, nullptr};  // Var of the guide
  int channels = 3;
  int radius = 0, patch = 0;
  float k = 1.0f;
  const Kernels* kernels = nullptr;
};

struct TileScratch {
  std::vector<float> weights;  // (2r+1)^2 x tile area
  std::vector<float> dist;     // patch-extended tile
  std::vector<float> hsum;
  std::vector<float> work;  // the kernel's per-chunk normal equations and coefficients
};

constexpr int kTileArea = kTileWidth * kTileHeight;
int offsets_of(int radius);
void tile_weights(const Geometry& g, const WeightSpec& s, const Rect& tile, TileScratch& scratch);

// NL-means filter over the whole frame: out_c(p) = sum_q w_pq data_c(q) / sum_q w_pq with the
// weights of `spec`, for every channel of `data` (out has as many channels).
void nlmeans_filter(const Geometry& g, const WeightSpec& spec, const Planes& data, Planes& out);

// Collaborative first-order regression (§4, §5.2): for every pixel p, weighted least squares of
// the `data` channels on the design [1, f_q - f_p] over the (2r+1)^2 window with the weights of
// `spec`; every q of the window receives the prediction of p's fit, weighted by w_pq, and the
// output is the weighted mean of the predictions that cover it. With hats[i] (nullable), also
// run i's hat diagonal dy_q/dx_q (weights fixed) in one plane.
struct RegressionSpec {
  WeightSpec weights;
  const float* features[kFeatures] = {};  // plane origins (a zero plane where a feature is absent)
  const float* data[kMaxData] = {};       // plane origins
  int data_channels = 3;                  // 3 or 9
};
// One regression per entry of `squarings` (weights.k's weights raised to the power 2^s: the
// bandwidth k / 2^(s/2)), sharing the weight computation; outs[i] receives entry i.
void regression(const Geometry& g, const RegressionSpec& spec, const std::vector<int>& squarings,
                const std::vector<Planes*>& outs, const std::vector<Planes*>& hats = {});
// How many squarings turn the weights of bandwidth `from` into those of `to` (-1: none do).
int squarings_between(float from, float to);

// §5.1 feature prefilter. Features are kFeatures planes: albedo RGB, normal XYZ, depth (zero
// planes where the frame lacks one, `present` = {albedo, normal, depth}). Each present group's
// half is NL-means filtered with weights from the other half (whose variance is estimated from
// the halves, (A - B)^2 / 2 smoothed over 3x3); the result is the mean of the two filtered halves.
struct PrefilterSpec {
  int radius = 5, patch = 3;
  float k = 0.5f;
  const Kernels* kernels = nullptr;
};
Planes prefilter_features(const Geometry& g, const Planes& half_a, const Planes& half_b,
                          const std::array<bool, 3>& present, const PrefilterSpec& spec);

// §5.3 selection between the first pass's bandwidths: per bandwidth i, filtered halves fa[i]
// (x_A regressed with B's weights) and fb[i]; a per-pixel MSE estimate from the halves,
// ((fa - x_B)^2 - Var[x_B] + (fb - x_A)^2 - Var[x_A]) / 2 averaged over channels, smoothed with
// `smoothing`'s NL-means weights; the bandwidth with the lowest estimate wins each pixel, and the
// winners' map, smoothed with the same weights, blends the candidates into out_a and out_b
// (`shares`, one plane per bandwidth, receives the blend weights).
void select_bandwidths(const Geometry& g, const std::vector<Planes>& fa,
                       const std::vector<Planes>& fb, const Planes& xa, const Planes& xb,
                       const Planes& va, const Planes& vb, const WeightSpec& smoothing,
                       Planes& out_a, Planes& out_b, Planes& shares);

// The kernel of one chunk of lanes consecutive output pixels: normal equations over every
// offset, the truncated-Cholesky solve, and the scatter of the predictions (with the hat
// diagonal when hat != nullptr). Pointers are at the chunk's first pixel p; q = p + doff[o].
struct ChunkArgs {
  const float* w = nullptr;  // w[o * w_stride + lane]
  std::ptrdiff_t w_stride = 0;
  const std::ptrdiff_t* doff = nullptr;
  int offsets = 0;
  const float* features[kFeatures] = {};
  const float* data[kMaxData] = {};
  int data_channels = 3;
  float* num[kMaxData] = {};
  float* den = nullptr;
  float* hat = nullptr;
  float* scratch = nullptr;  // >= chunk_scratch_floats()
  int squarings = 0;         // w^(2^squarings) (<= kMaxSquarings)
};
std::size_t chunk_scratch_floats();

// The NL-means weights of one tile for one offset: the distance term over the patch-extended tile
// (kExtStride floats per row), its box sum over the patch, exp(-max(0, d^2)) into w (tile rows).
constexpr int kMaxPatch = 8;
constexpr int kExtStride = kTileWidth + 2 * kMaxPatch;
struct WeightArgs {
  const float* guide[3] = {};     // at the tile's patch-extended origin (x0 - f, y0 - f)
  const float* variance[3] = {};  // likewise
  int channels = 3;
  std::ptrdiff_t stride = 0, doff = 0;
  int patch = 0;
  float scale = 1.0f;     // 1 / (k^2 channels (2f+1)^2)
  float* dist = nullptr;  // (kTileHeight + 2f) x kExtStride
  float* hsum = nullptr;  // (kTileHeight + 2f) x kTileWidth
  float* w = nullptr;     // kTileHeight x kTileWidth
};

// One kernel build: AVX-512, AVX2+FMA or the portable baseline.
struct Kernels {
  const char* name;
  int lanes;
  void (*regress)(const ChunkArgs&);
  void (*normal_equations)(const ChunkArgs&, float* out);
  void (*weights)(const WeightArgs&);
};
// Builds this CPU can run ("baseline" always) and the one "" selects (the best); throws
// std::invalid_argument for an unknown or unavailable build.
std::vector<std::string> isas_available();
const Kernels& kernels(const std::string& isa);

// For tests: the normal equations of one chunk (packed X^T W X then X^T W Y, per lane:
// out[e * lanes + l]) in double from plain loops.
void normal_equations_reference(const ChunkArgs& a, int lanes, double* out);

}  // namespace proden::nfor

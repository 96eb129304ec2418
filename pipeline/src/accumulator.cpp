#include "proden/accumulator.hpp"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cfloat>
#include <cmath>

#include "parallel.hpp"
#include "proden/error.hpp"
#include "proden/hash.hpp"

namespace proden {
namespace {

constexpr std::size_t kGrain = 4096;  // pixels per parallel task
constexpr std::size_t kBlock = 512;   // pixels per block of add()'s plane-by-plane updates
constexpr double kFeatureInf = 1e10;  // what +-Inf features become (Cycles' background depth)

float to_float(double v) {
  return static_cast<float>(
      std::clamp(v, -static_cast<double>(FLT_MAX), static_cast<double>(FLT_MAX)));
}

double sanitize_feature(float v, std::size_t& sanitized) {
  if (std::isfinite(v)) return v;
  ++sanitized;
  if (std::isnan(v)) return 0.0;
  return v > 0 ? kFeatureInf : -kFeatureInf;
}

bool is_constant(const Image& img) {
  for (int c = 0; c < img.channels(); ++c) {
    auto p = img.plane(c);
    if (std::any_of(p.begin(), p.end(), [&](float v) {
          return std::bit_cast<std::uint32_t>(v) != std::bit_cast<std::uint32_t>(p[0]);
        })) {
      return false;
    }
  }
  return true;
}

std::uint64_t fingerprint(const Pass& pass) {
  return hash_span(pass.colour.data(), 0x70726f64);
}

void check_plane(const Image& img, const Image& colour, int channels, const char* what,
                 const std::string& name) {
  if (img.empty()) return;
  if (img.channels() != channels || !img.same_size(colour)) {
    throw InputError(InputErrorKind::invalid_value, name,
                     std::string(what) + " is " + img.to_string() + ", expected " +
                         std::to_string(colour.width()) + "x" + std::to_string(colour.height()) +
                         "x" + std::to_string(channels));
  }
}

}  // namespace

void FrameAccumulator::Moments::reset(int ch, std::size_t pixels) {
  channels = ch;
  mean.assign(pixels * static_cast<std::size_t>(ch), 0.0);
  m2.assign(pixels * static_cast<std::size_t>(ch), 0.0);
}

double FrameAccumulator::total_spp() const {
  double s = 0.0;
  for (const auto& r : history_) s += r.spp;
  return s;
}

std::size_t FrameAccumulator::dropped_samples() const {
  std::size_t s = 0;
  for (const auto& r : history_) s += r.dropped_pixels;
  return s;
}

std::size_t FrameAccumulator::bytes_per_pixel(Layout layout, bool quarters) {
  // Two halves: weight (double), pass count (uint32), RGB mean and M2 (double). Features: a mean
  // per half and one M2 (double) per channel. Quarters: per half, sub-half 1's weight and its
  // colour and feature means (double).
  const std::size_t features =
      (layout.albedo ? 3 : 0) + (layout.normal ? 3 : 0) + (layout.depth ? 1 : 0);
  std::size_t b = 2 * (sizeof(double) + sizeof(std::uint32_t) + 3 * 2 * sizeof(double));
  b += features * 3 * sizeof(double);
  if (layout.variance) b += 3 * sizeof(double);
  if (quarters) b += 2 * (1 + 3 + features) * sizeof(double);
  return b;
}

std::size_t FrameAccumulator::state_bytes() const {
  return bytes_per_pixel(layout_, quarters_) * pixels();
}

std::uint64_t FrameAccumulator::check(const Pass& pass, const std::string& name) const {
  if (!std::isfinite(pass.spp) || pass.spp <= 0.0) {
    throw InputError(
        InputErrorKind::invalid_value, name,
        "samples per pixel must be a positive number, got " + std::to_string(pass.spp));
  }
  if (pass.colour.channels() != 3 || pass.colour.empty()) {
    throw InputError(InputErrorKind::missing_channels, name,
                     "colour must be a non-empty RGB image, got " + pass.colour.to_string());
  }
  check_plane(pass.albedo, pass.colour, 3, "albedo", name);
  check_plane(pass.normal, pass.colour, 3, "normal", name);
  check_plane(pass.depth, pass.colour, 1, "depth", name);
  check_plane(pass.variance, pass.colour, 3, "variance", name);
  // Hashed once per pass (a serial hash of the whole colour plane: ~25 ms at 1080p).
  const std::uint64_t fp = fingerprint(pass);
  if (empty()) return fp;

  if (pass.width() != width_ || pass.height() != height_) {
    throw InputError(InputErrorKind::size_mismatch, name,
                     "resolution " + std::to_string(pass.width()) + "x" +
                         std::to_string(pass.height()) + " differs from the frame's " +
                         std::to_string(width_) + "x" + std::to_string(height_));
  }
  if (pass.layout() != layout_) {
    throw InputError(InputErrorKind::layout_mismatch, name,
                     "carries " + pass.layout().to_string() + " but the frame's passes carry " +
                         layout_.to_string());
  }
  // A bit-identical pass repeats a seed: accepting it would shrink Var[x] and lie. A constant
  // image (all black, a flat background) is legitimately identical between seeds, so it passes.
  for (const auto& r : history_) {
    if (r.fingerprint == fp && !is_constant(pass.colour)) {
      throw InputError(
          InputErrorKind::duplicate, name,
          "identical to the already accumulated pass '" + r.name + "' (same seed rendered twice?)");
    }
  }
  return fp;
}

void FrameAccumulator::initialise(const Pass& pass) {
  // Build into locals first so an allocation failure leaves *this untouched.
  const std::size_t n = static_cast<std::size_t>(pass.width()) * pass.height();
  const Layout layout = pass.layout();
  std::array<Half, 2> halves;
  for (auto& h : halves) {
    h.weight.assign(n, 0.0);
    h.count.assign(n, 0);
    h.colour.reset(3, n);
    if (layout.albedo) h.albedo.assign(3 * n, 0.0);
    if (layout.normal) h.normal.assign(3 * n, 0.0);
    if (layout.depth) h.depth.assign(n, 0.0);
  }
  FeatureSpread albedo, normal, depth;
  if (layout.albedo) albedo = {3, std::vector<double>(3 * n, 0.0)};
  if (layout.normal) normal = {3, std::vector<double>(3 * n, 0.0)};
  if (layout.depth) depth = {1, std::vector<double>(n, 0.0)};
  std::vector<double> rv;
  if (layout.variance) rv.assign(3 * n, 0.0);
  std::array<SubHalf, 2> subs;
  if (quarters_) {
    for (auto& sh : subs) {
      sh.weight.assign(n, 0.0);
      sh.colour.assign(3 * n, 0.0);
      if (layout.albedo) sh.albedo.assign(3 * n, 0.0);
      if (layout.normal) sh.normal.assign(3 * n, 0.0);
      if (layout.depth) sh.depth.assign(n, 0.0);
    }
  }

  width_ = pass.width();
  height_ = pass.height();
  layout_ = layout;
  halves_ = std::move(halves);
  albedo_ = std::move(albedo);
  normal_ = std::move(normal);
  depth_ = std::move(depth);
  feature_halves_ = true;
  subs_ = std::move(subs);
  renderer_variance_ = std::move(rv);
}

AddResult FrameAccumulator::add(const Pass& pass, const std::string& name) {
  PassRecord record;
  record.fingerprint = check(pass, name);
  record.name = name;
  record.spp = pass.spp;
  record.half = passes() % 2;
  history_.reserve(history_.size() + 1);  // the only allocation that could fail after mutation
  if (empty()) initialise(pass);

  const std::size_t n = pixels();
  Half& half = halves_[static_cast<std::size_t>(record.half)];
  const Half& other = halves_[static_cast<std::size_t>(1 - record.half)];
  const Half& a = halves_[0];
  const Half& b = halves_[1];
  // Sub-half 1 of the pass's half, when the state keeps quarters and the pass belongs to it.
  SubHalf* sub = quarters_ && (passes() / 2) % 2 == 1
                     ? &subs_[static_cast<std::size_t>(record.half)]
                     : nullptr;
  const double w = pass.spp;
  tbb::combinable<std::size_t> dropped_count([] { return std::size_t{0}; });
  tbb::combinable<std::size_t> sanitized_count([] { return std::size_t{0}; });

  // Each chunk goes in blocks of kBlock pixels: first the per-pixel terms every plane shares
  // (whether the pass's colour is usable there, the weights before this pass and the update
  // factors), then each plane of the state on its own, so an inner loop streams a few planes
  // instead of all ~40 at once (the state is planar). Every element gets exactly the arithmetic
  // it got per pixel, in the same order: the state is the same to the bit.
  parallel_chunks(n, kGrain, [&](std::size_t begin, std::size_t end) {
    std::size_t dropped = 0;
    std::size_t sanitized = 0;
    std::array<unsigned char, kBlock> ok{};
    std::array<double, kBlock> wa{}, wb{}, w_old{}, f_total{}, f_half{}, f_sub{};
    for (std::size_t b0 = begin; b0 < end; b0 += kBlock) {
      const std::size_t m = std::min(end - b0, kBlock);
      for (std::size_t j = 0; j < m; ++j) {
        const std::size_t p = b0 + j;
        bool good = true;
        for (int c = 0; c < 3; ++c) good = good && std::isfinite(pass.colour.plane(c)[p]);
        if (layout_.variance) {
          for (int c = 0; c < 3; ++c) {
            const float v = pass.variance.plane(c)[p];
            good = good && std::isfinite(v) && v >= 0.0f;
          }
        }
        ok[j] = good ? 1 : 0;
        if (!good) {
          ++dropped;
          continue;
        }
        wa[j] = a.weight[p];
        wb[j] = b.weight[p];
        w_old[j] = half.weight[p] + other.weight[p];
        const double w_total = w_old[j] + w;
        const double w_half = half.weight[p] + w;
        f_total[j] = w / w_total;
        f_half[j] = w / w_half;
        if (sub) f_sub[j] = w / (sub->weight[p] + w);
      }
      // Features: the half's Welford mean, and M2 over all passes around the full mean (the
      // combination of the halves' means before this pass).
      auto feature = [&](FeatureSpread& sp, std::vector<double> Half::*mean, const Image& img) {
        for (int c = 0; c < sp.channels; ++c) {
          const std::size_t at = static_cast<std::size_t>(c) * n + b0;
          const float* x_in = img.plane(c).data() + b0;
          const double* am = (a.*mean).data() + at;
          const double* bm = (b.*mean).data() + at;
          double* hm = (half.*mean).data() + at;
          double* m2 = sp.m2.data() + at;
          for (std::size_t j = 0; j < m; ++j) {
            if (!ok[j]) continue;
            const double x = sanitize_feature(x_in[j], sanitized);
            const double full = w_old[j] > 0.0 ? (wa[j] * am[j] + wb[j] * bm[j]) / w_old[j] : 0.0;
            const double delta = x - full;
            m2[j] += w * delta * (x - (full + delta * f_total[j]));
            hm[j] += (x - hm[j]) * f_half[j];
          }
        }
      };
      if (layout_.albedo) feature(albedo_, &Half::albedo, pass.albedo);
      if (layout_.normal) feature(normal_, &Half::normal, pass.normal);
      if (layout_.depth) feature(depth_, &Half::depth, pass.depth);
      if (sub) {  // the sub-half's weighted means (features sanitised as above, not recounted)
        auto mean = [&](std::vector<double>& mv, const Image& img, int channels, bool is_feature) {
          for (int c = 0; c < channels; ++c) {
            const std::size_t at = static_cast<std::size_t>(c) * n + b0;
            const float* x_in = img.plane(c).data() + b0;
            double* sm = mv.data() + at;
            for (std::size_t j = 0; j < m; ++j) {
              if (!ok[j]) continue;
              std::size_t ignored = 0;
              const double x =
                  is_feature ? sanitize_feature(x_in[j], ignored) : static_cast<double>(x_in[j]);
              sm[j] += (x - sm[j]) * f_sub[j];
            }
          }
        };
        mean(sub->colour, pass.colour, 3, false);
        if (layout_.albedo) mean(sub->albedo, pass.albedo, 3, true);
        if (layout_.normal) mean(sub->normal, pass.normal, 3, true);
        if (layout_.depth) mean(sub->depth, pass.depth, 1, true);
        for (std::size_t j = 0; j < m; ++j) {
          if (ok[j]) sub->weight[b0 + j] += w;
        }
      }
      // The colour's weighted Welford mean and M2 in the pass's half.
      for (int c = 0; c < 3; ++c) {
        const std::size_t at = static_cast<std::size_t>(c) * n + b0;
        const float* x_in = pass.colour.plane(c).data() + b0;
        double* mean = half.colour.mean.data() + at;
        double* m2 = half.colour.m2.data() + at;
        for (std::size_t j = 0; j < m; ++j) {
          if (!ok[j]) continue;
          const double x = x_in[j];
          const double delta = x - mean[j];
          mean[j] += delta * f_half[j];
          m2[j] += w * delta * (x - mean[j]);
        }
      }
      for (std::size_t j = 0; j < m; ++j) {
        if (!ok[j]) continue;
        half.weight[b0 + j] += w;
        half.count[b0 + j] += 1;
      }
      if (layout_.variance) {
        for (int c = 0; c < 3; ++c) {
          const std::size_t at = static_cast<std::size_t>(c) * n + b0;
          const float* v_in = pass.variance.plane(c).data() + b0;
          double* rv = renderer_variance_.data() + at;
          for (std::size_t j = 0; j < m; ++j) {
            if (ok[j]) rv[j] += w * w * static_cast<double>(v_in[j]);
          }
        }
      }
    }
    dropped_count.local() += dropped;
    sanitized_count.local() += sanitized;
  });

  record.dropped_pixels = dropped_count.combine(std::plus<>());
  record.sanitized_features = sanitized_count.combine(std::plus<>());
  history_.push_back(record);
  return {passes() - 1, record.half, record.dropped_pixels, record.sanitized_features};
}

FrameEstimate FrameAccumulator::estimate(const EstimateOptions& options) const {
  FrameEstimate e;
  if (empty()) return e;
  const std::size_t n = pixels();
  // Every plane below is written at every element (holes and single-pass pixels by the serial
  // fallbacks after the parallel pass), so none is zero-filled first: that serial fill was 20-40 %
  // of the estimate's time on two threads (bench/RESULTS.md, *The estimate's planes*).
  const Half& a = halves_[0];
  const Half& b = halves_[1];
  e.mean = Image(width_, height_, 3, Image::uninitialized);
  e.variance = Image(width_, height_, 3, Image::uninitialized);
  e.passes = Image(width_, height_, 1, Image::uninitialized);
  // The halves are written in the same pass over the state as the frame (one read of it); the
  // quarters, rarer, read sigma^2 N per element back from `per_sample_var`.
  const bool halves = options.halves && passes() >= 2;
  const bool quarters = halves && options.quarters && quarters_ && passes() >= 4;
  if (halves) {
    for (std::size_t h = 0; h < 2; ++h) {
      e.half_mean[h] = Image(width_, height_, 3, Image::uninitialized);
      e.half_variance[h] = Image(width_, height_, 3, Image::uninitialized);
    }
  }
  std::vector<unsigned char> spatial(n, 0), hole(n, 0);
  std::vector<double> per_sample_var(quarters ? 3 * n : 0);  // sigma^2 N

  // Element i of each output plane, set once per pixel and channel. For the halves: a half
  // without a sample at the pixel (non-finite drops) falls back to the frame's estimate.
  std::array<float*, 3> mean_c{}, var_c{};
  std::array<std::array<float*, 3>, 2> half_mean_c{}, half_var_c{};
  for (int c = 0; c < 3; ++c) {
    mean_c[c] = e.mean.plane(c).data();
    var_c[c] = e.variance.plane(c).data();
    for (std::size_t h = 0; halves && h < 2; ++h) {
      half_mean_c[h][c] = e.half_mean[h].plane(c).data();
      half_var_c[h][c] = e.half_variance[h].plane(c).data();
    }
  }
  float* const passes_p = e.passes.plane(0).data();
  // Pixel p, channel c, once its (mean, var) are final: the quarters' sigma^2 N and the halves.
  const auto finish = [&](std::size_t p, int c, double psv) {
    const std::size_t i = static_cast<std::size_t>(c) * n + p;
    if (quarters) per_sample_var[i] = psv;
    if (!halves) return;
    for (std::size_t h = 0; h < 2; ++h) {
      const double hw = halves_[h].weight[p];
      const bool has = hw > 0.0;
      half_mean_c[h][c][p] = has ? to_float(halves_[h].colour.mean[i]) : mean_c[c][p];
      half_var_c[h][c][p] = has ? to_float(psv / hw) : var_c[c][p];
    }
  };

  parallel_chunks(n, kGrain, [&](std::size_t begin, std::size_t end) {
    for (std::size_t p = begin; p < end; ++p) {
      const double wa = a.weight[p], wb = b.weight[p], w = wa + wb;
      const std::uint32_t k = a.count[p] + b.count[p];
      passes_p[p] = static_cast<float>(k);
      if (w <= 0.0) {
        hole[p] = 1;
        continue;
      }
      for (int c = 0; c < 3; ++c) {
        const std::size_t i = static_cast<std::size_t>(c) * n + p;
        const double ma = a.colour.mean[i], mb = b.colour.mean[i];
        const double mean = (wa * ma + wb * mb) / w;
        const double d = ma - mb;
        const double m2 = a.colour.m2[i] + b.colour.m2[i] + d * d * (wa * wb / w);
        double var = 0.0;
        if (layout_.variance) {
          var = renderer_variance_[i] / (w * w);
        } else if (k >= 2) {
          var = std::max(m2, 0.0) / (k - 1) / w;
        } else {
          spatial[p] = 1;  // its variance, and so its halves, come from the spatial pass below
        }
        mean_c[c][p] = to_float(mean);
        var_c[c][p] = to_float(var);
        if (!spatial[p]) finish(p, c, var * w);
      }
    }
  });

  // Holes (every pass dropped this pixel): fill the mean from valid neighbours, then treat the
  // pixel like a single-pass one. Rare, so serial.
  for (int y = 0; y < height_; ++y) {
    for (int x = 0; x < width_; ++x) {
      const std::size_t p = static_cast<std::size_t>(y) * width_ + x;
      if (!hole[p]) continue;
      ++e.hole_pixels;
      spatial[p] = 1;
      for (int c = 0; c < 3; ++c) {
        double sum = 0.0;
        int cnt = 0;
        for (int dy = -1; dy <= 1; ++dy) {
          for (int dx = -1; dx <= 1; ++dx) {
            const int xx = x + dx, yy = y + dy;
            if (xx < 0 || yy < 0 || xx >= width_ || yy >= height_) continue;
            const std::size_t q = static_cast<std::size_t>(yy) * width_ + xx;
            if (hole[q]) continue;
            sum += e.mean.plane(c)[q];
            ++cnt;
          }
        }
        e.mean.plane(c)[p] = cnt > 0 ? to_float(sum / cnt) : 0.0f;
      }
    }
  }

  // Spatial fallback: the unbiased spread of the 3x3 neighbourhood of the mean estimates the
  // variance of one pixel's value (edges and texture make it an over-estimate: conservative).
  for (int y = 0; y < height_; ++y) {
    for (int x = 0; x < width_; ++x) {
      const std::size_t p = static_cast<std::size_t>(y) * width_ + x;
      if (!spatial[p]) continue;
      ++e.spatial_pixels;
      const double w = a.weight[p] + b.weight[p];
      for (int c = 0; c < 3; ++c) {
        double s1 = 0.0, s2 = 0.0;
        int cnt = 0;
        for (int dy = -1; dy <= 1; ++dy) {
          for (int dx = -1; dx <= 1; ++dx) {
            const int xx = x + dx, yy = y + dy;
            if (xx < 0 || yy < 0 || xx >= width_ || yy >= height_) continue;
            const double v = e.mean.at(xx, yy, c);
            s1 += v;
            s2 += v * v;
            ++cnt;
          }
        }
        const double m = e.mean.plane(c)[p];
        double var = m * m;  // a lone pixel (1x1 frame): assume 100 % relative error
        if (cnt >= 2) var = std::max(0.0, (s2 - s1 * s1 / cnt) / (cnt - 1));
        e.variance.plane(c)[p] = to_float(var);
        finish(p, c, var * (w > 0.0 ? w : 1.0));
      }
    }
  }

  if (layout_.variance) {
    e.variance_source = VarianceSource::renderer;
  } else if (e.spatial_pixels == n) {
    e.variance_source = VarianceSource::spatial;
  } else {
    e.variance_source = VarianceSource::between_passes;
  }

  if (options.features) {
    const bool feature_halves = halves && feature_halves_;
    auto features = [&](const FeatureSpread& s, std::vector<double> Half::*mean_of, Image& mean,
                        Image& var, std::array<Image, 2>& half_means) {
      if (s.channels == 0) return;
      mean = Image(width_, height_, s.channels, Image::uninitialized);
      var = Image(width_, height_, s.channels, Image::uninitialized);
      if (feature_halves) {
        for (auto& h : half_means) h = Image(width_, height_, s.channels, Image::uninitialized);
      }
      std::array<float*, 3> mean_f{}, var_f{}, half_a{}, half_b{};
      for (int c = 0; c < s.channels; ++c) {
        mean_f[c] = mean.plane(c).data();
        var_f[c] = var.plane(c).data();
        if (feature_halves) {
          half_a[c] = half_means[0].plane(c).data();
          half_b[c] = half_means[1].plane(c).data();
        }
      }
      const std::vector<double>& ma = a.*mean_of;
      const std::vector<double>& mb = b.*mean_of;
      parallel_chunks(n, kGrain, [&](std::size_t begin, std::size_t end) {
        for (std::size_t p = begin; p < end; ++p) {
          const double wa = a.weight[p], wb = b.weight[p], w = wa + wb;
          const std::uint32_t k = a.count[p] + b.count[p];
          for (int c = 0; c < s.channels; ++c) {
            const std::size_t i = static_cast<std::size_t>(c) * n + p;
            const double m = w > 0.0 ? (wa * ma[i] + wb * mb[i]) / w : 0.0;
            mean_f[c][p] = to_float(m);
            var_f[c][p] = k >= 2 ? to_float(std::max(s.m2[i], 0.0) / (k - 1) / w) : 0.0f;
            if (feature_halves) {  // a half without a sample here falls back to the full mean
              half_a[c][p] = to_float(wa > 0.0 ? ma[i] : m);
              half_b[c][p] = to_float(wb > 0.0 ? mb[i] : m);
            }
          }
        }
      });
    };
    features(albedo_, &Half::albedo, e.albedo, e.albedo_variance, e.half_albedo);
    features(normal_, &Half::normal, e.normal, e.normal_variance, e.half_normal);
    features(depth_, &Half::depth, e.depth, e.depth_variance, e.half_depth);
  }

  // Quarters: sub-half 1 is kept, sub-half 0 is the half less it. A quarter without a sample at
  // a pixel (non-finite drops) falls back to its half there, as a half falls back to the frame.
  if (quarters) {
    // Plane c of quarter 2h+s of a quantity with `channels` channels: the half's mean `hm`, the
    // sub-half's `sm`, the half's published image `fallback` where the quarter is empty.
    auto quarter = [&](std::size_t h, int s, const std::vector<double>& hm,
                       const std::vector<double>& sm, int channels, const Image& fallback,
                       Image& out) {
      out = Image(width_, height_, channels, Image::uninitialized);
      const Half& half = halves_[h];
      const SubHalf& sub = subs_[h];
      parallel_chunks(n, kGrain, [&](std::size_t begin, std::size_t end) {
        for (std::size_t p = begin; p < end; ++p) {
          const double w1 = sub.weight[p], w0 = half.weight[p] - w1;
          const double wq = s == 1 ? w1 : w0;
          for (int c = 0; c < channels; ++c) {
            const std::size_t i = static_cast<std::size_t>(c) * n + p;
            double m = fallback.plane(c)[p];
            if (wq > 0.0) m = s == 1 ? sm[i] : (half.weight[p] * hm[i] - w1 * sm[i]) / w0;
            out.plane(c)[p] = std::isfinite(m) ? to_float(m) : fallback.plane(c)[p];
          }
        }
      });
    };
    for (std::size_t h = 0; h < 2; ++h) {
      for (int s = 0; s < 2; ++s) {
        const std::size_t q = 2 * h + static_cast<std::size_t>(s);
        quarter(h, s, halves_[h].colour.mean, subs_[h].colour, 3, e.half_mean[h],
                e.quarter_mean[q]);
        e.quarter_variance[q] = Image(width_, height_, 3, Image::uninitialized);
        parallel_chunks(n, kGrain, [&](std::size_t begin, std::size_t end) {
          for (std::size_t p = begin; p < end; ++p) {
            const double w1 = subs_[h].weight[p], w0 = halves_[h].weight[p] - w1;
            const double wq = s == 1 ? w1 : w0;
            for (int c = 0; c < 3; ++c) {
              const std::size_t i = static_cast<std::size_t>(c) * n + p;
              e.quarter_variance[q].plane(c)[p] =
                  wq > 0.0 ? to_float(per_sample_var[i] / wq) : e.half_variance[h].plane(c)[p];
            }
          }
        });
        if (!e.half_albedo[h].empty()) {
          quarter(h, s, halves_[h].albedo, subs_[h].albedo, 3, e.half_albedo[h],
                  e.quarter_albedo[q]);
        }
        if (!e.half_normal[h].empty()) {
          quarter(h, s, halves_[h].normal, subs_[h].normal, 3, e.half_normal[h],
                  e.quarter_normal[q]);
        }
        if (!e.half_depth[h].empty()) {
          quarter(h, s, halves_[h].depth, subs_[h].depth, 1, e.half_depth[h], e.quarter_depth[q]);
        }
      }
    }
  }
  return e;
}

std::uint64_t FrameAccumulator::state_digest(HashKind kind) const {
  // Each value's bytes, chained through the seed.
  const auto chain = [kind]<class T>(std::span<const T> v, std::uint64_t seed) {
    return hash_with(kind, {reinterpret_cast<const unsigned char*>(v.data()), v.size_bytes()},
                     seed);
  };
  std::uint64_t h = chain(std::span<const int>(&width_, 1), 1);
  h = chain(std::span<const int>(&height_, 1), h);
  auto add = [&h, &chain](const auto& v) { h = chain(std::span(v.data(), v.size()), h); };
  for (const auto& half : halves_) {
    add(half.weight);
    add(half.count);
    add(half.colour.mean);
    add(half.colour.m2);
    add(half.albedo);
    add(half.normal);
    add(half.depth);
  }
  for (const FeatureSpread* s : {&albedo_, &normal_, &depth_}) add(s->m2);
  const int feature_halves = feature_halves_ ? 1 : 0;
  h = chain(std::span<const int>(&feature_halves, 1), h);
  if (quarters_) {  // states without quarters keep the digests they had before quarters existed
    h = chain(std::span<const int>(&feature_halves, 1), h ^ 0x71);
    for (const auto& sh : subs_) {
      add(sh.weight);
      add(sh.colour);
      add(sh.albedo);
      add(sh.normal);
      add(sh.depth);
    }
  }
  add(renderer_variance_);
  for (const auto& r : history_) {
    add(r.name);
    const double fields[] = {r.spp, static_cast<double>(r.half), static_cast<double>(r.fingerprint),
                             static_cast<double>(r.dropped_pixels)};
    h = chain(std::span<const double>(fields), h);
  }
  return h;
}

}  // namespace proden

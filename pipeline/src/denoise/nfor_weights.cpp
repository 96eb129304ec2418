// NFOR's whole-frame planes and its NL-means weights (§5.2: Rousselle, Knaus & Zwicker 2012's
// variance-cancelling patch distance), computed once per tile and offset and shared by the
// feature prefilter (§5.1), the regressions (§4, §5.2) and the selection's smoothing (§5.3).
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>

#include "nfor_internal.hpp"

namespace proden::nfor {
namespace {

int round_up(int v, int m) {
  return (v + m - 1) / m * m;
}

}  // namespace

Geometry::Geometry(int w, int h, int b) : width(w), height(h), border(b) {
  tiles_x = (w + kTileWidth - 1) / kTileWidth;
  tiles_y = (h + kTileHeight - 1) / kTileHeight;
  stride = round_up(tiles_x * kTileWidth + 2 * b, 16);
  rows = tiles_y * kTileHeight + 2 * b;
}

Planes::Planes(const Geometry& g, int channels, float fill)
    : channels_(channels),
      stride_(g.stride),
      origin_(static_cast<std::ptrdiff_t>(g.border) * g.stride + g.border),
      size_(g.plane_size()),
      data_(g.plane_size() * static_cast<std::size_t>(channels), fill) {}

void replicate_border(const Geometry& g, Planes& p) {
  const int x_lo = -g.border, x_hi = g.stride - g.border;  // columns [x_lo, x_hi)
  const int y_lo = -g.border, y_hi = g.rows - g.border;
  tbb::parallel_for(0, p.channels(), [&](int c) {
    float* o = p.origin(c);
    for (int y = 0; y < g.height; ++y) {
      float* row = o + g.offset(0, y);
      std::fill(row + x_lo, row, row[0]);
      std::fill(row + g.width, row + x_hi, row[g.width - 1]);
    }
    for (int y = y_lo; y < y_hi; ++y) {
      if (y >= 0 && y < g.height) continue;
      const int sy = std::clamp(y, 0, g.height - 1);
      std::copy(o + g.offset(x_lo, sy), o + g.offset(x_hi, sy), o + g.offset(x_lo, y));
    }
  });
}

Planes load(const Geometry& g, const View& v, float limit) {
  Planes p(g, v.channels);
  tbb::parallel_for(0, g.height, [&](int y) {
    for (int c = 0; c < v.channels; ++c) {
      float* row = p.origin(c) + g.offset(0, y);
      for (int x = 0; x < g.width; ++x) {
        const float val = v.at(x, y, c);
        row[x] = std::isfinite(val) ? std::clamp(val, -limit, limit)
                                    : (std::isnan(val) ? 0.0f
                                       : val > 0       ? limit
                                                       : -limit);
      }
    }
  });
  replicate_border(g, p);
  return p;
}

Planes box_mean(const Geometry& g, const Planes& p, int r) {
  Planes tmp(g, p.channels()), out(g, p.channels());
  tbb::parallel_for(0, p.channels(), [&](int c) {
    for (int y = 0; y < g.height; ++y) {
      const float* src = p.origin(c) + g.offset(0, y);
      float* dst = tmp.origin(c) + g.offset(0, y);
      for (int x = 0; x < g.width; ++x) {
        const int a = std::max(x - r, 0), b = std::min(x + r + 1, g.width);
        double s = 0;
        for (int q = a; q < b; ++q) s += src[q];
        dst[x] = static_cast<float>(s / (b - a));
      }
    }
    for (int y = 0; y < g.height; ++y) {
      const int a = std::max(y - r, 0), b = std::min(y + r + 1, g.height);
      float* dst = out.origin(c) + g.offset(0, y);
      for (int x = 0; x < g.width; ++x) {
        double s = 0;
        for (int q = a; q < b; ++q) s += tmp.origin(c)[g.offset(x, q)];
        dst[x] = static_cast<float>(s / (b - a));
      }
    }
  });
  replicate_border(g, out);
  return out;
}

int offsets_of(int radius) {
  return (2 * radius + 1) * (2 * radius + 1);
}

void tile_weights(const Geometry& g, const WeightSpec& s, const Rect& tile, TileScratch& sc) {
  const int r = s.radius, f = s.patch;
  const int eh = kTileHeight + 2 * f;
  sc.weights.resize(static_cast<std::size_t>(offsets_of(r)) * kTileArea);
  sc.dist.resize(static_cast<std::size_t>(kExtStride) * static_cast<std::size_t>(eh));
  sc.hsum.resize(static_cast<std::size_t>(kTileWidth) * static_cast<std::size_t>(eh));
  WeightArgs a;
  const std::ptrdiff_t ext = g.offset(tile.x0 - f, tile.y0 - f);
  a.channels = s.channels;
  for (int c = 0; c < s.channels; ++c) {
    a.guide[c] = s.guide[c] + ext;
    a.variance[c] = s.variance[c] + ext;
  }
  a.stride = g.stride;
  a.patch = f;
  a.scale = 1.0f / (s.k * s.k * static_cast<float>(s.channels * (2 * f + 1) * (2 * f + 1)));
  a.dist = sc.dist.data();
  a.hsum = sc.hsum.data();
  int o = 0;
  for (int dy = -r; dy <= r; ++dy) {
    for (int dx = -r; dx <= r; ++dx, ++o) {
      a.doff = g.offset(dx, dy);
      a.w = sc.weights.data() + static_cast<std::ptrdiff_t>(o) * kTileArea;
      s.kernels->weights(a);
      // Only pairs of image pixels count (the border and tile padding are replicas).
      const int x_lo = std::max(tile.x0, -dx), x_hi = std::min({tile.x1, g.width, g.width - dx});
      for (int y = tile.y0; y < tile.y1; ++y) {
        float* row = a.w + static_cast<std::ptrdiff_t>(y - tile.y0) * kTileWidth - tile.x0;
        if (y >= g.height || y + dy < 0 || y + dy >= g.height || x_lo >= x_hi) {
          std::fill(row + tile.x0, row + tile.x1, 0.0f);
          continue;
        }
        std::fill(row + tile.x0, row + x_lo, 0.0f);
        std::fill(row + x_hi, row + tile.x1, 0.0f);
      }
    }
  }
}

void nlmeans_filter(const Geometry& g, const WeightSpec& spec, const Planes& data, Planes& out) {
  const int r = spec.radius;
  const int channels = data.channels();
  tbb::enumerable_thread_specific<TileScratch> scratches;
  tbb::parallel_for(0, g.tiles_x * g.tiles_y, [&](int t) {
    TileScratch& scratch = scratches.local();
    const Rect tile = g.tile(t % g.tiles_x, t / g.tiles_x);
    tile_weights(g, spec, tile, scratch);
    std::vector<float>& acc = scratch.work;
    acc.assign(static_cast<std::size_t>(channels + 1) * kTileArea, 0.0f);
    float* den = acc.data() + static_cast<std::ptrdiff_t>(channels) * kTileArea;
    int o = 0;
    for (int dy = -r; dy <= r; ++dy) {
      for (int dx = -r; dx <= r; ++dx, ++o) {
        const float* w = scratch.weights.data() + static_cast<std::ptrdiff_t>(o) * kTileArea;
        for (int c = 0; c < channels; ++c) {
          const float* src = data.origin(c) + g.offset(tile.x0 + dx, tile.y0 + dy);
          float* num = acc.data() + static_cast<std::ptrdiff_t>(c) * kTileArea;
          for (int y = 0; y < kTileHeight; ++y) {
            const float* s = src + g.offset(0, y);
            const float* wr = w + y * kTileWidth;
            float* n = num + y * kTileWidth;
            for (int x = 0; x < kTileWidth; ++x) n[x] += wr[x] * s[x];
          }
        }
        for (int i = 0; i < kTileArea; ++i) den[i] += w[i];
      }
    }
    for (int c = 0; c < channels; ++c) {
      const float* num = acc.data() + static_cast<std::ptrdiff_t>(c) * kTileArea;
      float* dst = out.origin(c);
      for (int y = tile.y0; y < std::min(tile.y1, g.height); ++y) {
        for (int x = tile.x0; x < std::min(tile.x1, g.width); ++x) {
          const int i = (y - tile.y0) * kTileWidth + (x - tile.x0);
          // den >= the centre's own weight, 1 (its distance to itself is <= 0).
          dst[g.offset(x, y)] = num[i] / den[i];
        }
      }
    }
  });
  replicate_border(g, out);
}

}  // namespace proden::nfor

// NFOR's collaborative first-order regression (§4, §5.2) over the whole frame: tiles of output
// pixels p run in parallel, each with its NL-means weights, normal equations, solve and scatter
// of predictions into the q's of p's window. Tiles whose windows' footprints overlap never run at
// the same time (phases), so the scatter needs no locks and every pixel's sum is taken in the
// same order whatever the thread count: the result is deterministic.
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "nfor_internal.hpp"

namespace proden::nfor {

int squarings_between(float from, float to) {
  // w_to = w_from^((from / to)^2): a power of two up to 2^kMaxSquarings.
  const double ratio = static_cast<double>(from) * from / (static_cast<double>(to) * to);
  for (int s = 0; s <= kMaxSquarings; ++s) {
    if (std::abs(ratio - std::ldexp(1.0, s)) < 1e-6 * ratio) return s;
  }
  return -1;
}

void regression(const Geometry& g, const RegressionSpec& spec, const std::vector<int>& squarings,
                const std::vector<Planes*>& outs, const std::vector<Planes*>& hats) {
  const int r = spec.weights.radius;
  const int m = spec.data_channels;
  const std::size_t runs = squarings.size();
  const Kernels& kern = *spec.weights.kernels;
  auto hat_of = [&](std::size_t run) { return run < hats.size() ? hats[run] : nullptr; };
  std::vector<Planes> num, den, hat_acc;
  for (std::size_t i = 0; i < runs; ++i) {
    num.emplace_back(g, m);
    den.emplace_back(g, 1);
    hat_acc.push_back(hat_of(i) ? Planes(g, 1) : Planes());
  }
  std::vector<std::ptrdiff_t> doff;
  for (int dy = -r; dy <= r; ++dy) {
    for (int dx = -r; dx <= r; ++dx) doff.push_back(g.offset(dx, dy));
  }
  // Tiles (tx, ty) and (tx + sx, ty) write disjoint footprints (tile grown by r).
  const int sx = 1 + (2 * r + kTileWidth - 1) / kTileWidth;
  const int sy = 1 + (2 * r + kTileHeight - 1) / kTileHeight;
  tbb::enumerable_thread_specific<TileScratch> scratches;
  for (int py = 0; py < sy; ++py) {
    for (int px = 0; px < sx; ++px) {
      std::vector<int> tiles;
      for (int ty = py; ty < g.tiles_y; ty += sy) {
        for (int tx = px; tx < g.tiles_x; tx += sx) tiles.push_back(ty * g.tiles_x + tx);
      }
      tbb::parallel_for(std::size_t{0}, tiles.size(), [&](std::size_t i) {
        TileScratch& sc = scratches.local();
        const Rect tile = g.tile(tiles[i] % g.tiles_x, tiles[i] / g.tiles_x);
        tile_weights(g, spec.weights, tile, sc);
        sc.work.resize(chunk_scratch_floats());
        ChunkArgs a;
        a.w_stride = kTileArea;
        a.doff = doff.data();
        a.offsets = static_cast<int>(doff.size());
        a.data_channels = m;
        a.scratch = sc.work.data();
        for (std::size_t run = 0; run < runs; ++run) {
          a.squarings = squarings[run];
          for (int y = tile.y0; y < std::min(tile.y1, g.height); ++y) {
            for (int x = tile.x0; x < std::min(tile.x1, g.width); x += kern.lanes) {
              const std::ptrdiff_t p = g.offset(x, y);
              a.w = sc.weights.data() + (y - tile.y0) * kTileWidth + (x - tile.x0);
              for (int j = 0; j < kFeatures; ++j) a.features[j] = spec.features[j] + p;
              for (int c = 0; c < m; ++c) {
                a.data[c] = spec.data[c] + p;
                a.num[c] = num[run].origin(c) + p;
              }
              a.den = den[run].origin(0) + p;
              a.hat = hat_of(run) ? hat_acc[run].origin(0) + p : nullptr;
              kern.regress(a);
            }
          }
        }
      });
    }
  }
  for (std::size_t run = 0; run < runs; ++run) {
    Planes& out = *outs[run];
    tbb::parallel_for(0, g.height, [&](int y) {
      const float* d = den[run].origin(0) + g.offset(0, y);
      for (int c = 0; c < m; ++c) {
        const float* n = num[run].origin(c) + g.offset(0, y);
        float* o = out.origin(c) + g.offset(0, y);
        // den >= the weight of p's own fit at p, 1.
        for (int x = 0; x < g.width; ++x) o[x] = n[x] / d[x];
      }
      if (Planes* hat = hat_of(run)) {
        const float* h = hat_acc[run].origin(0) + g.offset(0, y);
        float* o = hat->origin(0) + g.offset(0, y);
        for (int x = 0; x < g.width; ++x) o[x] = h[x] / d[x];
      }
    });
    replicate_border(g, out);
    if (Planes* hat = hat_of(run)) replicate_border(g, *hat);
  }
}

}  // namespace proden::nfor

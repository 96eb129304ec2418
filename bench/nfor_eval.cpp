// NFOR against the truth on the evaluation scenes (docs/nfor.md): per level, the error of each
// NFOR stage and of NL-means, and how well each candidate error estimate of NFOR's output matches
// the true per-pixel error (the reference's own variance subtracted):
//   hat  SURE with the second pass's hat diagonal as dy/dx ((y - x)^2 - var + 2 hat var),
//   cv   half-buffer cross-validation (NforExtras::cross_validation),
//   mc   SURE with the Monte-Carlo divergence probe of pipeline/src/sure.cpp (K = 4 NFOR runs).
// For each: est/true of the frame's mean MSE, and the Spearman rank correlation of est and true
// over pixels and over 8x8 and 32x32 windows (window means).
//
//   proden_nfor_eval --scene DIR [--levels 8,32] [--threads N] [--no-mc] [--json]
// (DIR/spp<L>/pass_*.exr with DIR/reference/, or DIR/pass_*.exr with DIR/reference.exr)
//                    [--dump DIR]   (EXRs of x, y, the stages and the estimates per level)
#include <tbb/global_control.h>

#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <map>
#include <memory>
#include <numeric>
#include <sstream>
#include <string>
#include <vector>

#include "bench_common.hpp"
#include "eval_common.hpp"
#include "proden/accumulator.hpp"
#include "proden/denoise/nfor.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/metrics.hpp"
#include "proden/progressive.hpp"
#include "proden/sure.hpp"

namespace fs = std::filesystem;
using namespace proden;
using nlohmann::json;

namespace {

using bench::accumulate;
using bench::mean_of;
using bench::metrics_json;

// Ranks with ties averaged.
std::vector<double> ranks(const std::vector<double>& v) {
  std::vector<std::size_t> idx(v.size());
  std::iota(idx.begin(), idx.end(), 0);
  std::sort(idx.begin(), idx.end(), [&](std::size_t a, std::size_t b) { return v[a] < v[b]; });
  std::vector<double> r(v.size());
  for (std::size_t i = 0; i < idx.size();) {
    std::size_t j = i;
    while (j + 1 < idx.size() && v[idx[j + 1]] == v[idx[i]]) ++j;
    const double mean_rank = 0.5 * static_cast<double>(i + j);
    for (std::size_t k = i; k <= j; ++k) r[idx[k]] = mean_rank;
    i = j + 1;
  }
  return r;
}

double pearson(const std::vector<double>& a, const std::vector<double>& b) {
  const double n = static_cast<double>(a.size());
  const double ma = std::accumulate(a.begin(), a.end(), 0.0) / n;
  const double mb = std::accumulate(b.begin(), b.end(), 0.0) / n;
  double sab = 0, saa = 0, sbb = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    sab += (a[i] - ma) * (b[i] - mb);
    saa += (a[i] - ma) * (a[i] - ma);
    sbb += (b[i] - mb) * (b[i] - mb);
  }
  return saa > 0 && sbb > 0 ? sab / std::sqrt(saa * sbb) : 0.0;
}

double spearman(const std::vector<double>& a, const std::vector<double>& b) {
  return pearson(ranks(a), ranks(b));
}

// Channel-mean per pixel, then means over w x w windows (w = 1: per pixel).
std::vector<double> window_means(const Image& img, int w) {
  std::vector<double> out;
  for (int y0 = 0; y0 + w <= img.height(); y0 += w) {
    for (int x0 = 0; x0 + w <= img.width(); x0 += w) {
      double s = 0;
      for (int c = 0; c < 3; ++c) {
        for (int y = y0; y < y0 + w; ++y) {
          for (int x = x0; x < x0 + w; ++x) s += img.at(x, y, c);
        }
      }
      out.push_back(s / (3.0 * w * w));
    }
  }
  return out;
}

// Share of the true error held by the 10 % of windows the estimate ranks worst, over the share
// held by the truly worst 10 % (1 = it finds the worst windows).
double capture(const std::vector<double>& est, const std::vector<double>& truth) {
  const std::size_t n = std::max<std::size_t>(1, est.size() / 10);
  std::vector<std::size_t> by_est(est.size()), by_true(est.size());
  std::iota(by_est.begin(), by_est.end(), 0);
  std::iota(by_true.begin(), by_true.end(), 0);
  std::sort(by_est.begin(), by_est.end(), [&](auto a, auto b) { return est[a] > est[b]; });
  std::sort(by_true.begin(), by_true.end(), [&](auto a, auto b) { return truth[a] > truth[b]; });
  double got = 0, best = 0;
  for (std::size_t i = 0; i < n; ++i) {
    got += truth[by_est[i]];
    best += truth[by_true[i]];
  }
  return best > 0 ? got / best : 0.0;
}

json compare(const Image& est, const Image& truth) {
  json j = {{"est_over_true", mean_of(est) / std::max(mean_of(truth), 1e-30)}};
  for (int w : {1, 8, 32}) {
    const auto e = window_means(est, w), t = window_means(truth, w);
    j["spearman_" + std::to_string(w)] = spearman(e, t);
    if (w > 1) {
      j["pearson_" + std::to_string(w)] = pearson(e, t);
      j["capture10_" + std::to_string(w)] = capture(e, t);
    }
  }
  return j;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"NFOR stages and error estimates against the reference"};
  std::string dir, levels_csv, dump;
  int threads = 0;
  bool as_json = false, no_mc = false;
  NforParams np;
  app.add_option("--scene", dir, "Scene directory (spp<L>/pass_*.exr, reference/)")->required();
  app.add_option("--levels", levels_csv, "Comma-separated spp levels (default: all)");
  app.add_option("--threads", threads, "Threads (0 = all)");
  app.add_flag("--no-mc", no_mc, "Skip the Monte-Carlo SURE probe (4 extra NFOR runs)");
  app.add_flag("--json", as_json, "JSON lines output");
  app.add_option("--dump", dump, "Write EXRs of the images per level into this directory");
  bool no_second = false;
  app.add_flag("--no-second-pass", no_second);
  app.add_option("--second-pass-k", np.second_pass_k);
  app.add_option("--selection-radius", np.selection_radius);
  CLI11_PARSE(app, argc, argv);
  np.second_pass = !no_second;
  const auto limit = bench::limit_threads(threads);
  const bench::EvalSet set = bench::find_levels(dir, levels_csv);
  if (set.levels.empty()) {
    std::fprintf(stderr, "no passes in %s\n", dir.c_str());
    return 2;
  }
  const auto& ref_files = set.reference;
  const bench::Reference reference = bench::read_reference(ref_files);
  const FrameAccumulator& ref_frame = reference.frame;
  const FrameEstimate& ref = reference.estimate;
  const double ref_var = reference.mean_variance;
  const std::string scene = fs::path(dir).filename().string();

  for (const auto& [level, files] : set.levels) {
    if (files.empty()) continue;
    const FrameAccumulator f = accumulate(files, true);
    const FrameEstimate est = f.estimate();
    const DenoiseInputs din = denoise_inputs(est, est.mean, est.variance, true);
    const int W = din.width, H = din.height;
    const NforDenoiser nfor(np);
    NforExtras ex;
    ex.want_cross_validation = ex.want_hat = ex.want_stages = true;
    const Image y = nfor.run(din, &ex);
    const Image nl = bench::tiled_denoise(NlMeansDenoiser(), din, 256);

    // True per-pixel error of y: (y - ref)^2 minus the reference's own variance there.
    Image truth(W, H, 3), hat_sure(W, H, 3), mc_sure(W, H, 3);
    for (int c = 0; c < 3; ++c) {
      for (int py = 0; py < H; ++py) {
        for (int px = 0; px < W; ++px) {
          const double d = static_cast<double>(y.at(px, py, c)) - ref.mean.at(px, py, c);
          const double rv = ref_frame.passes() >= 2 ? ref.variance.at(px, py, c) : 0.0;
          truth.at(px, py, c) = static_cast<float>(d * d - rv);
          const double dx = static_cast<double>(y.at(px, py, c)) - est.mean.at(px, py, c);
          const double v = est.variance.at(px, py, c);
          hat_sure.at(px, py, c) = static_cast<float>(dx * dx - v + 2.0 * ex.hat.at(px, py, c) * v);
        }
      }
    }
    json row = {{"scene", scene},
                {"spp", f.total_spp()},
                {"passes", f.passes()},
                {"mode", ex.mode},
                {"render", metrics_json(est.mean, ref.mean, ref_var)},
                {"nlmeans", metrics_json(nl, ref.mean, ref_var)},
                {"nfor", metrics_json(y, ref.mean, ref_var)},
                {"true_mse", mean_of(truth)},
                {"seconds", ex.seconds.total}};
    for (const auto& [name, img] : ex.stages)
      row["stages"][name] = metrics_json(img, ref.mean, ref_var);
    row["estimates"]["hat"] = compare(hat_sure, truth);
    if (!ex.cross_validation.empty()) row["estimates"]["cv"] = compare(ex.cross_validation, truth);
    if (!no_mc) {
      // The probe of pipeline/src/sure.cpp (x and its halves perturbed together).
      const Rect all{0, 0, W, H};
      Buffer yb(all, 3), div(all, 3), s(all, 3);
      for (int c = 0; c < 3; ++c) {
        for (int py = 0; py < H; ++py) {
          for (int px = 0; px < W; ++px) yb.at(px, py, c) = y.at(px, py, c);
        }
      }
      divergence_monte_carlo(nfor, din, all, yb, MonteCarloProbes{}, div);
      sure(din.colour, din.variance, yb, div, all, s);
      store(s, all, mc_sure);
      row["estimates"]["mc"] = compare(mc_sure, truth);
    }
    if (!dump.empty()) {
      fs::create_directories(dump);
      std::vector<io::NamedChannel> ch;
      io::add_layer(ch, "render.", est.mean);
      io::add_layer(ch, "nfor.", y);
      io::add_layer(ch, "nlmeans.", nl);
      io::add_layer(ch, "reference.", ref.mean);
      for (std::size_t i = 0; i < ex.stages.size(); ++i) {
        io::add_layer(ch, "stage" + std::to_string(i) + ".", ex.stages[i].second);
      }
      io::add_layer(ch, "true_error.", truth);
      io::add_layer(ch, "hat_sure.", hat_sure);
      if (!ex.cross_validation.empty()) io::add_layer(ch, "cv.", ex.cross_validation);
      if (!no_mc) io::add_layer(ch, "mc_sure.", mc_sure);
      io::write_image((fs::path(dump) / (scene + "_" + std::to_string(level) + ".exr")).string(), W,
                      H, ch);
    }
    if (as_json) {
      std::cout << row.dump() << std::endl;
    } else {
      std::printf("%s %5.0f spp (%d passes, %s): relMSE render %.5f nlmeans %.5f nfor %.5f",
                  scene.c_str(), f.total_spp(), f.passes(), ex.mode.c_str(),
                  row["render"]["relmse"].get<double>(), row["nlmeans"]["relmse"].get<double>(),
                  row["nfor"]["relmse"].get<double>());
      for (const auto& [name, img] : ex.stages) {
        std::printf(" | %s %.5f", name.c_str(), row["stages"][name]["relmse"].get<double>());
      }
      std::printf("\n  est/true (spearman px, 8x8, 32x32; capture 8x8):");
      for (auto& [name, e] : row["estimates"].items()) {
        std::printf("  %s %.3f (%.2f %.2f %.2f; %.2f)", name.c_str(),
                    e["est_over_true"].get<double>(), e["spearman_1"].get<double>(),
                    e["spearman_8"].get<double>(), e["spearman_32"].get<double>(),
                    e["capture10_8"].get<double>());
      }
      std::printf("\n");
      std::fflush(stdout);
    }
  }
  return 0;
}

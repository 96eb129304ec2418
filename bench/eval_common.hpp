// Shared by the evaluation tools (proden_eval_levels, proden_nfor_eval): finding a scene's sample
// levels and reference, accumulating their passes, the thread limit and the metrics' JSON form.
//
// Layouts: DIR/spp<L>/pass_*.exr with DIR/reference/pass_*.exr (bench/render_eval_set.sh), or
// DIR/pass_*.exr with DIR/reference.exr (samples/renders/<scene>) as one level, 0.
#pragma once

#include <tbb/global_control.h>

#include <algorithm>
#include <filesystem>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "proden/accumulator.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/metrics.hpp"

namespace proden::bench {

inline std::vector<std::string> exr_files(const std::filesystem::path& dir,
                                          const std::string& prefix = "pass_") {
  std::vector<std::string> out;
  if (!std::filesystem::is_directory(dir)) return out;
  for (const auto& e : std::filesystem::directory_iterator(dir)) {
    const std::string n = e.path().filename().string();
    if (e.is_regular_file() && n.rfind(prefix, 0) == 0 && e.path().extension() == ".exr") {
      out.push_back(e.path().string());
    }
  }
  std::sort(out.begin(), out.end());
  return out;
}

// Adds `src` (spp n) into the running chunk `dst` (spp m): spp-weighted means, and the renderer
// variance of the merged mean, (m^2 v_dst + n^2 v_src) / (m + n)^2.
inline void merge_into(Pass& dst, const Pass& src) {
  if (dst.colour.empty()) {
    dst = src;
    return;
  }
  const double m = dst.spp, n = src.spp, w = m + n;
  auto mean = [&](Image& a, const Image& b) {
    for (std::size_t i = 0; i < a.data().size(); ++i)
      a.data()[i] = static_cast<float>((m * a.data()[i] + n * b.data()[i]) / w);
  };
  mean(dst.colour, src.colour);
  if (!dst.albedo.empty()) mean(dst.albedo, src.albedo);
  if (!dst.normal.empty()) mean(dst.normal, src.normal);
  if (!dst.depth.empty()) mean(dst.depth, src.depth);
  for (std::size_t i = 0; i < dst.variance.data().size(); ++i) {
    dst.variance.data()[i] = static_cast<float>(
        (m * m * dst.variance.data()[i] + n * n * src.variance.data()[i]) / (w * w));
  }
  dst.spp = w;
}

// The level's passes as given, or (chunks > 0) merged into `chunks` contiguous groups of nearly
// equal size, the way a farm renders a frame as a few big chunks: same samples, fewer passes.
inline FrameAccumulator accumulate(const std::vector<std::string>& files, bool features,
                                   int chunks = 0) {
  io::ReadOptions o;
  o.features = features;
  FrameAccumulator f;
  if (chunks <= 0 || chunks >= static_cast<int>(files.size())) {
    for (const auto& p : files) f.add(io::read_pass(p, o), p);
    return f;
  }
  const std::size_t n = files.size(), k = static_cast<std::size_t>(chunks);
  for (std::size_t g = 0; g < k; ++g) {
    Pass chunk;
    for (std::size_t i = g * n / k; i < (g + 1) * n / k; ++i)
      merge_into(chunk, io::read_pass(files[i], o));
    f.add(chunk, "chunk" + std::to_string(g));
  }
  return f;
}

inline double mean_of(const Image& img) {
  double s = 0;
  for (float v : img.data()) s += v;
  return s / static_cast<double>(img.data().size());
}

struct EvalSet {
  std::map<int, std::vector<std::string>> levels;  // spp level -> pass files
  std::vector<std::string> reference;
};

// The levels of `dir` (only those in the comma-separated `levels_csv` when it is not empty);
// `levels` is empty when the directory holds no passes.
inline EvalSet find_levels(const std::string& dir, const std::string& levels_csv) {
  namespace fs = std::filesystem;
  EvalSet s;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string n = e.path().filename().string();
    if (e.is_directory() && n.rfind("spp", 0) == 0)
      s.levels[std::stoi(n.substr(3))] = exr_files(e.path());
  }
  s.reference = exr_files(fs::path(dir) / "reference");
  if (s.levels.empty()) {
    const auto passes = exr_files(dir);
    if (passes.empty()) return s;
    s.levels[0] = passes;  // spp filled in from the files
    s.reference = {(fs::path(dir) / "reference.exr").string()};
  }
  if (!levels_csv.empty()) {
    std::map<int, std::vector<std::string>> keep;
    std::stringstream ss(levels_csv);
    std::string tok;
    while (std::getline(ss, tok, ',')) {
      const int l = std::stoi(tok);
      if (s.levels.count(l)) keep[l] = s.levels[l];
    }
    s.levels = keep;
  }
  return s;
}

// The reference's mean and the mean of its own variance (0 with one pass), which the true MSE of
// an image subtracts (`mse_corrected`).
struct Reference {
  FrameAccumulator frame;
  FrameEstimate estimate;
  double mean_variance = 0.0;
};
inline Reference read_reference(const std::vector<std::string>& files) {
  Reference r;
  r.frame = accumulate(files, false);
  r.estimate = r.frame.estimate({.halves = false, .features = false});
  r.mean_variance = r.frame.passes() >= 2 ? mean_of(r.estimate.variance) : 0.0;
  return r;
}

// Error metrics of `img` against the reference, and its MSE less the reference's own variance.
inline nlohmann::json metrics_json(const Image& img, const Image& ref, double ref_var) {
  const ErrorMetrics m = compute_metrics(img, ref);
  return {
      {"rmse", m.rmse},   {"relmse", m.relmse}, {"relmse_trimmed", m.relmse_trimmed},
      {"smape", m.smape}, {"mse", m.mse},       {"mse_corrected", std::max(m.mse - ref_var, 0.0)}};
}

// Caps TBB's threads at `threads` while the returned object lives (0 = no cap).
inline std::unique_ptr<tbb::global_control> limit_threads(int threads) {
  if (threads <= 0) return nullptr;
  return std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                               static_cast<std::size_t>(threads));
}

}  // namespace proden::bench

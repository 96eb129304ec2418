// Accuracy and time per sample level: for a scene directory of passes, accumulates each level,
// runs the pipeline, and reports RMSE/relMSE/SMAPE of render, denoised and result against the
// reference (the mean of reference passes, with their own variance subtracted from the MSE).
//
// Layouts: DIR/spp<L>/pass_*.exr with DIR/reference/pass_*.exr (bench/render_eval_set.sh), or
// DIR/pass_*.exr with DIR/reference.exr (samples/renders/<scene>) as one level. `--passes N` merges
// each level's passes into N chunks of the same total spp (few-pass frames, docs/pipeline.md).
//
// Also per level: the pipeline's own error estimates (no reference): mean Var[x] for the render,
// mean SURE for the denoised image, and for the result PipelineResult::estimated_error (what
// the daemon and `proden denoise --json` report), and the wall time of a denoise-only run (the
// NL-means filter alone, same tiles and threads, no Jacobian) for the "denoise-only" curve.
#include <tbb/blocked_range2d.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "proden/accumulator.hpp"
#include "proden/io/network_file.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/metrics.hpp"
#include "proden/progressive.hpp"

namespace fs = std::filesystem;
using namespace proden;
using nlohmann::json;

namespace {

std::vector<std::string> exr_files(const fs::path& dir, const std::string& prefix = "pass_") {
  std::vector<std::string> out;
  if (!fs::is_directory(dir)) return out;
  for (const auto& e : fs::directory_iterator(dir)) {
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
void merge_into(Pass& dst, const Pass& src) {
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
FrameAccumulator accumulate(const std::vector<std::string>& files, bool features, int chunks = 0) {
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

double mean_of(const Image& img) {
  double s = 0;
  for (float v : img.data()) s += v;
  return s / static_cast<double>(img.data().size());
}

// Wall seconds of the denoiser alone (NL-means, no derivative) over the frame in tiles.
double denoise_only_seconds(const FrameEstimate& est, const PipelineOptions& po, Image* out) {
  NlMeansParams p = po.nlmeans;
  p.use_features = p.use_features && po.features;
  const NlMeansDenoiser nl(p);
  const DenoiseInputs din = denoise_inputs(est, est.mean, est.variance, p.use_features);
  Image y(din.width, din.height, 3);
  const int tile = std::max(1, po.tile);
  const auto t0 = std::chrono::steady_clock::now();
  tbb::parallel_for(tbb::blocked_range2d<int>(0, (din.height + tile - 1) / tile, 1, 0,
                                              (din.width + tile - 1) / tile, 1),
                    [&](const tbb::blocked_range2d<int>& r) {
                      for (int ty = r.rows().begin(); ty < r.rows().end(); ++ty) {
                        for (int tx = r.cols().begin(); tx < r.cols().end(); ++tx) {
                          const Rect rect{tx * tile, ty * tile,
                                          std::min(din.width, (tx + 1) * tile),
                                          std::min(din.height, (ty + 1) * tile)};
                          Buffer b(rect, 3);
                          nl.denoise(din, rect, b, nullptr);
                          store(b, rect, y);
                        }
                      }
                    });
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (out) *out = std::move(y);
  return s;
}

json metrics_json(const Image& img, const Image& ref, double ref_var) {
  const ErrorMetrics m = compute_metrics(img, ref);
  return {{"rmse", m.rmse},
          {"relmse", m.relmse},
          {"smape", m.smape},
          {"mse", m.mse},
          {"mse_corrected", std::max(m.mse - ref_var, 0.0)}};
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"proden accuracy per sample level"};
  std::string dir;
  std::string levels_csv;
  bool as_json = false, no_features = false;
  int threads = 0, chunks = 0;
  PipelineOptions po;
  std::string rule = "stein", divergence = "auto";
  app.add_option("--scene", dir, "Scene directory")->required();
  app.add_option("--levels", levels_csv, "Comma-separated spp levels (default: all found)");
  app.add_flag("--json", as_json, "JSON lines output");
  app.add_flag("--no-features", no_features, "Colour only");
  app.add_option("--threads", threads, "Threads (0 = all)");
  app.add_option("--passes", chunks,
                 "Merge each level's passes into this many chunks (same spp; 0 = as rendered)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--mixer-radius", po.closed_form.radius);
  app.add_option("--mixer-wide-radius", po.closed_form.wide_radius, "0: one window");
  app.add_option("--garrote", po.closed_form.garrote);
  app.add_option("--pool", po.variance_pool_radius);
  app.add_option("--t0", po.ttest.t0);
  bool no_dof = false;
  app.add_flag("--no-ttest-dof", no_dof,
               "The authors' fixed t0 (no degrees-of-freedom correction)");
  app.add_option("--variance-floor", po.closed_form.variance_floor);
  std::string weight = "relative";  // the library default (ClosedFormParams)
  app.add_option("--mixer-weight", weight)
      ->check(CLI::IsMember({"uniform", "variance", "relative"}));
  std::string den = "nlmeans";
  app.add_option("--denoiser", den)->check(CLI::IsMember({"nlmeans", "gaussian"}));
  app.add_option("--sigma", po.gaussian_sigma);
  app.add_option("--rule", rule)->check(CLI::IsMember({"stein", "inverse-error"}));
  app.add_option("--divergence", divergence)->check(CLI::IsMember({"auto", "analytic", "mc"}));
  app.add_option("--search-radius", po.nlmeans.search_radius);
  app.add_option("--patch-radius", po.nlmeans.patch_radius);
  app.add_option("--k", po.nlmeans.k);
  app.add_option("--k-feature", po.nlmeans.k_feature);
  app.add_option("--tile", po.tile);
  bool no_ttest = false;
  app.add_flag("--no-ttest", no_ttest);
  std::string mixer_kind = "closed-form", weights;
  app.add_option("--mixer", mixer_kind)->check(CLI::IsMember({"closed-form", "network"}));
  app.add_option("--weights", weights, "Network weights (.pdnw; default: built-in)");
  CLI11_PARSE(app, argc, argv);
  po.mixer = mixer_kind == "network" ? MixerKind::network : MixerKind::closed_form;
  if (!weights.empty()) {
    po.weights = io::read_weights_file(weights);
    po.weights_source = weights;
  }
  po.t_test = !no_ttest;
  po.ttest.dof_correction = !no_dof;
  po.features = !no_features;
  po.closed_form.weight = weight == "uniform"    ? WindowWeight::uniform
                          : weight == "relative" ? WindowWeight::relative
                                                 : WindowWeight::variance;
  po.denoiser = den;
  po.closed_form.rule = rule == "stein" ? ClosedFormRule::stein : ClosedFormRule::inverse_error;
  po.divergence = divergence == "analytic" ? DivergenceMethod::analytic
                  : divergence == "mc"     ? DivergenceMethod::monte_carlo
                                           : DivergenceMethod::automatic;
  Pipeline pipeline(po);
  try {
    pipeline.commit();
  } catch (const PipelineError& e) {
    std::fprintf(stderr, "%s\n", e.what());
    return 2;
  }
  std::unique_ptr<tbb::global_control> limit;
  if (threads > 0) {
    limit = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                  static_cast<std::size_t>(threads));
  }

  // Levels and reference.
  std::map<int, std::vector<std::string>> levels;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string n = e.path().filename().string();
    if (e.is_directory() && n.rfind("spp", 0) == 0)
      levels[std::stoi(n.substr(3))] = exr_files(e.path());
  }
  std::vector<std::string> ref_files = exr_files(fs::path(dir) / "reference");
  if (levels.empty()) {
    const auto passes = exr_files(dir);
    if (passes.empty()) {
      std::fprintf(stderr, "no passes in %s\n", dir.c_str());
      return 2;
    }
    levels[0] = passes;  // spp filled in from the files
    ref_files = {(fs::path(dir) / "reference.exr").string()};
  }
  if (!levels_csv.empty()) {
    std::map<int, std::vector<std::string>> keep;
    std::stringstream ss(levels_csv);
    std::string tok;
    while (std::getline(ss, tok, ',')) {
      const int l = std::stoi(tok);
      if (levels.count(l)) keep[l] = levels[l];
    }
    levels = keep;
  }
  const FrameAccumulator ref_frame = accumulate(ref_files, false);
  const FrameEstimate ref_est = ref_frame.estimate({.halves = false, .features = false});
  const double ref_var = ref_frame.passes() >= 2 ? mean_of(ref_est.variance) : 0.0;

  if (!as_json) {
    std::printf("scene %s, reference %d pass(es) %.0f spp (mean variance %.3g)\n", dir.c_str(),
                ref_frame.passes(), ref_frame.total_spp(), ref_var);
    std::printf("%6s %-9s %10s %10s %10s %10s | %8s %8s\n", "spp", "image", "RMSE", "relMSE",
                "SMAPE", "est.MSE", "time s", "");
  }
  for (const auto& [level, files] : levels) {
    const auto t0 = std::chrono::steady_clock::now();
    const FrameAccumulator f = accumulate(files, !no_features, chunks);
    const FrameEstimate est = f.estimate({.halves = false, .features = !no_features});
    const auto t1 = std::chrono::steady_clock::now();
    const PipelineResult r = pipeline.execute(est);
    const double acc_s = std::chrono::duration<double>(t1 - t0).count();
    const double den_only_s =
        po.denoiser == "nlmeans"
            ? denoise_only_seconds(est, po, nullptr)
            : r.timings.wall * r.timings.denoise /
                  std::max(1e-12, r.timings.denoise + r.timings.sure + r.timings.mixer +
                                      r.timings.ttest + r.timings.compose);
    json row = {
        {"scene", fs::path(dir).filename().string()},
        {"spp", f.total_spp()},
        {"passes", f.passes()},
        {"mixer", r.mixer},
        {"inputs",
         Layout{r.inputs.albedo, r.inputs.normal, r.inputs.depth, f.layout().variance}.to_string()},
        {"render", metrics_json(est.mean, ref_est.mean, ref_var)},
        {"denoised", metrics_json(r.denoised, ref_est.mean, ref_var)},
        {"result", metrics_json(r.result, ref_est.mean, ref_var)},
        {"estimated_mse_render", mean_of(est.variance)},
        {"estimated_mse_denoised", mean_of(r.sure)},
        {"estimated_mse_result", r.estimated_error.mse},
        {"reference_mean_variance", ref_var},
        {"seconds",
         {{"read_accumulate", acc_s},
          {"pipeline_wall", r.timings.wall},
          {"update", acc_s + r.timings.wall},
          {"denoise_only_wall", den_only_s},
          {"denoise_cpu", r.timings.denoise},
          {"sure_cpu", r.timings.sure},
          {"mixer_cpu", r.timings.mixer},
          {"ttest_cpu", r.timings.ttest},
          {"compose_cpu", r.timings.compose}}}};
    if (as_json) {
      std::cout << row.dump() << "\n";
    } else {
      for (const char* k : {"render", "denoised", "result"}) {
        const auto& m = row[k];
        std::printf("%6.0f %-9s %10.5f %10.5f %10.5f %10.3g | %8.3f\n", f.total_spp(), k,
                    m["rmse"].get<double>(), m["relmse"].get<double>(), m["smape"].get<double>(),
                    std::string(k) == "render"     ? row["estimated_mse_render"].get<double>()
                    : std::string(k) == "denoised" ? row["estimated_mse_denoised"].get<double>()
                                                   : row["estimated_mse_result"].get<double>(),
                    r.timings.wall);
      }
    }
  }
  return 0;
}

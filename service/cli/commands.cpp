#include "cli/commands.hpp"

#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <iostream>
#include <optional>

#include "cli/progress.hpp"
#include "proden/accumulator.hpp"
#include "proden/aov.hpp"
#include "proden/error.hpp"
#include "proden/error_estimate.hpp"
#include "proden/io/network_file.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/metrics.hpp"
#include "proden/progressive.hpp"
#include "proden/protocol/estimate.hpp"
#include "proden/protocol/json.hpp"
#include "proden/protocol/pipeline_spec.hpp"
#include "proden/protocol/publish.hpp"

namespace proden::cli {
namespace {

using nlohmann::json;

io::ReadOptions read_options(const InputOptions& in) {
  io::ReadOptions r;
  r.renderer = in.renderer;
  r.spp = in.spp;
  r.features = in.features;
  r.view_layer = in.view_layer;
  return r;
}

void report(const InputError& e) {
  spdlog::error("{}: rejected ({}): {}", e.subject(), to_string(e.kind()), e.reason());
}

// Accumulates passes into a frame; rejected files are reported and leave the frame untouched.
struct Accumulated {
  FrameAccumulator frame;
  AovAccumulator aovs;
  io::PassInfo first;  // what the first accepted pass was read as
  int rejected = 0;
};

Accumulated accumulate(const std::vector<std::string>& files, const InputOptions& input,
                       const std::string& what, bool progress, bool aovs = false,
                       AccumulatorOptions frame = {}) {
  Accumulated a;
  a.frame = FrameAccumulator(frame);
  std::vector<AovChannel> pass_aovs;
  Progress bar(what, static_cast<int>(files.size()), progress);
  const auto options = read_options(input);
  for (const auto& f : files) {
    bar.step(f);
    try {
      io::PassInfo info;
      const Pass pass = io::read_pass(f, options, &info, aovs ? &pass_aovs : nullptr);
      const AddResult r = a.frame.add(pass, f);
      if (aovs) a.aovs.add(pass_aovs, pass.spp, info.aov_attributes);
      if (a.frame.passes() == 1) {
        a.first = info;
        if (info.layers.size() > 1 && input.view_layer.empty()) {
          std::string all;
          for (const auto& l : info.layers) all += (all.empty() ? "" : ", ") + l;
          spdlog::warn("{}: view layers {}; reading {} (the first; --view-layer chooses)", f, all,
                       info.layer);
        }
      }
      if (r.dropped_pixels > 0) {
        spdlog::warn("{}: {} pixel(s) with NaN/Inf samples dropped from this pass", f,
                     r.dropped_pixels);
      }
      if (r.sanitized_features > 0) {
        spdlog::warn("{}: {} non-finite feature value(s) replaced", f, r.sanitized_features);
      }
      if (info.spp_source == io::SppSource::assumed && a.frame.passes() == 1) {
        spdlog::info("{}: no sample count in the file; assuming 1 spp (use --spp)", f);
      }
    } catch (const InputError& e) {
      bar.done();
      report(e);
      ++a.rejected;
    }
  }
  return a;
}

// The pipeline the options describe, committed: a bad option or weights file is refused by its
// flag (exit 2) before any pass is read.
std::optional<Pipeline> committed_pipeline(const nlohmann::json& flags) {
  nlohmann::json given = flags;
  std::string weights_path;
  if (const auto w = given.find("weights"); w != given.end()) {
    weights_path = w->get<std::string>();
    given.erase(w);
  }
  try {
    PipelineOptions options = protocol::parse_pipeline_options(given);
    if (!weights_path.empty()) {
      options.weights = io::read_weights_file(weights_path);
      options.weights_source = weights_path;
    }
    Pipeline pipeline(std::move(options));
    pipeline.commit();
    return pipeline;
  } catch (const PipelineError& e) {
    spdlog::error("{}: {}", protocol::cli_flag(e.key()), e.message());
  } catch (const network::WeightsError& e) {
    spdlog::error("{}: {}", protocol::cli_flag(option_key(PipelineOption::weights)), e.what());
  }
  return std::nullopt;
}

}  // namespace

int run_denoise(const DenoiseOptions& o) {
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  std::optional<Pipeline> pipeline = committed_pipeline(o.pipeline);
  if (!pipeline) return kUsage;
  Accumulated a = accumulate(o.passes, o.input, "accumulate", o.progress, o.renderer_aovs,
                             {.quarters = pipeline->estimate_options().quarters});
  if (a.frame.empty()) {
    spdlog::error("no usable pass among {} file(s); nothing written", o.passes.size());
    return kBadInput;
  }
  const auto t1 = Clock::now();
  const FrameEstimate est = a.frame.estimate(pipeline->estimate_options());
  ErrorContext ectx;
  ectx.spp = a.frame.total_spp();
  ectx.passes = a.frame.passes();
  ectx.noise_scope =
      a.first.renderer == io::Renderer::cycles ? NoiseScope::pixel : NoiseScope::frame;
  const PipelineResult res = pipeline->execute(est, ectx);
  const auto t2 = Clock::now();

  // Written exactly as the daemon publishes (protocol/publish.hpp); the layers with --aov, the
  // renderer's AOVs beside the result.
  protocol::Attributes attributes =
      protocol::header_attributes(protocol::provenance_of(a.frame, est), res);
  if (!a.first.layer.empty()) attributes.emplace_back("proden:view_layer", a.first.layer);
  try {
    protocol::write_frame(o.out, res, attributes, {o.aov, o.half, o.compression}, &a.aovs);
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return kInternalError;
  }
  const auto t3 = Clock::now();
  const double accumulate_s = std::chrono::duration<double>(t1 - t0).count();
  const double pipeline_s = std::chrono::duration<double>(t2 - t1).count();
  const double write_s = std::chrono::duration<double>(t3 - t2).count();
  const double total_s = std::chrono::duration<double>(t3 - t0).count();
  const auto& tm = res.timings;
  json timings = {{"read_accumulate", accumulate_s},
                  {"pipeline_wall", pipeline_s},
                  {"denoise_cpu", tm.denoise},
                  {"sure_cpu", tm.sure},
                  {"mixer_cpu", tm.mixer},
                  {"ttest_cpu", tm.ttest},
                  {"compose_cpu", tm.compose},
                  {"cross_validation_cpu", tm.cross_validation},
                  {"write", write_s},
                  {"total", total_s}};

  if (o.json) {
    json j = protocol::frame_summary(a.frame, est);
    j["output"] = o.out;
    j["rejected_files"] = a.rejected;
    j["seconds"] = total_s;
    j["inputs_used"] = res.inputs.to_string();
    j["pipeline"] = {{"denoiser", res.denoiser},
                     {"mixer", res.mixer},
                     {"divergence", res.divergence},
                     {"t_test", res.t_test},
                     {"tile", pipeline->options().tile},
                     {"halo", res.halo},
                     {"noise_free", res.noise_free},
                     {"settings", protocol::settings_json(pipeline->options())}};
    if (res.mixer_weights != "none") j["pipeline"]["weights"] = res.mixer_weights;
    // The same keys, from the same numbers, as the daemon's frame status.
    protocol::put_estimated_error(j, res.estimated_error);
    j["renderer"] = io::to_string(a.first.renderer);
    j["view_layer"] = a.first.layer.empty() ? json() : json(a.first.layer);
    j["view_layers"] = a.first.layers;
    json aovs = json::array();
    for (const auto& [name, mode] : a.aovs.channels()) {
      aovs.push_back({{"name", name}, {"mode", to_string(mode)}});
    }
    j["aovs"] = aovs;
    if (o.timings) j["timings"] = timings;
    std::cout << j.dump(2) << "\n";
  } else {
    spdlog::info(
        "{}: {} pass(es), {} spp, inputs {}, variance from {}{}; {} + {} mixer{}; estimated MSE "
        "{:.3g} ({}); {:.2f} s",
        o.out, a.frame.passes(), a.frame.total_spp(), res.inputs.to_string(),
        protocol::to_string(est.variance_source), est.low_confidence() ? " (low confidence)" : "",
        res.denoiser, res.mixer, res.t_test ? " + t-test" : "", res.estimated_error.mse,
        res.estimated_error.source, total_s);
    if (o.timings) {
      std::fprintf(stderr,
                   "timings (s): read+accumulate %.3f | pipeline wall %.3f (cpu: denoise %.3f, "
                   "sure %.3f, mixer %.3f, t-test %.3f, compose %.3f, cross-validation %.3f) | "
                   "write %.3f | total %.3f\n",
                   accumulate_s, pipeline_s, tm.denoise, tm.sure, tm.mixer, tm.ttest, tm.compose,
                   tm.cross_validation, write_s, total_s);
    }
  }
  return a.rejected > 0 ? kBadInput : kOk;
}

int run_eval(const EvalOptions& o) {
  Accumulated ref = accumulate(o.references, o.input, "reference", true);
  if (ref.frame.empty()) {
    spdlog::error("no usable reference image");
    return kBadInput;
  }
  const FrameEstimate ref_est = ref.frame.estimate({.halves = false, .features = false});
  const Image& reference = ref_est.mean;
  // A reference rendered in passes carries its own noise: E[measured MSE] = MSE + mean Var[ref].
  double ref_var = 0.0;
  if (ref.frame.passes() >= 2) {
    for (float v : ref_est.variance.data()) ref_var += v;
    ref_var /= static_cast<double>(ref_est.variance.data().size());
  }
  int rejected = ref.rejected;
  json results = json::array();
  const auto options = read_options(o.input);
  const std::vector<std::string> layers =
      o.layers.empty() ? std::vector<std::string>{"result"} : o.layers;
  for (const auto& f : o.images) {
    for (const auto& layer : layers) {
      try {
        const Image img = io::read_layer(f, layer, options);
        if (!img.same_size(reference)) {
          throw InputError(InputErrorKind::size_mismatch, f,
                           "is " + std::to_string(img.width()) + "x" +
                               std::to_string(img.height()) + ", the reference is " +
                               std::to_string(reference.width()) + "x" +
                               std::to_string(reference.height()));
        }
        const ErrorMetrics m = compute_metrics(img, reference);
        json r = protocol::to_json(m);
        r["image"] = f;
        r["layer"] = layer;
        if (ref.frame.passes() >= 2) {
          r["mse_minus_reference_variance"] = m.mse - ref_var;
        }
        results.push_back(r);
      } catch (const InputError& e) {
        report(e);
        ++rejected;
      }
    }
  }
  if (o.json) {
    json j = {{"reference", o.references}, {"results", results}};
    if (ref.frame.passes() >= 2) j["reference_variance_mean"] = ref_var;
    std::cout << j.dump(2) << "\n";
  } else {
    std::printf("%-48s %-9s %12s %12s %12s %10s\n", "image", "layer", "RMSE", "relMSE", "SMAPE",
                "nonfinite");
    for (const auto& r : results) {
      std::printf("%-48s %-9s %12.6g %12.6g %12.6g %10zu\n", r["image"].get<std::string>().c_str(),
                  r["layer"].get<std::string>().c_str(), r["rmse"].get<double>(),
                  r["relmse"].get<double>(), r["smape"].get<double>(),
                  r["nonfinite"].get<std::size_t>());
    }
    if (ref.frame.passes() >= 2) {
      std::printf("reference: %d passes, mean variance %.6g (subtract from MSE)\n",
                  ref.frame.passes(), ref_var);
    }
  }
  return rejected > 0 ? kBadInput : kOk;
}

int run_info(const InfoOptions& o) {
  int rejected = 0;
  json all = json::array();
  for (const auto& f : o.files) {
    try {
      const io::PassInfo info = io::probe_pass(f, read_options(o.input));
      if (o.json) {
        all.push_back(protocol::to_json(info));
      } else {
        std::printf("%s\n", f.c_str());
        std::string layers;
        for (const auto& l : info.layers) layers += (layers.empty() ? "" : ", ") + l;
        std::printf("  renderer   %s%s\n", std::string(io::to_string(info.renderer)).c_str(),
                    info.layer.empty()
                        ? ""
                        : (" (view layer " + info.layer +
                           (info.layers.size() > 1 ? " of " + layers : std::string()) + ")")
                              .c_str());
        std::printf("  format     %s, %d subimage(s), %s colour\n", info.format.c_str(),
                    info.subimages, info.pixel_type.c_str());
        std::printf("  size       %dx%d\n", info.width, info.height);
        std::printf("  inputs     %s\n", info.layout.to_string().c_str());
        std::printf("  spp        %g (%s)\n", info.spp,
                    std::string(io::to_string(info.spp_source)).c_str());
        if (info.render_time) std::printf("  render     %.3f s\n", *info.render_time);
        std::string names;
        for (const auto& c : info.channels) names += (names.empty() ? "" : ", ") + c;
        std::printf("  channels   %s\n", names.c_str());
        std::string aovs;
        for (const auto& c : info.aovs) aovs += (aovs.empty() ? "" : ", ") + c;
        if (!aovs.empty()) std::printf("  aovs       %s\n", aovs.c_str());
      }
    } catch (const InputError& e) {
      report(e);
      ++rejected;
    }
  }
  if (o.json) std::cout << all.dump(2) << "\n";
  return rejected > 0 ? kBadInput : kOk;
}

}  // namespace proden::cli

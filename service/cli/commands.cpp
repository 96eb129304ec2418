#include "cli/commands.hpp"

#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <iostream>

#include "cli/progress.hpp"
#include "proden/accumulator.hpp"
#include "proden/error.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/metrics.hpp"
#include "proden/protocol/json.hpp"

#ifndef PRODEN_VERSION
#define PRODEN_VERSION "dev"
#endif

namespace proden::cli {
namespace {

using nlohmann::json;

io::ReadOptions read_options(const InputOptions& in) {
  io::ReadOptions r;
  r.renderer = in.renderer;
  r.spp = in.spp;
  r.features = in.features;
  return r;
}

void report(const InputError& e) {
  spdlog::error("{}: rejected ({}): {}", e.subject(), to_string(e.kind()), e.reason());
}

// Accumulates passes into a frame; rejected files are reported and leave the frame untouched.
struct Accumulated {
  FrameAccumulator frame;
  int rejected = 0;
};

Accumulated accumulate(const std::vector<std::string>& files, const InputOptions& input,
                       const std::string& what, bool progress) {
  Accumulated a;
  Progress bar(what, static_cast<int>(files.size()), progress);
  const auto options = read_options(input);
  for (const auto& f : files) {
    bar.step(f);
    try {
      io::PassInfo info;
      const Pass pass = io::read_pass(f, options, &info);
      const AddResult r = a.frame.add(pass, f);
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

}  // namespace

int run_denoise(const DenoiseOptions& o) {
  const auto t0 = std::chrono::steady_clock::now();
  Accumulated a = accumulate(o.passes, o.input, "accumulate", o.progress);
  if (a.frame.empty()) {
    spdlog::error("no usable pass among {} file(s); nothing written", o.passes.size());
    return kBadInput;
  }
  const FrameEstimate est = a.frame.estimate({.halves = false, .features = false});

  // The progressive pipeline (denoise, SURE, mixing) lands in a later stage; until then the
  // result is the accumulated render.
  const Image& result = est.mean;
  std::vector<io::NamedChannel> channels;
  io::add_layer(channels, "", result);
  if (o.aov) {
    io::add_layer(channels, "render.", est.mean);
    io::add_layer(channels, "variance.", est.variance);
  }
  io::WriteOptions w;
  w.half = o.half;
  w.attributes = {
      {"Software", std::string("proden ") + PRODEN_VERSION},
      {"proden:passes", std::to_string(a.frame.passes())},
      {"proden:spp", std::to_string(a.frame.total_spp())},
      {"proden:inputs", a.frame.layout().to_string()},
      {"proden:variance_source", std::string(protocol::to_string(est.variance_source))},
      {"proden:low_confidence", est.low_confidence() ? "true" : "false"},
  };
  try {
    io::write_image(o.out, a.frame.width(), a.frame.height(), channels, w);
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return kInternalError;
  }
  const double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();

  if (o.json) {
    json j = protocol::frame_summary(a.frame, est);
    j["output"] = o.out;
    j["rejected_files"] = a.rejected;
    j["seconds"] = secs;
    std::cout << j.dump(2) << "\n";
  } else {
    spdlog::info("{}: {} pass(es), {} spp, inputs {}, variance from {}{}; {:.2f} s", o.out,
                 a.frame.passes(), a.frame.total_spp(), a.frame.layout().to_string(),
                 protocol::to_string(est.variance_source),
                 est.low_confidence() ? " (low confidence)" : "", secs);
  }
  return a.rejected > 0 ? kBadInput : kOk;
}

int run_eval(const EvalOptions& o) {
  Accumulated ref = accumulate(o.references, o.input, "reference", true);
  if (ref.frame.empty()) {
    spdlog::error("no usable reference image");
    return kBadInput;
  }
  const Image reference = ref.frame.estimate({.halves = false, .features = false}).mean;
  int rejected = ref.rejected;
  json results = json::array();
  const auto options = read_options(o.input);
  for (const auto& f : o.images) {
    try {
      const Image img = io::read_rgb(f, options);
      if (!img.same_size(reference)) {
        throw InputError(InputErrorKind::size_mismatch, f,
                         "is " + std::to_string(img.width()) + "x" + std::to_string(img.height()) +
                             ", the reference is " + std::to_string(reference.width()) + "x" +
                             std::to_string(reference.height()));
      }
      json r = protocol::to_json(compute_metrics(img, reference));
      r["image"] = f;
      results.push_back(r);
    } catch (const InputError& e) {
      report(e);
      ++rejected;
    }
  }
  if (o.json) {
    std::cout << json{{"reference", o.references}, {"results", results}}.dump(2) << "\n";
  } else {
    std::printf("%-48s %12s %12s %12s %10s\n", "image", "RMSE", "relMSE", "SMAPE", "nonfinite");
    for (const auto& r : results) {
      std::printf("%-48s %12.6g %12.6g %12.6g %10zu\n", r["image"].get<std::string>().c_str(),
                  r["rmse"].get<double>(), r["relmse"].get<double>(), r["smape"].get<double>(),
                  r["nonfinite"].get<std::size_t>());
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
        std::printf("  renderer   %s%s\n", std::string(io::to_string(info.renderer)).c_str(),
                    info.layer.empty() ? "" : (" (view layer " + info.layer + ")").c_str());
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

#include "daemon/processor.hpp"

#include <OpenImageIO/imageio.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <stdexcept>
#include <string_view>

#include "proden/io/image_writer.hpp"
#include "proden/network/builtin.hpp"
#include "proden/progressive.hpp"

namespace proden::daemon {

bool FrameProcessor::supports(const protocol::PipelineSpec& spec, std::string& why) {
  if (spec.denoiser != "auto" && spec.denoiser != "nlmeans" && spec.denoiser != "none") {
    why = "pipeline.denoiser: one of auto, nlmeans, none";
    return false;
  }
  if (spec.mixer != "auto" && spec.mixer != "closed-form" && spec.mixer != "stein" &&
      spec.mixer != "inverse-error" && spec.mixer != "network") {
    why = "pipeline.mixer: one of auto, network, closed-form (= stein), stein, inverse-error";
    return false;
  }
  return true;
}

ProcessedFrame FrameProcessor::process(const FrameEstimate& estimate,
                                       const protocol::PipelineSpec& spec,
                                       const ErrorContext& error_context) {
  ProcessedFrame out;
  out.layers.emplace_back("render", estimate.mean);
  out.layers.emplace_back("variance", estimate.variance);
  const auto var = estimate.variance.data();
  if (spec.denoiser == "none") {  // publish the accumulated render; its own error is Var[x]
    out.result = estimate.mean;
    double sum = 0.0;
    for (float x : var) sum += static_cast<double>(x);
    out.estimated_mse = var.empty() ? 0.0 : sum / static_cast<double>(var.size());
    out.estimated_mse_source = "variance";
    out.error = estimate_error({&estimate.mean, &estimate.variance, &out.result}, error_context);
    return out;
  }
  PipelineOptions options;
  if (spec.mixer == "inverse-error") options.mixer.rule = ClosedFormRule::inverse_error;
  // "auto" is whichever mixer won on the validation scenes (network::kDefaultMixer).
  const bool use_network =
      spec.mixer == "network" ||
      (spec.mixer == "auto" && std::string_view(network::kDefaultMixer) == "network");
  std::unique_ptr<Mixer> mixer;
  if (use_network) mixer = std::make_unique<network::NetworkMixer>(network::builtin_network());
  PipelineResult r = run_pipeline(estimate, options, nullptr, mixer.get());
  // Error of z = x + a (y - x) from the pipeline's own estimates (SURE of z).
  out.estimated_mse = estimated_result_mse(estimate.mean, estimate.variance, r);
  out.estimated_mse_source = "variance+sure";
  out.stage_seconds = {{"denoise", r.timings.denoise}, {"sure", r.timings.sure},
                       {"mix", r.timings.mixer},       {"ttest", r.timings.ttest},
                       {"compose", r.timings.compose}, {"pipeline", r.timings.wall}};
  out.error = estimate_error(
      {&estimate.mean, &estimate.variance, &r.result, &r.denoised, &r.alpha, &r.sure},
      error_context);
  out.result = std::move(r.result);
  out.layers.emplace_back("denoised", std::move(r.denoised));
  out.layers.emplace_back("alpha", std::move(r.alpha));
  out.layers.emplace_back("sure", std::move(r.sure));
  return out;
}

std::vector<std::string> FrameProcessor::publish(
    const ProcessedFrame& frame, const std::string& base, bool png,
    const std::vector<std::pair<std::string, std::string>>& attributes,
    const AovAccumulator* aovs) {
  std::vector<io::NamedChannel> channels;
  io::add_layer(channels, "", frame.result);
  for (const auto& [name, img] : frame.layers) {
    io::add_layer(channels, name + ".", img, img.channels() == 1 ? "Y" : "RGB");
  }
  io::WriteOptions w;
  w.attributes = attributes;
  const std::vector<AovChannel> aov_planes = aovs ? aovs->result() : std::vector<AovChannel>{};
  io::add_aovs(channels, aov_planes);
  if (aovs)
    w.attributes.insert(w.attributes.end(), aovs->attributes().begin(), aovs->attributes().end());
  std::vector<std::string> written;
  io::write_image(base + ".exr", frame.result.width(), frame.result.height(), channels, w);
  written.push_back(base + ".exr");
  if (png) {
    write_png_preview(base + ".png", frame.result);
    written.push_back(base + ".png");
  }
  return written;
}

bool known_layer(const std::string& layer) {
  return layer == "result" || layer == "render" || layer == "variance" || layer == "denoised" ||
         layer == "alpha" || layer == "sure";
}

Image read_layer(const std::string& exr_path, const std::string& layer) {
  auto in = OIIO::ImageInput::open(exr_path);
  if (!in) throw std::runtime_error(exr_path + ": cannot open: " + OIIO::geterror());
  const OIIO::ImageSpec& spec = in->spec();
  const std::string prefix = layer == "result" ? "" : layer + ".";
  std::vector<int> idx;
  for (const char* s : {"R", "G", "B"}) {
    for (int c = 0; c < spec.nchannels; ++c) {
      if (spec.channelnames[static_cast<std::size_t>(c)] == prefix + s) idx.push_back(c);
    }
  }
  if (idx.size() != 3) {
    idx.clear();
    for (int c = 0; c < spec.nchannels; ++c) {
      if (spec.channelnames[static_cast<std::size_t>(c)] == prefix + "Y") idx.push_back(c);
    }
    if (idx.size() != 1) return {};
  }
  const int w = spec.width, h = spec.height;
  std::vector<float> all(static_cast<std::size_t>(w) * h * spec.nchannels);
  if (!in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, all.data())) {
    throw std::runtime_error(exr_path + ": read failed: " + in->geterror());
  }
  Image img(w, h, 3);
  const std::size_t n = img.pixels();
  for (int c = 0; c < 3; ++c) {
    const int src = idx[idx.size() == 3 ? static_cast<std::size_t>(c) : 0];
    auto plane = img.plane(c);
    for (std::size_t p = 0; p < n; ++p) {
      plane[p] = all[p * static_cast<std::size_t>(spec.nchannels) + static_cast<std::size_t>(src)];
    }
  }
  return img;
}

void write_png_preview(const std::string& path, const Image& rgb) {
  Image out(rgb.width(), rgb.height(), 3);
  for (int c = 0; c < 3; ++c) {
    auto src = rgb.plane(std::min(c, rgb.channels() - 1));
    auto dst = out.plane(c);
    for (std::size_t p = 0; p < src.size(); ++p) {
      float x = std::isfinite(src[p]) ? std::max(src[p], 0.0f) : 0.0f;
      x = x / (1.0f + x);
      x = x <= 0.0031308f ? 12.92f * x : 1.055f * std::pow(x, 1.0f / 2.4f) - 0.055f;
      dst[p] = std::clamp(x, 0.0f, 1.0f);
    }
  }
  std::vector<io::NamedChannel> channels;
  io::add_layer(channels, "", out);
  io::WriteOptions w;
  w.compression = "";
  io::write_image(path, out.width(), out.height(), channels, w);
}

}  // namespace proden::daemon

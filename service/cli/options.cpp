#include "cli/options.hpp"

#include <string>

#include "proden/protocol/compression.hpp"

namespace proden::cli {

void add_input_flags(CLI::App& cmd, InputOptions& in, std::string& renderer) {
  cmd.add_option("--renderer", renderer, "Renderer profile: auto, cycles, povray, generic")
      ->check(CLI::IsMember({"auto", "cycles", "povray", "generic"}))
      ->capture_default_str();
  cmd.add_option("--spp", in.spp, "Samples per pixel of each pass whose file does not say")
      ->check(CLI::PositiveNumber);
  cmd.add_flag("!--no-features", in.features,
               "Ignore albedo/normal/depth even if the passes carry them");
  cmd.add_option("--view-layer", in.view_layer,
                 "Blender view layer to read from multilayer EXRs (default: the alphabetically "
                 "first, said in the log)");
}

void PipelineFlags::add_to(CLI::App& cmd) {
  for (const auto& info : protocol::pipeline_option_table()) {
    Slot& s = slots_.emplace_back();
    s.info = &info;
    if (CLI::Option* existing = cmd.get_option_no_throw(info.flag)) {
      s.option = existing;
      continue;
    }
    switch (info.kind) {
      case protocol::OptionKind::choice:
        s.option = cmd.add_option(info.flag, s.text, info.help)
                       ->check(CLI::IsMember(info.choices))
                       ->type_name("NAME");
        break;
      case protocol::OptionKind::integer:
        s.option = cmd.add_option(info.flag, s.integer, info.help)
                       ->check(CLI::Range(info.min, info.max))
                       ->type_name("N");
        break;
      case protocol::OptionKind::boolean:
        s.option = cmd.add_flag(info.flag, s.flag, info.help);
        break;
      case protocol::OptionKind::text:
        s.option = cmd.add_option(info.flag, s.text, info.help)->type_name("FILE");
        break;
    }
  }
}

nlohmann::json PipelineFlags::given() const {
  nlohmann::json j = nlohmann::json::object();
  for (const Slot& s : slots_) {
    if (s.option->count() == 0) continue;
    const std::string key(s.info->key());
    switch (s.info->kind) {
      case protocol::OptionKind::choice:
      case protocol::OptionKind::text:
        j[key] = s.option->as<std::string>();
        break;
      case protocol::OptionKind::integer:
        j[key] = s.option->as<int>();
        break;
      case protocol::OptionKind::boolean:
        j[key] = false;  // the flag turns the option off
        break;
    }
  }
  return j;
}

void DenoiseCommand::add_to(CLI::App& app) {
  DenoiseOptions& den = options;
  command = app.add_subcommand("denoise", "Accumulate one frame's passes and write the result");
  CLI::App& d = *command;
  add_input_flags(d, den.input, renderer);
  d.add_option("--out", den.out, "Output EXR")->required();
  d.add_flag("--aov", den.aov,
             "Also write render, variance, denoised, alpha, sure and mixvariance layers");
  d.add_flag("--half", den.half, "Write 16-bit half floats instead of 32-bit");
  d.add_option("--compression", den.compression,
               "OpenEXR compression: " + protocol::frame_compressions() +
                   " (the job's output.compression; auto is piz here: the daemon publishes it "
                   "uncompressed and "
                   "compresses it when idle)")
      ->check([](const std::string& c) {
        return protocol::is_frame_compression(c) ? std::string()
                                                 : "one of " + protocol::frame_compressions();
      })
      ->capture_default_str();
  d.add_flag("--json", den.json, "Print a JSON summary of the frame on stdout");
  d.add_flag("-q,--quiet", quiet, "No progress display");
  d.add_option("passes", den.passes, "Pass files of one frame")->required();
  // The pipeline's options, spelt as the daemon's job JSON spells them (docs/api.md).
  pipeline.add_to(d);
  d.add_flag("--timings", den.timings, "Print the time of each stage");
  d.add_flag("!--no-renderer-aovs", den.renderer_aovs,
             "Do not accumulate the passes' AOVs (Combined.A, Depth, Mist, ...) beside the result");
}

void DenoiseCommand::finish() {
  options.input.renderer = io::parse_renderer(renderer).value_or(io::Renderer::automatic);
  options.progress = !quiet;
  options.pipeline = pipeline.given();
}

}  // namespace proden::cli

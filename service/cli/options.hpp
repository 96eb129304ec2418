// The CLI's command-line forms: the input flags shared by denoise, eval and info, and `proden
// denoise` with its pipeline flags registered from the options' vocabulary
// (protocol/pipeline_spec.hpp). The flags a user gave come back as {key: value}, the same form as a
// job's `pipeline` object, so the CLI and the daemon parse them into the same PipelineOptions.
#pragma once

#include <CLI/CLI.hpp>
#include <deque>
#include <nlohmann/json.hpp>
#include <string>

#include "cli/commands.hpp"
#include "proden/protocol/pipeline_spec.hpp"

namespace proden::cli {

// --renderer, --spp, --no-features and --view-layer.
void add_input_flags(CLI::App& cmd, InputOptions& in, std::string& renderer);

class PipelineFlags {
 public:
  // Adds every option of the table to `cmd`; a flag the command already has (--no-features, shared
  // with eval and info) is reused as it is.
  void add_to(CLI::App& cmd);
  // The options given on the command line, by key ("weights" included: the CLI reads that file).
  nlohmann::json given() const;

 private:
  struct Slot {
    const protocol::PipelineOptionInfo* info = nullptr;
    CLI::Option* option = nullptr;
    std::string text;
    int integer = 0;
    bool flag = false;
  };
  std::deque<Slot> slots_;  // stable addresses: CLI11 writes into them
};

// `proden denoise`: add_to() registers the subcommand and its flags (bound to this object, which
// must stay in place); finish() completes `options` after parsing.
struct DenoiseCommand {
  DenoiseOptions options;
  std::string renderer = "auto";
  bool quiet = false;
  PipelineFlags pipeline;
  CLI::App* command = nullptr;

  void add_to(CLI::App& app);
  void finish();
};

}  // namespace proden::cli

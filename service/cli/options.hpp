// `proden denoise`'s pipeline flags, registered from the options' vocabulary
// (protocol/pipeline_spec.hpp): after parsing, the flags a user gave come back as {key: value}, the
// same form as a job's `pipeline` object, so the CLI and the daemon parse them into the same
// PipelineOptions.
#pragma once

#include <CLI/CLI.hpp>
#include <deque>
#include <nlohmann/json.hpp>

#include "proden/protocol/pipeline_spec.hpp"

namespace proden::cli {

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

}  // namespace proden::cli

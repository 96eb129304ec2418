// The pipeline's options as proden's front ends spell them: one table gives each option's key
// (the job's `pipeline.<key>`, docs/api.md), its CLI flag, its accepted values or bounds and its
// help, and one parser turns {key: value} from either front end into the same PipelineOptions.
#pragma once

#include <nlohmann/json.hpp>
#include <string>
#include <string_view>
#include <vector>

#include "proden/progressive.hpp"

namespace proden::protocol {

enum class OptionKind {
  choice,   // a string among `choices`
  integer,  // an integer in [min, max]
  boolean,  // on by default; the CLI flag turns it off
  text,     // a string (a file name: CLI only)
};

struct PipelineOptionInfo {
  PipelineOption option;
  std::string flag;  // the CLI's spelling; for a boolean, the flag that turns it off
  OptionKind kind = OptionKind::choice;
  std::vector<std::string> choices;  // choice: every accepted spelling
  int min = 0, max = 0;              // integer: inclusive bounds (the front ends' limits)
  bool job = true;                   // also accepted as a job's pipeline.<key>
  std::string help;                  // ends with the default
  // Sets the option from a checked value, and reads it back in canonical spelling (null for a
  // CLI-only option, which the CLI applies itself).
  void (*apply)(PipelineOptions&, const nlohmann::json&) = nullptr;
  nlohmann::json (*read)(const PipelineOptions&) = nullptr;
  std::string_view key() const { return option_key(option); }
};

// Every option the front ends accept, in the order they are applied and documented.
const std::vector<PipelineOptionInfo>& pipeline_option_table();
// The entry with this key, or null.
const PipelineOptionInfo* find_option(std::string_view key);
// The CLI flag for an option key (the key itself for options without a flag).
std::string cli_flag(std::string_view key);

// Options from {key: value}: a job's `pipeline` object, or the CLI flags a user gave. Keys not
// given keep the library defaults ("auto" resolves to the default denoiser and mixer). Throws
// PipelineError naming the key: unknown key, wrong type, value not accepted, out of bounds, a
// CLI-only key, or a closed_form_rule that contradicts mixer stein|inverse-error.
PipelineOptions parse_pipeline_options(const nlohmann::json& given);

// The options in the same keys and canonical spellings (every job key; weights excluded):
// parse_pipeline_options(settings_json(o)) sets everything settings_json(o) shows.
nlohmann::json settings_json(const PipelineOptions& options);

}  // namespace proden::protocol

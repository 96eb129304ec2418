// The CLI's commands as functions over parsed options, so tests and the daemon can call them.
// Each returns a process exit code (see ExitCode).
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "proden/io/profile.hpp"
#include "proden/protocol/compression.hpp"

namespace proden::cli {

enum ExitCode : int {
  kOk = 0,
  kInternalError = 1,  // a bug or an environment failure (cannot write output, out of memory)
  kUsage = 2,          // bad command line
  kBadInput = 3,       // some input file was rejected (the rest was still processed)
};

struct InputOptions {
  io::Renderer renderer = io::Renderer::automatic;
  std::optional<double> spp;
  bool features = true;
  std::string view_layer;  // Cycles view layer ("" = the alphabetically first, said in the log)
};

struct DenoiseOptions {
  InputOptions input;
  // The pipeline options given, by key (protocol/pipeline_spec.hpp; the job JSON's `pipeline`
  // form), plus "weights": a network weights file to read instead of the built-in ones.
  nlohmann::json pipeline = nlohmann::json::object();
  std::vector<std::string> passes;
  std::string out;
  bool aov = false;
  bool half = false;
  std::string compression{protocol::kDefaultFrameCompression};  // protocol/compression.hpp
  bool json = false;
  bool timings = false;  // print each stage's time (and in --json)
  bool progress = true;
  bool renderer_aovs = true;  // accumulate the passes' AOVs and write them beside the result
};

struct EvalOptions {
  InputOptions input;
  std::vector<std::string> references;  // several = passes of a reference, averaged
  std::vector<std::string> images;
  std::vector<std::string> layers;  // "result" (R,G,B), "render", "denoised", ...; empty = result
  bool json = false;
};

struct InfoOptions {
  InputOptions input;
  std::vector<std::string> files;
  bool json = false;
};

int run_denoise(const DenoiseOptions& o);
int run_eval(const EvalOptions& o);
int run_info(const InfoOptions& o);

}  // namespace proden::cli

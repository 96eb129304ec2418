// The HTTP API contract of `proden serve` (docs/api.md): request and response bodies as C++ types
// with their JSON forms. Field names are part of the contract: extend, never rename.
#pragma once

#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "proden/progressive.hpp"
#include "proden/protocol/compression.hpp"
#include "proden/protocol/estimate.hpp"

namespace proden::protocol {

// An API failure: HTTP status, machine-readable code, human message -> {"error":{...}}.
class ApiError : public std::runtime_error {
 public:
  ApiError(int status, std::string code, const std::string& message)
      : std::runtime_error(message), status_(status), code_(std::move(code)) {}
  int status() const { return status_; }
  const std::string& code() const { return code_; }
  nlohmann::json to_json() const;

 private:
  int status_;
  std::string code_;
};

struct WatchSpec {
  std::string dir;      // absolute directory (canonicalised by the daemon)
  std::string pattern;  // relative path with {frame} (or ####) and {pass}
};

struct OutputSpec {
  std::string dir;
  bool png = false;  // also write a tone-mapped PNG preview (EXR is always written)
  // Base name of the published files: {job}, {frame} (unpadded) or a run of # (zero-padded).
  std::string name = "{job}_####";
  int history = 8;   // versions kept per frame besides the latest (0-1000)
  bool aovs = true;  // accumulate and write the renderer's AOVs beside the result
  std::string compression{kDefaultFrameCompression};  // the EXR's (protocol/compression.hpp)
};

// A job's `pipeline` object: the keys the client set, as sent (validated; echoed back with
// `denoiser` and `mixer` defaulting to "auto"), and the options they mean
// (protocol/pipeline_spec.hpp: the same vocabulary as the CLI's flags).
struct PipelineSpec {
  nlohmann::json given = nlohmann::json::object();
  PipelineOptions options;

  // From a `pipeline` object; throws PipelineError naming the key (parse_job_spec reports it as
  // 400 invalid_field "pipeline.<key>: ...").
  static PipelineSpec from_json(const nlohmann::json& given);
};

// A job as created by POST /api/v1/jobs and reported by GET /api/v1/jobs[/{id}].
struct JobSpec {
  std::string id;
  std::string name;
  std::optional<WatchSpec> watch;  // none: passes arrive only by upload
  std::string renderer = "auto";   // auto | cycles | povray | generic
  std::optional<double> spp;       // samples per pass when the files do not say
  PipelineSpec pipeline;
  OutputSpec output;
  std::string view_layer;        // Blender view layer to read ("" = the alphabetically first)
  std::optional<Target> target;  // when a frame is good enough
  int min_passes = 2;            // passes before a frame may converge
  bool paused = false;
  std::string created;  // RFC 3339 UTC
};

// The largest samples-per-pixel count one pass may claim (job spec `spp` or a file's header):
// 2^20. With it the accumulator's spp weights and their squares stay far from overflow.
inline constexpr double kMaxPassSpp = 1048576.0;

// Checks the numbers and names of a spec (throws ApiError 400 naming the field); parse_job_spec
// calls it, and the daemon calls it on any spec it is handed.
void validate_job_spec(const JobSpec& spec);

// Validates and parses a job creation body (throws ApiError 400 naming the bad field). Paths are
// returned as given; the daemon resolves them against its allowed roots.
JobSpec parse_job_spec(const nlohmann::json& body);
nlohmann::json to_json(const JobSpec& job);
JobSpec job_from_json(const nlohmann::json& j);  // the daemon's own persisted form

// One accepted pass of a frame, as persisted and reported.
struct PassIdentity {
  std::string pass;    // the {pass} value
  std::string source;  // path it was read from (watched file or stored upload)
  std::uint64_t size = 0;
  std::int64_t mtime_ns = 0;
  std::uint64_t content_hash = 0;  // hash of the file's bytes
};
nlohmann::json to_json(const PassIdentity& p);
PassIdentity pass_identity_from_json(const nlohmann::json& j);

// What GET .../frames lists and GET .../frames/{frame} details.
struct FrameStatus {
  std::string job;
  long frame = 0;
  int passes = 0;
  double spp = 0.0;
  std::uint64_t version = 0;  // increases with each published update
  std::string updated;        // RFC 3339 UTC of the last published version
  // The pipeline's own error estimate of the published result (PipelineResult::estimated_error):
  // the mean of the result's SURE ("source":"variance+sure"), or of Var[x] when nothing was
  // denoised ("source":"variance").
  double estimated_mse = 0.0;
  std::string estimated_mse_source = "variance";
  int width = 0, height = 0;
  std::string inputs;           // layout, e.g. "HDR+ALB+NRM"
  std::string variance_source;  // between_passes | renderer | spatial
  bool low_confidence = false;
  std::string state_digest;  // hex digest of the accumulated state
  std::vector<PassIdentity> pass_list;
  std::vector<nlohmann::json> quarantined;
  std::vector<std::string> outputs;  // published file paths
  bool pending = false;              // passes waiting to be processed
  // Issue 13 (docs/api.md): the full estimated_error object of the latest version (null before
  // the first), the convergence state, what was read, the versions that can be fetched.
  nlohmann::json estimated_error;
  bool converged = false;
  nlohmann::json convergence;
  std::string renderer, view_layer;
  std::vector<std::string> view_layers;
  nlohmann::json aovs = nlohmann::json::array();
  std::vector<std::uint64_t> versions;  // newest first
};
nlohmann::json to_json(const FrameStatus& f, bool detail);

// The published files' base name (no directory, no extension) of `frame` for output.name
// `name_template` and job `job`: {job}, {frame}, and Blender's # padding (at least that many
// digits).
std::string expand_output_name(const std::string& name_template, const std::string& job,
                               long frame);

// RFC 3339 UTC timestamp with milliseconds for `now`.
std::string now_rfc3339();

}  // namespace proden::protocol

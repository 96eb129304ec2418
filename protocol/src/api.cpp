#include "proden/protocol/api.hpp"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cmath>
#include <ctime>

#include "proden/protocol/json.hpp"
#include "proden/protocol/pipeline_spec.hpp"
#include "proden/protocol/publish.hpp"

namespace proden::protocol {

using nlohmann::json;

namespace {

[[noreturn]] void bad(const std::string& field, const std::string& why) {
  throw ApiError(400, "invalid_field", field + ": " + why);
}

std::string get_string(const json& obj, const char* key, const std::string& field, bool required,
                       const std::string& fallback = {}) {
  if (!obj.contains(key) || obj[key].is_null()) {
    if (required) bad(field, "required");
    return fallback;
  }
  if (!obj[key].is_string()) bad(field, "must be a string");
  return obj[key].get<std::string>();
}

// 1..max characters, each one `ok` accepts (no regular expression on request text).
template <class Pred>
bool charset(const std::string& s, std::size_t max, Pred ok) {
  return !s.empty() && s.size() <= max &&
         std::all_of(s.begin(), s.end(), [&](char c) { return ok(static_cast<unsigned char>(c)); });
}

void check_pattern(const std::string& p) {
  if (p.empty() || p.size() > 512) bad("watch.pattern", "must be 1-512 characters");
  if (p.front() == '/') bad("watch.pattern", "must be relative to watch.dir");
  if (p.find("{pass}") == std::string::npos) bad("watch.pattern", "needs a {pass} placeholder");
  if (p.find("{frame}") == std::string::npos && p.find('#') == std::string::npos) {
    bad("watch.pattern", "needs a {frame} placeholder (or Blender's #### padding)");
  }
  std::size_t start = 0;
  while (start <= p.size()) {
    const auto end = std::min(p.find('/', start), p.size());
    const std::string part = p.substr(start, end - start);
    if (part.empty() || part == "." || part == "..") {
      bad("watch.pattern", "empty, '.' or '..' path components are not allowed");
    }
    start = end + 1;
  }
  if (p.find('\0') != std::string::npos) bad("watch.pattern", "contains NUL");
}

// The job's pipeline object as the client gave it, denoiser and mixer defaulting to "auto".
json pipeline_json(const PipelineSpec& p) {
  json out = {{"denoiser", "auto"}, {"mixer", "auto"}};
  out.update(p.given);
  return out;
}

}  // namespace

PipelineSpec PipelineSpec::from_json(const json& given) {
  return {given, parse_pipeline_options(given)};
}

json ApiError::to_json() const {
  return {{"error", {{"code", code_}, {"message", what()}}}};
}

// Smallest spp a pass may claim: a fraction of a sample makes no sense below this.
constexpr double kMinPassSpp = 1e-3;

void validate_job_spec(const JobSpec& spec) {
  if (spec.spp &&
      (!std::isfinite(*spec.spp) || *spec.spp < kMinPassSpp || *spec.spp > kMaxPassSpp)) {
    bad("spp", "must be a number of samples per pass in [0.001, 1048576]");
  }
  if (!is_frame_compression(spec.output.compression)) {
    bad("output.compression", "one of " + frame_compressions());
  }
}

JobSpec parse_job_spec(const json& body) {
  if (!body.is_object()) throw ApiError(400, "invalid_body", "job body must be a JSON object");
  JobSpec j;
  j.name = get_string(body, "name", "name", true);
  const auto name_char = [](unsigned char c) {
    return std::isalnum(c) || c == '.' || c == '_' || c == '-';
  };
  if (!charset(j.name, 64, name_char) || j.name == "." || j.name == "..") {
    bad("name", "1-64 characters of A-Z a-z 0-9 . _ -");
  }
  if (body.contains("watch") && !body["watch"].is_null()) {
    const json& w = body["watch"];
    if (!w.is_object()) bad("watch", "must be an object");
    WatchSpec ws;
    ws.dir = get_string(w, "dir", "watch.dir", true);
    ws.pattern = get_string(w, "pattern", "watch.pattern", true);
    check_pattern(ws.pattern);
    j.watch = ws;
  }
  j.renderer = get_string(body, "renderer", "renderer", false, "auto");
  if (j.renderer != "auto" && j.renderer != "cycles" && j.renderer != "povray" &&
      j.renderer != "generic") {
    bad("renderer", "one of auto, cycles, povray, generic");
  }
  if (body.contains("spp") && !body["spp"].is_null()) {
    if (!body["spp"].is_number()) bad("spp", "must be a number");
    j.spp = body["spp"].get<double>();
  }
  if (body.contains("pipeline") && !body["pipeline"].is_null()) {
    const json& p = body["pipeline"];
    if (!p.is_object()) bad("pipeline", "must be an object");
    try {
      j.pipeline = PipelineSpec::from_json(p);
    } catch (const PipelineError& e) {
      bad("pipeline." + e.key(), e.message());
    }
  }
  if (!body.contains("output") || !body["output"].is_object()) bad("output", "required object");
  const json& o = body["output"];
  j.output.dir = get_string(o, "dir", "output.dir", true);
  if (o.contains("formats") && !o["formats"].is_null()) {
    if (!o["formats"].is_array()) bad("output.formats", "must be an array of \"exr\", \"png\"");
    for (const auto& f : o["formats"]) {
      if (f == "png") {
        j.output.png = true;
      } else if (f != "exr") {
        bad("output.formats", "supported formats are \"exr\" (always written) and \"png\"");
      }
    }
  }
  if (o.contains("png")) {
    if (!o["png"].is_boolean()) bad("output.png", "must be a boolean");
    j.output.png = j.output.png || o["png"].get<bool>();
  }
  if (o.contains("name") && !o["name"].is_null()) {
    j.output.name = get_string(o, "name", "output.name", false);
    if (!charset(j.output.name, 128, [](unsigned char c) {
          return std::isalnum(c) || c == '.' || c == '_' || c == '-' || c == '#' || c == '{' ||
                 c == '}';
        })) {
      bad("output.name", "1-128 characters of A-Z a-z 0-9 . _ - # { }");
    }
    const bool frame_tag = j.output.name.find("{frame}") != std::string::npos;
    const auto hashes = std::count(j.output.name.begin(), j.output.name.end(), '#');
    const auto first = j.output.name.find('#');
    const auto run_end =
        std::min(j.output.name.find_first_not_of('#', first), j.output.name.size());
    const bool one_run = hashes > 0 && run_end - first == static_cast<std::size_t>(hashes);
    if (frame_tag == (hashes > 0) || (hashes > 0 && !one_run)) {
      bad("output.name", "needs exactly one frame placeholder: {frame} or one run of #");
    }
    std::string rest = j.output.name;
    for (const char* tag : {"{job}", "{frame}"}) {
      for (auto at = rest.find(tag); at != std::string::npos; at = rest.find(tag)) {
        rest.erase(at, std::string_view(tag).size());
      }
    }
    if (rest.find_first_of("{}") != std::string::npos) {
      bad("output.name", "placeholders are {job}, {frame} and #");
    }
    if (j.output.name == "." || j.output.name == "..") bad("output.name", "not a file name");
  }
  if (o.contains("history") && !o["history"].is_null()) {
    if (!o["history"].is_number_integer() || o["history"].get<long long>() < 0 ||
        o["history"].get<long long>() > 1000) {
      bad("output.history", "an integer 0-1000");
    }
    j.output.history = o["history"].get<int>();
  }
  if (o.contains("aovs") && !o["aovs"].is_null()) {
    if (!o["aovs"].is_boolean()) bad("output.aovs", "must be a boolean");
    j.output.aovs = o["aovs"].get<bool>();
  }
  if (o.contains("compression") && !o["compression"].is_null()) {
    j.output.compression = get_string(o, "compression", "output.compression", false);
  }
  if (body.contains("view_layer") && !body["view_layer"].is_null()) {
    j.view_layer = get_string(body, "view_layer", "view_layer", false);
    if (j.view_layer.empty() || j.view_layer.size() > 64 ||
        j.view_layer.find_first_of(std::string_view("\0\n\r", 3)) != std::string::npos) {
      bad("view_layer", "1-64 characters, a Blender view layer name");
    }
  }
  if (body.contains("target") && !body["target"].is_null()) {
    j.target = parse_target(body["target"], "target");
  }
  if (body.contains("min_passes") && !body["min_passes"].is_null()) {
    if (!body["min_passes"].is_number_integer() || body["min_passes"].get<long long>() < 1 ||
        body["min_passes"].get<long long>() > 100000) {
      bad("min_passes", "an integer 1-100000");
    }
    j.min_passes = body["min_passes"].get<int>();
  }
  if (body.contains("paused")) {
    if (!body["paused"].is_boolean()) bad("paused", "must be a boolean");
    j.paused = body["paused"].get<bool>();
  }
  validate_job_spec(j);
  return j;
}

json to_json(const JobSpec& j) {
  json out = {{"id", j.id},
              {"name", j.name},
              {"renderer", j.renderer},
              {"pipeline", pipeline_json(j.pipeline)},
              {"output",
               {{"dir", j.output.dir},
                {"formats", j.output.png ? json::array({"exr", "png"}) : json::array({"exr"})},
                {"name", j.output.name},
                {"history", j.output.history},
                {"aovs", j.output.aovs},
                {"compression", j.output.compression}}},
              {"min_passes", j.min_passes},
              {"paused", j.paused},
              {"state", j.paused ? "paused" : "active"},
              {"created", j.created}};
  out["watch"] = j.watch ? json{{"dir", j.watch->dir}, {"pattern", j.watch->pattern}} : json();
  out["spp"] = j.spp ? json(*j.spp) : json();
  out["target"] = j.target ? to_json(*j.target) : json();
  out["view_layer"] = j.view_layer.empty() ? json() : json(j.view_layer);
  return out;
}

JobSpec job_from_json(const json& j) {
  JobSpec s = parse_job_spec(j);
  s.id = j.at("id").get<std::string>();
  s.created = j.value("created", "");
  return s;
}

json to_json(const PassIdentity& p) {
  return {{"pass", p.pass},
          {"source", p.source},
          {"size", p.size},
          {"mtime_ns", p.mtime_ns},
          {"content_hash", p.content_hash}};
}

PassIdentity pass_identity_from_json(const json& j) {
  PassIdentity p;
  p.pass = j.at("pass").get<std::string>();
  p.source = j.at("source").get<std::string>();
  p.size = checked_number<std::uint64_t>(j.at("size"), "size");
  p.mtime_ns = checked_number<std::int64_t>(j.at("mtime_ns"), "mtime_ns");
  p.content_hash = checked_number<std::uint64_t>(j.at("content_hash"), "content_hash");
  return p;
}

json to_json(const FrameStatus& f, bool detail) {
  json j = {{"job", f.job},         {"frame", f.frame},
            {"passes", f.passes},   {"spp", f.spp},
            {"version", f.version}, {"updated", f.updated.empty() ? json() : json(f.updated)},
            {"pending", f.pending}, {"converged", f.converged}};
  // The full estimated_error object of the latest version (docs/error_estimate.md); before the
  // first one, the pipeline's mean error alone.
  j["estimated_mse"] = f.estimated_mse;
  j["estimated_mse_source"] = f.estimated_mse_source;
  j["estimated_error"] = f.estimated_error.is_null()
                             ? json{{"mse", f.estimated_mse}, {"source", f.estimated_mse_source}}
                             : f.estimated_error;
  if (!detail) return j;
  j["width"] = f.width;
  j["height"] = f.height;
  j["inputs"] = f.inputs;
  j["variance_source"] = f.variance_source;
  j["low_confidence"] = f.low_confidence;
  j["state_digest"] = f.state_digest;
  json passes = json::array();
  for (const auto& p : f.pass_list) passes.push_back(to_json(p));
  j["pass_list"] = passes;
  j["quarantined"] = f.quarantined;
  j["outputs"] = f.outputs;
  j["convergence"] = f.convergence;
  j["renderer"] = f.renderer.empty() ? json() : json(f.renderer);
  j["view_layer"] = f.view_layer.empty() ? json() : json(f.view_layer);
  j["view_layers"] = f.view_layers;
  j["aovs"] = f.aovs;
  j["versions"] = f.versions;
  return j;
}

std::string expand_output_name(const std::string& t, const std::string& job, long frame) {
  std::string out;
  for (std::size_t i = 0; i < t.size();) {
    if (t.compare(i, 5, "{job}") == 0) {
      out += job;
      i += 5;
    } else if (t.compare(i, 7, "{frame}") == 0) {
      out += std::to_string(frame);
      i += 7;
    } else if (t[i] == '#') {
      std::size_t n = 0;
      while (i + n < t.size() && t[i + n] == '#') ++n;
      std::string digits = std::to_string(frame);
      if (digits.size() < n) digits.insert(0, n - digits.size(), '0');
      out += digits;
      i += n;
    } else {
      out += t[i++];
    }
  }
  return out;
}

std::string now_rfc3339() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t t = std::chrono::system_clock::to_time_t(now);
  const auto ms =
      std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000;
  std::tm tm{};
  gmtime_r(&t, &tm);
  char buf[96];
  std::snprintf(buf, sizeof buf, "%04d-%02d-%02dT%02d:%02d:%02d.%03dZ", tm.tm_year + 1900,
                tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, static_cast<int>(ms));
  return buf;
}

}  // namespace proden::protocol

// Fuzz target: JSON a client or an operator hands the daemon, parsed as the daemon parses it.
//  - A job body (POST /api/v1/jobs, daemon/api.cpp): the UTF-8 check, json::parse,
//    protocol::parse_job_spec (with PipelineSpec::from_json) and the watch-pattern compile.
//  - The daemon's config file (daemon/config.cpp: apply_json over the defaults).
// Every input is tried as both.
//
// Properties: a bad job is refused only with ApiError 400 (any other exception would be a 500,
// issue 11, class 1) and a bad config only with std::runtime_error; no undefined behaviour on any
// number (UBSan); every message is JSON-safe text. An accepted job holds bounded numbers (spp a
// sample count the pass reader accepts, issue 11, class 9) and round-trips: its JSON form parses
// back (job_from_json) to the same JSON. An accepted config round-trips through to_json as well.
#include <cmath>
#include <cstdint>
#include <string>
#include <string_view>

#include "daemon/config.hpp"
#include "daemon/pass_pattern.hpp"
#include "fuzz_check.hpp"
#include "proden/error.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/protocol/api.hpp"
#include "proden/protocol/pipeline_spec.hpp"

using namespace proden;
using nlohmann::json;

namespace {

void job(const json& body) {
  protocol::JobSpec spec;
  try {
    spec = protocol::parse_job_spec(body);
    if (spec.watch) {
      std::string why;
      if (!daemon::PassPattern::parse(spec.watch->pattern, why)) {
        fuzz::check_json_safe(why);
        return;
      }
    }
  } catch (const protocol::ApiError& e) {
    FUZZ_CHECK(e.status() == 400);
    fuzz::check_json_safe(e.what());
    fuzz::check_json_safe(e.code());
    (void)e.to_json().dump();
    return;
  }
  if (spec.spp) FUZZ_CHECK(io::valid_spp(*spec.spp));
  fuzz::check_json_safe(spec.name);
  spec.id = "j-fuzz";
  spec.created = "2026-01-01T00:00:00.000Z";
  const json once = protocol::to_json(spec);
  const std::string text = once.dump();  // strict: every string is UTF-8
  const protocol::JobSpec again = protocol::job_from_json(json::parse(text));
  FUZZ_CHECK(protocol::to_json(again).dump() == text);
  FUZZ_CHECK(protocol::settings_json(again.pipeline.options) ==
             protocol::settings_json(spec.pipeline.options));
}

void config(const json& j) {
  daemon::Config c;
  try {
    daemon::apply_json(c, j);
  } catch (const std::runtime_error& e) {
    fuzz::check_json_safe(io::printable(e.what()));
    return;
  }
  const json once = daemon::to_json(c);
  const std::string text = once.dump();
  daemon::Config d;
  daemon::apply_json(d, json::parse(text));  // must not throw
  FUZZ_CHECK(daemon::to_json(d).dump() == text);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string_view text(reinterpret_cast<const char*>(data), size);
  // As Api::route: a body that is not UTF-8 is refused before it is parsed.
  if (io::invalid_utf8_offset(text) != std::string_view::npos) return 0;
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    // nlohmann quotes the bytes it stopped at, which may cut a UTF-8 sequence: the daemon's
    // reply passes the message through io::printable (Api::error), as here.
    fuzz::check_json_safe(io::printable(std::string("body is not JSON: ") + e.what()));
    return 0;
  }
  job(j);
  config(j);
  return 0;
}

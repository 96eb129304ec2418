// Bounds of every number a client or operator gives the daemon: the job spec (POST /api/v1/jobs)
// and the config file; refusals name the field.
#include <catch2/catch.hpp>

#include "daemon/config.hpp"
#include "proden/protocol/api.hpp"

using namespace proden;
using nlohmann::json;

namespace {

std::string refusal(const json& body) {
  try {
    protocol::parse_job_spec(body);
  } catch (const protocol::ApiError& e) {
    CHECK(e.status() == 400);
    CHECK(e.code() == "invalid_field");
    return e.what();
  }
  return "";
}

json job_with(const char* key, json value) {
  json j = {{"name", "n"}, {"output", {{"dir", "/o"}}}};
  j[key] = std::move(value);
  return j;
}

std::string config_refusal(const json& j) {
  daemon::Config c;
  try {
    daemon::apply_json(c, j);
  } catch (const std::exception& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST_CASE("Job spec: spp must be a sane positive number", "[daemon][bounds]") {
  CHECK_THAT(refusal(job_with("spp", 1e300)), Catch::StartsWith("spp"));
  CHECK_THAT(refusal(job_with("spp", 0)), Catch::StartsWith("spp"));
  CHECK_THAT(refusal(job_with("spp", -4)), Catch::StartsWith("spp"));
  CHECK_THAT(refusal(job_with("spp", 1e-300)), Catch::StartsWith("spp"));
  CHECK_THAT(refusal(job_with("spp", protocol::kMaxPassSpp * 2)), Catch::StartsWith("spp"));
  CHECK_THAT(refusal(job_with("spp", "4")), Catch::StartsWith("spp"));
  CHECK(refusal(job_with("spp", 4)).empty());
  CHECK(refusal(job_with("spp", 0.5)).empty());
  CHECK(refusal(job_with("spp", protocol::kMaxPassSpp)).empty());
}

TEST_CASE("Job spec: validate_job_spec checks specs not parsed from JSON", "[daemon][bounds]") {
  protocol::JobSpec s = protocol::parse_job_spec(job_with("spp", 4));
  s.spp = std::numeric_limits<double>::quiet_NaN();
  CHECK_THROWS_AS(protocol::validate_job_spec(s), protocol::ApiError);
  s.spp = 8;
  CHECK_NOTHROW(protocol::validate_job_spec(s));
}

TEST_CASE("Job spec: output.compression is a lossless OpenEXR one, echoed back",
          "[daemon][bounds]") {
  const auto with = [](json c) {
    return json{{"name", "n"}, {"output", {{"dir", "/o"}, {"compression", std::move(c)}}}};
  };
  for (const char* lossy : {"dwaa", "b44", "pxr24", "ZIP", "", "zip "}) {
    CHECK_THAT(refusal(with(lossy)), Catch::StartsWith("output.compression"));
  }
  CHECK_THAT(refusal(with(3)), Catch::StartsWith("output.compression"));
  for (const auto c : protocol::kFrameCompressions) {
    const protocol::JobSpec s = protocol::parse_job_spec(with(std::string(c)));
    CHECK(s.output.compression == c);
    CHECK(protocol::to_json(s)["output"]["compression"] == std::string(c));
  }
  // A spec stored before the key existed reads with the default.
  const protocol::JobSpec d = protocol::parse_job_spec(job_with("spp", 4));
  CHECK(d.output.compression == protocol::kDefaultFrameCompression);
  protocol::JobSpec s = d;
  s.output.compression = "dwaa";
  CHECK_THROWS_AS(protocol::validate_job_spec(s), protocol::ApiError);
}

TEST_CASE("output.compression auto ends as PIZ; the others are themselves", "[daemon][bounds]") {
  CHECK(protocol::kDefaultFrameCompression == "auto");
  CHECK(protocol::resolve_frame_compression("auto") == "piz");
  for (const auto c : protocol::kFrameCompressions) {
    if (c == "auto") continue;
    CHECK(protocol::resolve_frame_compression(c) == c);
  }
  CHECK_THROWS_AS(protocol::resolve_frame_compression("dwaa"), std::invalid_argument);
}

TEST_CASE("Config: every number is bounded and a refusal names the key", "[daemon][bounds]") {
  CHECK(config_refusal(daemon::to_json(daemon::Config{})).empty());  // the defaults are valid
  CHECK_THAT(config_refusal({{"worker_threads", 1e300}}), Catch::Contains("worker_threads"));
  CHECK_THAT(config_refusal({{"worker_threads", 0}}), Catch::Contains("worker_threads"));
  CHECK_THAT(config_refusal({{"worker_threads", 2.5}}), Catch::Contains("worker_threads"));
  CHECK_THAT(config_refusal({{"port", 70000}}), Catch::Contains("port"));
  CHECK_THAT(config_refusal({{"io_threads", -1}}), Catch::Contains("io_threads"));
  CHECK_THAT(config_refusal({{"max_resident_frames", 1e12}}),
             Catch::Contains("max_resident_frames"));
  CHECK_THAT(config_refusal({{"limits", {{"max_upload_bytes", -1}}}}),
             Catch::Contains("limits.max_upload_bytes"));
  CHECK_THAT(config_refusal({{"limits", {{"max_body_bytes", 1e300}}}}),
             Catch::Contains("limits.max_body_bytes"));
  CHECK_THAT(config_refusal({{"limits", {{"sse_history", 1e15}}}}),
             Catch::Contains("limits.sse_history"));
  CHECK_THAT(config_refusal({{"limits", {{"request_timeout_ms", 0}}}}),
             Catch::Contains("limits.request_timeout_ms"));
  CHECK_THAT(config_refusal({{"watch", {{"settle_ms", 1e300}}}}),
             Catch::Contains("watch.settle_ms"));
  CHECK_THAT(config_refusal({{"watch", {{"max_attempts", 0}}}}),
             Catch::Contains("watch.max_attempts"));
  CHECK_THAT(config_refusal({{"watch", {{"tick_ms", -5}}}}), Catch::Contains("watch.tick_ms"));
  CHECK_THAT(config_refusal({{"watch", {{"max_depth", 1000}}}}),
             Catch::Contains("watch.max_depth"));
  daemon::Config c;
  c.worker_threads = 100000;
  CHECK_THROWS_WITH(daemon::validate(c), Catch::Contains("worker_threads"));
}

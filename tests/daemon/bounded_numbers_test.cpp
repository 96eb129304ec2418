// Numbers read from outside are bounded where they enter (issue 11, class 9): a job's spp, the
// daemon's config and a frame's state record. Before, nlohmann's get<T>() cast 1e20 into an int
// (undefined behaviour, flagged by UBSan in fuzz/job_config_fuzz.cpp), wrapped -1 into a byte
// count, and a job accepted an spp the pass reader then refused for every pass.
#include <catch2/catch.hpp>

#include <cmath>
#include <limits>
#include <stdexcept>

#include "daemon/config.hpp"
#include "daemon/frame_state.hpp"
#include "proden/protocol/api.hpp"

using namespace proden;
using nlohmann::json;

TEST_CASE("a job's spp is a sample count the pass reader accepts", "[bounds]") {
  const auto job = [](const char* spp) {
    return json::parse(std::string(R"({"name":"a","output":{"dir":"/x"},"spp":)") + spp + "}");
  };
  CHECK(*protocol::parse_job_spec(job("4")).spp == 4.0);
  CHECK(*protocol::parse_job_spec(job("4294967296")).spp == 4294967296.0);
  for (const char* bad : {"1e300", "4294967297", "0", "-1", "1e400"}) {
    INFO(bad);
    CHECK_THROWS_AS(protocol::parse_job_spec(job(bad)), protocol::ApiError);
  }
}

TEST_CASE("config numbers are integers in range, never cast", "[bounds][config]") {
  const auto apply = [](const char* text) {
    daemon::Config c;
    daemon::apply_json(c, json::parse(text));
    return c;
  };
  CHECK(apply(R"({"port": 9090})").port == 9090);
  CHECK(apply(R"({"limits": {"max_body_bytes": 2048}})").limits.max_body_bytes == 2048);
  for (const char* bad :
       {R"({"port": 1e20})", R"({"port": 4294967296})", R"({"worker_threads": 2.5})",
        R"({"limits": {"max_body_bytes": -1}})", R"({"input": {"max_pixels": -5}})",
        R"({"watch": {"settle_ms": 1e300}})", R"({"port": "80"})"}) {
    INFO(bad);
    CHECK_THROWS_AS(apply(bad), std::runtime_error);
  }
}

TEST_CASE("a frame record with a non-finite or out-of-range number is corrupt", "[bounds][state]") {
  daemon::FrameRecord rec;
  rec.frame = 3;
  rec.passes = 2;
  rec.spp = 8.0;
  const json good = daemon::to_json(rec);
  CHECK(daemon::frame_record_from_json(good).passes == 2);
  const auto with = [&](const char* key, const json& v) {
    json j = good;
    j[key] = v;
    return j;
  };
  CHECK_THROWS(
      daemon::frame_record_from_json(with("spp", std::numeric_limits<double>::infinity())));
  CHECK_THROWS(daemon::frame_record_from_json(with("estimated_mse", std::nan(""))));
  CHECK_THROWS(daemon::frame_record_from_json(with("passes", 1e20)));
  CHECK_THROWS(daemon::frame_record_from_json(with("width", 4294967296LL)));
  CHECK_THROWS(daemon::frame_record_from_json(with("version", -1)));
  CHECK_THROWS(daemon::frame_record_from_json(
      json::parse(good.dump().replace(good.dump().find("\"spp\":8.0"), 9, "\"spp\":1e400"))));
}

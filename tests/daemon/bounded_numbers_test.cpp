// Numbers read back from a frame's state record are bounded (issue 11, class 9; a job's spec and
// the config: spec_bounds_test.cpp). Before, nlohmann's get<T>() cast 1e20 into an int (undefined
// behaviour, which UBSan flags in the fuzz targets), wrapped -1 into a u64, and a record holding
// NaN or inf was accepted. (JSON text "1e400" nlohmann itself refuses: kept as a control.)
#include <catch2/catch.hpp>

#include <cmath>
#include <limits>

#include "daemon/frame_state.hpp"

using namespace proden;
using nlohmann::json;

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

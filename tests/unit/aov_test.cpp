// AovAccumulator: spp-weighted means with non-finite samples skipped, Cryptomatte and index passes
// passed through from the first pass, channels appearing later, strong guarantee on bad input,
// and the persisted form (round trip, corruption refused).
#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <limits>

#include "proden/aov.hpp"
#include "proden/error.hpp"
#include "proden/hash.hpp"

using namespace proden;

namespace {

AovChannel chan(const std::string& name, int w, int h, float v) {
  return {name, Image(w, h, 1, v)};
}

}  // namespace

TEST_CASE("AOVs: modes follow the channel names", "[aov]") {
  CHECK(aov_mode("Depth.Z") == AovMode::mean);
  CHECK(aov_mode("A") == AovMode::mean);
  CHECK(aov_mode("DiffCol.R") == AovMode::mean);
  CHECK(aov_mode("CryptoObject00.r") == AovMode::first_pass);
  CHECK(aov_mode("CryptoMaterial02.a") == AovMode::first_pass);
  CHECK(aov_mode("IndexOB.X") == AovMode::first_pass);
  CHECK(aov_mode("IndexMA.X") == AovMode::first_pass);
}

TEST_CASE("AOVs: spp-weighted means, non-finite samples skipped, pass-through", "[aov]") {
  AovAccumulator acc;
  acc.add({chan("Depth.Z", 4, 3, 2.0f), chan("CryptoObject00.r", 4, 3, 7.0f)}, 4.0,
          {{"cryptomatte/abc/name", "CryptoObject"}});
  auto second =
      std::vector<AovChannel>{chan("Depth.Z", 4, 3, 5.0f), chan("CryptoObject00.r", 4, 3, 9.0f),
                              chan("Mist.Z", 4, 3, 1.0f)};
  second[0].plane.at(1, 1, 0) = std::numeric_limits<float>::quiet_NaN();
  acc.add(second, 12.0, {{"cryptomatte/abc/name", "other"}});
  const auto r = acc.result();
  REQUIRE(r.size() == 3);
  CHECK(r[0].name == "CryptoObject00.r");
  CHECK(r[0].plane.at(0, 0, 0) == 7.0f);  // the first pass's, unchanged
  CHECK(r[1].name == "Depth.Z");
  CHECK(r[1].plane.at(0, 0, 0) == Approx((4 * 2.0 + 12 * 5.0) / 16.0));
  CHECK(r[1].plane.at(1, 1, 0) == 2.0f);  // the NaN sample is skipped
  CHECK(r[2].name == "Mist.Z");
  CHECK(r[2].plane.at(3, 2, 0) == 1.0f);  // appeared in pass 2: its own mean
  REQUIRE(acc.attributes().size() == 1);
  CHECK(acc.attributes()[0].second == "CryptoObject");  // the first pass's attribute stays
  const auto modes = acc.channels();
  CHECK(modes[0].second == AovMode::first_pass);
  CHECK(modes[1].second == AovMode::mean);
}

TEST_CASE("AOVs: bad input changes nothing", "[aov]") {
  AovAccumulator acc;
  acc.add({chan("Depth.Z", 4, 4, 1.0f)}, 1.0);
  const auto before = acc.serialize();
  CHECK_THROWS_AS(acc.add({chan("Depth.Z", 4, 4, 3.0f), chan("Mist.Z", 5, 4, 0.0f)}, 1.0),
                  std::invalid_argument);
  CHECK_THROWS_AS(acc.add({chan("Depth.Z", 8, 8, 3.0f)}, 1.0), std::invalid_argument);
  CHECK_THROWS_AS(acc.add({chan("Depth.Z", 4, 4, 3.0f), chan("Depth.Z", 4, 4, 3.0f)}, 1.0),
                  std::invalid_argument);
  CHECK_THROWS_AS(acc.add({chan("Depth.Z", 4, 4, 3.0f)}, 0.0), std::invalid_argument);
  CHECK(acc.serialize() == before);
}

TEST_CASE("AOVs: persisted state round-trips and refuses corruption", "[aov]") {
  AovAccumulator acc;
  CHECK(acc.serialize().empty());
  CHECK(AovAccumulator::deserialize({}).empty());
  acc.add({chan("A", 6, 5, 1.0f), chan("IndexOB.X", 6, 5, 3.0f)}, 2.0, {{"k", "v"}});
  acc.add({chan("A", 6, 5, 0.5f)}, 2.0);
  const auto blob = acc.serialize();
  const AovAccumulator back = AovAccumulator::deserialize(blob);
  CHECK(back.serialize() == blob);
  CHECK(back.result()[0].plane.at(2, 2, 0) == Approx(0.75));
  auto bad = blob;
  bad[bad.size() / 2] ^= 0x5a;
  CHECK_THROWS_AS(AovAccumulator::deserialize(bad), InputError);
  bad = blob;
  bad.resize(bad.size() - 9);
  CHECK_THROWS_AS(AovAccumulator::deserialize(bad), InputError);
  // Version 1 (daemons before frame state format 4): the same layout, checksummed by hash_bytes.
  REQUIRE(blob[7] == 2);
  auto v1 = blob;
  v1[7] = 1;
  const std::size_t body = v1.size() - 8;
  const std::uint64_t h = hash_bytes({v1.data(), body}, 0x616f7673746174);
  std::memcpy(v1.data() + body, &h, sizeof h);
  CHECK(AovAccumulator::deserialize(v1).serialize() == blob);
  v1[body / 2] ^= 0x5a;
  CHECK_THROWS_AS(AovAccumulator::deserialize(v1), InputError);
  auto v3 = blob;
  v3[7] = 3;  // a version this daemon does not know
  CHECK_THROWS_AS(AovAccumulator::deserialize(v3), InputError);
}

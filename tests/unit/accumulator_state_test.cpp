// FrameAccumulator persistence: serialize/deserialize round trips, corrupt blobs are refused,
// and states written by the previous format version still load.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <span>

#include "proden/accumulator.hpp"
#include "proden/error.hpp"
#include "proden/hash.hpp"
#include "test_support.hpp"

using namespace proden;

TEST_CASE("accumulator state round-trips bit-identically", "[accumulator][state]") {
  const Layout layouts[] = {Layout{}, Layout{true, true, true, false},
                            Layout{false, false, false, true}};
  for (const Layout& layout : layouts) {
    FrameAccumulator a;
    for (std::uint64_t s = 1; s <= 3; ++s)
      a.add(test::make_pass(17, 9, 2.0 + static_cast<double>(s), s, layout),
            "p" + std::to_string(s));
    const auto blob = a.serialize();
    FrameAccumulator b = FrameAccumulator::deserialize(blob);
    CHECK(b.state_digest() == a.state_digest());
    CHECK(b.passes() == 3);
    CHECK(b.layout() == layout);
    CHECK(b.history()[2].name == "p3");
    // Continuing after a restore gives the same state as never stopping.
    a.add(test::make_pass(17, 9, 4.0, 7, layout), "p7");
    b.add(test::make_pass(17, 9, 4.0, 7, layout), "p7");
    CHECK(b.state_digest() == a.state_digest());
    CHECK(b.serialize() == a.serialize());
  }
}

TEST_CASE("empty accumulator state round-trips", "[accumulator][state]") {
  FrameAccumulator a;
  FrameAccumulator b = FrameAccumulator::deserialize(a.serialize());
  CHECK(b.empty());
  CHECK(b.state_digest() == a.state_digest());
}

TEST_CASE("truncated or corrupt accumulator state is refused", "[accumulator][state]") {
  FrameAccumulator a;
  a.add(test::make_pass(8, 8, 4.0, 1), "a");
  a.add(test::make_pass(8, 8, 4.0, 2), "b");
  const auto blob = a.serialize();
  for (std::size_t cut :
       {std::size_t{0}, std::size_t{5}, std::size_t{16}, blob.size() / 2, blob.size() - 1}) {
    std::vector<std::uint8_t> t(blob.begin(), blob.begin() + static_cast<std::ptrdiff_t>(cut));
    CHECK_THROWS_AS(FrameAccumulator::deserialize(t), InputError);
  }
  auto flipped = blob;
  flipped[blob.size() / 3] ^= 0x40;
  CHECK_THROWS_AS(FrameAccumulator::deserialize(flipped), InputError);
  auto magic = blob;
  magic[0] = 'X';
  CHECK_THROWS_AS(FrameAccumulator::deserialize(magic), InputError);
  auto version = blob;
  version[7] = 99;
  CHECK_THROWS_AS(FrameAccumulator::deserialize(version), InputError);
}

namespace {

// The passes of tests/data/accumulator_v1.bin, a state written by format v1 (before feature
// halves): 5x4, albedo + normal + depth, 3 passes of 2, 3 and 4 spp.
float fixture_value(int k, int x, int y, int c, int salt) {
  return 0.1f + 0.01f * static_cast<float>((x * 7 + y * 13 + k * 29 + c * 3 + salt * 5) % 17);
}
Pass fixture_pass(int k) {
  Pass p;
  p.spp = 2.0 + k;
  p.colour = Image(5, 4, 3);
  p.albedo = Image(5, 4, 3);
  p.normal = Image(5, 4, 3);
  p.depth = Image(5, 4, 1);
  for (int y = 0; y < 4; ++y) {
    for (int x = 0; x < 5; ++x) {
      for (int c = 0; c < 3; ++c) {
        p.colour.at(x, y, c) = fixture_value(k, x, y, c, 0);
        p.albedo.at(x, y, c) = fixture_value(k, x, y, c, 1);
        p.normal.at(x, y, c) = fixture_value(k, x, y, c, 2) - 0.5f;
      }
      p.depth.at(x, y, 0) = 1.0f + fixture_value(k, x, y, 0, 3);
    }
  }
  return p;
}

std::vector<std::uint8_t> read_fixture(const std::string& name) {
  std::ifstream in(std::string(PRODEN_SOURCE_DIR) + "/tests/data/" + name, std::ios::binary);
  REQUIRE(in);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void check_images_close(const Image& a, const Image& b, double tol) {
  REQUIRE(a.same_size(b));
  REQUIRE(a.channels() == b.channels());
  for (std::size_t i = 0; i < a.data().size(); ++i) {
    INFO("value " << i);
    CHECK(a.data()[i] == Approx(b.data()[i]).margin(tol));
  }
}

}  // namespace

TEST_CASE("a version-1 state (no feature halves) still loads and keeps accumulating",
          "[accumulator][state]") {
  const auto blob = read_fixture("accumulator_v1.bin");
  REQUIRE(blob[7] == 1);  // the fixture really is version 1
  FrameAccumulator old = FrameAccumulator::deserialize(blob);
  CHECK(old.passes() == 3);
  CHECK(old.layout() == (Layout{true, true, true, false}));
  CHECK_FALSE(old.feature_halves());
  FrameAccumulator fresh;
  for (int k = 0; k < 3; ++k) fresh.add(fixture_pass(k), "v1pass" + std::to_string(k));
  CHECK(fresh.feature_halves());

  // Same statistics as accumulating the same passes today, but no feature halves.
  const FrameEstimate eo = old.estimate(), ef = fresh.estimate();
  check_images_close(eo.mean, ef.mean, 0.0);
  check_images_close(eo.variance, ef.variance, 0.0);
  check_images_close(eo.albedo, ef.albedo, 1e-7);
  check_images_close(eo.normal_variance, ef.normal_variance, 1e-9);
  check_images_close(eo.depth, ef.depth, 1e-7);
  REQUIRE_FALSE(eo.half_mean[0].empty());  // colour halves survive v1
  CHECK(eo.half_albedo[0].empty());
  CHECK(eo.half_depth[1].empty());
  REQUIRE_FALSE(ef.half_albedo[0].empty());

  // It keeps accumulating (feature means and spreads stay right) and saves as version 3
  // without ever claiming feature halves.
  old.add(fixture_pass(3), "v1pass3");
  fresh.add(fixture_pass(3), "v1pass3");
  const FrameEstimate eo4 = old.estimate(), ef4 = fresh.estimate();
  check_images_close(eo4.normal, ef4.normal, 1e-7);
  check_images_close(eo4.albedo_variance, ef4.albedo_variance, 1e-9);
  CHECK(eo4.half_normal[0].empty());
  const auto blob2 = old.serialize();
  CHECK(blob2[7] == 4);
  const FrameAccumulator again = FrameAccumulator::deserialize(blob2);
  CHECK_FALSE(again.feature_halves());
  CHECK(again.state_digest() == old.state_digest());
}

// tests/data/accumulator_v2.bin: written by format v2's serialize() (main at d765318, before
// quarters) from fixture_pass(0..3) named "v2pass0".."v2pass3"; kV2Digest is that writer's
// state_digest() of it, which the daemon stores beside the state and checks on load (made with
// the hash states before format 4 used: HashKind::legacy).
constexpr std::uint64_t kV2Digest = 0xc79b132e2820582cULL;

TEST_CASE("a version-2 state (no quarters) still loads, keeps its digest and accumulating",
          "[accumulator][state]") {
  const auto blob = read_fixture("accumulator_v2.bin");
  REQUIRE(blob[7] == 2);
  FrameAccumulator old = FrameAccumulator::deserialize(blob);
  CHECK(old.passes() == 4);
  CHECK(old.feature_halves());
  CHECK_FALSE(old.quarters());
  CHECK(old.state_digest(HashKind::legacy) == kV2Digest);
  CHECK(old.state_digest() != kV2Digest);  // format 4's digest is XXH3's
  FrameAccumulator plain, quartered({.quarters = true});
  for (int k = 0; k < 4; ++k) {
    plain.add(fixture_pass(k), "v2pass" + std::to_string(k));
    quartered.add(fixture_pass(k), "v2pass" + std::to_string(k));
  }
  // A state without quarters has the digest it had before quarters existed.
  CHECK(plain.state_digest(HashKind::legacy) == kV2Digest);
  CHECK(quartered.state_digest(HashKind::legacy) != kV2Digest);
  const FrameEstimate eo = old.estimate({.quarters = true});
  const FrameEstimate eq = quartered.estimate({.quarters = true});
  check_images_close(eo.mean, eq.mean, 0.0);
  check_images_close(eo.half_mean[1], eq.half_mean[1], 0.0);
  check_images_close(eo.half_normal[0], eq.half_normal[0], 0.0);
  CHECK(eo.quarter_mean[0].empty());  // its passes' sub-halves were never kept
  REQUIRE_FALSE(eq.quarter_mean[3].empty());
  old.add(fixture_pass(4), "v2pass4");
  CHECK(old.estimate({.quarters = true}).quarter_mean[0].empty());
  const auto blob3 = old.serialize();
  CHECK(blob3[7] == 4);
  CHECK_FALSE(FrameAccumulator::deserialize(blob3).quarters());
}

TEST_CASE("a state with quarters round-trips and resumes bit-identically", "[accumulator][state]") {
  FrameAccumulator a({.quarters = true});
  for (int k = 0; k < 5; ++k) a.add(fixture_pass(k), "q" + std::to_string(k));
  FrameAccumulator b = FrameAccumulator::deserialize(a.serialize());
  CHECK(b.quarters());
  CHECK(b.state_digest() == a.state_digest());
  a.add(fixture_pass(5), "q5");
  b.add(fixture_pass(5), "q5");
  CHECK(b.serialize() == a.serialize());
  const FrameEstimate ea = a.estimate({.quarters = true}), eb = b.estimate({.quarters = true});
  for (std::size_t q = 0; q < 4; ++q) {
    check_images_close(ea.quarter_mean[q], eb.quarter_mean[q], 0.0);
    check_images_close(ea.quarter_albedo[q], eb.quarter_albedo[q], 0.0);
  }
  // A sub-half flipped into a state changes what it loads as: the checksum refuses it.
  auto blob = a.serialize();
  blob[blob.size() / 2] ^= 1;
  CHECK_THROWS_AS(FrameAccumulator::deserialize(blob), InputError);
}

// tests/data/accumulator_v3.bin: written by format v3's serialize() as it was before the state
// was streamed (main at 656bb3d, which built the whole blob in one buffer) from fixture_pass(0..3)
// named "v3pass0".."v3pass3", with quarters. Version 4 is the same layout with another checksum:
// the streamed writer must produce those bytes, the version byte and the trailing checksum aside.
TEST_CASE("a streamed state is the version-3 layout, in pieces that leave the planes uncopied",
          "[accumulator][state]") {
  const auto v3 = read_fixture("accumulator_v3.bin");
  REQUIRE(v3[7] == 3);
  auto fixture = v3;
  fixture[7] = 4;
  const std::size_t body = fixture.size() - 8;
  const std::uint64_t sum =
      checksum_span(std::span<const std::uint8_t>(fixture).first(body), 0x61636373746174);
  std::memcpy(fixture.data() + body, &sum, sizeof sum);
  FrameAccumulator a({.quarters = true});
  for (int k = 0; k < 4; ++k) a.add(fixture_pass(k), "v3pass" + std::to_string(k));
  CHECK(a.serialize() == fixture);
  CHECK(a.serialized_size() == fixture.size());
  // The version-3 file still loads (its own hash), as the same state.
  CHECK(FrameAccumulator::deserialize(v3).state_digest() == a.state_digest());
  auto damaged = v3;
  damaged[body / 2] ^= 1;
  CHECK_THROWS_AS(FrameAccumulator::deserialize(damaged), InputError);
  std::vector<std::uint8_t> streamed;
  std::size_t pieces = 0;
  CHECK(a.serialize_to([&](std::span<const std::uint8_t> b) {
    streamed.insert(streamed.end(), b.begin(), b.end());
    ++pieces;
  }) == fixture.size());
  CHECK(streamed == fixture);
  CHECK(pieces >= 2);  // the body, then its hash
  // A checksum run beside it (the state file's) sees the same bytes, its checksum included.
  Checksum also(11);
  a.serialize_to([](std::span<const std::uint8_t>) {}, &also);
  CHECK(also.finish() == checksum_bytes(fixture, 11));
  CHECK(FrameAccumulator::deserialize(fixture).state_digest() == a.state_digest());

  // A frame big enough that each plane is handed over directly: the largest piece is one plane
  // (a half's colour means, 3 doubles per pixel), never the whole state.
  FrameAccumulator big;
  for (std::uint64_t s = 1; s <= 2; ++s)
    big.add(test::make_pass(160, 90, 4.0, s, Layout{true, true, true, false}),
            "p" + std::to_string(s));
  std::size_t largest = 0, total = 0;
  big.serialize_to([&](std::span<const std::uint8_t> b) {
    largest = std::max(largest, b.size());
    total += b.size();
  });
  CHECK(total == big.serialize().size());
  CHECK(largest == std::size_t{160} * 90 * 3 * sizeof(double));
}

// A state whose checksum is intact but which holds a non-finite number (damage before the
// checksum was computed, or a forged file) is refused: a frame never resumes from NaN (issue 11,
// class 9; the property fuzz/frame_state_fuzz.cpp asserts on every accepted state).
TEST_CASE("accumulator state with a non-finite number is refused", "[accumulator][state]") {
  FrameAccumulator a;
  a.add(test::make_pass(4, 3, 4.0, 1), "a");
  a.add(test::make_pass(4, 3, 4.0, 2), "b");
  const auto blob = a.serialize();
  // Re-seals a modified blob as serialize() does (its trailing hash).
  const auto seal = [](std::vector<std::uint8_t> b) {
    const std::size_t body = b.size() - 8;
    const std::uint64_t h =
        checksum_span(std::span<const std::uint8_t>(b).first(body), 0x61636373746174);
    std::memcpy(b.data() + body, &h, sizeof h);
    return b;
  };
  REQUIRE(FrameAccumulator::deserialize(seal(blob)).state_digest() == a.state_digest());
  const auto with_double_at = [&](std::size_t offset, double v) {
    auto b = blob;
    std::memcpy(b.data() + offset, &v, sizeof v);
    return seal(b);
  };
  // Half A's weight vector starts after magic(8) + width(4) + height(4) + flags(1) +
  // feature halves(1) + quarters(1) + length(8).
  constexpr std::size_t kFirstWeight = 27;
  for (double bad : {std::nan(""), std::numeric_limits<double>::infinity()}) {
    CHECK_THROWS_AS(FrameAccumulator::deserialize(with_double_at(kFirstWeight, bad)), InputError);
    // The last record's spp: before its half (i32) and three u64 counters, then the hash.
    const std::size_t last_spp = blob.size() - 8 - 3 * 8 - 4 - 8;
    CHECK_THROWS_AS(FrameAccumulator::deserialize(with_double_at(last_spp, bad)), InputError);
  }
  CHECK_THROWS_AS(
      FrameAccumulator::deserialize(with_double_at(blob.size() - 8 - 3 * 8 - 4 - 8, -4.0)),
      InputError);
}

// FrameAccumulator persistence: serialize/deserialize round trips, corrupt blobs are refused.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
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
        hash_span(std::span<const std::uint8_t>(b).first(body), 0x61636373746174);
    std::memcpy(b.data() + body, &h, sizeof h);
    return b;
  };
  REQUIRE(FrameAccumulator::deserialize(seal(blob)).state_digest() == a.state_digest());
  const auto with_double_at = [&](std::size_t offset, double v) {
    auto b = blob;
    std::memcpy(b.data() + offset, &v, sizeof v);
    return seal(b);
  };
  // Half A's weight vector starts after magic(8) + width(4) + height(4) + flags(1) + length(8).
  constexpr std::size_t kFirstWeight = 25;
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

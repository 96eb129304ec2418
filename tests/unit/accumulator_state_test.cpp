// FrameAccumulator persistence: serialize/deserialize round trips, corrupt blobs are refused.
#include <catch2/catch.hpp>

#include "proden/accumulator.hpp"
#include "proden/error.hpp"
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

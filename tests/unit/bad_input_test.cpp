// Bad files: each gives a clear InputError naming the file and the reason, and the frame's
// accumulated state stays exactly as it was.
#include <catch2/catch.hpp>

#include <filesystem>
#include <fstream>
#include <random>

#include "proden/accumulator.hpp"
#include "proden/error.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "test_support.hpp"

using namespace proden;
using Catch::Matchers::Contains;

namespace {

struct Frame {
  test::TempDir dir;
  FrameAccumulator acc;
  std::string good0, good1;
  Frame() {
    good0 = dir.file("pass_00.exr");
    good1 = dir.file("pass_01.exr");
    test::write_generic_exr(good0, test::make_pass(32, 16, 4, 1));
    test::write_generic_exr(good1, test::make_pass(32, 16, 4, 2));
    ingest(good0);
    ingest(good1);
  }
  void ingest(const std::string& f) { acc.add(io::read_pass(f), f); }

  // Ingesting `f` must fail with `kind`, a message naming the file and containing `reason`,
  // and leave the accumulated state bit-for-bit unchanged.
  void expect_rejected(const std::string& f, InputErrorKind kind, const std::string& reason) {
    const auto digest = acc.state_digest();
    const int passes = acc.passes();
    try {
      ingest(f);
      FAIL("accepted " << f);
    } catch (const InputError& e) {
      INFO(e.what());
      CHECK(e.kind() == kind);
      CHECK(e.subject() == f);
      CHECK_THAT(e.what(), Contains(f) && Contains(reason));
    }
    CHECK(acc.state_digest() == digest);
    CHECK(acc.passes() == passes);
  }
};

}  // namespace

TEST_CASE("zero-byte placeholder is refused", "[bad-input]") {
  Frame fr;
  const std::string f = fr.dir.file("placeholder.exr");
  std::ofstream(f).close();
  fr.expect_rejected(f, InputErrorKind::unreadable, "empty file (0 bytes)");
}

TEST_CASE("missing file is refused", "[bad-input]") {
  Frame fr;
  fr.expect_rejected(fr.dir.file("nope.exr"), InputErrorKind::unreadable, "no such file");
}

TEST_CASE("truncated EXR (half-written) is refused", "[bad-input]") {
  Frame fr;
  const std::string f3 = fr.dir.file("pass_03.exr");
  test::write_generic_exr(f3, test::make_pass(32, 16, 4, 3));
  const auto size = std::filesystem::file_size(f3);
  for (double fraction : {0.9, 0.5, 0.05}) {
    const std::string t =
        fr.dir.file("trunc_" + std::to_string(static_cast<int>(fraction * 100)) + ".exr");
    test::truncate_copy(f3, t, static_cast<std::uintmax_t>(static_cast<double>(size) * fraction));
    fr.expect_rejected(t, InputErrorKind::unreadable, "");
  }
}

TEST_CASE("truncated real Blender pass is refused", "[bad-input][real]") {
  Frame fr;
  FrameAccumulator blender;
  const std::string good = std::string(PRODEN_SAMPLES_DIR) + "/renders/cornell/pass_00.exr";
  const std::string t = fr.dir.file("blender_trunc.exr");
  test::truncate_copy(good, t, std::filesystem::file_size(good) / 2);
  blender.add(io::read_pass(good), good);
  const auto digest = blender.state_digest();
  CHECK_THROWS_AS(blender.add(io::read_pass(t), t), InputError);
  CHECK(blender.state_digest() == digest);
}

TEST_CASE("corrupt pixel data and garbage files are refused", "[bad-input]") {
  Frame fr;
  // A smooth image, so ZIP really compresses it: OpenEXR stores incompressible chunks raw, and
  // EXR has no checksum, so scrambled raw pixels are undetectable by any reader.
  Pass smooth = test::make_pass(32, 16, 4, 3);
  for (int c = 0; c < 3; ++c) {
    for (int y = 0; y < 16; ++y) {
      for (int x = 0; x < 32; ++x) smooth.colour.at(x, y, c) = 0.01f * static_cast<float>(x + y);
    }
  }
  const std::string f3 = fr.dir.file("pass_03.exr");
  test::write_generic_exr(f3, smooth);
  // Keep the header and offsets, scramble the compressed chunks.
  const auto size = std::filesystem::file_size(f3);
  {
    std::fstream io(f3, std::ios::in | std::ios::out | std::ios::binary);
    std::mt19937 rng(1);
    io.seekp(static_cast<std::streamoff>(size / 3));
    for (std::uintmax_t i = size / 3; i < size; ++i) io.put(static_cast<char>(rng()));
  }
  fr.expect_rejected(f3, InputErrorKind::unreadable, "");

  const std::string g = fr.dir.file("garbage.exr");
  {
    std::ofstream out(g, std::ios::binary);
    std::mt19937 rng(2);
    for (int i = 0; i < 4096; ++i) out.put(static_cast<char>(rng()));
  }
  fr.expect_rejected(g, InputErrorKind::unsupported_format, "not a readable image");
}

TEST_CASE("wrong resolution is refused", "[bad-input]") {
  Frame fr;
  const std::string f = fr.dir.file("small.exr");
  test::write_generic_exr(f, test::make_pass(16, 16, 4, 5));
  fr.expect_rejected(f, InputErrorKind::size_mismatch, "16x16 differs from the frame's 32x16");
}

TEST_CASE("missing colour channels are refused", "[bad-input]") {
  Frame fr;
  const std::string f = fr.dir.file("albedo_only.exr");
  Image alb(32, 16, 3, 0.5f);
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "Albedo.", alb);
  io::write_image(f, 32, 16, ch);
  fr.expect_rejected(f, InputErrorKind::missing_channels, "no colour channels");
}

TEST_CASE("a pass identical to an accumulated one is refused", "[bad-input]") {
  Frame fr;
  const std::string copy = fr.dir.file("copy_of_00.exr");
  std::filesystem::copy_file(fr.good0, copy);
  fr.expect_rejected(copy, InputErrorKind::duplicate, "identical to the already accumulated pass");
}

TEST_CASE("a file with NaN/Inf samples is accepted with those pixels dropped", "[bad-input]") {
  Frame fr;
  Pass p = test::make_pass(32, 16, 4, 9);
  p.colour.at(3, 4, 0) = std::numeric_limits<float>::quiet_NaN();
  p.colour.at(5, 6, 2) = -std::numeric_limits<float>::infinity();
  const std::string f = fr.dir.file("nan.exr");
  test::write_generic_exr(f, p);
  const Pass r = io::read_pass(f);
  const AddResult res = fr.acc.add(r, f);
  CHECK(res.dropped_pixels == 2);
  const FrameEstimate e = fr.acc.estimate();
  for (float v : e.mean.data()) REQUIRE(std::isfinite(v));
  for (float v : e.variance.data()) REQUIRE(std::isfinite(v));
  CHECK(e.passes.at(3, 4, 0) == 2.0f);
}

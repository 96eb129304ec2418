// Hostile pass files (issue 11, classes 1, 4 and 6): bytes that are not UTF-8 in channel names and
// header values, headers declaring gigabytes, and images of other formats named .exr. Each is
// refused (or reported) with a clear InputError, as printable text, before anything large is
// allocated; nothing here may crash or throw anything but InputError.
#include <OpenImageIO/imageio.h>
#include <sys/resource.h>
#include <catch2/catch.hpp>

#include <filesystem>
#include <nlohmann/json.hpp>

#include "exr_bytes.hpp"
#include "proden/error.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/protocol/json.hpp"
#include "test_support.hpp"

using namespace proden;
using Catch::Matchers::Contains;

namespace {

// Peak resident set of this process so far, in bytes.
std::uint64_t peak_rss() {
  rusage ru{};
  getrusage(RUSAGE_SELF, &ru);
  return static_cast<std::uint64_t>(ru.ru_maxrss) * 1024;
}

InputError read_error(const std::string& path, const io::ReadOptions& o = {}) {
  try {
    io::read_pass(path, o);
  } catch (const InputError& e) {
    return e;
  }
  FAIL("accepted " << path);
  throw std::logic_error("unreachable");
}

// An 8-bit RGB image in whatever format OIIO picks for `path`'s extension (PNG, TIFF, JPEG).
void write_8bit(const std::string& path, int size, unsigned char value) {
  auto out = OIIO::ImageOutput::create(path);
  REQUIRE(out);
  OIIO::ImageSpec spec(size, size, 3, OIIO::TypeDesc::UINT8);
  std::vector<unsigned char> px(static_cast<std::size_t>(size * size * 3), value);
  REQUIRE(out->open(path, spec));
  REQUIRE(out->write_image(OIIO::TypeDesc::UINT8, px.data()));
  REQUIRE(out->close());
}

// What the daemon does with a reader error: put it in a JSON event. It must not throw.
void require_json_safe(const std::string& text) {
  REQUIRE_NOTHROW(nlohmann::json({{"message", text}}).dump());
}

}  // namespace

TEST_CASE("an 8-bit PNG named .exr is refused by its magic bytes", "[io][hostile]") {
  test::TempDir dir;
  const std::string png = dir.file("frame.png");
  write_8bit(png, 8, 200);
  const std::string disguised = dir.file("pass_00.exr");
  std::filesystem::rename(png, disguised);
  for (auto r : {io::Renderer::automatic, io::Renderer::povray, io::Renderer::generic}) {
    io::ReadOptions o;
    o.renderer = r;
    const InputError e = read_error(disguised, o);
    CHECK(e.kind() == InputErrorKind::unsupported_format);
    CHECK_THAT(e.reason(), Contains("PNG"));
    CHECK_THROWS_AS(io::probe_pass(disguised, o), InputError);
  }
}

TEST_CASE("a Radiance HDR file is refused by the Cycles profile", "[io][hostile]") {
  test::TempDir dir;
  const Pass p = test::make_pass(6, 4, 1, 3);
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "", p.colour);
  io::write_image(dir.file("p.hdr"), 6, 4, ch);
  const std::string named_exr = dir.file("beauty_0001.exr");
  std::filesystem::rename(dir.file("p.hdr"), named_exr);
  io::ReadOptions cycles;
  cycles.renderer = io::Renderer::cycles;
  CHECK(read_error(named_exr, cycles).kind() == InputErrorKind::unsupported_format);
  io::ReadOptions pov;
  pov.renderer = io::Renderer::povray;
  CHECK(io::read_pass(named_exr, pov).colour.width() == 6);  // POV-Ray writes .hdr: accepted
}

TEST_CASE("TIFF, JPEG and random bytes are not passes", "[io][hostile]") {
  test::TempDir dir;
  for (const char* ext : {"tif", "jpg"}) {
    const std::string f = dir.file(std::string("img.") + ext);
    write_8bit(f, 4, 10);
    const std::string as_exr = dir.file(std::string("img_") + ext + ".exr");
    std::filesystem::rename(f, as_exr);
    CHECK(read_error(as_exr).kind() == InputErrorKind::unsupported_format);
  }
}

TEST_CASE("channel names and header values that are not UTF-8 come out printable",
          "[io][hostile]") {
  test::TempDir dir;
  // A channel the profiles do not know, with bytes that are not UTF-8, next to R,G,B.
  test::ExrSpec spec;
  spec.channels = {"B", "G", "R", "X\xff\xfe\x1b[2J"};
  spec.extra = {test::string_attribute("Software", "POV-Ray \xc3\x28 \xff"),
                test::string_attribute("note\xff", "\xed\xa0\x80")};
  const std::string f = dir.file("bytes.exr");
  test::write_bytes(f, test::exr_bytes(spec));
  io::PassInfo info;
  const Pass p = io::read_pass(f, {}, &info);
  CHECK(p.colour.width() == 4);
  CHECK(info.renderer == io::Renderer::povray);
  REQUIRE(info.channels.size() == 4);
  for (const auto& c : info.channels) require_json_safe(c);
  REQUIRE_NOTHROW(protocol::to_json(info).dump());
  CHECK_THAT(info.to_string(), !Contains("\x1b"));

  // Without colour channels the error lists the names found: printable too.
  spec.channels = {"\xff\xfe", "Y\x80"};
  const std::string g = dir.file("nocolour.exr");
  test::write_bytes(g, test::exr_bytes(spec));
  const InputError e = read_error(g);
  CHECK(e.kind() == InputErrorKind::missing_channels);
  require_json_safe(e.what());
  require_json_safe(e.reason());
  CHECK_THAT(e.reason(), Contains("\\xff\\xfe"));
}

TEST_CASE("a sample count that is not a finite count is refused", "[io][hostile]") {
  test::TempDir dir;
  for (const char* spp : {"inf", "1e300", "nan", "-4", "0"}) {
    test::ExrSpec spec;
    spec.channels = {"ViewLayer.Combined.B", "ViewLayer.Combined.G", "ViewLayer.Combined.R"};
    spec.extra = {test::string_attribute("cycles.ViewLayer.samples", spp)};
    const std::string f = dir.file(std::string("spp_") + spp + ".exr");
    test::write_bytes(f, test::exr_bytes(spec));
    INFO(spp);
    CHECK(read_error(f).kind() == InputErrorKind::invalid_value);
  }
}

TEST_CASE("a header attribute declaring 2^31 bytes is refused from the file size",
          "[io][hostile]") {
  test::TempDir dir;
  for (std::int64_t declared :
       {std::int64_t{0x7fffffff}, std::int64_t{1} << 30, std::int64_t{5000}}) {
    test::ExrSpec spec;
    test::ExrAttribute big{"bomb", "opaqueblob", {1, 2, 3, 4}, declared};
    spec.extra = {big};
    const std::string f = dir.file("attr_" + std::to_string(declared) + ".exr");
    test::write_bytes(f, test::exr_bytes(spec));
    const auto before = peak_rss();
    const InputError e = read_error(f);
    INFO(e.what());
    CHECK((e.kind() == InputErrorKind::too_large || e.kind() == InputErrorKind::unreadable));
    CHECK_THAT(e.reason(), Contains("attribute 'bomb' declares " + std::to_string(declared)));
    CHECK(peak_rss() - before < (std::uint64_t{64} << 20));
  }
}

TEST_CASE("12000x12000 pixels declared by a small file are refused before decoding",
          "[io][hostile]") {
  test::TempDir dir;
  test::ExrSpec spec;
  spec.declared_width = 12000;
  spec.declared_height = 12000;
  spec.width = 16;  // the scanlines actually present
  spec.height = 16;
  const std::string f = dir.file("huge.exr");
  test::write_bytes(f, test::exr_bytes(spec));
  REQUIRE(std::filesystem::file_size(f) < 8192);
  const auto before = peak_rss();
  const InputError e = read_error(f);
  INFO(e.what());
  CHECK(e.kind() == InputErrorKind::too_large);
  CHECK_THAT(e.reason(), Contains("12000x12000"));
  CHECK(peak_rss() - before < (std::uint64_t{64} << 20));
  CHECK_THROWS_AS(io::probe_pass(f), InputError);
}

// Two small files on which OpenImageIO 2.4's OpenEXR Core-library reader (the `openexr:core`
// attribute) crashed while proden tried it for speed (fuzz/findings.md, rows 6 and 7): a scanline
// file that also declares `tiles` (a division by zero) and a mutated Cycles pass whose header made
// the Core library allocate 1.7 GB. proden reads with OpenEXR's C++ library: each is read or
// refused with an InputError, within a small memory budget.
TEST_CASE("files that crashed OIIO's Core-library EXR reader are read or refused",
          "[io][hostile]") {
  for (const char* name : {"finding_core_tiles_in_scanline.exr", "finding_core_header_bomb.exr"}) {
    INFO(name);
    const std::string f = std::string(PRODEN_SOURCE_DIR) + "/fuzz/corpus/pass_reader/" + name;
    REQUIRE(std::filesystem::exists(f));
    const auto before = peak_rss();
    try {
      const Pass p = io::read_pass(f);
      CHECK(p.colour.width() > 0);
    } catch (const InputError& e) {
      CHECK_FALSE(std::string(e.reason()).empty());
    }
    CHECK(peak_rss() - before < (std::uint64_t{64} << 20));
  }
}

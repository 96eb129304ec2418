// The pass reader's bounds and byte-buffer entry points (io/image_header.hpp, pass_reader.hpp):
// header walks of hostile EXR and Radiance headers, the per-read memory budget, the frame size
// checked from the header, reads from memory that never touch the file system, printable text.
#include <OpenImageIO/imageio.h>
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <catch2/catch.hpp>

#include <filesystem>
#include <fstream>
#include <iterator>

#include "exr_bytes.hpp"
#include "proden/error.hpp"
#include "proden/io/image_header.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/io/text.hpp"
#include "test_support.hpp"

using namespace proden;
using Catch::Matchers::Contains;

namespace {

std::vector<std::uint8_t> slurp(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

InputError inspect_error(const std::vector<std::uint8_t>& bytes, const io::ReadLimits& lim = {}) {
  try {
    io::inspect_header(io::MemorySource(bytes), "mem", lim);
  } catch (const InputError& e) {
    return e;
  }
  FAIL("header accepted");
  throw std::logic_error("unreachable");
}

std::string samples(const std::string& rel) {
  return std::string(PRODEN_SAMPLES_DIR) + "/" + rel;
}

}  // namespace

TEST_CASE("printable text: valid UTF-8 passes, everything else is escaped", "[io][text]") {
  CHECK(io::printable("ViewLayer.Combined.R") == "ViewLayer.Combined.R");
  CHECK(io::printable("caf\xc3\xa9 \xe2\x82\xac \xf0\x9f\x98\x80") ==
        "caf\xc3\xa9 \xe2\x82\xac \xf0\x9f\x98\x80");
  CHECK(io::printable("a\xff"
                      "b") == "a\\xffb");
  CHECK(io::printable("\x1b[2J\n") == "\\x1b[2J\\x0a");
  CHECK(io::printable("\xc0\xaf") == "\\xc0\\xaf");                    // overlong '/'
  CHECK(io::printable("\xed\xa0\x80") == "\\xed\\xa0\\x80");           // a UTF-16 surrogate
  CHECK(io::printable("\xf4\x90\x80\x80") == "\\xf4\\x90\\x80\\x80");  // above U+10FFFF
  CHECK(io::printable("\xe2\x82") == "\\xe2\\x82");                    // cut short
  CHECK(io::printable(std::string("a\0b", 3)) == "a\\x00b");
  CHECK(io::is_valid_utf8("\xc3\xa9"));
  CHECK_FALSE(io::is_valid_utf8("\xc3"));
  CHECK(io::invalid_utf8_offset("ab\xff") == 2);
  // Every byte string becomes valid UTF-8.
  std::string all;
  for (int i = 0; i < 256; ++i) all += static_cast<char>(i);
  CHECK(io::is_valid_utf8(io::printable(all)));
}

TEST_CASE("formats are told by their magic bytes", "[io][format]") {
  const std::vector<std::uint8_t> exr = {0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0};
  CHECK(io::sniff_format(exr) == io::FileFormat::exr);
  const std::string hdr = "#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n";
  CHECK(io::sniff_format({reinterpret_cast<const std::uint8_t*>(hdr.data()), hdr.size()}) ==
        io::FileFormat::radiance);
  const std::string rgbe = "#?RGBE\n";
  CHECK(io::sniff_format({reinterpret_cast<const std::uint8_t*>(rgbe.data()), rgbe.size()}) ==
        io::FileFormat::radiance);
  const std::vector<std::uint8_t> png = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1a, '\n'};
  CHECK_FALSE(io::sniff_format(png));
  CHECK(io::describe_magic(png) == "PNG");
  CHECK(io::accepts(io::Renderer::cycles, io::FileFormat::exr));
  CHECK_FALSE(io::accepts(io::Renderer::cycles, io::FileFormat::radiance));
  CHECK(io::accepts(io::Renderer::povray, io::FileFormat::radiance));
}

TEST_CASE("EXR header walk: real files pass, hostile sizes are refused", "[io][format]") {
  for (const char* f : {"renders/cornell/pass_00.exr", "renders/textured_dof/pass_00.exr",
                        "renders/povray/pass_00.exr", "renders/povray/pass_00.hdr"}) {
    const auto bytes = slurp(samples(f));
    const auto h = io::inspect_header(io::MemorySource(bytes), f, {});
    CHECK(h.parts.at(0).width == 128);
    CHECK(h.header_bytes <= bytes.size());
  }
  // A good hand-built file, then each hostile variant of it.
  test::ExrSpec spec;
  CHECK(io::inspect_header(io::MemorySource(test::exr_bytes(spec)), "ok", {}).parts.size() == 1);

  SECTION("attribute longer than the file") {
    spec.extra = {{"blob", "opaque", {1, 2, 3}, 1000}};
    const auto e = inspect_error(test::exr_bytes(spec));
    CHECK(e.kind() == InputErrorKind::unreadable);
    CHECK_THAT(e.reason(), Contains("'blob' declares 1000 bytes"));
  }
  SECTION("attribute above the file limit") {
    spec.extra = {{"blob", "opaque", {1}, 0x7fffffff}};
    io::ReadLimits lim;
    lim.max_file_bytes = 1 << 20;
    CHECK(inspect_error(test::exr_bytes(spec), lim).kind() == InputErrorKind::too_large);
  }
  SECTION("negative attribute size") {
    spec.extra = {{"blob", "opaque", {1}, 0xffffffff}};
    CHECK(inspect_error(test::exr_bytes(spec)).kind() == InputErrorKind::too_large);
  }
  SECTION("pixels above the limit") {
    spec.declared_width = 5000;
    spec.declared_height = 5000;
    spec.pixels = false;
    io::ReadLimits lim;
    lim.max_pixels = 4096 * 4096;
    const auto e = inspect_error(test::exr_bytes(spec), lim);
    CHECK(e.kind() == InputErrorKind::too_large);
    CHECK_THAT(e.reason(), Contains("5000x5000"));
  }
  SECTION("more chunks than the file can hold") {
    spec.declared_width = 1000;
    spec.declared_height = 1000;  // 1000 uncompressed scanlines, none present
    spec.pixels = false;
    CHECK_THAT(inspect_error(test::exr_bytes(spec)).reason(), Contains("chunks declared"));
  }
  SECTION("too many channels") {
    spec.channels.clear();
    for (int i = 0; i < 20; ++i) spec.channels.push_back("C" + std::to_string(100 + i));
    io::ReadLimits lim;
    lim.max_channels = 16;
    CHECK(inspect_error(test::exr_bytes(spec), lim).kind() == InputErrorKind::too_large);
  }
  SECTION("every truncation of a good header is refused cleanly") {
    const auto good = test::exr_bytes(spec);
    const auto header_end = io::inspect_header(io::MemorySource(good), "ok", {}).header_bytes;
    for (std::size_t n = 0; n < header_end; ++n) {
      const std::vector<std::uint8_t> cut(good.begin(), good.begin() + static_cast<long>(n));
      INFO(n);
      REQUIRE_THROWS_AS(io::inspect_header(io::MemorySource(cut), "cut", {}), InputError);
    }
  }
  SECTION("deep data and unknown flags") {
    auto bytes = test::exr_bytes(spec);
    bytes[5] |= 0x08;  // non-image (deep) flag
    CHECK(inspect_error(bytes).kind() == InputErrorKind::unsupported_format);
    bytes = test::exr_bytes(spec);
    bytes[6] = 0x80;  // a flag that does not exist: corrupt
    CHECK(inspect_error(bytes).kind() == InputErrorKind::unreadable);
  }
}

TEST_CASE("Radiance header walk: bounded size and pixels", "[io][format]") {
  auto text = [](const std::string& s) { return std::vector<std::uint8_t>(s.begin(), s.end()); };
  const auto e1 = inspect_error(text("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 12000 +X 12000\n"));
  CHECK(e1.kind() == InputErrorKind::too_large);
  const auto e2 = inspect_error(text("#?RADIANCE\n\n-Y 100 +X 100\nxx"));
  CHECK(e2.kind() == InputErrorKind::unreadable);
  CHECK_THAT(e2.reason(), Contains("truncated"));
  CHECK(inspect_error(text("#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n1234")).kind() ==
        InputErrorKind::unsupported_format);
  CHECK(inspect_error(text("#?RADIANCE\n\n+Y 1 +X 1\n1234")).kind() ==
        InputErrorKind::unsupported_format);
  // A header that never ends (no blank line within 64 KiB).
  std::string endless = "#?RADIANCE\n";
  while (endless.size() < 70000) endless += "COMMENT=xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx\n";
  CHECK(inspect_error(text(endless)).kind() == InputErrorKind::unreadable);
}

TEST_CASE("reads from memory match reads from the file and never open the name", "[io][memory]") {
  for (const char* f : {"renders/cornell/pass_00.exr", "renders/povray/pass_00.hdr"}) {
    io::ReadOptions o;
    o.spp = 1;
    io::PassInfo a, b;
    const Pass from_file = io::read_pass(samples(f), o, &a);
    const auto bytes = slurp(samples(f));
    // A name that is no file: OIIO must read the bytes given, not open a path.
    const Pass from_memory = io::read_pass(io::MemorySource(bytes), "/nonexistent/x.exr", o, &b);
    CHECK(from_file.colour.data().size() == from_memory.colour.data().size());
    CHECK(std::equal(from_file.colour.data().begin(), from_file.colour.data().end(),
                     from_memory.colour.data().begin()));
    CHECK(from_file.layout() == from_memory.layout());
    CHECK(b.path == "/nonexistent/x.exr");
    CHECK(a.format == b.format);
    CHECK(b.read_bytes > 0);
  }
}

TEST_CASE("a descriptor source reads the same pass", "[io][memory]") {
  const std::string f = samples("renders/cornell/pass_01.exr");
  const int fd = ::open(f.c_str(), O_RDONLY | O_CLOEXEC);
  REQUIRE(fd >= 0);
  const auto size = std::filesystem::file_size(f);
  const Pass a = io::read_pass(io::FdSource(fd, size), "fd", {});
  ::close(fd);
  const Pass b = io::read_pass(f);
  CHECK(std::equal(a.colour.data().begin(), a.colour.data().end(), b.colour.data().begin()));
  CHECK(a.layout() == b.layout());
}

TEST_CASE("the per-read memory budget refuses a read before decoding", "[io][budget]") {
  const std::string f = samples("renders/cornell/pass_00.exr");
  io::PassInfo info = io::probe_pass(f);
  // 128x128, colour + albedo + normal + depth planes, the largest run and the file itself.
  CHECK(info.read_bytes > 128u * 128u * 10u * 4u);
  CHECK(info.read_bytes < 128u * 128u * 40u * 4u + std::filesystem::file_size(f));
  io::ReadOptions o;
  o.limits.max_memory_bytes = info.read_bytes - 1;
  try {
    io::read_pass(f, o);
    FAIL("read above the budget");
  } catch (const InputError& e) {
    CHECK(e.kind() == InputErrorKind::too_large);
    CHECK_THAT(e.reason(), Contains("budget"));
  }
  CHECK_THROWS_AS(io::probe_pass(f, o), InputError);
  o.limits.max_memory_bytes = info.read_bytes;
  CHECK(io::read_pass(f, o).colour.width() == 128);
  // Colour only needs less.
  o.features = false;
  o.variance = false;
  CHECK(io::probe_pass(f, o).read_bytes < info.read_bytes);
}

TEST_CASE("a pass of another size than the frame's is refused from its header", "[io][budget]") {
  io::ReadOptions o;
  o.frame_size = std::pair{64, 64};
  try {
    io::read_pass(samples("renders/cornell/pass_00.exr"), o);
    FAIL("accepted");
  } catch (const InputError& e) {
    CHECK(e.kind() == InputErrorKind::size_mismatch);
    CHECK_THAT(e.reason(), Contains("128x128 differs from the frame's 64x64"));
  }
  o.frame_size = std::pair{128, 128};
  CHECK(io::read_pass(samples("renders/cornell/pass_00.exr"), o).colour.width() == 128);
}

TEST_CASE("a FIFO named like a pass does not block the reader", "[io][hostile]") {
  test::TempDir dir;
  const std::string f = dir.file("pass_00.exr");
  REQUIRE(::mkfifo(f.c_str(), 0600) == 0);
  CHECK_THROWS_AS(io::read_pass(f), InputError);  // returns at once: not a regular file
}

TEST_CASE("the multi-part and tiled files OIIO writes pass the header walk", "[io][format]") {
  test::TempDir dir;
  const std::string f = dir.file("tiled.exr");
  auto out = OIIO::ImageOutput::create(f);
  REQUIRE(out);
  OIIO::ImageSpec spec(40, 30, 3, OIIO::TypeDesc::HALF);
  spec.tile_width = 16;
  spec.tile_height = 16;
  spec.attribute("compression", "piz");
  std::vector<float> px(40 * 30 * 3, 0.5f);
  REQUIRE(out->open(f, spec));
  REQUIRE(out->write_image(OIIO::TypeDesc::FLOAT, px.data()));
  REQUIRE(out->close());
  const Pass p = io::read_pass(f);
  CHECK(p.colour.width() == 40);
  CHECK(p.colour.at(3, 3, 1) == 0.5f);
}

// OpenEXR reads a value of a type it knows by the type's layout, not by the declared size (a
// channel list up to its terminator, a box2i as 16 bytes, a preview as width x height pixels).
// A header whose sizes disagree made OpenEXR read other bytes than the walk had checked: the
// pass_reader fuzz target found a 2.5 KB file whose channel list ended early, after which
// OpenEXR read an attribute size of 1.8 GB the walk had skipped as channel-list bytes
// (fuzz/corpus/pass_reader/finding_chlist_ends_early.exr).
TEST_CASE("EXR header walk: declared sizes must match the types' layouts", "[io][format]") {
  const auto refused = [](const test::ExrAttribute& extra) {
    test::ExrSpec spec;
    spec.extra = {extra};
    try {
      io::inspect_header(io::MemorySource(test::exr_bytes(spec)), "mem", {});
    } catch (const InputError& e) {
      return e.kind() == InputErrorKind::unreadable;
    }
    return false;
  };
  // A second channel list whose terminator comes before its declared end.
  std::vector<std::uint8_t> chlist = {'A', 0, 2, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 0};
  CHECK_FALSE(refused({"extraChannels", "chlist", chlist}));
  chlist.insert(chlist.end(), {'X', 'Y', 'Z', 0});
  CHECK(refused({"extraChannels", "chlist", chlist}));
  // A box2i of 20 bytes (OpenEXR reads 16) and a float of 8.
  CHECK(refused({"someBox", "box2i", std::vector<std::uint8_t>(20, 0)}));
  CHECK(refused({"someFloat", "float", std::vector<std::uint8_t>(8, 0)}));
  CHECK_FALSE(refused({"someFloat", "float", std::vector<std::uint8_t>(4, 0)}));
  // A preview declaring 60000 x 60000 pixels in 8 bytes (OpenEXR would allocate 14 GB).
  const std::vector<std::uint8_t> bomb = {0x60, 0xEA, 0, 0, 0x60, 0xEA, 0, 0};
  CHECK(refused({"preview", "preview", bomb}));
  std::vector<std::uint8_t> preview = {2, 0, 0, 0, 1, 0, 0, 0};
  preview.resize(8 + 2 * 1 * 4, 0x80);
  CHECK_FALSE(refused({"preview", "preview", preview}));
}

// OpenEXR's C++ library decodes a chunk read at a wrong offset as zeros, without an error: the
// pass_reader fuzz target found a pass whose header grew by 5 bytes, so that its one offset
// pointed into its own offset table (fuzz/corpus/pass_reader/finding_stale_chunk_offset.exr), and
// proden accumulated it as a black pass. The header walk now checks every offset against the
// chunk it names; a half-written file (offsets still 0) is refused the same way.
TEST_CASE("EXR offset tables must name the chunks they index", "[io][format]") {
  const std::string finding =
      std::string(PRODEN_SOURCE_DIR) + "/fuzz/corpus/pass_reader/finding_stale_chunk_offset.exr";
  try {
    io::read_pass(finding);
    FAIL("a pass whose chunk offset points into the offset table was accepted");
  } catch (const InputError& e) {
    CHECK(e.kind() == InputErrorKind::unreadable);
    CHECK_THAT(e.reason(), Contains("not where the offset table says"));
  }

  test::ExrSpec spec;  // uncompressed: one chunk per scanline, 3 of them
  const std::vector<std::uint8_t> good = test::exr_bytes(spec);
  const std::uint64_t table =
      io::inspect_header(io::MemorySource(good), "mem", {}).header_bytes - 8 * 3;
  const auto entry = [&](const std::vector<std::uint8_t>& b, int i) {
    std::uint64_t v = 0;
    for (int j = 7; j >= 0; --j) v = (v << 8) | b[table + 8 * static_cast<std::uint64_t>(i) + j];
    return v;
  };
  const auto with_entry = [&](int i, std::uint64_t v) {
    std::vector<std::uint8_t> b = good;
    for (int j = 0; j < 8; ++j)
      b[table + 8 * static_cast<std::uint64_t>(i) + j] = (v >> (8 * j)) & 0xFF;
    return b;
  };
  REQUIRE(entry(good, 0) == table + 24);  // the first chunk follows the table
  const auto refused = [](const std::vector<std::uint8_t>& b) {
    return inspect_error(b).kind() == InputErrorKind::unreadable &&
           std::string(inspect_error(b).reason()).find("offset table") != std::string::npos;
  };
  CHECK(refused(with_entry(1, 0)));                   // half-written: not filled in yet
  CHECK(refused(with_entry(1, entry(good, 1) - 4)));  // 4 bytes early
  CHECK(refused(with_entry(1, entry(good, 1) + 4)));  // 4 bytes late
  CHECK(refused(with_entry(2, entry(good, 1))));      // the chunk of another scanline
  CHECK(refused(with_entry(2, good.size())));         // past the end
  CHECK(refused(with_entry(0, table)));               // inside the table
  // Unchanged, it reads (files OIIO writes in every layout: pass_reader_test.cpp's round trips).
  CHECK(io::read_pass(io::MemorySource(good), "mem").colour.at(0, 0, 0) == 0.25f);
}

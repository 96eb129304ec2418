// Atomic image writes relative to a held directory descriptor (io/image_writer.hpp): the file
// lands in the directory that was opened, a symlink planted at its name is replaced rather than
// written through, and OIIO writes only through the descriptor.
#include <OpenImageIO/imageio.h>
#include <fcntl.h>
#include <unistd.h>
#include <catch2/catch.hpp>

#include <filesystem>
#include <fstream>
#include <map>

#include "proden/error.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "test_support.hpp"

using namespace proden;
namespace fs = std::filesystem;

namespace {

std::vector<io::NamedChannel> rgb(const Image& img) {
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "", img);
  return ch;
}

std::string slurp(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

// dir/out opened (the descriptor returned), then moved to dir/held and replaced by a symlink to
// dir/outside: what a symlink swapped in after the daemon opened its output directory looks like.
int open_then_swap(const test::TempDir& dir) {
  const fs::path out = dir.path() / "out";
  fs::create_directories(out);
  fs::create_directories(dir.path() / "outside");
  const int fd = ::open(out.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  REQUIRE(fd >= 0);
  fs::rename(out, dir.path() / "held");
  fs::create_symlink(dir.path() / "outside", out);
  return fd;
}

}  // namespace

TEST_CASE("write_image_at writes into the held directory, not where its path now leads",
          "[io][writer]") {
  test::TempDir dir;
  const fs::path outside = dir.path() / "outside";
  const int fd = open_then_swap(dir);
  const Image img(5, 4, 3, 0.5f);
  io::write_image_at(fd, "frame_0001.exr", 5, 4, rgb(img));
  io::WriteOptions png;
  png.compression = "";
  io::write_image_at(fd, "frame_0001.png", 5, 4, rgb(img), png);
  ::close(fd);
  CHECK(fs::is_empty(outside));
  CHECK(io::read_rgb((dir.path() / "held" / "frame_0001.exr").string()).at(2, 2, 1) == 0.5f);
  CHECK(slurp(dir.path() / "held" / "frame_0001.png").starts_with("\x89PNG"));
  // No temp file left behind, and nothing created in the working directory by name.
  for (const auto& e : fs::directory_iterator(dir.path() / "held")) {
    CHECK(e.path().filename().string().front() != '.');
  }
}

TEST_CASE("a symlink planted at the output name is replaced, never written through",
          "[io][writer]") {
  test::TempDir dir;
  const fs::path victim = dir.path() / "victim.txt";
  std::ofstream(victim) << "precious";
  fs::create_symlink(victim, dir.path() / "frame.exr");
  fs::create_hard_link(victim, dir.path() / "hard.exr");
  const Image img(3, 3, 3, 1.0f);
  io::write_image((dir.path() / "frame.exr").string(), 3, 3, rgb(img));
  io::write_image((dir.path() / "hard.exr").string(), 3, 3, rgb(img));
  CHECK(slurp(victim) == "precious");
  CHECK_FALSE(fs::is_symlink(dir.path() / "frame.exr"));
  CHECK(io::read_rgb((dir.path() / "frame.exr").string()).at(1, 1, 0) == 1.0f);
  CHECK(fs::hard_link_count(victim) == 1);
}

TEST_CASE("write errors name the file and leave nothing behind", "[io][writer]") {
  test::TempDir dir;
  const Image img(3, 3, 3, 1.0f);
  CHECK_THROWS_WITH(io::write_image((dir.path() / "nodir" / "f.exr").string(), 3, 3, rgb(img)),
                    Catch::Matchers::Contains("nodir/f.exr"));
  const int fd = ::open(dir.path().c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  CHECK_THROWS(io::write_image_at(fd, "a/b.exr", 3, 3, rgb(img)));
  CHECK_THROWS(io::write_image_at(fd, "f.unknownformat", 3, 3, rgb(img)));
  ::close(fd);
  CHECK(fs::is_empty(dir.path()));
}

TEST_CASE("an OutputDirectory binding routes path-based writes through its descriptor",
          "[io][writer]") {
  test::TempDir dir;
  const fs::path out = dir.path() / "out", outside = dir.path() / "outside";
  const int fd = open_then_swap(dir);
  const Image img(2, 2, 3, 0.25f);
  {
    const io::OutputDirectory bound(out.string() + "/", fd);
    io::write_image((out / "a.exr").string(), 2, 2, rgb(img));
    // Other directories are not affected.
    io::write_image((dir.path() / "b.exr").string(), 2, 2, rgb(img));
  }
  // Unbound again: the path is followed as usual.
  io::write_image((out / "c.exr").string(), 2, 2, rgb(img));
  ::close(fd);
  CHECK(fs::exists(dir.path() / "held" / "a.exr"));
  CHECK(fs::exists(dir.path() / "b.exr"));
  CHECK_FALSE(fs::exists(outside / "a.exr"));
  CHECK(fs::exists(outside / "c.exr"));
}

TEST_CASE("strips of any height write the planes exactly", "[io][writer]") {
  // 70 rows: strips of 1 row (1 byte), of a few rows (never a whole 16- or 32-row chunk), and
  // the default (the whole image), for each compression, float and half. Every layer must decode
  // to its plane. (The files differ only in OIIO's DateTime attribute.)
  test::TempDir dir;
  const Pass p = test::make_pass(37, 70, 4, 5, Layout{true, true, false, false});
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "", p.colour);
  io::add_layer(ch, "albedo.", p.albedo);
  io::add_layer(ch, "normal.", p.normal, "RGB");
  const std::pair<const char*, const Image*> layers[] = {
      {"", &p.colour}, {"albedo", &p.albedo}, {"normal", &p.normal}};
  for (const char* compression : {"piz", "zip", "none"}) {
    for (bool half : {false, true}) {
      for (std::uint64_t strip : {std::uint64_t{30} << 20, std::uint64_t{1}, std::uint64_t{3000}}) {
        INFO(compression << (half ? " half" : " float") << ", strip " << strip);
        io::WriteOptions o;
        o.compression = compression;
        o.half = half;
        o.strip_bytes = strip;
        const std::string f = dir.file("s.exr");
        io::write_image(f, 37, 70, ch, o);
        for (const auto& [name, plane] : layers) {
          const Image back = io::read_layer(f, name);
          REQUIRE(back.same_size(*plane));
          for (std::size_t i = 0; i < back.data().size(); ++i) {
            const float want = plane->data()[i];
            REQUIRE(std::abs(back.data()[i] - want) <=
                    (half ? 1e-3f * std::abs(want) + 1e-6f : 0.0f));
          }
        }
      }
    }
  }
}

TEST_CASE("read_layers decodes only the layers asked for, in strips, RGB or a lone Y",
          "[io][reader]") {
  // A published-like frame: R,G,B, an RGB layer, a one-channel layer (Y) and one more RGB layer
  // that is not asked for. Strips of 1 byte (one chunk at a time) and the whole image must give
  // the same planes; a Y layer comes back as three equal planes; an absent layer as empty, and
  // read_layer() names it in its error.
  test::TempDir dir;
  const Pass p = test::make_pass(29, 40, 4, 7, Layout{true, true, false, false});
  Image grey(29, 40, 1);
  for (std::size_t i = 0; i < grey.pixels(); ++i) grey.data()[i] = 0.25f * static_cast<float>(i);
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "", p.colour);
  io::add_layer(ch, "albedo.", p.albedo);
  io::add_layer(ch, "count.", grey, "Y");
  io::add_layer(ch, "normal.", p.normal);
  io::WriteOptions w;
  w.compression = "zip";  // 16-row chunks: a 1-byte strip reads 3 of them, one at a time
  const std::string f = dir.file("layers.exr");
  io::write_image(f, 29, 40, ch, w);
  for (const std::uint64_t strip : {std::uint64_t{1}, std::uint64_t{1} << 30}) {
    INFO("strip " << strip);
    io::ReadOptions o;
    o.strip_bytes = strip;
    const std::vector<Image> l =
        io::read_layers(f, {"result", "count", "missing", "albedo", ""}, o);
    REQUIRE(l.size() == 5);
    const auto same = [](const Image& a, const Image& b) {
      return a.same_size(b) && std::ranges::equal(a.data(), b.data());
    };
    CHECK(same(l[0], p.colour));
    REQUIRE(l[1].channels() == 3);
    for (int c = 0; c < 3; ++c) {
      CHECK(std::equal(grey.data().begin(), grey.data().end(), l[1].plane(c).begin()));
    }
    CHECK(l[2].empty());
    CHECK(same(l[3], p.albedo));
    CHECK(same(l[4], p.colour));
  }
  CHECK(std::ranges::equal(io::read_layer(f, "count").data(),
                           io::read_layers(f, {"count"})[0].data()));
  try {
    io::read_layer(f, "missing");
    FAIL("a missing layer was read");
  } catch (const proden::InputError& e) {
    CHECK(e.kind() == proden::InputErrorKind::missing_channels);
    CHECK_THAT(e.what(), Catch::Contains("layers.exr") && Catch::Contains("'missing'"));
  }
}

namespace {

// Every channel of an EXR as planes, its channel names, compression and string attributes.
struct ExrContents {
  std::vector<std::string> names;
  std::vector<std::vector<float>> planes;
  std::string compression;
  OIIO::TypeDesc format;
  std::map<std::string, std::string> strings;
};

ExrContents contents(const fs::path& f) {
  auto in = OIIO::ImageInput::open(f.string());
  REQUIRE(in);
  const OIIO::ImageSpec& spec = in->spec();
  ExrContents c;
  c.names = spec.channelnames;
  c.compression = spec.get_string_attribute("compression");
  c.format = spec.format;
  for (const auto& p : spec.extra_attribs) {
    if (p.type() == OIIO::TypeDesc::STRING && p.name() != "compression") {
      c.strings[p.name().string()] = p.get_string();
    }
  }
  const std::size_t n = static_cast<std::size_t>(spec.width) * spec.height;
  for (int ch = 0; ch < spec.nchannels; ++ch) {
    std::vector<float> plane(n);
    REQUIRE(in->read_image(0, 0, ch, ch + 1, OIIO::TypeDesc::FLOAT, plane.data()));
    c.planes.push_back(std::move(plane));
  }
  return c;
}

}  // namespace

TEST_CASE("compress_image_at rewrites an uncompressed EXR compressed, with the same contents",
          "[io][writer]") {
  test::TempDir dir;
  const Pass p = test::make_pass(41, 67, 4, 7, Layout{true, true, false, false});
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "", p.colour);
  io::add_layer(ch, "albedo.", p.albedo);
  io::add_layer(ch, "normal.", p.normal);
  const int fd = ::open(dir.path().c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  REQUIRE(fd >= 0);
  for (const bool half : {false, true}) {
    INFO((half ? "half" : "float"));
    io::WriteOptions o;
    o.compression = "none";
    o.half = half;
    o.attributes = {{"proden:version", "7"},
                    {"proden:estimated_error", R"({"mse":1e-3})"},
                    {"cryptomatte/abc/manifest", R"({"a":"3f800000"})"}};
    io::write_image_at(fd, "f.exr", 41, 67, ch, o);
    const ExrContents before = contents(dir.path() / "f.exr");
    REQUIRE(before.compression == "none");
    CHECK(io::compress_image_at(fd, "f.exr", "piz"));
    const ExrContents after = contents(dir.path() / "f.exr");
    CHECK(after.compression == "piz");
    CHECK(after.format == before.format);
    CHECK(after.names == before.names);
    CHECK(after.strings == before.strings);
    CHECK(after.strings.at("proden:version") == "7");
    CHECK(after.planes == before.planes);  // bit for bit
    // Compressed already: nothing to do, the file untouched.
    const std::string bytes = slurp(dir.path() / "f.exr");
    CHECK_FALSE(io::compress_image_at(fd, "f.exr", "piz"));
    CHECK(slurp(dir.path() / "f.exr") == bytes);
  }
  ::close(fd);
  for (const auto& e : fs::directory_iterator(dir.path())) {
    CHECK(e.path().filename().string().front() != '.');  // no temp file left
  }
}

TEST_CASE("compress_image_at leaves alone what is not a whole uncompressed EXR", "[io][writer]") {
  test::TempDir dir;
  const Image img(16, 16, 3, 0.5f);
  io::WriteOptions none;
  none.compression = "none";
  const int fd = ::open(dir.path().c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  REQUIRE(fd >= 0);
  io::write_image_at(fd, "whole.exr", 16, 16, rgb(img), none);
  // Cut short (a half-written or crafted file: its header claims more pixels than it holds).
  fs::copy_file(dir.path() / "whole.exr", dir.path() / "cut.exr");
  fs::resize_file(dir.path() / "cut.exr", fs::file_size(dir.path() / "whole.exr") / 2);
  const std::string cut = slurp(dir.path() / "cut.exr");
  CHECK_FALSE(io::compress_image_at(fd, "cut.exr", "piz"));
  CHECK(slurp(dir.path() / "cut.exr") == cut);
  // Not an EXR at all.
  std::ofstream(dir.path() / "text.exr") << "not an image";
  CHECK_FALSE(io::compress_image_at(fd, "text.exr", "piz"));
  CHECK(slurp(dir.path() / "text.exr") == "not an image");
  // A symlink at the name is not followed.
  fs::create_symlink(dir.path() / "whole.exr", dir.path() / "link.exr");
  CHECK_THROWS_WITH(io::compress_image_at(fd, "link.exr", "piz", "out/link.exr"),
                    Catch::Matchers::Contains("out/link.exr"));
  CHECK(contents(dir.path() / "whole.exr").compression == "none");
  CHECK_THROWS_WITH(io::compress_image_at(fd, "absent.exr", "piz"),
                    Catch::Matchers::Contains("absent.exr"));
  CHECK_THROWS(io::compress_image_at(fd, "../whole.exr", "piz"));
  ::close(fd);
}

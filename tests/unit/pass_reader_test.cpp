// Round trips of every supported input layout through the pass reader, and real renderer files.
#include <OpenImageIO/imageio.h>
#include <libdeflate.h>
#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <random>

#include "../../io/src/exr_chunks.hpp"
#include "../../io/src/strips.hpp"
#include "proden/error.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "test_support.hpp"

using namespace proden;
using Catch::Matchers::Contains;

namespace {

// |a - b| <= rel * max(|b|, floor) per value.
void require_close(const Image& a, const Image& b, double rel, double floor = 1e-3) {
  REQUIRE(a.same_size(b));
  REQUIRE(a.channels() == b.channels());
  for (std::size_t i = 0; i < a.data().size(); ++i) {
    const double x = a.data()[i], y = b.data()[i];
    if (std::abs(x - y) > rel * std::max(std::abs(y), floor)) {
      FAIL("value " << i << ": " << x << " vs " << y);
    }
  }
}

std::string samples(const std::string& rel) {
  return std::string(PRODEN_SAMPLES_DIR) + "/" + rel;
}

std::vector<std::uint8_t> file_bytes(const std::string& f) {
  std::ifstream in(f, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// `rgb` written to `f` as the only layer of a ZIP-compressed EXR (what the chunk decoder reads).
void write_zip_rgb(const std::string& f, const Image& rgb) {
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "", rgb, "RGB");
  io::WriteOptions o;
  o.compression = "zip";
  io::write_image(f, rgb.width(), rgb.height(), ch, o);
}

// A W x H RGB image of the values i % 97: compresses well under ZIP.
Image ramp97(int W, int H) {
  Image ramp(W, H, 3);
  for (std::size_t i = 0; i < ramp.data().size(); ++i) ramp.data()[i] = static_cast<float>(i % 97);
  return ramp;
}

io::HeaderSummary walk(const std::vector<std::uint8_t>& bytes, const std::string& name) {
  return io::inspect_header(io::MemorySource(bytes), name, {});
}

// Every value of the two images has the same bits.
void require_same_bits(const Image& a, const Image& b) {
  REQUIRE(a.same_size(b));
  REQUIRE(a.channels() == b.channels());
  if (a.data().empty()) return;
  REQUIRE(std::memcmp(a.data().data(), b.data().data(), a.data().size() * sizeof(float)) == 0);
}

void require_same_pass(const Pass& a, const Pass& b) {
  require_same_bits(a.colour, b.colour);
  require_same_bits(a.albedo, b.albedo);
  require_same_bits(a.normal, b.normal);
  require_same_bits(a.depth, b.depth);
  require_same_bits(a.variance, b.variance);
}

}  // namespace

TEST_CASE("Blender multilayer EXR layout round-trips (float and half)", "[io]") {
  test::TempDir dir;
  const Layout feats{true, true, true, false};
  const Pass p = test::make_pass(17, 9, 16, 5, feats);
  for (bool half : {false, true}) {
    std::vector<io::NamedChannel> ch;
    Image alpha(17, 9, 1, 1.0f);
    io::add_layer(ch, "RenderLayer.Combined.", p.colour);
    io::add_layer(ch, "RenderLayer.Combined.", alpha, "A");
    io::add_layer(ch, "RenderLayer.Denoising Albedo.", p.albedo);
    io::add_layer(ch, "RenderLayer.Denoising Normal.", p.normal, "XYZ");
    io::add_layer(ch, "RenderLayer.Denoising Depth.", p.depth, "Z");
    io::WriteOptions o;
    o.half = half;
    o.attributes = {{"cycles.RenderLayer.samples", "16"},
                    {"cycles.RenderLayer.render_time", "01:02.50"}};
    const std::string f = dir.file(half ? "half.exr" : "float.exr");
    io::write_image(f, 17, 9, ch, o);

    io::PassInfo info;
    const Pass r = io::read_pass(f, {}, &info);
    CHECK(info.renderer == io::Renderer::cycles);
    CHECK(info.layer == "RenderLayer");
    CHECK(info.spp == 16);
    CHECK(info.spp_source == io::SppSource::header);
    CHECK(info.pixel_type == (half ? "half" : "float"));
    REQUIRE(info.render_time.has_value());
    CHECK(*info.render_time == Approx(62.5));
    CHECK(info.layout == feats);
    const double tol = half ? 1e-3 : 0.0;
    require_close(r.colour, p.colour, tol);
    require_close(r.albedo, p.albedo, tol);
    require_close(r.normal, p.normal, tol);
    require_close(r.depth, p.depth, tol);
    CHECK(r.variance.empty());

    // Simulate only what is asked for: features can be skipped.
    io::ReadOptions colour_only;
    colour_only.features = false;
    CHECK(io::read_pass(f, colour_only).layout() == Layout{});
  }
}

TEST_CASE("generic EXR layout with albedo, normal, depth and variance round-trips", "[io]") {
  test::TempDir dir;
  const Layout all{true, true, true, true};
  const Pass p = test::make_pass(8, 8, 2, 9, all);
  test::write_generic_exr(dir.file("g.exr"), p);
  io::PassInfo info;
  io::ReadOptions o;
  o.spp = 2;
  const Pass r = io::read_pass(dir.file("g.exr"), o, &info);
  CHECK(info.renderer == io::Renderer::generic);
  CHECK(info.spp_source == io::SppSource::option);
  CHECK(r.spp == 2);
  CHECK(r.layout() == all);
  require_close(r.colour, p.colour, 0);
  require_close(r.variance, p.variance, 0);
  require_close(r.normal, p.normal, 0);
  // Without --spp the sample count is assumed to be 1 and said so.
  io::PassInfo assumed;
  io::read_pass(dir.file("g.exr"), {}, &assumed);
  CHECK(assumed.spp_source == io::SppSource::assumed);
  CHECK(assumed.spp == 1);
}

TEST_CASE("POV-Ray-style half RGB EXR and Radiance HDR round-trip", "[io]") {
  test::TempDir dir;
  Pass p = test::make_pass(12, 10, 1, 21);
  for (float& v : p.colour.data()) v = std::abs(v);  // RGBE cannot store negatives
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "", p.colour);
  io::WriteOptions o;
  o.half = true;
  o.attributes = {{"Software", "POV-Ray 3.7.0.10.unofficial"}};
  io::write_image(dir.file("pov.exr"), 12, 10, ch, o);
  io::PassInfo info;
  const Pass r = io::read_pass(dir.file("pov.exr"), {}, &info);
  CHECK(info.renderer == io::Renderer::povray);
  CHECK(info.pixel_type == "half");
  require_close(r.colour, p.colour, 1e-3);

  io::write_image(dir.file("pov.hdr"), 12, 10, ch, {});
  io::PassInfo hinfo;
  const Pass h = io::read_pass(dir.file("pov.hdr"), {}, &hinfo);
  CHECK(hinfo.format == "hdr");
  // RGBE: one exponent for the pixel, so small channels are quantised relative to the largest.
  require_close(h.colour, p.colour, 1.0 / 64, 0.5);
}

TEST_CASE("multi-part EXR: channels gathered across parts", "[io]") {
  test::TempDir dir;
  const Pass p = test::make_pass(6, 5, 4, 33, Layout{true, false, false, false});
  const std::string f = dir.file("multi.exr");
  auto out = OIIO::ImageOutput::create(f);
  REQUIRE(out);
  OIIO::ImageSpec specs[2] = {OIIO::ImageSpec(6, 5, 3, OIIO::TypeDesc::FLOAT),
                              OIIO::ImageSpec(6, 5, 3, OIIO::TypeDesc::FLOAT)};
  specs[0].channelnames = {"R", "G", "B"};
  specs[1].channelnames = {"Albedo.R", "Albedo.G", "Albedo.B"};
  specs[0].attribute("oiio:subimagename", "beauty");
  specs[1].attribute("oiio:subimagename", "albedo");
  REQUIRE(out->open(f, 2, specs));
  auto interleave = [](const Image& img) {
    std::vector<float> v(img.pixels() * 3);
    for (std::size_t i = 0; i < img.pixels(); ++i) {
      for (int c = 0; c < 3; ++c) v[i * 3 + static_cast<std::size_t>(c)] = img.plane(c)[i];
    }
    return v;
  };
  REQUIRE(out->write_image(OIIO::TypeDesc::FLOAT, interleave(p.colour).data()));
  REQUIRE(out->open(f, specs[1], OIIO::ImageOutput::AppendSubimage));
  REQUIRE(out->write_image(OIIO::TypeDesc::FLOAT, interleave(p.albedo).data()));
  REQUIRE(out->close());

  io::PassInfo info;
  const Pass r = io::read_pass(f, {}, &info);
  CHECK(info.subimages == 2);
  CHECK(r.layout() == Layout{true, false, false, false});
  require_close(r.colour, p.colour, 0);
  require_close(r.albedo, p.albedo, 0);
}

TEST_CASE("strips hold whole compression chunks", "[io]") {
  CHECK(io::chunk_rows("zip") == 16);
  CHECK(io::chunk_rows("piz") == 32);
  CHECK(io::chunk_rows("dwaa:45") == 32);
  CHECK(io::chunk_rows("dwab") == 256);
  CHECK(io::chunk_rows("none") == 1);
  CHECK(io::chunk_rows("") == 1);
  // 1080p, 27 float channels: 30 MiB holds 151 rows, so 128 (four PIZ chunks).
  CHECK(io::strip_rows(30u << 20, 1920u * 27 * 4, 32, 1080) == 128);
  // A budget below one chunk still reads one whole chunk, and never past the image.
  CHECK(io::strip_rows(1, 1920u * 27 * 4, 16, 1080) == 16);
  CHECK(io::strip_rows(1, 1920u * 27 * 4, 256, 100) == 100);
  // Below 32 rows of budget: whole chunks of the file's own height.
  CHECK(io::strip_rows(20u * 1000, 1000, 16, 1080) == 16);
  CHECK(io::strip_rows(20u * 1000, 1000, 1, 1080) == 20);
  // DWAB's 256-row chunks are not a divisor of 32: multiples of 256.
  CHECK(io::strip_rows(600u * 1000, 1000, 256, 1080) == 512);
}

TEST_CASE("scanlines read in strips of any height equal one whole read", "[io]") {
  // A strip of 1 byte or 1000 bytes is one 16-row ZIP chunk per decode (the 19-row image in two
  // reads, the second of 3 rows), the default the whole image; a tiled file is read whole whatever
  // the strip. Values must match bit for bit, and a smaller strip must lower the read's peak.
  test::TempDir dir;
  const Layout feats{true, true, true, false};
  const Pass p = test::make_pass(23, 19, 4, 7, feats);
  auto write = [&](const std::string& name, int tile, int origin, bool half) {
    const std::string f = dir.file(name);
    auto out = OIIO::ImageOutput::create(f);
    REQUIRE(out);
    OIIO::ImageSpec spec(23, 19, 10, half ? OIIO::TypeDesc::HALF : OIIO::TypeDesc::FLOAT);
    spec.channelnames = {"R",        "G",        "B",        "Albedo.R", "Albedo.G",
                         "Albedo.B", "Normal.X", "Normal.Y", "Normal.Z", "Depth.Z"};
    spec.x = spec.full_x = origin;
    spec.y = spec.full_y = origin;
    if (tile > 0) {
      spec.tile_width = tile;
      spec.tile_height = tile;
    }
    std::vector<float> v(23 * 19 * 10);
    const Image* src[4] = {&p.colour, &p.albedo, &p.normal, &p.depth};
    for (std::size_t i = 0; i < 23 * 19; ++i) {
      int c = 0;
      for (const Image* img : src) {
        for (int k = 0; k < img->channels(); ++k)
          v[i * 10 + static_cast<std::size_t>(c++)] = img->plane(k)[i];
      }
    }
    REQUIRE(out->open(f, spec));
    REQUIRE(out->write_image(OIIO::TypeDesc::FLOAT, v.data()));
    REQUIRE(out->close());
    return f;
  };
  const std::string files[] = {write("scan.exr", 0, 0, false), write("half.exr", 0, 0, true),
                               write("origin.exr", 0, 3, false), write("tiled.exr", 8, 0, false)};
  // OpenImageIO's strips (the chunk decoder has none: it is compared with them at the end).
  io::ReadOptions library;
  library.exr_decoder = io::ExrDecoder::library;
  for (const std::string& f : files) {
    INFO(f);
    io::PassInfo whole_info;
    const Pass whole = io::read_pass(f, library, &whole_info);
    REQUIRE(whole.layout() == Layout{true, true, true, false});
    require_close(whole.colour, p.colour, f.find("half") != std::string::npos ? 1e-3 : 0.0);
    // The default route (the chunk decoder for the scanline files, a data window at 3,3 too).
    require_same_pass(io::read_pass(f), whole);
    for (std::uint64_t strip : {std::uint64_t{1}, std::uint64_t{1000}}) {
      io::ReadOptions o = library;
      o.strip_bytes = strip;
      io::PassInfo info;
      const Pass r = io::read_pass(f, o, &info);
      require_close(r.colour, whole.colour, 0);
      require_close(r.albedo, whole.albedo, 0);
      require_close(r.normal, whole.normal, 0);
      require_close(r.depth, whole.depth, 0);
      if (f.find("tiled") == std::string::npos) {
        CHECK(info.read_bytes < whole_info.read_bytes);
      } else {
        CHECK(info.read_bytes == whole_info.read_bytes);
      }
    }
  }
}

TEST_CASE("the chunk decoder reads what OpenEXR's C++ library reads, bit for bit", "[io][chunks]") {
  // Every compression a pass may come in, float and half: files the chunk decoder takes (NONE,
  // ZIPS, ZIP) and those left to OpenImageIO must both give the library's floats.
  test::TempDir dir;
  const Layout feats{true, true, true, false};
  const Pass p = test::make_pass(70, 45, 4, 11, feats);
  io::ReadOptions library;
  library.exr_decoder = io::ExrDecoder::library;
  for (const char* compression : {"none", "rle", "zips", "zip", "piz", "pxr24", "b44", "dwaa"}) {
    for (bool half : {false, true}) {
      INFO(compression << (half ? " half" : " float"));
      const std::string f = dir.file(std::string(compression) + (half ? "_h.exr" : "_f.exr"));
      test::write_generic_exr(f, p, half, compression);
      const std::string c = compression;
      CHECK(io::detail::chunk_decodes(walk(file_bytes(f), f)) ==
            (c == "none" || c == "zips" || c == "zip"));
      const Pass reference = io::read_pass(f, library);
      REQUIRE(reference.layout() == feats);
      require_same_pass(io::read_pass(f), reference);
      // From memory, as the daemon reads a pass it has hashed.
      const auto bytes = file_bytes(f);
      require_same_pass(io::read_pass(io::MemorySource(bytes), f, {}), reference);
    }
  }
  // Real renders: Cycles (ZIP, float and half) and POV-Ray.
  for (const char* rel : {"renders/cornell/pass_00.exr", "renders/textured_dof/pass_00.exr",
                          "renders/povray/pass_00.exr"}) {
    INFO(rel);
    REQUIRE(io::detail::chunk_decodes(walk(file_bytes(samples(rel)), rel)));
    std::vector<AovChannel> a, b;
    require_same_pass(io::read_pass(samples(rel), {}, nullptr, &a),
                      io::read_pass(samples(rel), library, nullptr, &b));
    REQUIRE(a.size() == b.size());
    for (std::size_t k = 0; k < a.size(); ++k) require_same_bits(a[k].plane, b[k].plane);
  }
  // Layers of a published frame (read_layers), one channel wanted three times (a lone Y).
  {
    Image y(33, 17, 1);
    for (std::size_t i = 0; i < y.data().size(); ++i) y.data()[i] = 0.25f * static_cast<float>(i);
    const Image rgb(33, 17, 3, 0.5f);  // the channels below point into it
    std::vector<io::NamedChannel> ch;
    io::add_layer(ch, "", rgb, "RGB");
    io::add_layer(ch, "alpha.", y, "Y");
    const std::string f = dir.file("layers.exr");
    io::write_image(f, 33, 17, ch, {});
    REQUIRE(io::detail::chunk_decodes(walk(file_bytes(f), f)));
    const auto got = io::read_layers(f, {"result", "alpha"}, {});
    const auto want = io::read_layers(f, {"result", "alpha"}, library);
    require_same_bits(got[0], want[0]);
    require_same_bits(got[1], want[1]);
    for (int c = 0; c < 3; ++c) {
      REQUIRE(std::memcmp(got[1].plane(c).data(), y.data().data(), y.data().size() * 4) == 0);
    }
  }
}

TEST_CASE("the chunk decoder reads chunks stored uncompressed and refuses corrupt ones",
          "[io][chunks]") {
  // Noise does not deflate: OpenEXR then stores a ZIP chunk as it is, which must be copied, not
  // inflated. The test checks that the file really holds such chunks.
  test::TempDir dir;
  const int W = 64, H = 40;
  std::mt19937 rng(7);
  Image noise(W, H, 3);
  for (float& v : noise.data()) {
    // random sign and mantissa, an exponent of a finite number
    const auto bits =
        static_cast<std::uint32_t>((rng() & 0x807FFFFFu) | ((1u + rng() % 254u) << 23));
    std::memcpy(&v, &bits, 4);
  }
  const std::string f = dir.file("noise.exr");
  write_zip_rgb(f, noise);
  auto bytes = file_bytes(f);
  const io::HeaderSummary h = walk(bytes, f);
  REQUIRE(io::detail::chunk_decodes(h));
  const auto& offsets = h.parts.front().chunk_offsets;
  REQUIRE(offsets.size() == 3);  // 16, 16 and 8 lines
  int stored = 0;
  for (std::size_t k = 0; k < offsets.size(); ++k) {
    std::int32_t size = 0;
    std::memcpy(&size, bytes.data() + offsets[k] + 4, 4);
    stored += size == (k < 2 ? 16 : 8) * W * 3 * 4;
  }
  REQUIRE(stored > 0);
  io::ReadOptions library;
  library.exr_decoder = io::ExrDecoder::library;
  require_same_bits(io::read_pass(f).colour, io::read_pass(f, library).colour);
  require_same_bits(io::read_pass(f).colour, noise);

  // A compressed chunk with a byte changed inside its data, and one that claims more bytes than
  // its lines hold: refused as unreadable, naming the file.
  const std::string g = dir.file("flat.exr");
  write_zip_rgb(g, ramp97(W, H));
  const auto good = file_bytes(g);
  const auto gh = walk(good, g);
  REQUIRE(io::detail::chunk_decodes(gh));
  const std::uint64_t first = gh.parts.front().chunk_offsets.front();
  std::int32_t size = 0;
  std::memcpy(&size, good.data() + first + 4, 4);
  REQUIRE(size < 16 * W * 3 * 4);  // compressed
  auto bad = good;
  bad[first + 8 + static_cast<std::size_t>(size) / 2] ^= 0x5A;
  auto too_big = good;
  const std::int32_t more = 16 * W * 3 * 4 + 1;
  std::memcpy(too_big.data() + first + 4, &more, 4);
  for (const auto* b : {&bad, &too_big}) {
    try {
      (void)io::read_pass(io::MemorySource(*b), "bad.exr", {});
      FAIL("a corrupt chunk was read");
    } catch (const InputError& e) {
      CHECK(e.kind() == InputErrorKind::unreadable);
      CHECK_THAT(std::string(e.what()), Contains("bad.exr"));
    }
  }
}

TEST_CASE("the chunk decoder says what is wrong with a chunk's zlib stream", "[io][chunks]") {
  // Chunk 0 of a compressible file replaced by crafted zlib streams (libdeflate's compressor):
  // one that inflates to exactly the chunk's lines (the control: read), one to fewer bytes, one
  // to more, and one whose Adler-32 is off. Each bad one is refused as unreadable, naming the
  // file, the chunk and what is wrong; the other chunks stay as written.
  test::TempDir dir;
  const int W = 64, H = 40;
  const std::string f = dir.file("ramp.exr");
  write_zip_rgb(f, ramp97(W, H));
  const auto good = file_bytes(f);
  const auto h = walk(good, f);
  REQUIRE(io::detail::chunk_decodes(h));
  const std::uint64_t at = h.parts.front().chunk_offsets[0];
  const std::uint64_t next = h.parts.front().chunk_offsets[1];
  const std::size_t lines = 16 * W * 3 * 4;  // chunk 0: 16 lines of 3 float channels
  const std::unique_ptr<libdeflate_compressor, void (*)(libdeflate_compressor*)> compressor(
      libdeflate_alloc_compressor(6), libdeflate_free_compressor);
  libdeflate_compressor* c = compressor.get();
  REQUIRE(c != nullptr);
  const auto with_stream = [&](std::size_t n, bool bad_adler) {
    std::vector<unsigned char> raw(n);
    for (std::size_t i = 0; i < n; ++i) raw[i] = static_cast<unsigned char>(i % 7);
    std::vector<unsigned char> z(libdeflate_zlib_compress_bound(c, n));
    z.resize(libdeflate_zlib_compress(c, raw.data(), n, z.data(), z.size()));
    REQUIRE(!z.empty());
    if (bad_adler) z.back() ^= 1;
    REQUIRE(8 + z.size() <= next - at);  // fits chunk 0's place
    auto b = good;
    const auto size = static_cast<std::int32_t>(z.size());
    std::memcpy(b.data() + at + 4, &size, 4);
    std::memcpy(b.data() + at + 8, z.data(), z.size());
    return b;
  };
  const Pass control = io::read_pass(io::MemorySource(with_stream(lines, false)), "c.exr", {});
  CHECK(control.width() == W);
  const std::pair<std::vector<unsigned char>, std::string> bad[] = {
      {with_stream(lines - 16, false), "chunk 0 inflates to fewer bytes"},
      {with_stream(lines + 16, false), "chunk 0 inflates to more bytes"},
      {with_stream(lines, true), "chunk 0 does not inflate"}};
  for (const auto& [bytes, why] : bad) {
    INFO(why);
    try {
      (void)io::read_pass(io::MemorySource(bytes), "bad.exr", {});
      FAIL("a corrupt chunk was read");
    } catch (const InputError& e) {
      CHECK(e.kind() == InputErrorKind::unreadable);
      CHECK_THAT(std::string(e.what()), Contains("bad.exr") && Contains(why));
    }
  }
}

TEST_CASE("ZIP's predictor is undone as OpenEXR's file layout specifies", "[io][chunks]") {
  // The reference, one byte at a time from the layout's description: a running sum of the stored
  // differences less 128, then the even-indexed bytes (stored first) and the odd-indexed ones
  // put back in turn. Lengths around the 16- and 32-byte blocks of the SSE2 path and its tails.
  std::mt19937 rng(11);
  for (const std::size_t n :
       {std::size_t{1}, std::size_t{2}, std::size_t{15}, std::size_t{16}, std::size_t{17},
        std::size_t{31}, std::size_t{32}, std::size_t{33}, std::size_t{47}, std::size_t{64},
        std::size_t{65}, std::size_t{1000}, std::size_t{4097}}) {
    INFO("n = " << n);
    std::vector<unsigned char> stored(n);
    for (auto& b : stored) b = static_cast<unsigned char>(rng());
    std::vector<unsigned char> sum = stored, want(n);
    for (std::size_t i = 1; i < n; ++i)
      sum[i] = static_cast<unsigned char>(sum[i - 1] + sum[i] - 128);
    for (std::size_t i = 0; i < n; ++i)
      want[i] = i % 2 == 0 ? sum[i / 2] : sum[(n + 1) / 2 + i / 2];
    std::vector<unsigned char> t = stored, got(n, 0xEE);
    io::detail::undo_zip_predictor(t.data(), n, got.data());
    REQUIRE(t == sum);
    REQUIRE(got == want);
  }
}

TEST_CASE("the chunk decoder's scratch counts against the read budget", "[io][chunks]") {
  // A chunk holds every channel of its lines, wanted or not: 63 channels of which the colour is
  // read. Each decoding thread holds three chunks' worth (stored, inflated, reordered).
  test::TempDir dir;
  const int W = 512, H = 32;
  std::vector<io::NamedChannel> ch;
  const Image flat(W, H, 3, 0.5f);
  io::add_layer(ch, "", flat, "RGB");
  for (int k = 0; k < 20; ++k) io::add_layer(ch, "aux" + std::to_string(k) + ".", flat, "RGB");
  const std::string f = dir.file("wide.exr");
  io::write_image(f, W, H, ch, {});
  const auto bytes = file_bytes(f);
  const auto h = walk(bytes, f);
  REQUIRE(io::detail::chunk_decodes(h));
  REQUIRE(io::detail::chunk_scratch_bytes(h.parts.front()) == 3u * 16 * W * 63 * 4);
  io::ReadOptions o;
  o.features = false;
  o.limits.max_memory_bytes = 3 << 20;  // the library's strip fits, one thread's scratch does not
  io::ReadOptions library = o;
  library.exr_decoder = io::ExrDecoder::library;
  const Pass ref = io::read_pass(f, library);
  try {
    (void)io::read_pass(f, o);
    FAIL("read beyond the budget");
  } catch (const InputError& e) {
    CHECK(e.kind() == InputErrorKind::too_large);
  }
  o.limits.max_memory_bytes = 256 << 20;
  require_same_bits(io::read_pass(f, o).colour, ref.colour);
}

TEST_CASE("real Blender Cycles pass from samples/", "[io][real]") {
  io::PassInfo info;
  const Pass p = io::read_pass(samples("renders/cornell/pass_00.exr"), {}, &info);
  CHECK(info.renderer == io::Renderer::cycles);
  CHECK(info.layer == "ViewLayer");
  CHECK(info.width == 128);
  CHECK(info.height == 128);
  CHECK(info.spp == 4);
  CHECK(info.spp_source == io::SppSource::header);
  CHECK(info.layout == Layout{true, true, true, false});
  double sum = 0;
  for (float v : p.colour.data()) {
    REQUIRE(std::isfinite(v));
    sum += v;
  }
  CHECK(sum > 0);  // a lit scene
  // The half-float scene decodes too.
  io::PassInfo hinfo;
  io::read_pass(samples("renders/textured_dof/pass_00.exr"), {}, &hinfo);
  CHECK(hinfo.pixel_type == "half");
  CHECK(hinfo.renderer == io::Renderer::cycles);
}

TEST_CASE("real POV-Ray passes from samples/ (EXR and HDR)", "[io][real]") {
  io::PassInfo info;
  io::ReadOptions o;
  o.spp = 1;
  const Pass p = io::read_pass(samples("renders/povray/pass_00.exr"), o, &info);
  CHECK(info.renderer == io::Renderer::povray);
  CHECK(info.width == 128);
  CHECK(info.pixel_type == "half");
  io::PassInfo hinfo;
  const Pass h = io::read_pass(samples("renders/povray/pass_00.hdr"), o, &hinfo);
  CHECK(hinfo.format == "hdr");
  REQUIRE(h.colour.same_size(p.colour));
  // Same render, two encodings: agree within RGBE/half precision on average.
  double diff = 0, mag = 0;
  for (std::size_t i = 0; i < p.colour.data().size(); ++i) {
    diff += std::abs(p.colour.data()[i] - h.colour.data()[i]);
    mag += std::abs(p.colour.data()[i]);
  }
  CHECK(diff / mag < 0.01);
}

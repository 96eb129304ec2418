// PreviewCache: layer renditions of a published EXR, made once per version.
#include <catch2/catch.hpp>

#include "daemon/preview_cache.hpp"
#include "daemon/processor.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/protocol/api.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using namespace proden;
using namespace proden::daemon;

namespace {

// A published-like EXR: R,G,B plus a "render" layer.
fs::path write_published(const test::TempDir& t) {
  Image rgb(6, 4, 3), render(6, 4, 3);
  for (int c = 0; c < 3; ++c) {
    auto a = rgb.plane(c);
    auto b = render.plane(c);
    for (std::size_t i = 0; i < a.size(); ++i) {
      a[i] = 0.1f * static_cast<float>(c + 1);
      b[i] = 0.5f;
    }
  }
  std::vector<io::NamedChannel> ch;
  io::add_layer(ch, "", rgb);
  io::add_layer(ch, "render.", render);
  const fs::path p = t.path() / "shot_0001.exr";
  io::write_image(p.string(), 6, 4, ch);
  return p;
}

int status_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const protocol::ApiError& e) {
    return e.status();
  }
  return 0;
}

}  // namespace

TEST_CASE("PreviewCache: unknown formats and layers are refused", "[daemon][preview]") {
  CHECK(status_of([] { PreviewCache::check_request("tiff", ""); }) == 400);
  CHECK(status_of([] { PreviewCache::check_request("png", "bogus"); }) == 400);
  CHECK(status_of([] { PreviewCache::check_request("png", "alpha"); }) == 0);
}

TEST_CASE("PreviewCache: a rendition is made once per version", "[daemon][preview]") {
  test::TempDir t;
  const fs::path exr = write_published(t);
  const fs::path cache = t.path() / "cache";
  PreviewCache pc;
  const auto whole = pc.get(cache, exr, 1, 1, "exr", "");
  CHECK(whole.path == exr);
  CHECK(whole.content_type == "image/x-exr");
  const auto png = pc.get(cache, exr, 1, 1, "png", "render");
  CHECK(png.content_type == "image/png");
  REQUIRE(fs::exists(png.path));
  const auto made = fs::last_write_time(png.path);
  CHECK(pc.get(cache, exr, 1, 1, "png", "render").path == png.path);
  CHECK(fs::last_write_time(png.path) == made);  // served from the cache
  const auto v2 = pc.get(cache, exr, 1, 2, "png", "render");
  CHECK(v2.path != png.path);
  CHECK(fs::exists(v2.path));
  CHECK_FALSE(fs::exists(png.path));  // the old version's rendition is gone
  const auto layer = pc.get(cache, exr, 1, 2, "exr", "render");
  CHECK(read_layer(layer.path.string(), "result").plane(0)[0] == Approx(0.5f));
}

TEST_CASE("PreviewCache: a layer the frame lacks is 404", "[daemon][preview]") {
  test::TempDir t;
  const fs::path exr = write_published(t);
  PreviewCache pc;
  CHECK(status_of([&] { pc.get(t.path() / "cache", exr, 1, 1, "png", "alpha"); }) == 404);
}

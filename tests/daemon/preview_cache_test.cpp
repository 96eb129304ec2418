// PreviewCache: layer renditions of a published EXR, made once per version.
#include <catch2/catch.hpp>

#include <OpenImageIO/imageio.h>

#include <cmath>
#include <map>

#include "daemon/colour_map.hpp"
#include "daemon/preview_cache.hpp"
#include "daemon/processor.hpp"
#include "proden/io/image_writer.hpp"
#include "proden/io/pass_reader.hpp"
#include "proden/protocol/api.hpp"
#include "test_support.hpp"

namespace fs = std::filesystem;
using namespace proden;
using namespace proden::daemon;

namespace {

// A rendition (PNG or single-layer EXR) as RGB planes, read as any client would read it.
Image rendition(const std::string& path) {
  auto in = OIIO::ImageInput::open(path);
  REQUIRE(in);
  const OIIO::ImageSpec spec = in->spec();
  std::vector<float> px(static_cast<std::size_t>(spec.width) * spec.height * spec.nchannels);
  REQUIRE(in->read_image(0, 0, 0, spec.nchannels, OIIO::TypeDesc::FLOAT, px.data()));
  Image img(spec.width, spec.height, 3);
  for (int c = 0; c < 3; ++c) {
    const int src = std::min(c, spec.nchannels - 1);
    auto plane = img.plane(c);
    for (std::size_t p = 0; p < plane.size(); ++p) {
      plane[p] = px[p * static_cast<std::size_t>(spec.nchannels) + static_cast<std::size_t>(src)];
    }
  }
  return img;
}

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
  CHECK(rendition(layer.path.string()).plane(0)[0] == Approx(0.5f));
}

TEST_CASE("PreviewCache: a layer the frame lacks is 404", "[daemon][preview]") {
  test::TempDir t;
  const fs::path exr = write_published(t);
  PreviewCache pc;
  CHECK(status_of([&] { pc.get(t.path() / "cache", exr, 1, 1, "png", "alpha"); }) == 404);
}

namespace {

// A published EXR with every layer the pipeline writes (alpha a gradient, errors positive).
// With `cv`, also the error estimate's cross-validation layers (docs/error_estimate.md), and with
// `spread` a linear denoiser's `cvspread` among them.
fs::path write_full(const test::TempDir& t, bool cv = false, bool spread = false) {
  const int w = 16, h = 8;
  std::map<std::string, Image> layers;
  for (const char* n : {"", "render.", "variance.", "denoised.", "alpha.", "sure."}) {
    layers[n] = Image(w, h, 3);
  }
  if (cv) {
    layers["cvsquare."] = Image(w, h, 3, 4e-4f);
    layers["cvvariance."] = Image(w, h, 3, 1e-4f);
    if (spread) layers["cvspread."] = Image(w, h, 3, 2e-4f);
  }
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      for (int c = 0; c < 3; ++c) {
        layers[""].at(x, y, c) = 0.5f;
        layers["render."].at(x, y, c) = 0.5f + 0.01f * static_cast<float>(x);
        layers["denoised."].at(x, y, c) = 0.5f;
        layers["variance."].at(x, y, c) = 1e-4f * static_cast<float>(1 + x);
        layers["sure."].at(x, y, c) = 1e-5f;
        layers["alpha."].at(x, y, c) = static_cast<float>(x) / static_cast<float>(w - 1);
      }
    }
  }
  std::vector<io::NamedChannel> ch;
  for (const auto& [n, img] : layers) io::add_layer(ch, n, img);
  const fs::path p = t.path() / (spread ? "full_spread_0001.exr"
                                 : cv   ? "full_cv_0001.exr"
                                        : "full_0001.exr");
  io::write_image(p.string(), w, h, ch);
  return p;
}

PreviewCache::Request png(const std::string& layer) {
  PreviewCache::Request r;
  r.format = "png";
  r.layer = layer;
  return r;
}

std::string header(const PreviewCache::File& f, const std::string& name) {
  for (const auto& [k, v] : f.headers) {
    if (k == name) return v;
  }
  return "";
}

}  // namespace

TEST_CASE("PreviewCache: alpha and errors are colour-mapped with their range",
          "[daemon][preview]") {
  test::TempDir t;
  const fs::path exr = write_full(t);
  PreviewCache pc;
  PreviewCache::Request r = png("alpha");
  const auto alpha = pc.get(t.path() / "cache", exr, 1, 1, r);
  CHECK(header(alpha, "X-Proden-Colormap") == "viridis");
  CHECK(header(alpha, "X-Proden-Scale") == "linear");
  CHECK(header(alpha, "X-Proden-Range") == "0 1");
  const Image a = rendition(alpha.path.string());  // the PNG, as RGB in [0,1]
  REQUIRE(a.width() == 16);
  // viridis: the left edge (alpha 0) is dark purple, the right edge (alpha 1) yellow
  CHECK(a.at(0, 0, 0) == Approx(0x44 / 255.0f).margin(1e-3));
  CHECK(a.at(0, 0, 2) == Approx(0x54 / 255.0f).margin(1e-3));
  CHECK(a.at(15, 0, 0) == Approx(0xfd / 255.0f).margin(1e-3));
  CHECK(a.at(15, 0, 1) == Approx(0xe7 / 255.0f).margin(1e-3));

  r.layer = "variance";
  const auto var = pc.get(t.path() / "cache", exr, 1, 1, r);
  CHECK(header(var, "X-Proden-Colormap") == "magma");
  CHECK(header(var, "X-Proden-Scale") == "log");
  CHECK(header(var, "X-Proden-Range") == "0.0001 0.01");
  const Image v = rendition(var.path.string());
  CHECK(v.at(15, 0, 0) > v.at(0, 0, 0) + 0.2f);  // not black: brighter where the variance is larger
  // Served again from the cache, with the same headers.
  CHECK(header(pc.get(t.path() / "cache", exr, 1, 1, r), "X-Proden-Range") == "0.0001 0.01");
  r.range = std::pair{1e-6, 1.0};
  CHECK(header(pc.get(t.path() / "cache", exr, 1, 1, r), "X-Proden-Range") == "1e-06 1");

  const auto err = pc.get(t.path() / "cache", exr, 1, 1, png("error"));
  CHECK(header(err, "X-Proden-Scale") == "log");
}

TEST_CASE("PreviewCache: the error map uses the cross-validation layers when they are there",
          "[daemon][preview]") {
  test::TempDir t;
  PreviewCache pc;
  PreviewCache::Request r;
  r.format = "exr";
  r.layer = "error";
  for (const int kind : {0, 1, 2}) {  // no cross-validation, cross-validation, with a spread
    INFO("cross-validation layers " << kind);
    const bool cv = kind > 0, spread = kind == 2;
    const fs::path exr = write_full(t, cv, spread);
    // A cache of its own per file: renditions are keyed by (version, parameters).
    const fs::path cache = t.path() / ("cache" + std::to_string(kind));
    const Image got = rendition(pc.get(cache, exr, 1, 1, r).path.string());
    const std::string e = exr.string();
    const std::vector<Image> l = io::read_layers(e, {"render", "variance", "denoised", "alpha",
                                                     "sure", "cvsquare", "cvvariance", "cvspread"});
    const Image &x = l[0], &v = l[1], &y = l[2], &a = l[3], &s = l[4], &q = l[5], &qv = l[6],
                &sp = l[7];
    REQUIRE(q.empty() == !cv);
    REQUIRE(sp.empty() == !spread);
    const Image want = spread ? result_error(x, v, y, a, s, &q, &qv, &sp)
                       : cv   ? result_error(x, v, y, a, s, &q, &qv)
                              : result_error(x, v, y, a, s);
    // What the map would be without the layer that sets this kind apart.
    const Image other = spread ? result_error(x, v, y, a, s, &q, &qv)
                        : cv   ? result_error(x, v, y, a, s)
                               : Image{};
    REQUIRE(got.same_size(want));
    bool differs = false;
    for (std::size_t i = 0; i < want.data().size(); ++i) {
      CHECK(got.data()[i] == Approx(want.data()[i]).margin(1e-9));
      if (cv && std::abs(other.data()[i] - want.data()[i]) > 1e-6f) differs = true;
    }
    if (cv) CHECK(differs);  // the map is not SURE's, nor the bracket's without the spread
  }
}

TEST_CASE("PreviewCache: thumbnails and exposures are separate renditions", "[daemon][preview]") {
  test::TempDir t;
  const fs::path exr = write_full(t);
  PreviewCache pc;
  PreviewCache::Request r = png("render");
  const auto full = pc.get(t.path() / "cache", exr, 1, 1, r);
  r.size = 8;
  const auto thumb = pc.get(t.path() / "cache", exr, 1, 1, r);
  CHECK(thumb.path != full.path);
  CHECK(thumb.etag != full.etag);
  CHECK(rendition(thumb.path.string()).width() == 8);
  CHECK(rendition(thumb.path.string()).height() == 4);
  r.size = 0;
  r.exposure = 2.0;
  const auto bright = pc.get(t.path() / "cache", exr, 1, 1, r);
  CHECK(rendition(bright.path.string()).at(0, 0, 0) >
        rendition(full.path.string()).at(0, 0, 0) + 0.05f);
  // A new version clears every rendition of the old one.
  pc.get(t.path() / "cache", exr, 1, 2, r);
  CHECK_FALSE(fs::exists(thumb.path));
  CHECK_FALSE(fs::exists(full.path));
}

TEST_CASE("PreviewCache: query parameters are validated", "[daemon][preview]") {
  using Q = std::map<std::string, std::string>;
  const auto r = PreviewCache::Request::from_query(
      Q{{"format", "png"}, {"layer", "sure"}, {"size", "160"}, {"range", "1e-6,1e-2"}});
  CHECK(r.size == 160);
  CHECK(r.range->first == Approx(1e-6));
  CHECK(PreviewCache::Request::from_query(Q{{"format", "png"}, {"exposure", "1.1"}}).exposure ==
        Approx(1.0));  // quarter-EV steps
  CHECK(PreviewCache::Request::from_query(Q{}).format == "exr");
  for (const Q& bad :
       {Q{{"format", "png"}, {"size", "7"}}, Q{{"format", "png"}, {"size", "1e9"}},
        Q{{"format", "png"}, {"size", "16.5"}}, Q{{"format", "exr"}, {"exposure", "1"}},
        Q{{"format", "png"}, {"exposure", "nan"}}, Q{{"format", "png"}, {"exposure", "99"}},
        Q{{"format", "png"}, {"layer", "result"}, {"range", "0,1"}},
        Q{{"format", "png"}, {"layer", "sure"}, {"range", "0,1"}},
        Q{{"format", "png"}, {"layer", "alpha"}, {"range", "1,0"}},
        Q{{"format", "png"}, {"layer", "alpha"}, {"range", "x"}},
        Q{{"format", "png"}, {"layer", "bogus"}}}) {
    CHECK(status_of([&] { PreviewCache::Request::from_query(bad); }) == 400);
  }
}

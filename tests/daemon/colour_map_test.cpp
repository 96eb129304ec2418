// colour_map: how layers are drawn for people (tone map with exposure, colour maps with linear
// and log scales, auto range, thumbnails, the result's per-pixel error).
#include <catch2/catch.hpp>

#include <cmath>
#include <limits>

#include "daemon/colour_map.hpp"

using namespace proden;
using namespace proden::daemon;

namespace {

std::array<int, 3> px(const Rgb8& img, int x, int y) {
  const std::size_t i = (static_cast<std::size_t>(y) * img.width + x) * 3;
  return {img.data[i], img.data[i + 1], img.data[i + 2]};
}

}  // namespace

TEST_CASE("colour_map: layers are drawn by kind", "[daemon][colour_map]") {
  CHECK(layer_view("result").colour);
  CHECK(layer_view("render").colour);
  CHECK(layer_view("denoised").colour);
  const LayerView alpha = layer_view("alpha");
  CHECK_FALSE(alpha.colour);
  CHECK(alpha.scale == Scale::linear);
  CHECK(alpha.map == ColourMap::viridis);
  for (const char* l :
       {"variance", "mixvariance", "sure", "cvsquare", "cvvariance", "cvspread", "error"}) {
    CHECK_FALSE(layer_view(l).colour);
    CHECK(layer_view(l).scale == Scale::log);
    CHECK(layer_view(l).map == ColourMap::magma);
  }
}

TEST_CASE("colour_map: tone map is Reinhard then sRGB, scaled by the exposure",
          "[daemon][colour_map]") {
  Image img(3, 1, 3);
  for (int c = 0; c < 3; ++c) {
    img.at(0, 0, c) = 0.0f;
    img.at(1, 0, c) = 1.0f;  // x/(1+x) = 0.5 -> sRGB 0.7354 -> 188
    img.at(2, 0, c) = std::numeric_limits<float>::quiet_NaN();
  }
  const Rgb8 t = tone_map(img, 0.0);
  CHECK(px(t, 0, 0) == std::array<int, 3>{0, 0, 0});
  CHECK(px(t, 1, 0) == std::array<int, 3>{188, 188, 188});
  CHECK(px(t, 2, 0) == std::array<int, 3>{0, 0, 0});
  // +1 EV: x = 2 -> 2/3 -> sRGB 0.8360 -> 213
  CHECK(px(tone_map(img, 1.0), 1, 0)[0] == 213);
  CHECK(px(tone_map(img, -1.0), 1, 0)[0] < 188);
}

TEST_CASE("colour_map: alpha maps linearly over [0,1] (not a flat grey)", "[daemon][colour_map]") {
  const std::vector<float> v = {0.0f, 0.5f, 1.0f, 2.0f, -1.0f};
  const Rgb8 m = apply_colour_map(v, 5, 1, ColourMap::viridis, {0.0, 1.0, Scale::linear});
  const auto stops = colour_stops(ColourMap::viridis, 2);
  CHECK(stops.front() == "#440154");  // viridis' ends
  CHECK(stops.back() == "#fde725");
  CHECK(px(m, 0, 0) == std::array<int, 3>{0x44, 0x01, 0x54});
  CHECK(px(m, 2, 0) == std::array<int, 3>{0xfd, 0xe7, 0x25});
  CHECK(px(m, 1, 0) != px(m, 0, 0));
  CHECK(px(m, 1, 0) != px(m, 2, 0));
  CHECK(px(m, 3, 0) == px(m, 2, 0));  // above the range: the top colour
  CHECK(px(m, 4, 0) == px(m, 0, 0));  // below: the bottom colour
}

TEST_CASE("colour_map: errors map on a log scale", "[daemon][colour_map]") {
  const std::vector<float> v = {1e-6f, 1e-4f, 1e-2f, 0.0f, -3.0f};
  const Rgb8 m = apply_colour_map(v, 5, 1, ColourMap::magma, {1e-6, 1e-2, Scale::log});
  const auto all = colour_stops(ColourMap::magma, 256);  // t = 0.5 <-> 1e-4: entry 127 or 128
  char buf[8];
  const auto c = px(m, 1, 0);
  std::snprintf(buf, sizeof buf, "#%02x%02x%02x", c[0], c[1], c[2]);
  CHECK((std::string(buf) == all[127] || std::string(buf) == all[128]));
  CHECK(px(m, 3, 0) == px(m, 0, 0));  // zero and negative: the lowest colour
  CHECK(px(m, 4, 0) == px(m, 0, 0));
  CHECK(px(m, 2, 0) != px(m, 0, 0));
}

TEST_CASE("colour_map: the auto log range covers the values in whole decades",
          "[daemon][colour_map]") {
  std::vector<float> v;
  for (int i = 0; i < 1000; ++i)
    v.push_back(static_cast<float>(3e-5 * std::pow(10.0, 2.0 * i / 999)));
  v.push_back(-1.0f);
  v.push_back(std::numeric_limits<float>::infinity());
  const ScalarRange r = auto_log_range(v);
  CHECK(r.scale == Scale::log);
  CHECK(r.lo == Approx(1e-5));
  CHECK(r.hi == Approx(1e-2));
  const ScalarRange none = auto_log_range(std::vector<float>{0.0f, -1.0f});
  CHECK(none.lo == Approx(1e-6));
  CHECK(none.hi == Approx(1e-2));
  const ScalarRange one = auto_log_range(std::vector<float>{1e-3f, 1e-3f});
  CHECK(one.hi / one.lo == Approx(10.0));
  std::vector<float> wide = {1e-30f, 1.0f};
  for (int i = 0; i < 200; ++i) wide.push_back(i % 2 ? 1e-30f : 1.0f);
  const ScalarRange w = auto_log_range(wide);
  CHECK(w.hi / w.lo == Approx(1e8));  // at most eight decades
}

TEST_CASE("colour_map: thumbnails are area averages", "[daemon][colour_map]") {
  Image img(8, 4, 1);
  for (int y = 0; y < 4; ++y) {
    for (int x = 0; x < 8; ++x) img.at(x, y, 0) = static_cast<float>(x < 4 ? 1 : 3);
  }
  img.at(7, 3, 0) = std::numeric_limits<float>::quiet_NaN();
  const Image t = downscale(img, 2);
  REQUIRE(t.width() == 2);
  REQUIRE(t.height() == 1);
  CHECK(t.at(0, 0, 0) == Approx(1.0f));
  CHECK(t.at(1, 0, 0) == Approx(3.0f));   // the NaN sample is left out
  CHECK(downscale(img, 8).width() == 8);  // fits already
  const Image odd = downscale(Image(1000, 3, 3, 2.0f), 160);
  CHECK(odd.width() == 160);
  CHECK(odd.height() == 1);
  CHECK(odd.at(100, 0, 2) == Approx(2.0f));
}

TEST_CASE("colour_map: the result's error per pixel, floored at the render's share",
          "[daemon][colour_map]") {
  Image x(2, 1, 1), v(2, 1, 1), y(2, 1, 1), a(2, 1, 1), s(2, 1, 1);
  // pixel 0: a = 0.5, Var 0.04, SURE 0.01, y - x = 0.1:
  //   0.5*0.04 + 0.5*0.01 - 0.25*0.01 = 0.0225 (floor 0.25*0.04 = 0.01)
  x.at(0, 0, 0) = 1.0f;
  y.at(0, 0, 0) = 1.1f;
  v.at(0, 0, 0) = 0.04f;
  s.at(0, 0, 0) = 0.01f;
  a.at(0, 0, 0) = 0.5f;
  // pixel 1: SURE negative drives the sum below the floor (1-a)^2 Var = 0.0016
  x.at(1, 0, 0) = 1.0f;
  y.at(1, 0, 0) = 1.0f;
  v.at(1, 0, 0) = 0.01f;
  s.at(1, 0, 0) = -0.1f;
  a.at(1, 0, 0) = 0.6f;
  const Image e = result_error(x, v, y, a, s);
  CHECK(e.at(0, 0, 0) == Approx(0.0225f));
  CHECK(e.at(1, 0, 0) == Approx(0.0016f));
}

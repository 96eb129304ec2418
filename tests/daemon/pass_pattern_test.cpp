// The watch-pattern matcher (service/daemon/pass_pattern.hpp): what the documented grammar
// matches, and that hostile patterns and names finish at once (issue 11, class 3: a pattern of
// repeated placeholders compiled to std::regex backtracked for hours on one long file name).
#include <catch2/catch.hpp>

#include <chrono>
#include <string>

#include "daemon/watcher.hpp"

using proden::daemon::PassPattern;

namespace {

std::string m(const PassPattern& p, const std::string& path) {
  const auto r = p.match(path);
  return r ? std::to_string(r->frame) + "|" + r->pass : "-";
}

}  // namespace

TEST_CASE("watch patterns match what docs/api.md says", "[pattern]") {
  const PassPattern blender("pass_{pass}/beauty_####.exr");
  CHECK(m(blender, "pass_07/beauty_0012.exr") == "12|07");
  CHECK(m(blender, "pass_07/beauty_12345.exr") == "12345|07");  // at least 4 digits
  CHECK(m(blender, "pass_07/beauty_012.exr") == "-");
  CHECK(m(blender, "pass_07/beauty_0012.exr.tmp") == "-");
  CHECK(m(blender, "pass_07/sub/beauty_0012.exr") == "-");  // depth is fixed
  CHECK(m(blender, "beauty_0012.exr") == "-");
  CHECK(m(blender, "pass_/beauty_0012.exr") == "-");     // {pass} is one or more
  CHECK(m(blender, "pass_a.b/beauty_0012.exr") == "-");  // '.' is not a pass character
  CHECK(blender.depth() == 1);

  const PassPattern flat("p{pass}_{frame}.exr");  // {pass} may contain '_': greedy, then back
  CHECK(m(flat, "p07_0001.exr") == "1|07");
  CHECK(m(flat, "pa_b_0001.exr") == "1|a_b");
  CHECK(m(flat, "p07_.exr") == "-");
  CHECK(flat.depth() == 0);

  const PassPattern adjacent("{pass}{frame}.exr");  // ambiguous: {pass} takes all it can
  CHECK(m(adjacent, "abc123.exr") == "3|abc12");

  const PassPattern repeated("f{frame}/{pass}_{frame}.exr");  // repeated: must agree
  CHECK(m(repeated, "f0012/a_12.exr") == "12|a");
  CHECK(m(repeated, "f0012/a_13.exr") == "-");

  const PassPattern literal("{x}/{pass}_{frame}.exr");  // braces that are no placeholder
  CHECK(m(literal, "{x}/b_3.exr") == "3|b");
  CHECK(m(literal, "x/b_3.exr") == "-");

  const PassPattern digits("{pass}_{frame}.exr");
  CHECK(m(digits, "a_999999999.exr") == "999999999|a");
  CHECK(m(digits, "a_1000000000.exr") == "-");  // more than 9 digits
  CHECK(m(digits, "a_0000000000042.exr") == "42|a");
  CHECK(m(digits,
          "a_\xff"
          "1.exr") == "-");
}

TEST_CASE("bad patterns are refused with a reason", "[pattern]") {
  std::string why;
  CHECK_FALSE(PassPattern::parse("", why));
  CHECK_FALSE(PassPattern::parse("beauty_{frame}.exr", why));
  CHECK(why == "needs a {pass} placeholder");
  CHECK_FALSE(PassPattern::parse("{pass}.exr", why));
  CHECK_FALSE(PassPattern::parse("a//{pass}_{frame}", why));
  CHECK_FALSE(PassPattern::parse("../{pass}_{frame}", why));
  CHECK_FALSE(PassPattern::parse(std::string("{pass}\0{frame}", 14), why));
  CHECK_FALSE(PassPattern::parse("{pass}_##########", why));  // 10 '#'
  std::string many;
  for (int i = 0; i < 9; ++i) many += "{pass}";
  CHECK_FALSE(PassPattern::parse(many + "{frame}", why));
  CHECK(why == "more than 8 placeholders");
  CHECK_FALSE(PassPattern::parse(std::string(600, 'a') + "{pass}{frame}", why));
  std::string deep;
  for (int i = 0; i < 17; ++i) deep += "d/";
  CHECK_FALSE(PassPattern::parse(deep + "{pass}_{frame}", why));
  CHECK_THROWS_AS(PassPattern("nothing"), std::invalid_argument);
}

TEST_CASE("hostile patterns and long names finish in linear time", "[pattern][hostile]") {
  // Each of these took a backtracking regex exponential or high-polynomial time.
  const std::string long_name(4000, 'a');
  const std::string long_digits(4000, '1');
  std::string alternating;
  for (int i = 0; i < 2000; ++i) alternating += "a1";
  const std::vector<std::string> patterns = {
      "{pass}{pass}{pass}{pass}{pass}{pass}{pass}{frame}.exr",
      "{pass}{frame}{pass}{frame}{pass}{frame}{pass}{frame}x",
      "########{pass}{pass}{pass}{pass}{pass}{pass}!",
      "{pass}_{pass}_{pass}_{pass}_{frame}_{frame}_{frame}_{frame}",
  };
  for (const auto& pat : patterns) {
    INFO(pat);
    const PassPattern p(pat);
    for (const auto& name : {long_name, long_digits, alternating, long_name + "_1_2_3_4_5_6_7_8"}) {
      const auto t0 = std::chrono::steady_clock::now();
      CHECK_FALSE(p.match(name));
      // Generous: a linear matcher takes microseconds; the regex took hours.
      CHECK(std::chrono::steady_clock::now() - t0 < std::chrono::seconds(2));
    }
  }
}

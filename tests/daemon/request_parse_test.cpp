// What the daemon reads out of a request's bytes (service/daemon/request_parse.hpp): targets,
// frame numbers, Last-Event-ID, bearer tokens. fuzz/http_request_fuzz.cpp checks the same
// functions on arbitrary bytes; these are the documented cases.
#include <catch2/catch.hpp>

#include <string>

#include "daemon/request_parse.hpp"

using namespace proden::daemon;

TEST_CASE("request targets split into decoded segments and query", "[request]") {
  std::string why;
  const auto t = parse_target("/api/v1/jobs/j%31/frames/7/image?format=png&layer=a+b&x", why);
  REQUIRE(t);
  CHECK(t->path == std::vector<std::string>{"api", "v1", "jobs", "j1", "frames", "7", "image"});
  CHECK(t->query.at("format") == "png");
  CHECK(t->query.at("layer") == "a b");
  CHECK(t->query.at("x").empty());
  CHECK(parse_target("//livez/", why)->path == std::vector<std::string>{"livez"});
}

TEST_CASE("request targets that are not UTF-8 text are refused, naming the part", "[request]") {
  std::string why;
  CHECK_FALSE(parse_target("livez", why));
  CHECK_FALSE(parse_target("/api/%FF", why));
  CHECK(why.find("path segment 2") != std::string::npos);
  CHECK_FALSE(parse_target("/a/%0A", why));              // a control character, however encoded
  CHECK_FALSE(parse_target("/a?layer=%ED%A0%80", why));  // a UTF-16 surrogate
  CHECK(why.find("'layer'") != std::string::npos);
}

TEST_CASE("frame numbers are 1-9 decimal digits", "[request]") {
  CHECK(parse_frame_number("0") == 0L);
  CHECK(parse_frame_number("0007") == 7L);
  CHECK(parse_frame_number("999999999") == 999999999L);
  CHECK_FALSE(parse_frame_number(""));
  CHECK_FALSE(parse_frame_number("1000000000"));  // 10 digits
  CHECK_FALSE(parse_frame_number("-1"));
  CHECK_FALSE(parse_frame_number("+1"));
  CHECK_FALSE(parse_frame_number(" 1"));
  CHECK_FALSE(parse_frame_number("1e3"));
  CHECK_FALSE(parse_frame_number("\xd9\xa3"));  // ARABIC-INDIC DIGIT THREE is not a digit here
}

TEST_CASE("Last-Event-ID is a 64-bit decimal", "[request]") {
  CHECK(parse_event_id("42") == 42u);
  CHECK(parse_event_id("18446744073709551615") == 18446744073709551615u);
  CHECK_FALSE(parse_event_id("18446744073709551616"));
  CHECK_FALSE(parse_event_id(""));
  CHECK_FALSE(parse_event_id("-1"));
  CHECK_FALSE(parse_event_id("12a"));
}

TEST_CASE("bearer tokens: scheme case-insensitive, token as sent", "[request]") {
  CHECK(bearer_token("Bearer abc") == std::string_view("abc"));
  CHECK(bearer_token("bEaReR a b") == std::string_view("a b"));
  CHECK_FALSE(bearer_token("Bearer "));
  CHECK_FALSE(bearer_token("Basic abc"));
  CHECK_FALSE(bearer_token("Bearerabc"));
}

// WebAssets: the embedded dashboard's pack, content negotiation and revalidation.
#include <catch2/catch.hpp>

#include <string>

#include "daemon/web_assets.hpp"

using namespace proden::daemon;

namespace {

std::string pack_of(const std::string& manifest, const std::string& data) {
  return "PRDNWEB1 " + std::to_string(manifest.size()) + "\n" + manifest + data;
}

std::span<const std::uint8_t> bytes(const std::string& s) {
  return {reinterpret_cast<const std::uint8_t*>(s.data()), s.size()};
}

Request get(const std::string& target, const std::string& accept = "",
            const std::string& inm = "") {
  Request r{http::verb::get, target, 11};
  if (!accept.empty()) r.set(http::field::accept_encoding, accept);
  if (!inm.empty()) r.set(http::field::if_none_match, inm);
  return r;
}

const std::string kManifest =
    R"({"files":[{"path":"/index.html","type":"text/html; charset=utf-8","etag":"\"i1\"","immutable":false,"offset":0,"size":5,"gzip_offset":5,"gzip_size":3},)"
    R"({"path":"/assets/app-1.js","type":"text/javascript; charset=utf-8","etag":"\"a1\"","immutable":true,"offset":8,"size":2,"gzip_offset":0,"gzip_size":0}]})";
const std::string kData =
    "<html"
    "GZ!"
    "js";

}  // namespace

TEST_CASE("WebAssets: serves the page and hashed assets with their headers", "[daemon][web]") {
  const std::string pack = pack_of(kManifest, kData);
  const WebAssets w(bytes(pack));
  REQUIRE(w.size() == 2);
  auto page = w.serve(get("/?x=1"));
  REQUIRE(page);
  CHECK(page->result() == http::status::ok);
  CHECK(page->body() == "<html");
  CHECK(page->at(http::field::content_type) == "text/html; charset=utf-8");
  CHECK(page->at(http::field::cache_control) == "no-cache");
  CHECK(page->at(http::field::vary) == "Accept-Encoding");
  CHECK(page->count("Content-Security-Policy") == 1);
  CHECK(page->count(http::field::content_encoding) == 0);

  auto gz = w.serve(get("/index.html", "br, gzip;q=0.8"));
  REQUIRE(gz);
  CHECK(gz->body() == "GZ!");
  CHECK(gz->at(http::field::content_encoding) == "gzip");

  auto js = w.serve(get("/assets/app-1.js", "gzip"));
  REQUIRE(js);
  CHECK(js->body() == "js");  // no gzip copy: identity
  CHECK(js->at(http::field::cache_control) == "public, max-age=31536000, immutable");

  auto again = w.serve(get("/assets/app-1.js", "", "W/\"x\", \"a1\""));
  REQUIRE(again);
  CHECK(again->result() == http::status::not_modified);
  CHECK(again->body().empty());

  CHECK_FALSE(w.serve(get("/nope.js")));
  CHECK_FALSE(w.serve(get("/assets/../index.html")));
}

TEST_CASE("WebAssets: Accept-Encoding", "[daemon][web]") {
  CHECK(accepts_gzip("gzip"));
  CHECK(accepts_gzip("deflate, GZIP"));
  CHECK(accepts_gzip("*"));
  CHECK(accepts_gzip("gzip;q=0.5"));
  CHECK_FALSE(accepts_gzip(""));
  CHECK_FALSE(accepts_gzip("br, deflate"));
  CHECK_FALSE(accepts_gzip("gzip;q=0"));
  CHECK_FALSE(accepts_gzip("gzip; q=0.000"));
}

TEST_CASE("WebAssets: a malformed pack is refused", "[daemon][web]") {
  CHECK_THROWS(WebAssets(bytes(std::string("nonsense"))));
  CHECK_THROWS(WebAssets(bytes(pack_of(kManifest, "short"))));  // a file lies outside
  CHECK_THROWS(WebAssets(bytes(std::string("PRDNWEB1 999\n{}"))));
  CHECK(WebAssets(bytes(pack_of(R"({"files":[]})", ""))).empty());
}

TEST_CASE("WebAssets: the built-in pack has the dashboard", "[daemon][web]") {
  // Built from web/ when node_modules is present (make test installs it).
  const WebAssets& w = WebAssets::builtin();
  REQUIRE_FALSE(w.empty());
  const auto* index = w.find("/");
  REQUIRE(index);
  CHECK(index->content_type == "text/html; charset=utf-8");
  CHECK_FALSE(index->gzip.empty());
}

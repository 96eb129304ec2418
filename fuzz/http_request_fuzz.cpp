// Fuzz target: the bytes of an HTTP request as the daemon reads them (daemon/http_server.cpp:
// Boost.Beast's request parser with the daemon's header and body limits), then everything proden
// itself reads out of it (daemon/request_parse.hpp): the target's path segments and query
// (parse_target), the frame number of a frames/{frame} path, the Authorization bearer token and
// Last-Event-ID (header or ?last_event_id=).
//
// Properties: no crash or UB on any bytes; a refused target's reason is JSON-safe text; an accepted
// target has non-empty segments and keys/values of UTF-8 without control characters, and encoding
// it again reproduces it (percent-encoding round trip); a frame number, an event id and a token are
// accepted exactly when their grammar says, with the value their text spells.
#include <boost/beast/core/flat_buffer.hpp>
#include <boost/beast/http.hpp>
#include <cstdint>
#include <string>
#include <string_view>

#include "daemon/config.hpp"
#include "daemon/request_parse.hpp"
#include "fuzz_check.hpp"

namespace http = boost::beast::http;
using namespace proden;
using namespace proden::daemon;

namespace {

bool clean(std::string_view s) {
  if (!io::is_valid_utf8(s)) return false;
  for (const char c : s) {
    const auto u = static_cast<unsigned char>(c);
    if (u < 0x20 || u == 0x7F) return false;
  }
  return true;
}

std::string encode(std::string_view s) {
  static constexpr char kHex[] = "0123456789ABCDEF";
  std::string out;
  for (const char c : s) {
    const auto u = static_cast<unsigned char>(c);
    if ((u >= 'A' && u <= 'Z') || (u >= 'a' && u <= 'z') || (u >= '0' && u <= '9') || u == '-' ||
        u == '.' || u == '_' || u == '~') {
      out += c;
    } else {
      out += '%';
      out += kHex[u >> 4];
      out += kHex[u & 15];
    }
  }
  return out;
}

std::string_view digits_without_leading_zeros(std::string_view s) {
  const auto nz = s.find_first_not_of('0');
  return nz == std::string_view::npos ? std::string_view("0") : s.substr(nz);
}

bool all_digits(std::string_view s) {
  for (const char c : s) {
    if (c < '0' || c > '9') return false;
  }
  return !s.empty();
}

void check_target(std::string_view raw) {
  std::string why;
  const auto t = parse_target(raw, why);
  if (!t) {
    fuzz::check_json_safe(why);
    return;
  }
  std::string again;
  for (const auto& seg : t->path) {
    FUZZ_CHECK(!seg.empty() && clean(seg));
    again += "/" + encode(seg);
  }
  if (again.empty()) again = "/";
  char sep = '?';
  for (const auto& [k, v] : t->query) {
    FUZZ_CHECK(clean(k) && clean(v));
    again += sep + encode(k) + "=" + encode(v);
    sep = '&';
  }
  const auto u = parse_target(again, why);
  FUZZ_CHECK(u && u->path == t->path && u->query == t->query);

  // frames/{frame}: the route's frame number.
  if (t->path.size() >= 6 && t->path[4] == "frames") {
    const std::string& s = t->path[5];
    const auto frame = parse_frame_number(s);
    FUZZ_CHECK(frame.has_value() == (all_digits(s) && s.size() <= 9));
    if (frame) {
      FUZZ_CHECK(*frame >= 0 && *frame <= 999999999);
      FUZZ_CHECK(std::to_string(*frame) == digits_without_leading_zeros(s));
    }
  }
  if (const auto it = t->query.find("last_event_id"); it != t->query.end()) {
    (void)parse_event_id(it->second);
  }
}

void check_event_id(std::string_view v) {
  const auto id = parse_event_id(v);
  if (!id) return;
  FUZZ_CHECK(all_digits(v) && v.size() <= 20);
  FUZZ_CHECK(std::to_string(*id) == digits_without_leading_zeros(v));
}

void check_bearer(std::string_view v) {
  const auto token = bearer_token(v);
  if (!token) return;
  FUZZ_CHECK(v.size() > 7);
  std::string scheme(v.substr(0, 7));
  for (char& c : scheme) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  FUZZ_CHECK(scheme == "bearer ");
  FUZZ_CHECK(*token == v.substr(7));
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const Limits limits;  // the daemon's defaults (deploy/proden.example.json)
  http::request_parser<http::string_body> parser;
  parser.header_limit(static_cast<std::uint32_t>(limits.max_header_bytes));
  parser.body_limit(limits.max_body_bytes);
  parser.eager(true);
  boost::beast::error_code ec;
  std::size_t used = 0;
  while (used < size && !ec && !parser.is_done()) {
    const std::size_t n = parser.put(boost::asio::buffer(data + used, size - used), ec);
    if (n == 0 && !ec) break;
    used += n;
  }
  if (!ec && !parser.is_done() && parser.is_header_done()) parser.put_eof(ec);
  if (!parser.is_header_done()) {
    // What the server never parses, proden never sees; the raw bytes still go through the pure
    // functions, which take any string.
    const std::string_view raw(reinterpret_cast<const char*>(data), size);
    check_target(raw);
    check_event_id(raw);
    check_bearer(raw);
    return 0;
  }
  const auto& req = parser.get();
  check_target(std::string_view(req.target().data(), req.target().size()));
  const auto auth = req[http::field::authorization];
  check_bearer(std::string_view(auth.data(), auth.size()));
  const auto last = req["Last-Event-ID"];
  check_event_id(std::string_view(last.data(), last.size()));
  for (const auto& field : req) {
    (void)io::printable(std::string_view(field.value().data(), field.value().size()));
  }
  return 0;
}

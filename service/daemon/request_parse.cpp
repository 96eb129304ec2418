#include "daemon/request_parse.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>

#include "proden/io/text.hpp"

namespace proden::daemon {
namespace {

int hex_value(char c) {
  if (c >= '0' && c <= '9') return c - '0';
  if (c >= 'a' && c <= 'f') return c - 'a' + 10;
  if (c >= 'A' && c <= 'F') return c - 'A' + 10;
  return -1;
}

std::string url_decode(std::string_view s, bool plus_is_space) {
  std::string out;
  out.reserve(s.size());
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '%' && i + 2 < s.size() && hex_value(s[i + 1]) >= 0 && hex_value(s[i + 2]) >= 0) {
      out += static_cast<char>(hex_value(s[i + 1]) * 16 + hex_value(s[i + 2]));
      i += 2;
    } else if (plus_is_space && s[i] == '+') {
      out += ' ';
    } else {
      out += s[i];
    }
  }
  return out;
}

// UTF-8 without control characters (a name, an id, a parameter value).
bool clean_text(std::string_view s) {
  if (!io::is_valid_utf8(s)) return false;
  return std::none_of(s.begin(), s.end(), [](char c) {
    const auto u = static_cast<unsigned char>(c);
    return u < 0x20 || u == 0x7F;
  });
}

}  // namespace

std::optional<Target> parse_target(std::string_view target, std::string& why) {
  if (target.empty() || target.front() != '/') {
    why = "request target: must start with '/'";
    return std::nullopt;
  }
  Target out;
  const auto q = target.find('?');
  const std::string_view p = target.substr(0, q);
  std::size_t start = 0;
  while (start < p.size()) {
    auto end = p.find('/', start);
    if (end == std::string_view::npos) end = p.size();
    if (end > start) {
      std::string seg = url_decode(p.substr(start, end - start), false);
      if (!clean_text(seg)) {
        why = "request target: path segment " + std::to_string(out.path.size() + 1) +
              " is not UTF-8 text";
        return std::nullopt;
      }
      out.path.push_back(std::move(seg));
    }
    start = end + 1;
  }
  if (q == std::string_view::npos) return out;
  const std::string_view qs = target.substr(q + 1);
  start = 0;
  while (start < qs.size()) {
    auto end = qs.find('&', start);
    if (end == std::string_view::npos) end = qs.size();
    const auto kv = qs.substr(start, end - start);
    const auto eq = kv.find('=');
    if (!kv.empty()) {
      std::string key = url_decode(kv.substr(0, eq), true);
      std::string value = eq == std::string_view::npos ? "" : url_decode(kv.substr(eq + 1), true);
      if (!clean_text(key)) {
        why = "request target: a query parameter name is not UTF-8 text";
        return std::nullopt;
      }
      if (!clean_text(value)) {
        why = "request target: query parameter '" + key + "' is not UTF-8 text";
        return std::nullopt;
      }
      out.query[std::move(key)] = std::move(value);
    }
    start = end + 1;
  }
  return out;
}

std::optional<std::uint64_t> parse_event_id(std::string_view v) {
  if (v.empty() || v.size() > 20) return std::nullopt;
  std::uint64_t id = 0;
  const auto [ptr, ec] = std::from_chars(v.data(), v.data() + v.size(), id);
  if (ec != std::errc() || ptr != v.data() + v.size()) return std::nullopt;
  return id;
}

std::optional<long> parse_frame_number(std::string_view s) {
  if (s.empty() || s.size() > 9) return std::nullopt;
  long frame = 0;
  for (const char c : s) {
    if (c < '0' || c > '9') return std::nullopt;
    frame = frame * 10 + (c - '0');
  }
  return frame;
}

std::optional<std::string_view> bearer_token(std::string_view auth) {
  constexpr std::string_view prefix = "bearer ";
  if (auth.size() <= prefix.size()) return std::nullopt;
  for (std::size_t i = 0; i < prefix.size(); ++i) {
    if (std::tolower(static_cast<unsigned char>(auth[i])) != prefix[i]) return std::nullopt;
  }
  return auth.substr(prefix.size());
}

}  // namespace proden::daemon

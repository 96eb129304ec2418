// What the daemon reads out of a request's bytes before it routes it: the target's path segments
// and query, a frame number, a Last-Event-ID, a bearer token. Pure functions over byte strings
// (tests/daemon/request_parse_test.cpp, fuzz/http_request_fuzz.cpp).
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace proden::daemon {

// A request target split into percent-decoded path segments and query parameters.
struct Target {
  std::vector<std::string> path;
  std::map<std::string, std::string> query;
};

// Parses an origin-form target ("/a/b?x=1&y=2"). Every decoded segment, key and value must be
// UTF-8 without control characters; otherwise nullopt with `why` naming the part ("path segment
// 3", "query parameter 'layer'"), for a 400.
std::optional<Target> parse_target(std::string_view target, std::string& why);

// A Last-Event-ID value: decimal digits only, fits 64 bits.
std::optional<std::uint64_t> parse_event_id(std::string_view value);

// A frame number as a path segment: 1-9 decimal digits (leading zeros allowed), or nullopt.
std::optional<long> parse_frame_number(std::string_view segment);

// The token of an "Authorization: Bearer <token>" value (scheme case-insensitive), or nullopt.
std::optional<std::string_view> bearer_token(std::string_view authorization);

}  // namespace proden::daemon

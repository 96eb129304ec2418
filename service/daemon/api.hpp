// Api: the REST routes of `proden serve` (/api/v1/jobs..., /api/v1/events, /metrics, /livez,
// /readyz) over the Engine, with bearer-token checks on mutating requests and JSON errors.
// The contract is documented in docs/api.md. Request bytes are checked where they enter: a target
// or body that is not UTF-8 is a 400 naming the part, never a string handed on.
#pragma once

#include <atomic>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "daemon/engine.hpp"
#include "daemon/files.hpp"
#include "daemon/http_server.hpp"

namespace proden::daemon {

class Api : public Handler {
 public:
  Api(const Config& config, Engine& engine, const Roots& roots, EventHub& events, Metrics& metrics,
      std::string token);
  std::optional<Response> before_body(const http::request_header<>& header,
                                      BodyPolicy& policy) override;
  Reply handle(Incoming& request) override;
  Response error(int status, const std::string& code, const std::string& message) override;
  void set_draining() { draining_ = true; }

 private:
  Reply route(Incoming& in, const std::vector<std::string>& path,
              const std::map<std::string, std::string>& query);
  Reply upload(Incoming& in, const std::vector<std::string>& path);
  Reply image(const Request& req, const std::string& id, long frame,
              const std::map<std::string, std::string>& query);
  Response json_response(int status, const nlohmann::json& body) const;
  bool authorized(const http::request_header<>& header) const;

  Config config_;
  Engine& engine_;
  const Roots& roots_;
  EventHub& events_;
  Metrics& metrics_;
  std::string token_;
  std::atomic<bool> draining_{false};
};

// ---- request parsing (byte strings in, fuzzable) ------------------------------------------------

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

// The token of an "Authorization: Bearer <token>" value (scheme case-insensitive), or nullopt.
std::optional<std::string_view> bearer_token(std::string_view authorization);

}  // namespace proden::daemon

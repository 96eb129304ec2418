// Api: the REST routes of `proden serve` (/api/v1/jobs..., /api/v1/events, /metrics, /livez,
// /readyz) over the Engine, with bearer-token checks on mutating requests and JSON errors.
// The contract is documented in docs/api.md.
#pragma once

#include <atomic>
#include <string>

#include "daemon/engine.hpp"
#include "daemon/http_server.hpp"

namespace proden::daemon {

class Api : public Handler {
 public:
  Api(const Config& config, Engine& engine, EventHub& events, Metrics& metrics, std::string token);
  std::optional<Response> before_body(const http::request_header<>& header,
                                      BodyPolicy& policy) override;
  Reply handle(Request& request) override;
  Response error(int status, const std::string& code, const std::string& message) override;
  void set_draining() { draining_ = true; }

 private:
  Reply route(Request& req, const std::vector<std::string>& path,
              const std::map<std::string, std::string>& query);
  Response json_response(int status, const nlohmann::json& body) const;
  bool authorized(const http::request_header<>& header) const;

  Config config_;
  Engine& engine_;
  EventHub& events_;
  Metrics& metrics_;
  std::string token_;
  std::atomic<bool> draining_{false};
};

// Splits "/a/b?x=1&y=2" into decoded path segments and query parameters.
void split_target(std::string_view target, std::vector<std::string>& path,
                  std::map<std::string, std::string>& query);

}  // namespace proden::daemon

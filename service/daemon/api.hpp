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
#include "daemon/request_parse.hpp"

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

}  // namespace proden::daemon

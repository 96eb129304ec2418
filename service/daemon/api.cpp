#include "daemon/api.hpp"

#include <spdlog/spdlog.h>

#include "daemon/colour_map.hpp"
#include "daemon/files.hpp"
#include "daemon/web_assets.hpp"

namespace proden::daemon {

using nlohmann::json;
using protocol::ApiError;

namespace {

std::string url_decode(std::string_view s) {
  std::string out;
  out.reserve(s.size());
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] == '%' && i + 2 < s.size() && std::isxdigit(static_cast<unsigned char>(s[i + 1])) &&
        std::isxdigit(static_cast<unsigned char>(s[i + 2]))) {
      out += static_cast<char>(std::stoi(std::string(s.substr(i + 1, 2)), nullptr, 16));
      i += 2;
    } else if (s[i] == '+') {
      out += ' ';
    } else {
      out += s[i];
    }
  }
  return out;
}

bool mutating(http::verb v) {
  return v == http::verb::post || v == http::verb::put || v == http::verb::delete_ ||
         v == http::verb::patch;
}

// Reads that carry the daemon's data (everything but the probes and the dashboard's files).
bool protected_read(const std::vector<std::string>& p) {
  return !p.empty() && (p[0] == "api" || p[0] == "metrics");
}

bool constant_time_equal(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  unsigned char d = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    d |= static_cast<unsigned char>(a[i] ^ b[i]);
  }
  return d == 0;
}

// True for PUT /api/v1/jobs/{id}/frames/{frame}/passes/{pass}.
bool is_upload(http::verb v, const std::vector<std::string>& p) {
  return v == http::verb::put && p.size() == 8 && p[0] == "api" && p[1] == "v1" && p[2] == "jobs" &&
         p[4] == "frames" && p[6] == "passes";
}

[[noreturn]] void not_allowed(const char* allow) {
  throw ApiError(405, "method_not_allowed", std::string("allowed: ") + allow);
}

// GET /api/v1/colormaps: how each layer is drawn as a PNG, and the maps' colours for legends.
json colour_maps_json() {
  json maps = json::object();
  for (ColourMap cm : {ColourMap::viridis, ColourMap::magma}) {
    maps[std::string(name(cm))] = colour_stops(cm, 32);
  }
  json layers = json::object();
  for (const char* l :
       {"result", "render", "denoised", "alpha", "variance", "mixvariance", "sure", "error"}) {
    const LayerView v = layer_view(l);
    if (v.colour) {
      layers[l] = {{"kind", "colour"}};
    } else {
      layers[l] = {{"kind", "scalar"}, {"colormap", name(v.map)}, {"scale", name(v.scale)}};
    }
  }
  return {{"colormaps", maps}, {"layers", layers}};
}

}  // namespace

void split_target(std::string_view target, std::vector<std::string>& path,
                  std::map<std::string, std::string>& query) {
  const auto q = target.find('?');
  std::string_view p = target.substr(0, q);
  std::size_t start = 0;
  while (start < p.size()) {
    auto end = p.find('/', start);
    if (end == std::string_view::npos) end = p.size();
    if (end > start) path.push_back(url_decode(p.substr(start, end - start)));
    start = end + 1;
  }
  if (q == std::string_view::npos) return;
  std::string_view qs = target.substr(q + 1);
  start = 0;
  while (start < qs.size()) {
    auto end = qs.find('&', start);
    if (end == std::string_view::npos) end = qs.size();
    const auto kv = qs.substr(start, end - start);
    const auto eq = kv.find('=');
    if (!kv.empty()) {
      query[url_decode(kv.substr(0, eq))] =
          eq == std::string_view::npos ? "" : url_decode(kv.substr(eq + 1));
    }
    start = end + 1;
  }
}

Api::Api(const Config& config, Engine& engine, EventHub& events, Metrics& metrics,
         std::string token)
    : config_(config),
      engine_(engine),
      events_(events),
      metrics_(metrics),
      token_(std::move(token)) {}

Response Api::json_response(int status, const json& body) const {
  Response r{static_cast<http::status>(status), 11};
  r.set(http::field::server, "proden");
  r.set(http::field::content_type, "application/json");
  r.set(http::field::cache_control, "no-store");
  r.body() = body.dump() + "\n";
  return r;
}

Response Api::error(int status, const std::string& code, const std::string& message) {
  metrics_.inc("proden_errors_total", "http_" + std::to_string(status));
  Response r = json_response(status, {{"error", {{"code", code}, {"message", message}}}});
  if (status == 401) r.set(http::field::www_authenticate, "Bearer realm=\"proden\"");
  return r;
}

bool Api::authorized(const http::request_header<>& h) const {
  if (token_.empty()) return true;
  const auto auth = h[http::field::authorization];
  const boost::beast::string_view prefix = "Bearer ";
  if (auth.size() <= prefix.size() || !boost::beast::iequals(auth.substr(0, 7), prefix)) {
    return false;
  }
  return constant_time_equal(std::string_view(auth.data(), auth.size()).substr(7), token_);
}

std::optional<Response> Api::before_body(const http::request_header<>& h, BodyPolicy& policy) {
  std::vector<std::string> path;
  std::map<std::string, std::string> query;
  split_target(std::string_view(h.target().data(), h.target().size()), path, query);
  if ((mutating(h.method()) || (!config_.open_reads && protected_read(path))) && !authorized(h)) {
    return error(401, "unauthorized", "this request needs Authorization: Bearer <token>");
  }
  if (is_upload(h.method(), path)) {
    try {
      engine_.check_upload(path[3], path[5], path[7]);
    } catch (const ApiError& e) {
      return error(e.status(), e.code(), e.what());
    }
    policy.limit = config_.limits.max_upload_bytes;
    policy.timeout_ms = config_.limits.upload_timeout_ms;
  }
  return std::nullopt;
}

Handler::Reply Api::handle(Request& req) {
  std::vector<std::string> path;
  std::map<std::string, std::string> query;
  split_target(std::string_view(req.target().data(), req.target().size()), path, query);
  try {
    return route(req, path, query);
  } catch (const ApiError& e) {
    return {error(e.status(), e.code(), e.what())};
  } catch (const json::exception& e) {
    return {error(400, "invalid_json", e.what())};
  } catch (const std::exception& e) {
    spdlog::error("{} {}: {}", std::string(req.method_string()), std::string(req.target()),
                  e.what());
    return {error(500, "internal", e.what())};
  }
}

Handler::Reply Api::route(Request& req, const std::vector<std::string>& p,
                          const std::map<std::string, std::string>& query) {
  const auto m = req.method();
  const std::size_t n = p.size();
  if (n == 1 && p[0] == "livez") {
    return {json_response(200, {{"status", "ok"}})};
  }
  if (n == 1 && p[0] == "readyz") {
    const bool ok = engine_.ready() && !draining_;
    return {json_response(ok ? 200 : 503, {{"status", ok ? "ready" : "not_ready"}})};
  }
  if (n == 1 && p[0] == "metrics") {
    if (m != http::verb::get) not_allowed("GET");
    metrics_.set("proden_sse_clients", static_cast<double>(events_.clients()));
    Response r{http::status::ok, 11};
    r.set(http::field::content_type, "text/plain; version=0.0.4; charset=utf-8");
    r.body() = metrics_.render();
    return {r};
  }
  if (n == 0 || p[0] != "api") {  // the dashboard's static files
    if (config_.dashboard && (m == http::verb::get || m == http::verb::head)) {
      if (auto r = WebAssets::builtin().serve(req)) return {std::move(*r)};
      if (n == 0) {
        throw ApiError(404, "not_found",
                       "this proden was built without the dashboard (web/: npm ci, then rebuild; "
                       "docs/dashboard.md)");
      }
    }
    throw ApiError(404, "not_found", "no such endpoint");
  }
  if (n < 3 || p[1] != "v1") throw ApiError(404, "not_found", "no such endpoint");
  if (draining_ && m != http::verb::get) {
    throw ApiError(503, "unavailable", "the daemon is shutting down");
  }
  if (n == 3 && p[2] == "events") {
    if (m != http::verb::get) not_allowed("GET");
    Reply r;
    r.sse = true;
    std::string last(req["Last-Event-ID"]);
    if (last.empty() && query.count("last_event_id")) last = query.at("last_event_id");
    if (!last.empty()) {
      try {
        r.last_event_id = std::stoull(last);
      } catch (...) {
        throw ApiError(400, "invalid_parameter", "Last-Event-ID must be an event id");
      }
    }
    return r;
  }
  if (n == 3 && p[2] == "colormaps") {
    if (m != http::verb::get) not_allowed("GET");
    return {json_response(200, colour_maps_json())};
  }
  if (p[2] != "jobs") throw ApiError(404, "not_found", "no such endpoint");
  if (n == 3) {
    if (m == http::verb::get) {
      json list = json::array();
      for (const auto& j : engine_.jobs()) list.push_back(protocol::to_json(j));
      return {json_response(200, {{"jobs", list}})};
    }
    if (m != http::verb::post) not_allowed("GET, POST");
    json body;
    try {
      body = json::parse(req.body());
    } catch (const json::exception& e) {
      throw ApiError(400, "invalid_json", std::string("body is not JSON: ") + e.what());
    }
    auto spec = engine_.create_job(protocol::parse_job_spec(body));
    Response r = json_response(201, protocol::to_json(spec));
    r.set(http::field::location, "/api/v1/jobs/" + spec.id);
    return {r};
  }
  const std::string& id = p[3];
  if (n == 4) {
    if (m == http::verb::get) return {json_response(200, protocol::to_json(engine_.job(id)))};
    if (m != http::verb::delete_) not_allowed("GET, DELETE");
    engine_.delete_job(id);
    Response r{http::status::no_content, 11};
    return {r};
  }
  if (n == 5 && p[4] == "history") {
    if (m != http::verb::get) not_allowed("GET");
    return {json_response(200, {{"job", id}, {"frames", engine_.job_history(id)}})};
  }
  if (n == 5 && p[4] == "quarantine") {
    if (m != http::verb::get) not_allowed("GET");
    return {json_response(200, {{"job", id}, {"quarantined", engine_.quarantined(id)}})};
  }
  if (n == 5 && (p[4] == "pause" || p[4] == "resume")) {
    if (m != http::verb::post) not_allowed("POST");
    return {json_response(200, protocol::to_json(engine_.set_paused(id, p[4] == "pause")))};
  }
  if (p[4] != "frames") throw ApiError(404, "not_found", "no such endpoint");
  if (n == 5) {
    if (m != http::verb::get) not_allowed("GET");
    json list = json::array();
    for (const auto& f : engine_.frames(id)) list.push_back(protocol::to_json(f, false));
    return {json_response(200, {{"job", id}, {"frames", list}})};
  }
  const std::string& frame_s = p[5];
  if (frame_s.empty() || frame_s.size() > 9 ||
      !std::all_of(frame_s.begin(), frame_s.end(), ::isdigit)) {
    throw ApiError(400, "invalid_frame", "frame must be a non-negative integer");
  }
  const long frame = std::stol(frame_s);
  if (n == 6) {
    if (m != http::verb::get) not_allowed("GET");
    return {json_response(200, protocol::to_json(engine_.frame(id, frame), true))};
  }
  if (n == 7 && p[6] == "history") {
    if (m != http::verb::get) not_allowed("GET");
    return {json_response(
        200, {{"job", id}, {"frame", frame}, {"versions", engine_.history(id, frame)}})};
  }
  if (n == 7 && p[6] == "image") {
    if (m != http::verb::get) not_allowed("GET");
    std::optional<std::uint64_t> version;
    if (query.count("version")) {
      const std::string& v = query.at("version");
      if (v.empty() || v.size() > 18 || !std::all_of(v.begin(), v.end(), ::isdigit) ||
          std::stoull(v) == 0) {
        throw ApiError(400, "invalid_parameter", "version must be a positive integer");
      }
      version = std::stoull(v);
    }
    const auto img = engine_.image(id, frame, PreviewCache::Request::from_query(query), version);
    Response r{http::status::ok, 11};
    r.set(http::field::cache_control, "no-cache");
    r.set(http::field::etag, img.etag);
    r.set("X-Proden-Version", std::to_string(img.version));
    for (const auto& [k, v] : img.headers) r.set(k, v);
    const auto inm = req[http::field::if_none_match];
    if (!inm.empty() && std::string_view(inm.data(), inm.size()) == img.etag) {
      r.result(http::status::not_modified);
      return {r};
    }
    auto bytes = read_file(img.path);
    if (!bytes) throw ApiError(404, "not_found", "published image is not readable");
    r.set(http::field::content_type, img.content_type);
    r.body().assign(reinterpret_cast<const char*>(bytes->data()), bytes->size());
    return {r};
  }
  if (n == 8 && p[6] == "passes") {
    if (m != http::verb::put) not_allowed("PUT");
    return {json_response(202, engine_.upload(id, frame_s, p[7], req.body()))};
  }
  throw ApiError(404, "not_found", "no such endpoint");
}

}  // namespace proden::daemon

#include "daemon/api.hpp"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <utility>

#include "daemon/colour_map.hpp"
#include "daemon/files.hpp"
#include "daemon/pass_pattern.hpp"
#include "daemon/web_assets.hpp"
#include "proden/io/text.hpp"
#include "proden/progressive.hpp"

namespace proden::daemon {

using nlohmann::json;
using protocol::ApiError;

namespace {

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

bool is_health(const std::vector<std::string>& p) {
  return p.size() == 1 && (p[0] == "livez" || p[0] == "readyz" || p[0] == "metrics");
}

[[noreturn]] void not_allowed(const char* allow) {
  throw ApiError(405, "method_not_allowed", std::string("allowed: ") + allow);
}

// Removes a spooled upload when the request ends without handing it on.
struct SpoolGuard {
  const std::filesystem::path& path;
  ~SpoolGuard() {
    if (!path.empty()) ::unlink(path.c_str());
  }
};

// GET /api/v1/colormaps: how each layer is drawn as a PNG, and the maps' colours for legends.
json colour_maps_json() {
  json maps = json::object();
  for (ColourMap cm : {ColourMap::viridis, ColourMap::magma}) {
    maps[std::string(name(cm))] = colour_stops(cm, 32);
  }
  json layers = json::object();
  std::vector<std::string> names(layer_names().begin(), layer_names().end());
  names.emplace_back("error");  // drawn from the layers (PreviewCache), not written itself
  for (const std::string& l : names) {
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

Api::Api(const Config& config, Engine& engine, const Roots& roots, EventHub& events,
         Metrics& metrics, std::string token)
    : config_(config),
      engine_(engine),
      roots_(roots),
      events_(events),
      metrics_(metrics),
      token_(std::move(token)) {}

Response Api::json_response(int status, const json& body) const {
  Response r{static_cast<http::status>(status), 11};
  r.set(http::field::server, "proden");
  r.set(http::field::content_type, "application/json");
  r.set(http::field::cache_control, "no-store");
  // Strings in replies are UTF-8 by construction (checked on the way in, io::printable from
  // files); `replace` keeps a missed byte from ever turning a reply into an exception.
  r.body() = body.dump(-1, ' ', false, json::error_handler_t::replace) + "\n";
  return r;
}

Response Api::error(int status, const std::string& code, const std::string& message) {
  metrics_.inc("proden_errors_total", "http_" + std::to_string(status));
  Response r =
      json_response(status, {{"error", {{"code", code}, {"message", io::printable(message)}}}});
  if (status == 401) r.set(http::field::www_authenticate, "Bearer realm=\"proden\"");
  return r;
}

bool Api::authorized(const http::request_header<>& h) const {
  if (token_.empty()) return true;
  const auto auth = h[http::field::authorization];
  const auto token = bearer_token(std::string_view(auth.data(), auth.size()));
  return token && constant_time_equal(*token, token_);
}

std::optional<Response> Api::before_body(const http::request_header<>& h, BodyPolicy& policy) {
  std::string why;
  const auto target = parse_target(std::string_view(h.target().data(), h.target().size()), why);
  if (!target) return error(400, "bad_request", why);
  const bool auth = authorized(h);
  if ((mutating(h.method()) || (!config_.open_reads && protected_read(target->path))) && !auth) {
    return error(401, "unauthorized", "this request needs Authorization: Bearer <token>");
  }
  policy.inline_ok = is_health(target->path) && h.method() == http::verb::get;
  policy.reserve_ok = is_health(target->path) || (!token_.empty() && auth);
  if (is_upload(h.method(), target->path)) {
    const auto& p = target->path;
    try {
      // Streamed to a new hidden file in the job's upload area (the file system of its final
      // place; a restart removes leftovers), never into memory.
      policy.spool = engine_.upload_spool(p[3], p[5], p[7]);
    } catch (const ApiError& e) {
      return error(e.status(), e.code(), e.what());
    }
    policy.limit = config_.limits.max_upload_bytes;
    policy.timeout_ms = config_.limits.upload_timeout_ms;
  }
  return std::nullopt;
}

Handler::Reply Api::handle(Incoming& in) {
  SpoolGuard spool{in.body_file};
  Request& req = in.request;
  std::string why;
  const auto target = parse_target(std::string_view(req.target().data(), req.target().size()), why);
  if (!target) return {error(400, "bad_request", why)};
  try {
    return route(in, target->path, target->query);
  } catch (const ApiError& e) {
    return {error(e.status(), e.code(), e.what())};
  } catch (const json::exception& e) {
    return {error(400, "invalid_json", e.what())};
  } catch (const std::exception& e) {
    spdlog::error("{} {}: {}", std::string(req.method_string()),
                  io::printable(std::string(req.target())), io::printable(e.what()));
    return {error(500, "internal", e.what())};
  }
}

Handler::Reply Api::upload(Incoming& in, const std::vector<std::string>& p) {
  const std::filesystem::path spooled = std::exchange(in.body_file, {});  // the engine owns it
  const auto answer = engine_.upload_spooled(p[3], p[5], p[7], spooled);
  return {json_response(answer.value("status", "") == "ingested" ? 200 : 202, answer)};
}

Handler::Reply Api::image(const Request& req, const std::string& id, long frame,
                          const std::map<std::string, std::string>& query) {
  std::optional<std::uint64_t> version;  // ?version=K: an older version kept (docs/api.md)
  if (query.count("version")) {
    const std::string& v = query.at("version");
    if (v.empty() || v.size() > 18 || !std::all_of(v.begin(), v.end(), ::isdigit) ||
        std::stoull(v) == 0) {
      throw ApiError(400, "invalid_parameter", "version must be a positive integer");
    }
    version = std::stoull(v);
  }
  const auto img = engine_.image(id, frame, PreviewCache::Request::from_query(query), version);
  Reply r;
  r.response = Response{http::status::ok, 11};
  r.response.set(http::field::server, "proden");
  r.response.set(http::field::cache_control, "no-cache");
  r.response.set(http::field::etag, img.etag);
  r.response.set("X-Proden-Version", std::to_string(img.version));
  for (const auto& [k, v] : img.headers) r.response.set(k, v);
  const auto inm = req[http::field::if_none_match];
  if (!inm.empty() && std::string_view(inm.data(), inm.size()) == img.etag) {
    r.response.result(http::status::not_modified);
    return r;
  }
  // Published outputs live in an allowed root (opened beneath it); renditions in the state dir.
  UniqueFd fd;
  if (img.path.string().starts_with(config_.state_dir + "/")) {
    fd = UniqueFd(open_regular_nofollow(img.path));
  } else {
    FileError err = FileError::none;
    std::string why;
    fd = roots_.open(img.path, O_RDONLY | O_NONBLOCK | O_NOCTTY, err, why);
    if (err == FileError::escape) {
      spdlog::warn("image {}: {}", img.path.string(), why);
      throw ApiError(403, "path_forbidden", "the published image is no longer inside the roots");
    }
  }
  struct stat st {};
  if (!fd || ::fstat(fd.get(), &st) != 0 || !S_ISREG(st.st_mode)) {
    throw ApiError(404, "not_found", "published image is not readable");
  }
  r.response.set(http::field::content_type, img.content_type);
  r.file = std::move(fd);
  return r;
}

Handler::Reply Api::route(Incoming& in, const std::vector<std::string>& p,
                          const std::map<std::string, std::string>& query) {
  Request& req = in.request;
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
    const auto header = req["Last-Event-ID"];
    std::string last(header.data(), header.size());
    if (last.empty() && query.count("last_event_id")) last = query.at("last_event_id");
    if (!last.empty()) {
      r.last_event_id = parse_event_id(last);
      if (!r.last_event_id) {
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
    if (const auto bad = io::invalid_utf8_offset(req.body()); bad != std::string::npos) {
      throw ApiError(400, "invalid_json",
                     "body is not UTF-8 (byte " + std::to_string(bad) + " of the body)");
    }
    json body;
    try {
      body = json::parse(req.body());
    } catch (const json::exception& e) {
      throw ApiError(400, "invalid_json", std::string("body is not JSON: ") + e.what());
    }
    auto spec = protocol::parse_job_spec(body);
    if (spec.watch) {
      std::string why;
      if (!PassPattern::parse(spec.watch->pattern, why)) {
        throw ApiError(400, "invalid_field", "watch.pattern: " + why);
      }
    }
    spec = engine_.create_job(std::move(spec));
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
  const auto frame_no = parse_frame_number(p[5]);
  if (!frame_no) throw ApiError(400, "invalid_frame", "frame must be a non-negative integer");
  const long frame = *frame_no;
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
    return image(req, id, frame, query);
  }
  if (n == 8 && p[6] == "passes") {
    if (m != http::verb::put) not_allowed("PUT");
    if (in.body_file.empty()) throw ApiError(400, "invalid_pass", "empty body");
    return upload(in, p);
  }
  throw ApiError(404, "not_found", "no such endpoint");
}

}  // namespace proden::daemon

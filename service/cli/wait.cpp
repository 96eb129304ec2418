#include "cli/wait.hpp"

#include <spdlog/spdlog.h>

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <optional>
#include <regex>
#include <stdexcept>
#include <thread>

#include <nlohmann/json.hpp>

#include "cli/commands.hpp"

namespace proden::cli {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
namespace asio = boost::asio;
using tcp = asio::ip::tcp;
using nlohmann::json;
using Clock = std::chrono::steady_clock;

// The daemon answered with an error status.
struct HttpError : std::runtime_error {
  HttpError(int s, std::string c, const std::string& m)
      : std::runtime_error(m), status(s), code(std::move(c)) {}
  int status;
  std::string code;
};

struct Target {
  std::string host, port, prefix;
};

std::optional<Target> parse_url(const std::string& url) {
  static const std::regex re(R"(http://([^/:]+)(?::(\d+))?(/.*)?)");
  std::smatch m;
  if (!std::regex_match(url, m, re)) return std::nullopt;
  Target t{m[1], m[2].matched ? std::string(m[2]) : "80", m[3].matched ? std::string(m[3]) : ""};
  while (!t.prefix.empty() && t.prefix.back() == '/') t.prefix.pop_back();
  return t;
}

class Client {
 public:
  Client(Target t, std::string token) : t_(std::move(t)), token_(std::move(token)) {}

  // GET -> parsed JSON body; throws HttpError on a status >= 400, beast::system_error when
  // unreachable.
  json get(const std::string& path, std::chrono::milliseconds timeout) {
    beast::tcp_stream s(ioc_);
    connect(s, timeout);
    http::request<http::empty_body> req{http::verb::get, t_.prefix + path, 11};
    headers(req);
    s.expires_after(timeout);
    check(run([&](auto done) { http::async_write(s, req, done); }));
    beast::flat_buffer buf;
    http::response<http::string_body> res;
    check(run([&](auto done) { http::async_read(s, buf, res, done); }));
    beast::error_code ec;
    s.socket().shutdown(tcp::socket::shutdown_both, ec);
    json body = json::parse(res.body(), nullptr, false);
    if (res.result_int() >= 400) {
      std::string code = "http_" + std::to_string(res.result_int()), msg = res.body();
      if (body.is_object() && body.contains("error")) {
        code = body["error"].value("code", code);
        msg = body["error"].value("message", msg);
      }
      throw HttpError(static_cast<int>(res.result_int()), code, msg);
    }
    if (body.is_discarded()) throw std::runtime_error("the daemon answered something not JSON");
    return body;
  }

  // Reads events from GET /api/v1/events (after `last_id`) until `stop(type, data)` returns
  // true or `timeout` passes without a complete event; returns false on timeout. Updates last_id.
  template <class Stop>
  bool follow(std::optional<std::uint64_t>& last_id, std::chrono::milliseconds timeout, Stop stop) {
    beast::tcp_stream s(ioc_);
    connect(s, timeout);
    http::request<http::empty_body> req{http::verb::get, t_.prefix + "/api/v1/events", 11};
    headers(req);
    req.set(http::field::accept, "text/event-stream");
    if (last_id) req.set("Last-Event-ID", std::to_string(*last_id));
    s.expires_after(timeout);
    check(run([&](auto done) { http::async_write(s, req, done); }));
    beast::flat_buffer buf;
    http::response_parser<http::buffer_body> p;
    p.body_limit(boost::none);
    const auto ec0 = run([&](auto done) { http::async_read_header(s, buf, p, done); });
    if (ec0 == beast::error::timeout) return false;
    check(ec0);
    if (p.get().result_int() != 200) {
      throw HttpError(static_cast<int>(p.get().result_int()), "events", "event stream refused");
    }
    std::string pending;
    char chunk[8192];
    const auto until = Clock::now() + timeout;
    while (!p.is_done()) {
      // Rounded up like the wait's own time left: the stream ends at or after `until`, which is
      // at or after the wait's deadline, never a fraction of a millisecond before it.
      const auto left = std::chrono::ceil<std::chrono::milliseconds>(until - Clock::now());
      if (left.count() <= 0) return false;
      p.get().body().data = chunk;
      p.get().body().size = sizeof chunk;
      s.expires_after(left);
      beast::error_code ec = run([&](auto done) { http::async_read_some(s, buf, p, done); });
      if (ec == beast::error::timeout) return false;
      if (ec && ec != http::error::need_buffer) throw beast::system_error(ec);
      pending.append(chunk, sizeof chunk - p.get().body().size);
      for (auto end = pending.find("\n\n"); end != std::string::npos; end = pending.find("\n\n")) {
        const std::string block = pending.substr(0, end);
        pending.erase(0, end + 2);
        std::string type, data;
        std::size_t start = 0;
        while (start <= block.size()) {
          const auto nl = std::min(block.find('\n', start), block.size());
          const std::string line = block.substr(start, nl - start);
          start = nl + 1;
          if (line.rfind("id: ", 0) == 0) {
            try {
              last_id = std::stoull(line.substr(4));
            } catch (const std::exception&) {
            }
          } else if (line.rfind("event: ", 0) == 0) {
            type = line.substr(7);
          } else if (line.rfind("data: ", 0) == 0) {
            data += line.substr(6);
          }
        }
        if (type.empty()) continue;
        const json d = json::parse(data, nullptr, false);
        if (stop(type, d)) return true;
      }
    }
    return false;  // the daemon closed the stream: the caller reconnects
  }

 private:
  // Runs one asynchronous operation to completion (the stream's expiry bounds it: beast's
  // timeouts apply to asynchronous operations only) and returns its error code.
  template <class Initiate>
  beast::error_code run(Initiate initiate) {
    beast::error_code result;
    initiate([&result](beast::error_code ec, auto&&...) { result = ec; });
    ioc_.restart();
    ioc_.run();
    return result;
  }
  static void check(const beast::error_code& ec) {
    if (ec) throw beast::system_error(ec);
  }
  void connect(beast::tcp_stream& s, std::chrono::milliseconds timeout) {
    tcp::resolver r(ioc_);
    const auto endpoints = r.resolve(t_.host, t_.port);
    s.expires_after(timeout);
    check(run([&](auto done) { s.async_connect(endpoints, done); }));
  }
  template <class Req>
  void headers(Req& req) {
    req.set(http::field::host, t_.host);
    req.set(http::field::user_agent, "proden-wait");
    if (!token_.empty()) req.set(http::field::authorization, "Bearer " + token_);
  }
  Target t_;
  std::string token_;
  asio::io_context ioc_;
};

bool holds(const json& frame, bool converged, std::uint64_t k) {
  if (frame.is_null()) return false;
  if (converged) return frame.value("converged", false);
  return frame.value("version", std::uint64_t{0}) > k;
}

void print(const WaitOptions& o, const json& frame) {
  if (o.quiet) return;
  if (o.json) {
    std::cout << frame.dump(2) << "\n";
    return;
  }
  if (frame.is_null()) {
    std::printf("frame %ld of job %s: no pass yet\n", o.frame, o.job.c_str());
    return;
  }
  const json& e = frame.value("estimated_error", json::object());
  std::printf("frame %ld of job %s: version %llu, %d pass(es), %g spp, converged %s", o.frame,
              o.job.c_str(),
              static_cast<unsigned long long>(frame.value("version", std::uint64_t{0})),
              frame.value("passes", 0), frame.value("spp", 0.0),
              frame.value("converged", false) ? "yes" : "no");
  if (e.contains("relmse") && e["relmse"].is_number()) {
    std::printf(", relMSE %.4g", e["relmse"].get<double>());
  }
  if (e.contains("equivalent_spp") && e["equivalent_spp"].is_number()) {
    std::printf(", equivalent spp %.4g", e["equivalent_spp"].get<double>());
  }
  std::printf("\n");
}

}  // namespace

int run_wait(const WaitOptions& in) {
  WaitOptions o = in;
  if (o.url.empty()) {
    const char* env = std::getenv("PRODEN_URL");
    o.url = env && *env ? env : "http://127.0.0.1:8080";
  }
  const auto target = parse_url(o.url);
  if (!target) {
    spdlog::error(
        "--url: {} is not http://host[:port] (proden speaks plain HTTP; put a TLS proxy "
        "in front)",
        o.url);
    return kUsage;
  }
  bool converged = o.until == "converged";
  std::uint64_t k = 0;
  if (!converged) {
    static const std::regex re(R"(version>(\d{1,18}))");
    std::smatch m;
    if (!std::regex_match(o.until, m, re)) {
      spdlog::error("--until: '{}' is neither 'converged' nor 'version>K'", o.until);
      return kUsage;
    }
    k = std::stoull(m[1]);
  }
  std::string token;
  if (!o.token_file.empty()) {
    std::ifstream f(o.token_file);
    if (!f) {
      spdlog::error("--token-file: cannot read {}", o.token_file);
      return kUsage;
    }
    std::getline(f, token);
    while (!token.empty() && std::isspace(static_cast<unsigned char>(token.back()))) {
      token.pop_back();
    }
  }
  const bool forever = !(o.timeout > 0);
  const auto deadline =
      Clock::now() + std::chrono::milliseconds(static_cast<long long>(o.timeout * 1000.0));
  // Rounded up: an operation that expires with the wait ends at or after the deadline, so its
  // timeout reads as the wait's own (expired() holds), never as a failing daemon.
  auto left = [&] {
    if (forever) return std::chrono::milliseconds(30000);
    return std::max(
        std::chrono::milliseconds(1),
        std::min(std::chrono::milliseconds(30000),
                 std::chrono::ceil<std::chrono::milliseconds>(deadline - Clock::now())));
  };
  auto expired = [&] { return !forever && Clock::now() >= deadline; };

  Client c(*target, token);
  const std::string frame_path = "/api/v1/jobs/" + o.job + "/frames/" + std::to_string(o.frame);
  json last = nullptr;
  std::optional<std::uint64_t> last_id;
  bool reached_once = false, failing = false;
  std::chrono::milliseconds backoff(200);
  for (;;) {
    bool following = false;  // the events stream was being read (its read ends at the deadline)
    bool ended = false;      // the daemon closed the events stream before the deadline
    try {
      try {
        last = c.get(frame_path, left());
      } catch (const HttpError& e) {
        if (e.status != 404) throw;
        if (e.what() == std::string("no job ") + o.job) {
          spdlog::error("job {} does not exist on {}", o.job, o.url);
          return kWaitNoJob;
        }
        last = nullptr;  // the frame has no pass yet: wait for it
      }
      reached_once = true;
      failing = false;
      backoff = std::chrono::milliseconds(200);
      if (holds(last, converged, k)) {
        print(o, last);
        return kOk;
      }
      if (expired()) break;
      bool deleted = false;
      following = true;
      ended = !c.follow(last_id, left(), [&](const std::string& type, const json& d) {
        if (!d.is_object() || d.value("job", "") != o.job) return false;
        if (type == "job" && d.value("state", "") == "deleted") {
          deleted = true;
          return true;
        }
        return d.contains("frame") && d["frame"].is_number() && d["frame"].get<long>() == o.frame;
      });
      if (deleted) {
        spdlog::error("job {} was deleted", o.job);
        return kWaitNoJob;
      }
    } catch (const HttpError& e) {
      spdlog::warn("{}: {} {}", o.url, e.status, e.what());
      failing = true;
    } catch (const std::exception& e) {  // unreachable, reset, malformed: retry until the end
      spdlog::debug("{}: {}", o.url, e.what());
      // An operation cut by the wait's own deadline is the wait timing out, not a failing
      // daemon: the events read, or a request to a daemon that has answered in this wait (it
      // may have got only the last millisecond). A daemon never reached stays unreachable.
      const auto* se = dynamic_cast<const beast::system_error*>(&e);
      const bool cut = se && se->code() == beast::error::timeout;
      if (expired() && (following || (cut && reached_once))) break;
      failing = true;
    }
    if (expired()) break;
    if (failing) {
      std::this_thread::sleep_for(std::min(backoff, left()));
      backoff = std::min(backoff * 2, std::chrono::milliseconds(5000));
    } else if (ended) {
      // The daemon ended the event stream (a drain, a slow-reader cut): reconnect after a pause,
      // not in a tight loop against a daemon that keeps closing it.
      std::this_thread::sleep_for(std::min(std::chrono::milliseconds(200), left()));
    }
  }
  if (failing) {
    spdlog::error("{} could not be reached (or kept failing){}", o.url,
                  reached_once ? " at the end of the wait" : "");
    return kWaitUnreachable;
  }
  spdlog::error("timed out after {} s waiting for frame {} of job {} to be {}", o.timeout, o.frame,
                o.job, o.until);
  print(o, last);
  return kWaitTimeout;
}

}  // namespace proden::cli

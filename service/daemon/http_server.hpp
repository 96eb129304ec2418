// HttpServer: Boost.Beast HTTP/1.1 server (patterned on Beast's advanced server): an acceptor,
// one session per connection with a time limit before every read and write, header and body
// limits, keep-alive, and Server-Sent Events streams fed by the EventHub. Routing and API logic
// live in the Handler (api.hpp); this file only moves bytes safely:
// - the I/O threads never run handlers that decode, encode or touch large files: those run on a
//   small handler pool, so /livez answers while uploads are validated (issue 11, class 5);
// - upload bodies are streamed to a spool file, never held in memory; files are served with
//   file_body from a descriptor the handler opened;
// - event streams have their own limit and a per-client cap, and the last connections are kept
//   for health checks and authenticated requests (class 7).
#pragma once

#include <atomic>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/thread_pool.hpp>
#include <boost/beast/http.hpp>

#include "daemon/config.hpp"
#include "daemon/events.hpp"
#include "daemon/files.hpp"
#include "daemon/metrics.hpp"

namespace proden::daemon {

namespace http = boost::beast::http;
using Request = http::request<http::string_body>;
using Response = http::response<http::string_body>;

// What the server needs from the application.
class Handler {
 public:
  virtual ~Handler() = default;
  struct BodyPolicy {
    std::size_t limit = 0;
    int timeout_ms = 0;
    // Non-empty: stream the body into this new file (created O_EXCL) instead of memory; the
    // handler then owns the file (Incoming::body_file) and must move or remove it.
    std::filesystem::path spool;
    bool inline_ok = false;   // cheap and bounded (health probes): answer on the I/O thread
    bool reserve_ok = false;  // may use the reserved connections (health, authenticated)
  };
  // Called once the headers are in: may refuse early (auth, 404, size) by returning a response,
  // otherwise sets how large and how slow the body may be and where it goes.
  virtual std::optional<Response> before_body(const http::request_header<>& header,
                                              BodyPolicy& policy) = 0;
  struct Incoming {
    Request request;                  // the body is empty when it was spooled
    std::filesystem::path body_file;  // the spooled body, if any
    std::uint64_t body_bytes = 0;
  };
  struct Reply {
    Reply() = default;
    Reply(Response r) : response(std::move(r)) {}  // NOLINT: implicit on purpose
    Response response;
    bool sse = false;  // start an event stream instead (response ignored)
    std::optional<std::uint64_t> last_event_id;
    // A file to send as the body (response's status and headers are used, its body is not).
    UniqueFd file;
  };
  // Runs on the handler pool (or the I/O thread when the policy said inline_ok).
  virtual Reply handle(Incoming& request) = 0;
  // Must not throw.
  virtual Response error(int status, const std::string& code, const std::string& message) = 0;
};

class HttpServer {
 public:
  HttpServer(const Config& config, Handler& handler, EventHub& events, Metrics& metrics);
  ~HttpServer();
  // Binds and listens (throws on failure); returns the bound port.
  unsigned short listen(const std::string& address, unsigned short port);
  void run(int threads);  // starts the I/O threads and the handler pool
  void stop();            // stops accepting, closes connections, joins the threads
  boost::asio::io_context& context() { return ioc_; }

  class Session;

 private:
  void accept();
  friend class Session;
  void track(const std::shared_ptr<Session>& s);
  void untrack(Session* s);
  // Admits an event stream from `peer`: 0 = yes, else the HTTP status refusing it (503 when all
  // stream slots are taken, 429 when this client holds its share).
  int admit_stream(const std::string& peer);
  void release_stream(const std::string& peer);

  Config config_;
  Handler& handler_;
  EventHub& events_;
  Metrics& metrics_;
  boost::asio::io_context ioc_;
  boost::asio::ip::tcp::acceptor acceptor_;
  std::unique_ptr<boost::asio::thread_pool> pool_;
  std::vector<std::thread> threads_;
  std::mutex mu_;
  std::set<std::weak_ptr<Session>, std::owner_less<std::weak_ptr<Session>>> sessions_;
  int streams_ = 0;                          // mu_
  std::map<std::string, int> peer_streams_;  // mu_
  std::atomic<int> connections_{0};
  std::atomic<bool> stopped_{false};
};

}  // namespace proden::daemon

// HttpServer: Boost.Beast HTTP/1.1 server (patterned on Beast's advanced server): an acceptor,
// one session per connection with a time limit before every read and write, header and body
// limits, keep-alive, and Server-Sent Events streams fed by the EventHub. Routing and API logic
// live in the Handler (api.hpp); this file only moves bytes safely.
#pragma once

#include <atomic>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/http.hpp>

#include "daemon/config.hpp"
#include "daemon/events.hpp"
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
  };
  // Called once the headers are in: may refuse early (auth, 404, size) by returning a response,
  // otherwise sets how large and how slow the body may be.
  virtual std::optional<Response> before_body(const http::request_header<>& header,
                                              BodyPolicy& policy) = 0;
  struct Reply {
    Reply() = default;
    Reply(Response r) : response(std::move(r)) {}  // NOLINT: implicit on purpose
    Response response;
    bool sse = false;  // start an event stream instead (response ignored)
    std::optional<std::uint64_t> last_event_id;
  };
  virtual Reply handle(Request& request) = 0;
  virtual Response error(int status, const std::string& code, const std::string& message) = 0;
};

class HttpServer {
 public:
  HttpServer(const Config& config, Handler& handler, EventHub& events, Metrics& metrics);
  ~HttpServer();
  // Binds and listens (throws on failure); returns the bound port.
  unsigned short listen(const std::string& address, unsigned short port);
  void run(int threads);  // starts the I/O threads
  void stop();            // stops accepting, closes connections, joins the threads
  boost::asio::io_context& context() { return ioc_; }

  class Session;
  class SseSession;

 private:
  void accept();
  friend class Session;
  friend class SseSession;
  void track(const std::shared_ptr<Session>& s);
  void untrack(Session* s);

  Config config_;
  Handler& handler_;
  EventHub& events_;
  Metrics& metrics_;
  boost::asio::io_context ioc_;
  boost::asio::ip::tcp::acceptor acceptor_;
  std::vector<std::thread> threads_;
  std::mutex mu_;
  std::set<std::weak_ptr<Session>, std::owner_less<std::weak_ptr<Session>>> sessions_;
  std::atomic<int> connections_{0};
  std::atomic<bool> stopped_{false};
};

}  // namespace proden::daemon

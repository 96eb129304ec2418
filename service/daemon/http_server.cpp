#include "daemon/http_server.hpp"

#include <fcntl.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <boost/asio/dispatch.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <boost/asio/write.hpp>
#include <boost/beast/core.hpp>
#include <chrono>
#include <deque>

namespace proden::daemon {

namespace beast = boost::beast;
namespace net = boost::asio;
using tcp = net::ip::tcp;
using std::chrono::milliseconds;

namespace {

// A reserved connection (see Limits::reserved_connections) waits at most this long for its one
// request, so holding reserve slots open costs an attacker a new connection every few seconds.
constexpr int kReservedTimeoutMs = 5000;

std::string peer_of(const tcp::socket& s) {
  beast::error_code ec;
  auto a = s.remote_endpoint(ec).address();
  if (ec) return "?";
  if (a.is_v6() && a.to_v6().is_v4_mapped()) a = a.to_v6().to_v4();
  return a.to_string();
}

}  // namespace

class HttpServer::Session : public std::enable_shared_from_this<Session>, public EventSink {
 public:
  Session(tcp::socket&& socket, HttpServer& server, bool reserved)
      : stream_(std::move(socket)),
        server_(server),
        cfg_(server.config_.limits),
        peer_(peer_of(stream_.socket())),
        reserved_(reserved) {
    server_.metrics_.set("proden_http_connections", ++server_.connections_);
  }
  ~Session() override {
    discard_spool();
    server_.metrics_.set("proden_http_connections", --server_.connections_);
  }

  void start() {
    net::dispatch(stream_.get_executor(), [self = shared_from_this()] { self->read_header(); });
  }

  void close() {
    net::post(stream_.get_executor(), [self = shared_from_this()] { self->do_close(); });
  }

  void deliver(std::shared_ptr<const std::string> wire) override {
    net::post(stream_.get_executor(), [self = shared_from_this(), wire = std::move(wire)] {
      if (self->closed_) return;
      if (self->queue_.size() >= self->cfg_.sse_queue_limit) {
        spdlog::warn("SSE client too slow ({} events queued); disconnecting", self->queue_.size());
        self->do_close();
        return;
      }
      self->queue_.push_back(wire);
      if (!self->writing_) self->write_next();
    });
  }

 private:
  int header_timeout_ms() const {
    const int t = first_ ? cfg_.request_timeout_ms : cfg_.idle_timeout_ms;
    return reserved_ ? std::min(t, kReservedTimeoutMs) : t;
  }

  void read_header() {
    if (closed_) return;
    header_parser_.emplace();
    header_parser_->header_limit(static_cast<std::uint32_t>(cfg_.max_header_bytes));
    // The parser checks Content-Length against this as the header arrives; the route's own
    // limit is applied once the handler has seen the header.
    header_parser_->body_limit(std::max(cfg_.max_body_bytes, cfg_.max_upload_bytes));
    stream_.expires_after(milliseconds(header_timeout_ms()));
    http::async_read_header(stream_, buffer_, *header_parser_,
                            beast::bind_front_handler(&Session::on_header, shared_from_this()));
  }

  void on_header(beast::error_code ec, std::size_t) {
    if (ec) return read_failed(ec);
    policy_ = Handler::BodyPolicy{cfg_.max_body_bytes, cfg_.request_timeout_ms, {}, false, false};
    std::optional<Response> early;
    try {
      early = server_.handler_.before_body(header_parser_->get().base(), policy_);
    } catch (const std::exception& e) {
      early = server_.handler_.error(500, "internal", e.what());
    }
    if (early) return write(std::move(*early), true);
    if (reserved_ && !policy_.reserve_ok) {
      server_.metrics_.inc("proden_errors_total", "connection_limit");
      return write(server_.handler_.error(503, "unavailable",
                                          "connection limit reached: only health checks and "
                                          "authenticated requests are served"),
                   true);
    }
    const auto length = header_parser_->content_length();
    if (length && *length > policy_.limit) {
      return write(server_.handler_.error(413, "payload_too_large",
                                          "body of " + std::to_string(*length) +
                                              " bytes exceeds the limit of " +
                                              std::to_string(policy_.limit)),
                   true);
    }
    if (!policy_.spool.empty()) {
      file_parser_.emplace(std::move(*header_parser_));
      file_parser_->body_limit(policy_.limit);
      // The spool file: new (O_EXCL), never through a symlink, private until it is checked.
      const int fd =
          ::open(policy_.spool.c_str(), O_RDWR | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0600);
      if (fd < 0) {
        return write(
            server_.handler_.error(500, "internal",
                                   "cannot store the upload: " + std::string(std::strerror(errno))),
            true);
      }
      spool_ = policy_.spool;
      beast::file f;
      f.native_handle(fd);
      beast::error_code fe;
      file_parser_->get().body().reset(std::move(f), fe);
      // Beast reads max(512, free capacity) bytes per read; the header left ~1 KiB, so a spooled
      // body would arrive in ~1 KiB reads (48 MB/s on loopback). 64 KiB, Beast's per-read cap,
      // for this body only: released again once it is on disk.
      buffer_.reserve(kBodyReadBytes);
    } else {
      string_parser_.emplace(std::move(*header_parser_));
      string_parser_->body_limit(policy_.limit);
    }
    header_parser_.reset();
    if (is_done()) return on_body({}, 0);
    stream_.expires_after(milliseconds(policy_.timeout_ms));
    const auto expect = file_parser_ ? file_parser_->get()[http::field::expect]
                                     : string_parser_->get()[http::field::expect];
    if (beast::iequals(expect, "100-continue")) {
      static const std::string cont = "HTTP/1.1 100 Continue\r\n\r\n";
      net::async_write(stream_, net::buffer(cont),
                       [self = shared_from_this()](beast::error_code e, std::size_t) {
                         if (e) return self->do_close();
                         self->read_body();
                       });
      return;
    }
    read_body();
  }

  bool is_done() const {
    return file_parser_ ? file_parser_->is_done() : string_parser_->is_done();
  }

  void read_body() {
    if (file_parser_) {
      http::async_read(stream_, buffer_, *file_parser_,
                       beast::bind_front_handler(&Session::on_body, shared_from_this()));
    } else {
      http::async_read(stream_, buffer_, *string_parser_,
                       beast::bind_front_handler(&Session::on_body, shared_from_this()));
    }
  }

  void read_failed(beast::error_code ec) {
    discard_spool();
    if (ec == http::error::header_limit) {
      return write(server_.handler_.error(431, "headers_too_large", "request headers too large"),
                   true);
    }
    if (ec == http::error::body_limit) {
      return write(server_.handler_.error(413, "payload_too_large", "request body too large"),
                   true);
    }
    if (ec.category() == http::make_error_code(http::error::bad_target).category() &&
        ec != http::error::end_of_stream && ec != http::error::partial_message) {
      return write(server_.handler_.error(400, "bad_request", "malformed HTTP: " + ec.message()),
                   true);
    }
    do_close();  // end of stream, time limit (the stream is already closed), reset
  }

  void on_body(beast::error_code ec, std::size_t) {
    if (ec) return read_failed(ec);
    auto in = std::make_shared<Handler::Incoming>();
    if (file_parser_) {
      auto msg = file_parser_->release();
      in->body_bytes = msg.body().file().size(ec);
      msg.body().close();
      in->request = Request(std::move(msg.base()));
      in->body_file = spool_;
      spool_.clear();  // the handler owns it now
      buffer_.shrink_to_fit();
    } else {
      in->request = string_parser_->release();
      in->body_bytes = in->request.body().size();
    }
    file_parser_.reset();
    string_parser_.reset();
    keep_alive_ = in->request.keep_alive();
    stream_.expires_never();  // the handler's time is not the client's
    if (policy_.inline_ok) return finish(handle(*in));
    // Off the I/O threads: decoding, encoding and disk work must not stall other connections.
    net::post(*server_.pool_, [self = shared_from_this(), in] {
      auto reply = std::make_shared<Handler::Reply>(self->handle(*in));
      net::post(self->stream_.get_executor(), [self, reply] { self->finish(std::move(*reply)); });
    });
  }

  Handler::Reply handle(Handler::Incoming& in) {
    try {
      return server_.handler_.handle(in);
    } catch (const std::exception& e) {
      return server_.handler_.error(500, "internal", e.what());
    } catch (...) {
      return server_.handler_.error(500, "internal", "unknown error");
    }
  }

  void finish(Handler::Reply&& reply) {
    if (closed_) return;
    if (reply.sse) return start_sse(reply.last_event_id);
    if (reply.file) {
      http::response<http::file_body> res{reply.response.result(), reply.response.version()};
      for (const auto& f : reply.response.base()) res.set(f.name_string(), f.value());
      beast::file f;
      f.native_handle(reply.file.release());
      beast::error_code ec;
      res.body().reset(std::move(f), ec);
      if (ec) {
        return write(server_.handler_.error(500, "internal", "cannot send the file"), true);
      }
      return write(std::move(res), !keep_alive_);
    }
    write(std::move(reply.response), !keep_alive_);
  }

  template <class Body>
  void write(http::response<Body>&& res, bool close) {
    const unsigned status = res.result_int();
    server_.metrics_.inc("proden_http_requests_total", std::to_string(status / 100) + "xx");
    res.keep_alive(!close && !reserved_ && !server_.stopped_);
    res.prepare_payload();
    auto sp = std::make_shared<http::response<Body>>(std::move(res));
    stream_.expires_after(milliseconds(cfg_.request_timeout_ms));
    http::async_write(stream_, *sp,
                      [self = shared_from_this(), sp](beast::error_code ec, std::size_t) {
                        if (ec || !sp->keep_alive()) return self->do_close();
                        self->first_ = false;
                        self->read_header();
                      });
  }

  // ---- Server-Sent Events ----
  void start_sse(std::optional<std::uint64_t> last_id) {
    if (reserved_ && !policy_.reserve_ok) {
      return write(server_.handler_.error(503, "unavailable", "connection limit reached"), true);
    }
    if (const int refused = server_.admit_stream(peer_)) {
      server_.metrics_.inc("proden_errors_total", "stream_limit");
      auto res = server_.handler_.error(
          refused, refused == 429 ? "too_many_streams" : "unavailable",
          refused == 429 ? "this client has " + std::to_string(cfg_.max_sse_per_client) +
                               " event streams open (limits.max_sse_per_client)"
                         : "all event-stream slots are taken (limits.max_sse_streams)");
      res.set(http::field::retry_after, "5");
      return write(std::move(res), true);
    }
    server_.metrics_.inc("proden_http_requests_total", "2xx");
    sse_ = true;
    queue_.push_back(std::make_shared<const std::string>(
        "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-cache\r\n"
        "Connection: keep-alive\r\nX-Accel-Buffering: no\r\n\r\nretry: 2000\n\n"));
    write_next();
    server_.events_.subscribe(shared_from_this(), last_id);
    keepalive_ = std::make_unique<net::steady_timer>(stream_.get_executor());
    arm_keepalive();
    // Any bytes or EOF from the client end the stream.
    stream_.socket().async_read_some(
        net::buffer(discard_),
        [self = shared_from_this()](beast::error_code, std::size_t) { self->do_close(); });
  }

  void arm_keepalive() {
    keepalive_->expires_after(milliseconds(cfg_.sse_keepalive_ms));
    keepalive_->async_wait([self = shared_from_this()](beast::error_code ec) {
      if (ec || self->closed_) return;
      if (self->queue_.empty()) {
        self->queue_.push_back(std::make_shared<const std::string>(": keep-alive\n\n"));
        if (!self->writing_) self->write_next();
      }
      self->arm_keepalive();
    });
  }

  void write_next() {
    if (closed_ || queue_.empty()) {
      writing_ = false;
      return;
    }
    writing_ = true;
    auto msg = queue_.front();
    // A client that stops reading is cut off: every write has the request time limit.
    stream_.expires_after(milliseconds(cfg_.request_timeout_ms));
    net::async_write(stream_, net::buffer(*msg),
                     [self = shared_from_this(), msg](beast::error_code ec, std::size_t) {
                       if (ec) return self->do_close();
                       self->stream_.expires_never();
                       self->queue_.pop_front();
                       self->write_next();
                     });
  }

  void do_close() {
    if (closed_) return;
    closed_ = true;
    if (sse_) {
      server_.events_.unsubscribe(this);
      server_.release_stream(peer_);
    }
    if (keepalive_) keepalive_->cancel();
    beast::error_code ec;
    stream_.socket().shutdown(tcp::socket::shutdown_both, ec);
    stream_.socket().close(ec);
    discard_spool();
    server_.untrack(this);
  }

  void discard_spool() {
    if (spool_.empty()) return;
    if (file_parser_) file_parser_->get().body().close();
    ::unlink(spool_.c_str());
    spool_.clear();
  }

  beast::tcp_stream stream_;
  HttpServer& server_;
  Limits cfg_;
  std::string peer_;
  bool reserved_;
  static constexpr std::size_t kBodyReadBytes = 64 << 10;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::empty_body>> header_parser_;
  std::optional<http::request_parser<http::string_body>> string_parser_;
  std::optional<http::request_parser<http::file_body>> file_parser_;
  Handler::BodyPolicy policy_;
  std::filesystem::path spool_;  // a body being streamed to disk, until the handler owns it
  bool first_ = true;
  bool keep_alive_ = true;
  bool closed_ = false;
  bool sse_ = false;
  bool writing_ = false;
  std::deque<std::shared_ptr<const std::string>> queue_;
  std::unique_ptr<net::steady_timer> keepalive_;
  std::array<char, 256> discard_{};
};

HttpServer::HttpServer(const Config& config, Handler& handler, EventHub& events, Metrics& metrics)
    : config_(config),
      handler_(handler),
      events_(events),
      metrics_(metrics),
      acceptor_(net::make_strand(ioc_)) {  // accept handlers and stop()'s close: one strand
  // The reserve is at most a quarter of all connections; streams never take it.
  auto& l = config_.limits;
  l.reserved_connections = std::clamp(l.reserved_connections, 0, l.max_connections / 4);
  l.max_sse_streams =
      std::max(0, std::min(l.max_sse_streams, l.max_connections - l.reserved_connections));
}

HttpServer::~HttpServer() {
  stop();
}

unsigned short HttpServer::listen(const std::string& address, unsigned short port) {
  const auto addr = net::ip::make_address(address == "localhost" ? "127.0.0.1" : address);
  const tcp::endpoint ep(addr, port);
  acceptor_.open(ep.protocol());
  acceptor_.set_option(net::socket_base::reuse_address(true));
  acceptor_.bind(ep);
  acceptor_.listen(net::socket_base::max_listen_connections);
  accept();
  return acceptor_.local_endpoint().port();
}

void HttpServer::accept() {
  acceptor_.async_accept(net::make_strand(ioc_), [this](beast::error_code ec, tcp::socket s) {
    if (ec) {
      if (!acceptor_.is_open() || stopped_) return;
      spdlog::warn("accept: {}", ec.message());  // e.g. out of descriptors: keep serving
    } else if (connections_ >= config_.limits.max_connections) {
      beast::error_code ignored;
      s.close(ignored);
      metrics_.inc("proden_errors_total", "connection_limit");
    } else {
      const bool reserved =
          connections_ >= config_.limits.max_connections - config_.limits.reserved_connections;
      auto session = std::make_shared<Session>(std::move(s), *this, reserved);
      track(session);
      session->start();
    }
    if (!stopped_) accept();
  });
}

void HttpServer::track(const std::shared_ptr<Session>& s) {
  std::lock_guard lock(mu_);
  sessions_.insert(s);
}

void HttpServer::untrack(Session* s) {
  std::lock_guard lock(mu_);
  std::erase_if(sessions_, [s](const auto& w) {
    auto p = w.lock();
    return !p || p.get() == s;
  });
}

int HttpServer::admit_stream(const std::string& peer) {
  std::lock_guard lock(mu_);
  if (streams_ >= config_.limits.max_sse_streams) return 503;
  int& mine = peer_streams_[peer];
  if (mine >= config_.limits.max_sse_per_client) return 429;
  ++mine;
  ++streams_;
  return 0;
}

void HttpServer::release_stream(const std::string& peer) {
  std::lock_guard lock(mu_);
  --streams_;
  if (auto it = peer_streams_.find(peer); it != peer_streams_.end() && --it->second <= 0) {
    peer_streams_.erase(it);
  }
}

void HttpServer::run(int threads) {
  pool_ = std::make_unique<net::thread_pool>(
      static_cast<std::size_t>(std::max(1, config_.handler_threads)));
  for (int i = 0; i < std::max(1, threads); ++i) {
    threads_.emplace_back([this] { ioc_.run(); });
  }
}

void HttpServer::stop() {
  if (stopped_.exchange(true)) return;
  net::post(acceptor_.get_executor(), [this] {
    beast::error_code ec;
    acceptor_.close(ec);
  });
  std::vector<std::shared_ptr<Session>> live;
  {
    std::lock_guard lock(mu_);
    for (const auto& w : sessions_) {
      if (auto s = w.lock()) live.push_back(s);
    }
  }
  for (auto& s : live) s->close();  // also cancels uploads being read (their spool is removed)
  live.clear();
  // Give in-flight responses a moment, then stop.
  for (int i = 0; i < 50 && connections_ > 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  // Handlers still running finish (each is bounded: a header probe, one image rendition); their
  // replies go nowhere once the I/O threads stop.
  if (pool_) pool_->join();
  ioc_.stop();
  for (auto& t : threads_) {
    if (t.joinable()) t.join();
  }
  threads_.clear();
}

}  // namespace proden::daemon

#include "daemon/http_server.hpp"

#include <spdlog/spdlog.h>

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

class HttpServer::Session : public std::enable_shared_from_this<Session>, public EventSink {
 public:
  Session(tcp::socket&& socket, HttpServer& server)
      : stream_(std::move(socket)), server_(server), cfg_(server.config_.limits) {
    server_.metrics_.set("proden_http_connections", ++server_.connections_);
  }
  ~Session() override { server_.metrics_.set("proden_http_connections", --server_.connections_); }

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
  void read_header() {
    if (closed_) return;
    parser_.emplace();
    parser_->header_limit(static_cast<std::uint32_t>(cfg_.max_header_bytes));
    parser_->body_limit(std::max(cfg_.max_body_bytes, cfg_.max_upload_bytes));
    stream_.expires_after(milliseconds(first_ ? cfg_.request_timeout_ms : cfg_.idle_timeout_ms));
    http::async_read_header(stream_, buffer_, *parser_,
                            beast::bind_front_handler(&Session::on_header, shared_from_this()));
  }

  void on_header(beast::error_code ec, std::size_t) {
    if (ec) return read_failed(ec);
    Handler::BodyPolicy policy{cfg_.max_body_bytes, cfg_.request_timeout_ms};
    std::optional<Response> early;
    try {
      early = server_.handler_.before_body(parser_->get().base(), policy);
    } catch (const std::exception& e) {
      early = server_.handler_.error(500, "internal", e.what());
    }
    if (early) return write(std::move(*early), true);
    const auto length = parser_->content_length();
    if (length && *length > policy.limit) {
      return write(
          server_.handler_.error(413, "payload_too_large",
                                 "body of " + std::to_string(*length) +
                                     " bytes exceeds the limit of " + std::to_string(policy.limit)),
          true);
    }
    parser_->body_limit(policy.limit);
    if (parser_->is_done()) return on_body({}, 0);
    stream_.expires_after(milliseconds(policy.timeout_ms));
    const auto expect = parser_->get()[http::field::expect];
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

  void read_body() {
    http::async_read(stream_, buffer_, *parser_,
                     beast::bind_front_handler(&Session::on_body, shared_from_this()));
  }

  void read_failed(beast::error_code ec) {
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
    Request req = parser_->release();
    Handler::Reply reply;
    try {
      reply = server_.handler_.handle(req);
    } catch (const std::exception& e) {
      reply.response = server_.handler_.error(500, "internal", e.what());
    }
    if (reply.sse) return start_sse(reply.last_event_id);
    write(std::move(reply.response), !req.keep_alive());
  }

  void write(Response&& res, bool close) {
    const unsigned status = res.result_int();
    server_.metrics_.inc("proden_http_requests_total", std::to_string(status / 100) + "xx");
    res.keep_alive(!close && !server_.stopped_);
    res.prepare_payload();
    auto sp = std::make_shared<Response>(std::move(res));
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
    server_.metrics_.inc("proden_http_requests_total", "2xx");
    sse_ = true;
    stream_.expires_never();  // a stream lives until the client leaves; slow ones are dropped
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
    net::async_write(stream_.socket(), net::buffer(*msg),
                     [self = shared_from_this(), msg](beast::error_code ec, std::size_t) {
                       if (ec) return self->do_close();
                       self->queue_.pop_front();
                       self->write_next();
                     });
  }

  void do_close() {
    if (closed_) return;
    closed_ = true;
    if (sse_) server_.events_.unsubscribe(this);
    if (keepalive_) keepalive_->cancel();
    beast::error_code ec;
    stream_.socket().shutdown(tcp::socket::shutdown_both, ec);
    stream_.socket().close(ec);
    server_.untrack(this);
  }

  beast::tcp_stream stream_;
  HttpServer& server_;
  Limits cfg_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  bool first_ = true;
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
      acceptor_(net::make_strand(ioc_)) {}  // accept handlers and stop()'s close: one strand

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
      auto session = std::make_shared<Session>(std::move(s), *this);
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

void HttpServer::run(int threads) {
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
  for (auto& s : live) s->close();
  live.clear();
  // Give in-flight responses a moment, then stop.
  for (int i = 0; i < 50 && connections_ > 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ioc_.stop();
  for (auto& t : threads_) {
    if (t.joinable()) t.join();
  }
  threads_.clear();
}

}  // namespace proden::daemon

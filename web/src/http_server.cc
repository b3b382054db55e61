// The I/O half of the server, after Beast's http_server_async example: a Listener accepts, one
// Session per connection reads a request, asks the Router (router.h) for the answer and writes
// it. Every wait has a deadline (tcp_stream::expires_after).

#include "concord/web/http_server.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <boost/asio/dispatch.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <cassert>
#include <limits>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <unordered_map>
#include <utility>

#include "concord/web/json_response.h"
#include "router.h"

namespace concord::web {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = boost::beast::http;
using tcp = boost::asio::ip::tcp;
using beast::error_code;

/// Pause before accepting again after accept failed (e.g. out of file descriptors), so a
/// persistent failure neither spins nor floods the log.
constexpr std::chrono::milliseconds kAcceptRetryDelay{100};
/// Bytes read and discarded from a client before closing after an error response.
constexpr std::size_t kMaxDrainBytes = 1 << 20;

std::string endpoint_text(const tcp::endpoint& endpoint) {
  const std::string address = endpoint.address().to_string();
  const std::string port = std::to_string(endpoint.port());
  return endpoint.address().is_v6() ? "[" + address + "]:" + port : address + ":" + port;
}

bool is_http_error(const error_code& error) {
  return error.category() == make_error_code(http::error::bad_method).category();
}

class Session;

/// What the listener and every session share; outlives the HttpServer while connections finish.
struct ServerState {
  explicit ServerState(ServerOptions server_options) : options(std::move(server_options)) {}

  const ServerOptions options;
  Router router;

  std::atomic<std::uint64_t> connections_accepted{0};
  std::atomic<std::uint64_t> connections_rejected{0};
  std::atomic<std::uint64_t> connections_timed_out{0};
  std::atomic<std::uint64_t> requests{0};
  std::atomic<std::uint64_t> requests_rejected{0};
  std::atomic<std::uint64_t> responses_2xx{0};
  std::atomic<std::uint64_t> responses_3xx{0};
  std::atomic<std::uint64_t> responses_4xx{0};
  std::atomic<std::uint64_t> responses_5xx{0};

  /// Open sessions (serving and refusing), for stop() and for the connection limit.
  std::mutex sessions_mutex;
  std::unordered_map<const Session*, std::weak_ptr<Session>> sessions;
  std::size_t serving_sessions = 0;
  std::unordered_map<std::string, std::size_t> serving_per_client;  // by client address
  bool stopped = false;

  void count_response(int status) {
    switch (status / 100) {
      case 2:
        ++responses_2xx;
        break;
      case 3:
        ++responses_3xx;
        break;
      case 4:
        ++responses_4xx;
        break;
      default:
        ++responses_5xx;
        break;
    }
  }
};

/// One connection: read a request, answer it, repeat while keep-alive; or, when refusing the
/// connection, answer 503 and close. Runs on its own strand.
class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(tcp::socket&& socket, std::shared_ptr<ServerState> state, bool serving,
          std::string client, std::string refusal)
      : stream_(std::move(socket)),
        state_(std::move(state)),
        client_(std::move(client)),
        refusal_(std::move(refusal)),
        serving_(serving) {
    error_code error;
    const tcp::endpoint peer = stream_.socket().remote_endpoint(error);
    peer_ = error ? std::string("unknown peer") : endpoint_text(peer);
  }

  ~Session() {
    std::lock_guard lock(state_->sessions_mutex);
    state_->sessions.erase(this);
    if (serving_) {
      --state_->serving_sessions;
      const auto it = state_->serving_per_client.find(client_);
      if (it != state_->serving_per_client.end() && --it->second == 0)
        state_->serving_per_client.erase(it);
    }
  }

  Session(const Session&) = delete;
  Session& operator=(const Session&) = delete;

  void start() {
    asio::dispatch(stream_.get_executor(), [self = shared_from_this()] {
      if (self->serving_) {
        self->read_request();
      } else {
        self->send_error(503, self->refusal_);
      }
    });
  }

  /// Closes the connection from any thread; pending operations end with operation_aborted.
  void close() {
    asio::post(stream_.get_executor(), [self = shared_from_this()] { self->stream_.close(); });
  }

 private:
  // 1. Read the header with the whole request's size limit and deadline.
  void read_request() {
    const ServerOptions& options = state_->options;
    parser_.emplace();
    parser_->header_limit(static_cast<std::uint32_t>(std::min<std::size_t>(
        options.max_request_bytes, std::numeric_limits<std::uint32_t>::max())));
    parser_->body_limit(options.max_request_bytes);
    stream_.expires_after(options.request_timeout);
    http::async_read_header(stream_, buffer_, *parser_,
                            beast::bind_front_handler(&Session::on_header, shared_from_this()));
  }

  // 2. Check the body against what the header left of the limit, then read it.
  void on_header(error_code error, std::size_t header_bytes) {
    if (error) return on_read_error(error);
    const std::size_t limit = state_->options.max_request_bytes;
    const std::uint64_t body_allowance = header_bytes < limit ? limit - header_bytes : 0;
    const auto content_length = parser_->content_length();
    if (content_length && *content_length > body_allowance) {
      return on_read_error(http::error::body_limit);
    }
    parser_->body_limit(body_allowance);  // bounds chunked bodies
    if (parser_->is_done()) return on_request();
    http::async_read(stream_, buffer_, *parser_,
                     beast::bind_front_handler(&Session::on_body, shared_from_this()));
  }

  void on_body(error_code error, std::size_t /*bytes*/) {
    if (error) return on_read_error(error);
    on_request();
  }

  // 3. Answer: the Router decides, this only turns its Response into HTTP.
  void on_request() {
    ++state_->requests;
    // The parser accepts HTTP/1.0 and HTTP/1.1 only (anything else is a bad_version error).
    const http::request<http::string_body>& request = parser_->get();
    const beast::string_view method = request.method_string();
    const beast::string_view target = request.target();
    const Response response = state_->router.handle(std::string_view(method.data(), method.size()),
                                                    std::string_view(target.data(), target.size()));
    const bool keep_alive = request.keep_alive();
    send(response, request.version(), keep_alive, request.method() == http::verb::head,
         /*linger=*/false);
  }

  void on_read_error(error_code error) {
    if (error == http::error::end_of_stream || error == asio::error::operation_aborted) {
      return close_now();  // the client closed between requests, or stop()
    }
    if (error == beast::error::timeout) {
      ++state_->connections_timed_out;
      spdlog::debug("HTTP: closed connection from {}: no complete request within {} ms", peer_,
                    state_->options.request_timeout.count());
      return;  // tcp_stream closed the socket
    }
    if (error == http::error::header_limit || error == http::error::body_limit) {
      ++state_->requests_rejected;
      const bool header = error == http::error::header_limit;
      spdlog::debug("HTTP: request from {} larger than {} bytes ({} too large)", peer_,
                    state_->options.max_request_bytes, header ? "header" : "body");
      return send_error(header ? 431 : 413,
                        std::string(header ? "request header" : "request") + " larger than " +
                            std::to_string(state_->options.max_request_bytes) + " bytes");
    }
    if (is_http_error(error) && error != http::error::partial_message) {
      ++state_->requests_rejected;
      spdlog::debug("HTTP: malformed request from {}: {}", peer_, error.message());
      return send_error(400, "malformed HTTP request: " + error.message());
    }
    // Connection reset, or end of stream in the middle of a request: nobody to answer.
    spdlog::debug("HTTP: connection from {} failed while reading: {}", peer_, error.message());
    close_now();
  }

  /// Answers with a JSON error, then closes (after draining what the client still sends, so the
  /// answer is not lost to a TCP reset).
  void send_error(int status, std::string message) {
    send(error_response(status, std::move(message)), 11, /*keep_alive=*/false, /*head=*/false,
         /*linger=*/true);
  }

  void send(const Response& response, unsigned version, bool keep_alive, bool head, bool linger) {
    state_->count_response(response.status);
    response_ = {};
    response_.version(version);
    response_.result(static_cast<unsigned>(response.status));
    response_.set(http::field::server, state_->options.server_name);
    if (!response.content_type.empty()) {
      response_.set(http::field::content_type, response.content_type);
    }
    for (const auto& [name, value] : response.headers) response_.set(name, value);
    response_.keep_alive(keep_alive);
    if (response.status == 204 || response.status == 304) {
      // No body and no Content-Length (RFC 9110 8.6).
    } else {
      response_.body() = response.body;
      response_.prepare_payload();
      if (head) response_.body().clear();  // Content-Length still announces the GET body
    }
    stream_.expires_after(state_->options.request_timeout);
    http::async_write(
        stream_, response_,
        beast::bind_front_handler(&Session::on_write, shared_from_this(), keep_alive, linger));
  }

  void on_write(bool keep_alive, bool linger, error_code error, std::size_t /*bytes*/) {
    if (error) {
      if (error != asio::error::operation_aborted) {
        spdlog::debug("HTTP: writing to {} failed: {}", peer_, error.message());
      }
      return close_now();
    }
    if (keep_alive) return read_request();
    error_code ignored;
    stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
    if (!linger) return close_now();
    // 4. Lingering close: read and discard until the client closes or the deadline passes.
    drained_bytes_ = 0;
    stream_.expires_after(state_->options.request_timeout);
    drain();
  }

  void drain() {
    stream_.async_read_some(asio::buffer(drain_buffer_),
                            [self = shared_from_this()](error_code error, std::size_t bytes) {
                              self->drained_bytes_ += bytes;
                              if (error || self->drained_bytes_ > kMaxDrainBytes)
                                return self->close_now();
                              self->drain();
                            });
  }

  void close_now() { stream_.close(); }

  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  http::response<http::string_body> response_;
  std::array<char, 4096> drain_buffer_{};
  std::size_t drained_bytes_ = 0;
  std::shared_ptr<ServerState> state_;
  std::string peer_;
  const std::string client_;   // client address (no port)
  const std::string refusal_;  // 503 message when not serving
  const bool serving_;
};

/// Accepts connections and hands each to a Session, within the connection limit.
class Listener : public std::enable_shared_from_this<Listener> {
 public:
  Listener(asio::io_context& io_context, std::shared_ptr<ServerState> state)
      : io_context_(io_context),
        acceptor_(asio::make_strand(io_context)),
        retry_timer_(acceptor_.get_executor()),
        state_(std::move(state)) {}

  /// Binds and listens; returns the port. Throws std::runtime_error.
  std::uint16_t open() {
    const ServerOptions& options = state_->options;
    const std::string where = options.address + ":" + std::to_string(options.port);
    error_code error;
    const asio::ip::address address = asio::ip::make_address(options.address, error);
    if (error)
      throw std::runtime_error("HTTP server: invalid listen address '" + options.address + "'");
    const tcp::endpoint endpoint(address, options.port);
    auto fail = [&](const char* step) {
      throw std::runtime_error("HTTP server: cannot " + std::string(step) + " " + where + ": " +
                               error.message());
    };
    if (acceptor_.open(endpoint.protocol(), error); error) fail("open a socket for");
    if (acceptor_.set_option(asio::socket_base::reuse_address(true), error); error) {
      fail("set SO_REUSEADDR for");
    }
    if (acceptor_.bind(endpoint, error); error) fail("bind");
    if (acceptor_.listen(asio::socket_base::max_listen_connections, error); error)
      fail("listen on");
    const tcp::endpoint local = acceptor_.local_endpoint(error);
    if (error) fail("read the local port of");
    spdlog::info("HTTP server listening on {}", endpoint_text(local));
    return local.port();
  }

  void start_accepting() {
    asio::dispatch(acceptor_.get_executor(), [self = shared_from_this()] { self->accept(); });
  }

  void close() {
    asio::post(acceptor_.get_executor(), [self = shared_from_this()] {
      error_code ignored;
      self->acceptor_.close(ignored);
      self->retry_timer_.cancel();
    });
  }

 private:
  void accept() {
    if (!acceptor_.is_open()) return;
    acceptor_.async_accept(asio::make_strand(io_context_),
                           beast::bind_front_handler(&Listener::on_accept, shared_from_this()));
  }

  void on_accept(error_code error, tcp::socket socket) {
    if (error == asio::error::operation_aborted || !acceptor_.is_open()) return;
    if (error) {
      spdlog::error("HTTP server: accept failed: {}", error.message());
      retry_timer_.expires_after(kAcceptRetryDelay);
      retry_timer_.async_wait([self = shared_from_this()](error_code wait_error) {
        if (!wait_error) self->accept();
      });
      return;
    }
    ++state_->connections_accepted;
    admit(std::move(socket));
    accept();
  }

  /// Serves the connection, or refuses it with 503 when max_connections are served, or just
  /// closes it when as many are already being refused.
  void admit(tcp::socket socket) {
    const std::size_t limit = state_->options.max_connections;
    const std::size_t client_limit =
        std::min(state_->options.max_connections_per_client, state_->options.max_connections);
    error_code error;
    const tcp::endpoint remote = socket.remote_endpoint(error);
    const std::string client = error ? std::string("?") : remote.address().to_string();
    std::shared_ptr<Session> session;
    {
      std::lock_guard lock(state_->sessions_mutex);
      if (state_->stopped) return;
      const auto per_client = state_->serving_per_client.find(client);
      const std::size_t client_serving =
          per_client == state_->serving_per_client.end() ? 0 : per_client->second;
      const bool serving = state_->serving_sessions < limit && client_serving < client_limit;
      const std::size_t refusing = state_->sessions.size() - state_->serving_sessions;
      std::string refusal;
      if (!serving) {
        ++state_->connections_rejected;
        refusal = state_->serving_sessions >= limit
                      ? "too many connections (limit " + std::to_string(limit) + ")"
                      : "too many connections from " + client + " (limit " +
                            std::to_string(client_limit) + " per client)";
        const auto now = std::chrono::steady_clock::now();
        if (now - last_refusal_log_ >= std::chrono::seconds(10)) {  // at most one line per 10 s
          spdlog::warn("HTTP server: refused a connection: {} ({} refusals before it not logged)",
                       refusal, refusals_not_logged_);
          last_refusal_log_ = now;
          refusals_not_logged_ = 0;
        } else {
          ++refusals_not_logged_;
        }
        if (refusing >= limit) return;  // the socket closes here
      }
      session = std::make_shared<Session>(std::move(socket), state_, serving, client, refusal);
      state_->sessions.emplace(session.get(), session);
      if (serving) {
        ++state_->serving_sessions;
        ++state_->serving_per_client[client];
      }
    }
    session->start();
  }

  asio::io_context& io_context_;
  tcp::acceptor acceptor_;
  asio::steady_timer retry_timer_;
  std::shared_ptr<ServerState> state_;
  std::chrono::steady_clock::time_point last_refusal_log_{};
  std::uint64_t refusals_not_logged_ = 0;
};

}  // namespace

void ServerOptions::validate() const {
  auto fail = [](const std::string& field, const std::string& value, const char* requirement) {
    throw std::invalid_argument("ServerOptions." + field + " = " + value + ": " + requirement);
  };
  error_code error;
  boost::asio::ip::make_address(address, error);
  if (error) fail("address", "'" + address + "'", "not an IPv4 or IPv6 address");
  if (max_request_bytes < 256) {
    fail("max_request_bytes", std::to_string(max_request_bytes), "must be at least 256");
  }
  if (request_timeout.count() <= 0) {
    fail("request_timeout", std::to_string(request_timeout.count()) + " ms", "must be positive");
  }
  if (max_connections < 1) fail("max_connections", "0", "must be at least 1");
  if (max_connections_per_client < 1) fail("max_connections_per_client", "0", "must be at least 1");
}

struct HttpServer::Impl {
  Impl(asio::io_context& io, ServerOptions options)
      : io_context(io), state(std::make_shared<ServerState>(std::move(options))) {}

  asio::io_context& io_context;
  std::shared_ptr<ServerState> state;
  std::shared_ptr<Listener> listener;
  std::atomic<std::uint16_t> port{0};
};

HttpServer::HttpServer(boost::asio::io_context& io_context, ServerOptions options)
    : impl_(std::make_unique<Impl>(io_context, std::move(options))) {}

HttpServer::~HttpServer() { stop(); }

void HttpServer::get(std::string path, Handler handler) {
  assert(!impl_->listener && "register routes before start()");
  impl_->state->router.add_get(std::move(path), std::move(handler));
}

void HttpServer::start() {
  assert(!impl_->listener && "start() is called once");
  impl_->state->options.validate();
  auto listener = std::make_shared<Listener>(impl_->io_context, impl_->state);
  impl_->port = listener->open();
  impl_->listener = std::move(listener);
  impl_->listener->start_accepting();
}

void HttpServer::stop() {
  std::vector<std::shared_ptr<Session>> open_sessions;
  {
    std::lock_guard lock(impl_->state->sessions_mutex);
    if (impl_->state->stopped) return;
    impl_->state->stopped = true;
    for (const auto& [key, weak] : impl_->state->sessions) {
      if (auto session = weak.lock()) open_sessions.push_back(std::move(session));
    }
  }
  if (impl_->listener) impl_->listener->close();
  for (const auto& session : open_sessions) session->close();
}

std::uint16_t HttpServer::port() const { return impl_->port; }

ServerCounters HttpServer::counters() const {
  const ServerState& state = *impl_->state;
  ServerCounters counters;
  counters.connections_accepted = state.connections_accepted;
  counters.connections_rejected = state.connections_rejected;
  counters.connections_timed_out = state.connections_timed_out;
  {
    std::lock_guard lock(impl_->state->sessions_mutex);
    counters.connections_active = impl_->state->serving_sessions;
  }
  counters.requests = state.requests;
  counters.requests_rejected = state.requests_rejected;
  counters.responses_2xx = state.responses_2xx;
  counters.responses_3xx = state.responses_3xx;
  counters.responses_4xx = state.responses_4xx;
  counters.responses_5xx = state.responses_5xx;
  return counters;
}

}  // namespace concord::web

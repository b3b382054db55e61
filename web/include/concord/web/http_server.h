#pragma once
/// \file
/// A small HTTP/1.1 server answering GET (and HEAD) routes registered by the caller, for reading
/// a daemon's state with curl. Boost.Beast does the work underneath; this header shows none of it.
///
/// Threading: the server runs on the io_context given to it. Route handlers are called on a
/// thread running that io_context, so a handler must be quick (it delays every other connection
/// served by that thread) and must only read data that is safe to read from that thread (the
/// daemon hands them immutable snapshots). If several threads run the io_context, handlers of
/// different connections may run at the same time.
///
/// Every connection is bounded: a whole request (header and body) must arrive within
/// ServerOptions::request_timeout and fit in ServerOptions::max_request_bytes, an idle
/// keep-alive connection is closed after request_timeout, and at most
/// ServerOptions::max_connections are served at once (further ones get 503).

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace boost::asio {
class io_context;
}  // namespace boost::asio

namespace concord::web {

/// What a handler sees of a request.
struct Request {
  /// "GET" or "HEAD"; requests with other methods never reach a handler (405).
  std::string method;
  /// The request target as sent, e.g. "/trajectory?format=tum".
  std::string target;
  /// The percent-decoded path of the target, e.g. "/trajectory".
  std::string path;
  /// The percent-decoded query parameters ('+' decodes to a space); a parameter without '='
  /// maps to ""; when a name is repeated the last value wins.
  std::map<std::string, std::string> query;
};

/// What a handler answers.
struct Response {
  /// HTTP status, 200..599 (anything else is answered with 500 and logged).
  int status = 200;
  /// Content-Type field; omitted when empty.
  std::string content_type = "application/json";
  /// The body (not sent for HEAD requests, nor for 204 and 304).
  std::string body;
  /// Extra header fields, e.g. {"Allow", "GET, HEAD"} or {"Cache-Control", "no-store"}. Server,
  /// Content-Length and Connection are set by the server.
  std::vector<std::pair<std::string, std::string>> headers;
};

/// Builds the response to one GET or HEAD request. May throw: the client then gets a 500 JSON
/// error, the exception is logged and the server keeps running.
using Handler = std::function<Response(const Request&)>;

/// Where and how the server listens. HttpServer::start() validates it.
struct ServerOptions {
  /// IPv4 or IPv6 address to listen on ("0.0.0.0" for every interface).
  std::string address = "127.0.0.1";
  /// TCP port; 0 picks a free ephemeral port (see HttpServer::port()).
  std::uint16_t port = 8080;
  /// Largest request accepted, header and body together, in bytes; a larger header is answered
  /// with 431, a larger body with 413, and the connection is closed. At least 256.
  std::size_t max_request_bytes = 8192;
  /// Time a client has to send a whole request, counted from the end of the previous response
  /// (or from connecting); also the idle limit of a keep-alive connection and the limit for
  /// writing a response. Positive.
  std::chrono::milliseconds request_timeout{5000};
  /// Connections served at once; one more is answered with 503 and closed. At least 1.
  std::size_t max_connections = 64;
  /// Connections served at once for one client address; one more is answered with 503 and
  /// closed, so one client cannot hold every slot. At least 1 (above max_connections it is
  /// max_connections).
  std::size_t max_connections_per_client = 8;
  /// The Server header field.
  std::string server_name = "concordd";

  /// Throws std::invalid_argument naming the field and its bad value.
  void validate() const;
};

/// Monotonic counts since start(), except connections_active.
struct ServerCounters {
  /// Connections accepted, including those refused with 503.
  std::uint64_t connections_accepted = 0;
  /// Connections refused because max_connections (or max_connections_per_client for that
  /// client) were being served.
  std::uint64_t connections_rejected = 0;
  /// Connections closed because a request or a keep-alive wait exceeded request_timeout.
  std::uint64_t connections_timed_out = 0;
  /// Connections being served now.
  std::uint64_t connections_active = 0;
  /// Requests read completely and routed (whatever their answer).
  std::uint64_t requests = 0;
  /// Requests refused before routing: malformed, including HTTP versions other than 1.0 and
  /// 1.1 (400), too large (413, 431).
  std::uint64_t requests_rejected = 0;
  /// Responses sent, by status class.
  std::uint64_t responses_2xx = 0;
  std::uint64_t responses_3xx = 0;
  std::uint64_t responses_4xx = 0;
  std::uint64_t responses_5xx = 0;
};

/// The HTTP server. Register routes with get(), then start(); stop() (or the destructor) closes
/// the listening socket and every connection.
///
/// Unknown paths are answered with 404, known paths with a method other than GET or HEAD with
/// 405 and an Allow field, all errors with a JSON body {"error": {"status": N, "message": "..."}}
/// (see error_response in json_response.h).
class HttpServer {
 public:
  /// Serves on `io_context`, which must outlive the server's use of it (run it after start()).
  HttpServer(boost::asio::io_context& io_context, ServerOptions options);
  /// Calls stop().
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  /// Registers `handler` for GET and HEAD requests to exactly `path` (which starts with '/' and
  /// has no query). HEAD is answered like GET without the body. Call before start(); a path
  /// registers once.
  void get(std::string path, Handler handler);

  /// Validates the options, binds and listens, and starts accepting once the io_context runs.
  /// Throws std::invalid_argument on bad options and std::runtime_error naming the address and
  /// port when listening fails (e.g. the port is in use). Call once.
  void start();

  /// Stops accepting and closes every connection (in-flight responses are dropped). Safe to call
  /// from any thread and more than once; the io_context's run() returns once nothing else uses it.
  void stop();

  /// The port listened on (the chosen one when ServerOptions::port is 0); 0 before start().
  std::uint16_t port() const;

  /// A snapshot of the counters; safe to call from any thread (e.g. from a /metrics handler).
  ServerCounters counters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace concord::web

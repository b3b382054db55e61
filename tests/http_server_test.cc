#include "concord/web/http_server.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <array>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <chrono>
#include <functional>
#include <future>
#include <nlohmann/json.hpp>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>

#include "concord/web/json_response.h"
#include "concord/web/target.h"

namespace concord::web {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = boost::beast::http;
using tcp = boost::asio::ip::tcp;
using ::testing::HasSubstr;
using namespace std::chrono_literals;

/// Every client operation gives up after this long, so a broken server fails a test quickly.
constexpr auto kClientDeadline = 1000ms;

/// A server on an ephemeral loopback port with its io_context running on a thread of its own.
/// The destructor stops the server and checks that the io_context then runs out of work.
class RunningServer {
 public:
  explicit RunningServer(ServerOptions options = {},
                         const std::function<void(HttpServer&)>& add_routes = add_default_routes)
      : server_(io_context_, with_ephemeral_port(std::move(options))) {
    add_routes(server_);
    server_.start();
    thread_ = std::thread([this] {
      io_context_.run();
      stopped_.set_value();
    });
  }

  ~RunningServer() { stop(); }

  /// Stops the server and joins its thread: afterwards every completion handler has run, so the
  /// counters are final.
  void stop() {
    if (!thread_.joinable()) return;
    asio::post(io_context_, [this] { server_.stop(); });
    if (stopped_.get_future().wait_for(1s) != std::future_status::ready) {
      ADD_FAILURE() << "the io_context still has work 1 s after stop()";
      io_context_.stop();
    }
    thread_.join();
  }

  RunningServer(const RunningServer&) = delete;
  RunningServer& operator=(const RunningServer&) = delete;

  std::uint16_t port() const { return server_.port(); }
  ServerCounters counters() const { return server_.counters(); }

  static void add_default_routes(HttpServer& server) {
    server.get("/healthz", [](const Request&) { return json_response(200, {{"ok", true}}); });
    server.get("/echo", [](const Request& request) {
      nlohmann::json query = nlohmann::json::object();
      for (const auto& [name, value] : request.query) query[name] = value;
      return json_response(200, {{"method", request.method},
                                 {"target", request.target},
                                 {"path", request.path},
                                 {"query", query}});
    });
    server.get("/metrics", [](const Request&) {
      return Response{200, "text/plain; version=0.0.4", "concord_up 1\n", {}};
    });
    server.get("/throw", [](const Request&) -> Response {
      throw std::runtime_error("deliberate failure in a test handler");
    });
  }

 private:
  static ServerOptions with_ephemeral_port(ServerOptions options) {
    options.address = "127.0.0.1";
    options.port = 0;
    return options;
  }

  asio::io_context io_context_;
  HttpServer server_;
  std::promise<void> stopped_;
  std::thread thread_;
};

/// A synchronous HTTP client with a deadline on every operation: each call runs the client's
/// own io_context until the asynchronous operation completes or kClientDeadline passes.
class TestClient {
 public:
  explicit TestClient(std::uint16_t port) : stream_(io_context_) {
    error_code_ = {};
    stream_.expires_after(kClientDeadline);
    stream_.async_connect(tcp::endpoint(asio::ip::make_address("127.0.0.1"), port),
                          [this](beast::error_code error) { error_code_ = error; });
    run();
    if (error_code_) throw std::runtime_error("connect failed: " + error_code_.message());
  }

  /// Sends bytes as they are (any request, well formed or not).
  void send_raw(const std::string& bytes) {
    stream_.expires_after(kClientDeadline);
    asio::async_write(stream_, asio::buffer(bytes),
                      [this](beast::error_code error, std::size_t) { error_code_ = error; });
    run();
    if (error_code_) throw std::runtime_error("send failed: " + error_code_.message());
  }

  void send(http::verb method, const std::string& target, bool keep_alive = true) {
    http::request<http::string_body> request(method, target, 11);
    request.set(http::field::host, "127.0.0.1");
    request.keep_alive(keep_alive);
    request.prepare_payload();
    stream_.expires_after(kClientDeadline);
    http::async_write(stream_, request,
                      [this](beast::error_code error, std::size_t) { error_code_ = error; });
    run();
    if (error_code_) throw std::runtime_error("send failed: " + error_code_.message());
  }

  /// The next response; `head` when it answers a HEAD request (no body follows).
  http::response<http::string_body> receive(bool head = false) {
    http::response_parser<http::string_body> parser;
    parser.skip(head);
    stream_.expires_after(kClientDeadline);
    http::async_read(stream_, buffer_, parser,
                     [this](beast::error_code error, std::size_t) { error_code_ = error; });
    run();
    if (error_code_) throw std::runtime_error("receive failed: " + error_code_.message());
    return parser.release();
  }

  http::response<http::string_body> get(const std::string& target) {
    send(http::verb::get, target);
    return receive();
  }

  /// Reads until the server closes the connection; returns whether it did within `deadline`
  /// without sending anything more.
  bool server_closes(std::chrono::milliseconds deadline = kClientDeadline) {
    stream_.expires_after(deadline);
    std::size_t received = 0;
    std::function<void(beast::error_code, std::size_t)> on_read;
    on_read = [&](beast::error_code error, std::size_t bytes) {
      received += bytes;
      error_code_ = error;
      if (!error) stream_.async_read_some(asio::buffer(scratch_), on_read);
    };
    stream_.async_read_some(asio::buffer(scratch_), on_read);
    run();
    const bool closed =
        error_code_ == asio::error::eof || error_code_ == asio::error::connection_reset;
    return closed && received == 0 && buffer_.size() == 0;
  }

 private:
  void run() {
    io_context_.restart();
    io_context_.run();
  }

  asio::io_context io_context_;
  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::array<char, 1024> scratch_{};
  beast::error_code error_code_;
};

nlohmann::json body_json(const http::response<http::string_body>& response) {
  return nlohmann::json::parse(response.body());
}

/// Checks that `response` is the JSON error {"error": {"status": status, "message": ...}}.
void expect_json_error(const http::response<http::string_body>& response, int status) {
  EXPECT_EQ(response.result_int(), static_cast<unsigned>(status));
  EXPECT_EQ(response[http::field::content_type], "application/json");
  const nlohmann::json body = body_json(response);
  ASSERT_TRUE(body.contains("error")) << response.body();
  EXPECT_EQ(body["error"]["status"], status);
  EXPECT_TRUE(body["error"]["message"].is_string());
  EXPECT_FALSE(body["error"]["message"].get<std::string>().empty());
}

void expect_healthy(std::uint16_t port) {
  TestClient client(port);
  const auto response = client.get("/healthz");
  EXPECT_EQ(response.result_int(), 200u);
  EXPECT_EQ(body_json(response), nlohmann::json({{"ok", true}}));
}

// ---- Pure parts: target parsing and JSON bodies ----

TEST(ParseTarget, SplitsAndDecodesPathAndQuery) {
  const ParsedTarget parsed = parse_target("/a%20b/c+d?format=kitti&name=x%2By+z&flag&&k=1&k=2");
  ASSERT_TRUE(parsed.ok()) << parsed.error;
  EXPECT_EQ(parsed.path, "/a b/c+d");
  const std::map<std::string, std::string> expected{
      {"format", "kitti"}, {"name", "x+y z"}, {"flag", ""}, {"k", "2"}};
  EXPECT_EQ(parsed.query, expected);
}

TEST(ParseTarget, RejectsMalformedTargets) {
  EXPECT_THAT(parse_target("").error, HasSubstr("start with '/'"));
  EXPECT_THAT(parse_target("http://host/x").error, HasSubstr("start with '/'"));
  EXPECT_THAT(parse_target("/x%4").error, HasSubstr("path"));
  EXPECT_THAT(parse_target("/x?a=%zz").error, HasSubstr("query"));
  EXPECT_THAT(parse_target("/x?a%=1").error, HasSubstr("query"));
}

TEST(PercentDecode, DecodesEscapesAndOptionallyPlus) {
  EXPECT_EQ(percent_decode("a%2fb%2F+", false), std::optional<std::string>("a/b/+"));
  EXPECT_EQ(percent_decode("a+b", true), std::optional<std::string>("a b"));
  EXPECT_EQ(percent_decode("%00", false), std::optional<std::string>(std::string(1, '\0')));
  EXPECT_EQ(percent_decode("%", false), std::nullopt);
  EXPECT_EQ(percent_decode("%g0", false), std::nullopt);
}

TEST(JsonResponse, ErrorBodyAndInvalidUtf8) {
  const Response error = error_response(404, "no route for /x");
  EXPECT_EQ(error.status, 404);
  EXPECT_EQ(error.content_type, "application/json");
  EXPECT_EQ(nlohmann::json::parse(error.body),
            nlohmann::json({{"error", {{"status", 404}, {"message", "no route for /x"}}}}));
  // Strings received from peers may be invalid UTF-8; that must not throw.
  EXPECT_NO_THROW(json_response(200, {{"name", std::string("bad \xff byte")}}));
}

TEST(ServerOptions, ValidateNamesTheBadField) {
  ServerOptions options;
  EXPECT_NO_THROW(options.validate());
  options.max_connections = 0;
  try {
    options.validate();
    ADD_FAILURE() << "expected std::invalid_argument";
  } catch (const std::invalid_argument& error) {
    EXPECT_THAT(error.what(), HasSubstr("max_connections"));
  }
  options = ServerOptions{};
  options.address = "not-an-address";
  EXPECT_THROW(options.validate(), std::invalid_argument);
}

// ---- The server over loopback ----

TEST(HttpServer, GetReturnsBodyStatusAndContentType) {
  RunningServer server;
  TestClient client(server.port());
  const auto health = client.get("/healthz");
  EXPECT_EQ(health.result_int(), 200u);
  EXPECT_EQ(health[http::field::content_type], "application/json");
  EXPECT_EQ(health[http::field::server], "concordd");
  EXPECT_EQ(body_json(health), nlohmann::json({{"ok", true}}));

  const auto metrics = client.get("/metrics");
  EXPECT_EQ(metrics.result_int(), 200u);
  EXPECT_EQ(metrics[http::field::content_type], "text/plain; version=0.0.4");
  EXPECT_EQ(metrics.body(), "concord_up 1\n");
  EXPECT_EQ(metrics[http::field::content_length], std::to_string(metrics.body().size()));
}

TEST(HttpServer, QueryParametersArePercentDecoded) {
  RunningServer server;
  TestClient client(server.port());
  const auto response = client.get("/echo?format=kitti&name=robot%2001+left&empty");
  ASSERT_EQ(response.result_int(), 200u);
  const nlohmann::json body = body_json(response);
  EXPECT_EQ(body["method"], "GET");
  EXPECT_EQ(body["path"], "/echo");
  EXPECT_EQ(body["target"], "/echo?format=kitti&name=robot%2001+left&empty");
  EXPECT_EQ(body["query"],
            nlohmann::json({{"format", "kitti"}, {"name", "robot 01 left"}, {"empty", ""}}));
}

TEST(HttpServer, MalformedPercentEncodingGives400) {
  RunningServer server;
  TestClient client(server.port());
  expect_json_error(client.get("/echo?name=%zz"), 400);
  // A bad target is the client's mistake in a well-formed message: the connection stays open.
  EXPECT_EQ(client.get("/healthz").result_int(), 200u);
}

TEST(HttpServer, UnknownPathGives404JsonError) {
  RunningServer server;
  TestClient client(server.port());
  const auto response = client.get("/no/such/route");
  expect_json_error(response, 404);
  EXPECT_THAT(body_json(response)["error"]["message"].get<std::string>(),
              HasSubstr("/no/such/route"));
}

TEST(HttpServer, PostToGetRouteGives405WithAllow) {
  RunningServer server;
  TestClient client(server.port());
  client.send(http::verb::post, "/healthz");
  const auto response = client.receive();
  expect_json_error(response, 405);
  EXPECT_EQ(response[http::field::allow], "GET, HEAD");
  // Unknown paths stay 404 whatever the method.
  client.send(http::verb::delete_, "/nowhere");
  expect_json_error(client.receive(), 404);
}

TEST(HttpServer, HeadAnswersLikeGetWithoutBody) {
  RunningServer server;
  TestClient client(server.port());
  const auto get = client.get("/metrics");
  client.send(http::verb::head, "/metrics");
  const auto head = client.receive(/*head=*/true);
  EXPECT_EQ(head.result_int(), 200u);
  EXPECT_EQ(head[http::field::content_type], "text/plain; version=0.0.4");
  EXPECT_EQ(head[http::field::content_length], std::to_string(get.body().size()));
  EXPECT_TRUE(head.body().empty());
  // Had the server sent a body after the HEAD response, this response would not parse.
  const auto after = client.get("/healthz");
  EXPECT_EQ(after.result_int(), 200u);
  EXPECT_EQ(body_json(after), nlohmann::json({{"ok", true}}));
}

TEST(HttpServer, OversizedBodyGives413AndCloses) {
  ServerOptions options;
  options.max_request_bytes = 1024;
  RunningServer server(options);
  {
    TestClient client(server.port());
    client.send_raw("GET /healthz HTTP/1.1\r\nHost: x\r\nContent-Length: 20000\r\n\r\n" +
                    std::string(20000, 'x'));
    const auto response = client.receive();
    expect_json_error(response, 413);
    EXPECT_FALSE(response.keep_alive());
    EXPECT_TRUE(client.server_closes());
  }
  {
    // Header and body each under the limit, together over it.
    TestClient client(server.port());
    client.send_raw("GET /healthz HTTP/1.1\r\nHost: x\r\nX-Padding: " + std::string(600, 'p') +
                    "\r\nContent-Length: 600\r\n\r\n" + std::string(600, 'x'));
    expect_json_error(client.receive(), 413);
  }
  expect_healthy(server.port());
  EXPECT_EQ(server.counters().requests_rejected, 2u);
}

TEST(HttpServer, OversizedHeaderGives431AndCloses) {
  ServerOptions options;
  options.max_request_bytes = 1024;
  RunningServer server(options);
  {
    TestClient client(server.port());
    client.send_raw("GET /healthz HTTP/1.1\r\nHost: x\r\nX-Padding: " + std::string(4000, 'p') +
                    "\r\n\r\n");
    const auto response = client.receive();
    expect_json_error(response, 431);
    EXPECT_TRUE(client.server_closes());
  }
  expect_healthy(server.port());
}

TEST(HttpServer, GarbageBytesGive400AndClose) {
  RunningServer server;
  {
    TestClient client(server.port());
    client.send_raw("\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03 not http\r\n\r\n");
    const auto response = client.receive();
    expect_json_error(response, 400);
    EXPECT_FALSE(response.keep_alive());
    EXPECT_TRUE(client.server_closes());
  }
  {
    TestClient client(server.port());
    client.send_raw("GET /healthz HTTP/1.1\r\nHost: x\r\nBad Header Line\r\n\r\n");
    expect_json_error(client.receive(), 400);
  }
  expect_healthy(server.port());
}

TEST(HttpServer, HttpVersionsOtherThan1xGive400) {
  RunningServer server;
  TestClient client(server.port());
  client.send_raw("GET /healthz HTTP/2.0\r\nHost: x\r\n\r\n");
  const auto response = client.receive();
  expect_json_error(response, 400);
  EXPECT_THAT(body_json(response)["error"]["message"].get<std::string>(), HasSubstr("version"));
  EXPECT_TRUE(client.server_closes());
}

TEST(HttpServer, ThrowingHandlerGives500AndServerKeepsRunning) {
  RunningServer server;
  TestClient client(server.port());
  const auto response = client.get("/throw");
  expect_json_error(response, 500);
  // The exception text stays in the log, not in the answer.
  EXPECT_THAT(response.body(), ::testing::Not(HasSubstr("deliberate")));
  EXPECT_EQ(client.get("/healthz").result_int(), 200u);
  expect_healthy(server.port());
}

TEST(HttpServer, InvalidHandlerStatusGives500) {
  RunningServer server(ServerOptions{}, [](HttpServer& http_server) {
    http_server.get("/bad", [](const Request&) { return Response{42, "text/plain", "", {}}; });
  });
  TestClient client(server.port());
  expect_json_error(client.get("/bad"), 500);
}

TEST(HttpServer, KeepAliveServesTwoRequestsOnOneConnection) {
  RunningServer server;
  TestClient client(server.port());
  const auto first = client.get("/healthz");
  EXPECT_EQ(first.result_int(), 200u);
  EXPECT_TRUE(first.keep_alive());
  const auto second = client.get("/echo?n=2");
  EXPECT_EQ(second.result_int(), 200u);
  EXPECT_EQ(body_json(second)["query"]["n"], "2");
  EXPECT_EQ(server.counters().connections_accepted, 1u);
  EXPECT_EQ(server.counters().requests, 2u);
}

TEST(HttpServer, ConnectionCloseIsHonoured) {
  RunningServer server;
  TestClient client(server.port());
  client.send(http::verb::get, "/healthz", /*keep_alive=*/false);
  const auto response = client.receive();
  EXPECT_EQ(response.result_int(), 200u);
  EXPECT_FALSE(response.keep_alive());
  EXPECT_TRUE(client.server_closes());
}

TEST(HttpServer, SilentAndSlowClientsAreClosedAfterTimeoutWhileOthersAreServed) {
  ServerOptions options;
  options.request_timeout = 200ms;
  RunningServer server(options);
  const auto connected = std::chrono::steady_clock::now();
  TestClient silent(server.port());
  TestClient slow(server.port());
  slow.send_raw("GET /healthz HTTP/1.1\r\n");  // and never the rest

  expect_healthy(server.port());

  EXPECT_TRUE(silent.server_closes());
  const auto elapsed = std::chrono::steady_clock::now() - connected;
  EXPECT_GE(elapsed, 200ms);
  EXPECT_LT(elapsed, kClientDeadline);
  // Both connections started their 200 ms at about the same time.
  EXPECT_TRUE(slow.server_closes(300ms));
  server.stop();  // the server counts a timeout after closing the socket
  EXPECT_EQ(server.counters().connections_timed_out, 2u);
}

TEST(HttpServer, IdleKeepAliveConnectionIsClosedAfterTimeout) {
  ServerOptions options;
  options.request_timeout = 200ms;
  RunningServer server(options);
  TestClient client(server.port());
  EXPECT_EQ(client.get("/healthz").result_int(), 200u);
  EXPECT_TRUE(client.server_closes());
}

TEST(HttpServer, ConnectionsOverTheLimitGet503) {
  ServerOptions options;
  options.max_connections = 1;
  RunningServer server(options);
  TestClient first(server.port());
  EXPECT_EQ(first.get("/healthz").result_int(), 200u);  // the first connection is being served

  TestClient second(server.port());
  second.send(http::verb::get, "/healthz");
  expect_json_error(second.receive(), 503);
  EXPECT_TRUE(second.server_closes());

  EXPECT_EQ(first.get("/healthz").result_int(), 200u);
  const ServerCounters counters = server.counters();
  EXPECT_EQ(counters.connections_rejected, 1u);
  EXPECT_EQ(counters.connections_active, 1u);
}

TEST(HttpServer, OneClientCannotHoldEverySlot) {
  ServerOptions options;
  options.max_connections = 8;
  options.max_connections_per_client = 2;
  RunningServer server(options);
  TestClient first(server.port());
  TestClient second(server.port());
  EXPECT_EQ(first.get("/healthz").result_int(), 200u);
  EXPECT_EQ(second.get("/healthz").result_int(), 200u);
  TestClient third(server.port());  // same client address (loopback): over its share
  third.send(http::verb::get, "/healthz");
  expect_json_error(third.receive(), 503);
  EXPECT_EQ(server.counters().connections_rejected, 1u);
}

TEST(HttpServer, CountersCountRequestsAndResponseClasses) {
  RunningServer server;
  TestClient client(server.port());
  client.get("/healthz");
  client.get("/healthz");
  client.get("/missing");
  client.get("/throw");
  const ServerCounters counters = server.counters();
  EXPECT_EQ(counters.requests, 4u);
  EXPECT_EQ(counters.responses_2xx, 2u);
  EXPECT_EQ(counters.responses_3xx, 0u);
  EXPECT_EQ(counters.responses_4xx, 1u);
  EXPECT_EQ(counters.responses_5xx, 1u);
  EXPECT_EQ(counters.connections_accepted, 1u);
  EXPECT_EQ(counters.connections_active, 1u);
}

TEST(HttpServer, StopClosesOpenConnections) {
  asio::io_context io_context;
  HttpServer server(io_context, ServerOptions{"127.0.0.1", 0});
  server.get("/healthz", [](const Request&) { return json_response(200, {{"ok", true}}); });
  server.start();
  std::promise<void> stopped;
  std::thread thread([&] {
    io_context.run();
    stopped.set_value();
  });
  TestClient client(server.port());
  EXPECT_EQ(client.get("/healthz").result_int(), 200u);

  asio::post(io_context, [&] { server.stop(); });
  EXPECT_TRUE(client.server_closes());
  const bool run_returned = stopped.get_future().wait_for(1s) == std::future_status::ready;
  EXPECT_TRUE(run_returned) << "io_context.run() still busy after stop()";
  if (!run_returned) io_context.stop();
  thread.join();
}

TEST(HttpServer, PortInUseMakesStartThrow) {
  RunningServer first;
  asio::io_context io_context;
  HttpServer second(io_context, ServerOptions{"127.0.0.1", first.port()});
  try {
    second.start();
    ADD_FAILURE() << "start() on a port in use did not throw";
  } catch (const std::runtime_error& error) {
    EXPECT_THAT(error.what(), HasSubstr("127.0.0.1:" + std::to_string(first.port())));
    EXPECT_THAT(error.what(), HasSubstr("in use"));
  }
  expect_healthy(first.port());
}

}  // namespace
}  // namespace concord::web

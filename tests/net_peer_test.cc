// PeerNetwork and FrameListener over loopback: handshake, messages both ways, tie-break of
// simultaneous dials, heartbeat timeout, reconnect, Goodbye, malformed input from raw sockets,
// queue overflow, discovery. Every wait is on a condition with a deadline; no test sleeps.
#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <boost/asio.hpp>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <optional>
#include <set>
#include <thread>

#include "concord/net/frame_listener.h"
#include "concord/net/identity.h"
#include "concord/net/peer_network.h"
#include "concord/net/reconnect_backoff.h"
#include "concord/net/secure_channel.h"
#include "concord/v1/concord.pb.h"

namespace concord::net {
namespace {

namespace asio = boost::asio;
using tcp = asio::ip::tcp;
using Clock = std::chrono::steady_clock;
using namespace std::chrono_literals;

/// Upper bound of every wait; the conditions normally hold within a few hundred ms.
constexpr auto kDeadline = 5s;

/// The key of the test team.
std::shared_ptr<const TeamKey> test_key() {
  static const auto key = std::make_shared<const TeamKey>(TeamKey::from_seed_for_tests("test"));
  return key;
}

/// Short timings so that every test takes well under 2 s.
PeerNetworkOptions test_options(int robot) {
  PeerNetworkOptions options;
  options.team_key = test_key();
  options.team = "test";
  options.robot_id = robot;
  options.listen_address = "127.0.0.1";
  options.heartbeat_interval = 20ms;
  options.heartbeat_timeout = 400ms;
  options.hello_timeout = 400ms;
  options.reconnect_initial = 20ms;
  options.reconnect_max = 100ms;
  options.stop_linger = 200ms;
  options.capabilities = {"consensus.lockstep"};
  return options;
}

std::string loopback(std::uint16_t port) { return "127.0.0.1:" + std::to_string(port); }

/// Waits until `predicate` holds or the deadline passes. Waiters are woken by every callback of
/// the nodes (and re-check at least every 10 ms for counters that change without a callback).
class Waiter {
 public:
  void notify() {
    { std::lock_guard lock(mutex_); }
    condition_.notify_all();
  }
  bool until(const std::function<bool()>& predicate,
             std::chrono::milliseconds timeout = kDeadline) {
    const auto deadline = Clock::now() + timeout;
    std::unique_lock lock(mutex_);
    while (!predicate()) {
      if (Clock::now() >= deadline) return false;
      condition_.wait_for(lock, 10ms);
    }
    return true;
  }

 private:
  std::mutex mutex_;
  std::condition_variable condition_;
};

/// One daemon's network on its own io_context thread, recording what its callbacks saw.
class Node {
 public:
  Node(PeerNetworkOptions options, Waiter& waiter)
      : waiter_(waiter), network_(std::make_unique<PeerNetwork>(io_, std::move(options))) {
    network_->set_peer_handler([this](int robot, bool up) {
      {
        std::lock_guard lock(mutex_);
        peer_events_.emplace_back(robot, up);
      }
      waiter_.notify();
    });
    network_->set_message_handler([this](int robot, const v1::Envelope& envelope) {
      {
        std::lock_guard lock(mutex_);
        messages_.emplace_back(robot, envelope);
      }
      if (on_message) on_message(robot, envelope);
      waiter_.notify();
    });
  }

  ~Node() {
    if (thread_.joinable()) stop();
    network_.reset();  // before io_: the network posts to it
  }

  void start() {
    network_->start();
    thread_ = std::thread([this] {
      io_.run();
      io_returned_ = true;
      waiter_.notify();
    });
  }

  /// Graceful stop; true if the io_context ran out of work within the deadline.
  bool stop(const std::string& reason = "test over") {
    network_->stop(reason);
    const bool ran_out = waiter_.until([this] { return io_returned_.load(); });
    if (!ran_out) io_.stop();
    thread_.join();
    return ran_out;
  }

  /// Like a hung process: the io_context stops, sockets stay open and silent.
  void freeze() {
    io_.stop();
    thread_.join();
  }

  PeerNetwork& network() { return *network_; }
  std::uint16_t port() const { return network_->listen_port(); }
  NetworkCounters totals() const { return network_->totals(); }
  /// Up according to the peer callback (which runs after the statistics are updated, so the
  /// snapshots agree once this holds).
  bool is_up(int robot) const {
    std::lock_guard lock(mutex_);
    for (auto event = peer_events_.rbegin(); event != peer_events_.rend(); ++event)
      if (event->first == robot) return event->second;
    return false;
  }
  bool is_live(int robot) const {
    const std::vector<int> live = network_->live_peers();
    return std::find(live.begin(), live.end(), robot) != live.end();
  }
  std::optional<PeerStats> stats(int robot) const {
    for (const PeerStats& stats : network_->peers())
      if (stats.robot == robot) return stats;
    return std::nullopt;
  }
  std::vector<std::pair<int, bool>> peer_events() const {
    std::lock_guard lock(mutex_);
    return peer_events_;
  }
  std::vector<std::pair<int, v1::Envelope>> messages() const {
    std::lock_guard lock(mutex_);
    return messages_;
  }

  /// Called on the io thread for every delivered message (set before start()).
  std::function<void(int, const v1::Envelope&)> on_message;

 private:
  Waiter& waiter_;
  asio::io_context io_;
  mutable std::mutex mutex_;
  std::vector<std::pair<int, bool>> peer_events_;
  std::vector<std::pair<int, v1::Envelope>> messages_;
  std::unique_ptr<PeerNetwork> network_;
  std::thread thread_;
  std::atomic<bool> io_returned_{false};
};

/// A hand-driven TCP client for malformed and misbehaving peers.
class RawClient {
 public:
  explicit RawClient(std::uint16_t port) : socket_(io_) {
    socket_.connect(tcp::endpoint(asio::ip::make_address("127.0.0.1"), port));
  }
  void write(const std::string& bytes) { asio::write(socket_, asio::buffer(bytes)); }
  void send(const v1::Envelope& envelope) { write(frame_of(envelope)); }
  /// send() that ignores a connection already closed by the other side.
  void try_send(const v1::Envelope& envelope) {
    boost::system::error_code ignored;
    asio::write(socket_, asio::buffer(frame_of(envelope)), ignored);
  }

  /// Runs the channel handshake as the dialer with `key`; true if the other side accepted it
  /// (then send() seals and read() opens). False if the connection closed or the proof failed.
  bool secure(const TeamKey& key) {
    channel_ = std::make_unique<SecureChannel>(key, SecureChannel::Role::kInitiator);
    std::string hello;
    append_raw_frame(channel_->hello(), hello);
    write(hello);
    std::string error;
    const auto peer_hello = read_payload();
    if (!peer_hello) return false;
    const auto proof = channel_->accept_hello(*peer_hello, error);
    if (!proof) return false;
    std::string frame;
    append_raw_frame(*proof, frame);
    boost::system::error_code ignored;
    asio::write(socket_, asio::buffer(frame), ignored);
    const auto peer_proof = read_payload();
    return peer_proof && channel_->accept_proof(*peer_proof, error);
  }

  /// Reads until `done()` holds, the peer closes or the deadline passes; true if `done()` held
  /// or (when `done` is empty) the peer closed.
  bool read(const std::function<bool()>& done = {}, std::chrono::milliseconds timeout = kDeadline) {
    bool finished = false;
    std::function<void()> read_more = [&] {
      socket_.async_read_some(asio::buffer(chunk_),
                              [&](const boost::system::error_code& error, std::size_t bytes) {
                                if (error) {
                                  closed_ = true;
                                  finished = !done;
                                  return;
                                }
                                decoder_.feed(std::string_view(chunk_.data(), bytes));
                                std::string payload;
                                while (decoder_.next_payload(payload) ==
                                       FrameDecoder::Status::kFrame) {
                                  std::string error;
                                  std::optional<std::string> plain =
                                      channel_ ? channel_->open(payload, error) : payload;
                                  v1::Envelope envelope;
                                  if (plain &&
                                      parse_envelope(*plain, std::nullopt, envelope).kind ==
                                          FrameErrorKind::kNone)
                                    frames_.push_back(envelope);
                                }
                                if (done && done()) {
                                  finished = true;
                                  return;
                                }
                                read_more();
                              });
    };
    read_more();
    io_.restart();
    io_.run_for(timeout);
    if (!io_.stopped()) {  // deadline: cancel the pending read
      socket_.cancel();
      io_.restart();
      io_.run();
    }
    return finished;
  }
  bool read_until_closed() { return read(); }

  /// Every complete frame received so far.
  const std::vector<v1::Envelope>& frames() const { return frames_; }
  std::size_t count(v1::Envelope::BodyCase body) const {
    std::size_t n = 0;
    for (const v1::Envelope& envelope : frames()) n += envelope.body_case() == body;
    return n;
  }
  bool closed() const { return closed_; }
  /// The channel binding of this connection (after secure()).
  std::string binding() const { return channel_->binding(); }

 private:
  std::string frame_of(const v1::Envelope& envelope) {
    if (!channel_ || !channel_->established()) return encode_frame(envelope);
    std::string frame;
    append_raw_frame(channel_->seal(envelope.SerializeAsString()), frame);
    return frame;
  }

  /// Blocking read of the next frame's payload (handshake), within the deadline.
  std::optional<std::string> read_payload() {
    std::string payload;
    const auto deadline = Clock::now() + kDeadline;
    while (decoder_.next_payload(payload) != FrameDecoder::Status::kFrame) {
      if (decoder_.failed() || Clock::now() > deadline) return std::nullopt;
      bool done = false;
      boost::system::error_code read_error;
      std::size_t received = 0;
      socket_.async_read_some(asio::buffer(chunk_),
                              [&](const boost::system::error_code& error, std::size_t bytes) {
                                read_error = error;
                                received = bytes;
                                done = true;
                              });
      io_.restart();
      io_.run_for(kDeadline);
      if (!done) {
        socket_.cancel();
        io_.restart();
        io_.run();
        return std::nullopt;
      }
      if (read_error) {
        closed_ = true;
        return std::nullopt;
      }
      decoder_.feed(std::string_view(chunk_.data(), received));
    }
    return payload;
  }

  std::unique_ptr<SecureChannel> channel_;
  asio::io_context io_;
  tcp::socket socket_;
  std::array<char, 64 * 1024> chunk_{};
  FrameDecoder decoder_{FrameDecoderOptions{kDefaultMaxFrameBytes, std::nullopt}};
  std::vector<v1::Envelope> frames_;
  bool closed_ = false;
};

v1::Envelope raw_hello(int robot, const std::string& team = "test",
                       std::uint32_t version = kProtocolVersion) {
  v1::Envelope envelope;
  envelope.set_protocol_version(version);
  envelope.set_team(team);
  envelope.set_sender(static_cast<std::uint32_t>(robot));
  envelope.mutable_hello()->set_robot_id(static_cast<std::uint32_t>(robot));
  envelope.mutable_hello()->set_listen_address("127.0.0.1");
  envelope.mutable_hello()->set_listen_port(1);
  envelope.mutable_hello()->set_instance(12345);
  return envelope;
}

v1::Envelope marginal(std::uint64_t round, std::vector<std::int64_t> ids, double value) {
  v1::Envelope envelope;
  envelope.set_round(round);
  v1::Marginal& m = *envelope.mutable_marginal();
  m.set_round(round);
  for (std::int64_t id : ids) {
    m.add_landmark_ids(id);
    for (int k = 0; k < 3; ++k) m.add_mean(value + k);
  }
  v1::CovarianceBlock& block = *m.add_blocks();
  block.set_landmarks(static_cast<std::uint32_t>(ids.size()));
  const std::size_t n = 3 * ids.size();
  for (std::size_t i = 0; i < n * (n + 1) / 2; ++i) block.add_packed_upper(0.5);
  m.set_degree(1);
  return envelope;
}

/// Two nodes; b dials a.
struct Pair {
  explicit Pair(int robot_a = 1, int robot_b = 2)
      : a(std::make_unique<Node>(test_options(robot_a), waiter)) {
    a->start();
    PeerNetworkOptions options = test_options(robot_b);
    options.peers = {loopback(a->port())};
    b = std::make_unique<Node>(options, waiter);
  }
  bool connect() {
    b->start();
    const int robot_a = a->network().options().robot_id;
    const int robot_b = b->network().options().robot_id;
    return waiter.until([&] { return a->is_up(robot_b) && b->is_up(robot_a); });
  }
  Waiter waiter;
  std::unique_ptr<Node> a;
  std::unique_ptr<Node> b;
};

// ---------------------------------------------------------------------------------------------
// Pure helpers

TEST(HostPort, ParsesAndPrints) {
  EXPECT_EQ(parse_host_port("127.0.0.1:7000"), (HostPort{"127.0.0.1", 7000}));
  EXPECT_EQ(parse_host_port("robot2.local:1"), (HostPort{"robot2.local", 1}));
  EXPECT_EQ(parse_host_port("[::1]:65535"), (HostPort{"::1", 65535}));
  EXPECT_EQ((HostPort{"::1", 80}).to_string(), "[::1]:80");
  EXPECT_EQ((HostPort{"10.0.0.2", 80}).to_string(), "10.0.0.2:80");
  for (const char* bad : {"", "host", "host:", ":80", "host:0", "host:65536", "host:8x", "::1:80",
                          "[::1]80", "[::1]:"})
    EXPECT_FALSE(parse_host_port(bad)) << bad;
}

TEST(ReconnectBackoff, DoublesWithinJitterUpToTheCapAndResets) {
  ReconnectBackoff backoff({100ms, 1000ms, 2.0, 0.2}, 7);
  const std::vector<double> expected = {100, 200, 400, 800, 1000, 1000, 1000};
  for (double base : expected) {
    const auto delay = backoff.next().count();
    EXPECT_GE(delay, base * 0.8 - 1) << base;
    EXPECT_LE(delay, base * 1.2 + 1) << base;
  }
  backoff.reset();
  EXPECT_EQ(backoff.current(), 100ms);
  // Jitter actually spreads the delays.
  std::set<long> distinct;
  for (int i = 0; i < 20; ++i) {
    backoff.reset();
    distinct.insert(static_cast<long>(backoff.next().count()));
  }
  EXPECT_GT(distinct.size(), 5u);
}

TEST(PeerNetworkOptions, ValidateNamesTheFieldAndValue) {
  EXPECT_TRUE(test_options(1).validate().empty());
  PeerNetworkOptions options = test_options(-1);
  options.team = "";
  options.listen_address = "nowhere";
  options.peers = {"127.0.0.1:7000", "bad"};
  options.heartbeat_timeout = 10ms;
  options.send_queue_limit = 0;
  options.reconnect_jitter = 1.5;
  const std::vector<std::string> problems = options.validate();
  std::string all;
  for (const std::string& problem : problems) all += problem + "\n";
  EXPECT_EQ(problems.size(), 7u) << all;
  for (const char* needle : {"team:", "robot_id: -1", "listen_address: 'nowhere'", "peers: 'bad'",
                             "heartbeat_timeout: 10 ms", "send_queue_limit", "reconnect_jitter"})
    EXPECT_NE(all.find(needle), std::string::npos) << needle << " in\n" << all;
  asio::io_context io;
  PeerNetwork network(io, options);
  EXPECT_THROW(network.start(), std::invalid_argument);
}

TEST(PeerNetwork, StartFailsClearlyWhenThePortIsTaken) {
  asio::io_context io;
  PeerNetwork first(io, test_options(1));
  first.start();
  PeerNetworkOptions options = test_options(2);
  options.listen_port = first.listen_port();
  PeerNetwork second(io, options);
  try {
    second.start();
    FAIL() << "bound a port already in use";
  } catch (const std::runtime_error& error) {
    EXPECT_NE(std::string(error.what()).find(std::to_string(first.listen_port())),
              std::string::npos)
        << error.what();
  }
  first.stop("test over");
  io.run_for(kDeadline);
  EXPECT_TRUE(io.stopped());  // ran out of work
}

// ---------------------------------------------------------------------------------------------
// Two daemons

TEST(PeerNetwork, HandshakeBringsBothSidesUpWithTheRightIds) {
  Pair pair(4, 9);
  ASSERT_TRUE(pair.connect());
  EXPECT_EQ(pair.a->network().live_peers(), std::vector<int>{9});
  EXPECT_EQ(pair.b->network().live_peers(), std::vector<int>{4});
  EXPECT_EQ(pair.a->peer_events(), (std::vector<std::pair<int, bool>>{{9, true}}));
  EXPECT_EQ(pair.b->peer_events(), (std::vector<std::pair<int, bool>>{{4, true}}));
  const PeerStats b_at_a = *pair.a->stats(9);
  EXPECT_TRUE(b_at_a.up);
  EXPECT_EQ(b_at_a.capabilities, std::vector<std::string>{"consensus.lockstep"});
  EXPECT_NE(b_at_a.instance, 0u);
  EXPECT_EQ(b_at_a.reconnects, 0u);
  EXPECT_EQ(b_at_a.dial_address, loopback(pair.b->port()));  // learned from its Hello
  EXPECT_EQ(pair.b->stats(4)->dial_address, loopback(pair.a->port()));
  EXPECT_EQ(pair.a->totals().connections_accepted, 1u);
  EXPECT_EQ(pair.b->totals().connections_dialed, 1u);
  EXPECT_EQ(pair.a->totals().handshakes_completed, 1u);
  EXPECT_EQ(pair.b->totals().handshakes_completed, 1u);
  EXPECT_EQ(pair.a->totals().open_connections, 1u);
}

TEST(PeerNetwork, MarginalRoundTripFillsHeadersAndMovesCounters) {
  Pair pair(1, 2);
  // b answers every Marginal with one of its own for the same round.
  pair.b->on_message = [&](int robot, const v1::Envelope& envelope) {
    if (envelope.has_marginal())
      pair.b->network().send(robot, marginal(envelope.round(), {7, 8}, 20.0));
  };
  ASSERT_TRUE(pair.connect());
  ASSERT_TRUE(pair.a->network().send(2, marginal(5, {3}, 10.0)));
  ASSERT_TRUE(pair.waiter.until([&] { return !pair.a->messages().empty(); }));

  const auto at_b = pair.b->messages();
  ASSERT_EQ(at_b.size(), 1u);
  EXPECT_EQ(at_b[0].first, 1);
  const v1::Envelope& sent = at_b[0].second;
  EXPECT_EQ(sent.protocol_version(), kProtocolVersion);
  EXPECT_EQ(sent.team(), "test");
  EXPECT_EQ(sent.sender(), 1u);
  EXPECT_GE(sent.seq(), 2u);  // the Hello was seq 1 on this connection
  EXPECT_EQ(sent.round(), 5u);
  ASSERT_EQ(sent.marginal().landmark_ids_size(), 1);
  EXPECT_EQ(sent.marginal().landmark_ids(0), 3);
  EXPECT_EQ(sent.marginal().mean(2), 12.0);
  EXPECT_EQ(sent.marginal().blocks(0).packed_upper_size(), 6);

  const auto at_a = pair.a->messages();
  ASSERT_EQ(at_a.size(), 1u);
  EXPECT_EQ(at_a[0].first, 2);
  EXPECT_EQ(at_a[0].second.sender(), 2u);
  EXPECT_EQ(at_a[0].second.round(), 5u);
  EXPECT_EQ(at_a[0].second.marginal().landmark_ids_size(), 2);
  EXPECT_EQ(at_a[0].second.marginal().mean(3), 20.0);

  // Heartbeats measure a round trip (a few ms at most on loopback).
  ASSERT_TRUE(pair.waiter.until([&] { return pair.a->stats(2)->rtt_samples >= 2; }));
  const PeerStats stats = *pair.a->stats(2);
  EXPECT_GT(stats.rtt_last.count(), 0);
  EXPECT_LT(stats.rtt_mean, 1s);
  EXPECT_GT(stats.bytes_in, 0u);
  EXPECT_GT(stats.bytes_out, 0u);
  EXPECT_GE(stats.messages_in, 2u);  // Hello, Marginal, heartbeats
  EXPECT_GE(stats.messages_out, 2u);
  EXPECT_EQ(stats.drops, 0u);
  EXPECT_GE(stats.last_seen, stats.connected_since);
  const NetworkCounters totals = pair.a->totals();
  EXPECT_GE(totals.bytes_in, stats.bytes_in);
  EXPECT_GE(totals.messages_out, stats.messages_out);
  EXPECT_EQ(totals.send_drops, 0u);
}

TEST(PeerNetwork, SendToAnUnknownPeerIsACountedDrop) {
  Pair pair;
  ASSERT_TRUE(pair.connect());
  EXPECT_FALSE(pair.a->network().send(42, marginal(1, {1}, 0.0)));
  EXPECT_EQ(pair.a->totals().send_drops, 1u);
  EXPECT_EQ(pair.a->network().broadcast(marginal(1, {1}, 0.0)), 1);
  ASSERT_TRUE(pair.waiter.until([&] { return pair.b->messages().size() == 1; }));
}

TEST(PeerNetwork, SimultaneousDialsLeaveExactlyOneConnection) {
  // Both sides dial each other at once, several times over to exercise the race both ways.
  for (int attempt = 0; attempt < 4; ++attempt) {
    SCOPED_TRACE(attempt);
    Waiter waiter;
    Node a(test_options(1 + attempt % 2), waiter);  // the lower id alternates between a and b
    Node b(test_options(2 - attempt % 2), waiter);
    a.start();
    b.start();
    a.network().add_peer({"127.0.0.1", b.port()});
    b.network().add_peer({"127.0.0.1", a.port()});
    const int id_a = 1 + attempt % 2, id_b = 2 - attempt % 2;
    ASSERT_TRUE(waiter.until([&] {
      return a.is_up(id_b) && b.is_up(id_a) && a.totals().open_connections == 1 &&
             b.totals().open_connections == 1;
    })) << "open connections "
        << a.totals().open_connections << " / " << b.totals().open_connections;
    EXPECT_EQ(a.totals().duplicates_closed + b.totals().duplicates_closed, 2u);
    // The survivor is the connection the lower id dialed; it carries messages both ways.
    Node& lower = id_a < id_b ? a : b;
    EXPECT_EQ(lower.totals().connections_dialed, 1u);
    ASSERT_TRUE(a.network().send(id_b, marginal(1, {1}, 1.0)));
    ASSERT_TRUE(b.network().send(id_a, marginal(1, {2}, 2.0)));
    ASSERT_TRUE(waiter.until([&] { return a.messages().size() == 1 && b.messages().size() == 1; }));
    EXPECT_EQ(a.totals().open_connections, 1u);
  }
}

TEST(PeerNetwork, HeartbeatTimeoutMarksASilentPeerDown) {
  Pair pair;
  ASSERT_TRUE(pair.connect());
  const auto frozen_at = Clock::now();
  pair.b->freeze();  // its sockets stay open but nothing is read or written any more
  ASSERT_TRUE(pair.waiter.until([&] { return !pair.a->is_up(2); }));
  const auto detected_after = Clock::now() - frozen_at;
  EXPECT_GE(detected_after, 400ms - 50ms);  // not before the timeout (minus one tick)
  EXPECT_EQ(pair.a->totals().heartbeat_timeouts, 1u);
  EXPECT_EQ(pair.a->peer_events(), (std::vector<std::pair<int, bool>>{{2, true}, {2, false}}));
  EXPECT_FALSE(pair.a->network().send(2, marginal(1, {1}, 0.0)));
  EXPECT_GE(pair.a->stats(2)->drops, 1u);
}

TEST(PeerNetwork, RawPeerThatHandshakesThenGoesSilentTimesOut) {
  Waiter waiter;
  Node a(test_options(1), waiter);
  a.start();
  RawClient raw(a.port());
  ASSERT_TRUE(raw.secure(*test_key()));
  raw.send(raw_hello(7));
  ASSERT_TRUE(waiter.until([&] { return a.is_up(7); }));
  // It receives a's Hello and then heartbeats, answers none, and is closed for silence.
  EXPECT_TRUE(raw.read_until_closed());
  EXPECT_TRUE(waiter.until([&] { return !a.is_up(7); }));
  EXPECT_EQ(a.totals().heartbeat_timeouts, 1u);
  const std::vector<v1::Envelope> frames = raw.frames();
  ASSERT_FALSE(frames.empty());
  EXPECT_TRUE(frames.front().has_hello());
  EXPECT_EQ(frames.front().hello().robot_id(), 1u);
  EXPECT_EQ(frames.front().hello().listen_port(), a.port());
  EXPECT_EQ(frames.front().seq(), 1u);
  EXPECT_GE(raw.count(v1::Envelope::kHeartbeat), 5u);
}

TEST(PeerNetwork, ReconnectsAfterThePeerRestartsOnTheSamePort) {
  Waiter waiter;
  auto b = std::make_unique<Node>(test_options(2), waiter);
  b->start();
  const std::uint16_t port = b->port();
  PeerNetworkOptions options = test_options(1);
  options.peers = {loopback(port)};
  Node a(options, waiter);
  a.start();
  ASSERT_TRUE(waiter.until([&] { return a.is_up(2); }));
  const std::uint64_t old_instance = a.stats(2)->instance;

  b->freeze();
  b.reset();  // closes its sockets without a Goodbye, like a crashed process
  ASSERT_TRUE(waiter.until([&] { return !a.is_up(2); }));

  options = test_options(2);
  options.listen_port = port;
  b = std::make_unique<Node>(options, waiter);  // no static peers: a has to redial it
  b->start();
  ASSERT_TRUE(waiter.until([&] { return a.is_up(2) && b->is_up(1); }));
  const PeerStats stats = *a.stats(2);
  EXPECT_EQ(stats.reconnects, 1u);
  EXPECT_NE(stats.instance, old_instance);
  EXPECT_EQ(a.peer_events(), (std::vector<std::pair<int, bool>>{{2, true}, {2, false}, {2, true}}));
  EXPECT_GE(a.totals().connections_dialed, 2u);
  ASSERT_TRUE(a.network().send(2, marginal(9, {1}, 0.0)));
  ASSERT_TRUE(waiter.until([&] { return b->messages().size() == 1; }));
}

TEST(PeerNetwork, GoodbyeMarksDownWithoutRedialUntilThePeerComesBack) {
  Waiter waiter;
  auto b = std::make_unique<Node>(test_options(2), waiter);
  Node c(test_options(3), waiter);
  b->start();
  c.start();
  const std::uint16_t b_port = b->port();
  PeerNetworkOptions options = test_options(1);
  options.peers = {loopback(b_port), loopback(c.port())};
  Node a(options, waiter);
  a.start();
  ASSERT_TRUE(waiter.until([&] { return a.is_up(2) && a.is_up(3); }));

  ASSERT_TRUE(b->stop("maintenance"));  // Goodbye, then its io_context runs out of work
  ASSERT_TRUE(waiter.until([&] { return !a.is_up(2); }));
  EXPECT_EQ(a.stats(2)->last_goodbye, "maintenance");
  const auto messages = a.messages();
  ASSERT_EQ(messages.size(), 1u);  // the Goodbye is forwarded
  EXPECT_EQ(messages[0].first, 2);
  EXPECT_EQ(messages[0].second.goodbye().reason(), "maintenance");

  // a must not redial b: wait for ten more heartbeats from c (10 x 20 ms, i.e. several
  // reconnect delays) and check that a dialed nothing in the meantime.
  const NetworkCounters before = a.totals();
  const std::uint64_t samples = a.stats(3)->rtt_samples;
  ASSERT_TRUE(waiter.until([&] { return a.stats(3)->rtt_samples >= samples + 10; }));
  EXPECT_EQ(a.totals().connections_dialed, before.connections_dialed);
  EXPECT_EQ(a.totals().dial_failures, before.dial_failures);

  // It comes back and dials a: up again, counted as a reconnect.
  options = test_options(2);
  options.listen_port = b_port;
  options.peers = {loopback(a.port())};
  b = std::make_unique<Node>(options, waiter);
  b->start();
  ASSERT_TRUE(waiter.until([&] { return a.is_up(2); }));
  EXPECT_EQ(a.stats(2)->reconnects, 1u);
  EXPECT_EQ(a.stats(2)->last_goodbye, "maintenance");
}

TEST(PeerNetwork, StopSendsGoodbyeAndTheIoContextRunsOutOfWork) {
  Pair pair;
  ASSERT_TRUE(pair.connect());
  ASSERT_TRUE(pair.a->network().send(2, marginal(3, {1}, 0.0)));
  ASSERT_TRUE(pair.a->stop("done"));
  // b got the message queued before stop, then the Goodbye.
  ASSERT_TRUE(pair.waiter.until([&] { return !pair.b->is_up(1); }));
  const auto messages = pair.b->messages();
  ASSERT_EQ(messages.size(), 2u);
  EXPECT_TRUE(messages[0].second.has_marginal());
  EXPECT_EQ(messages[1].second.goodbye().reason(), "done");
  EXPECT_EQ(pair.a->peer_events(), (std::vector<std::pair<int, bool>>{{2, true}, {2, false}}));
  EXPECT_FALSE(pair.a->network().send(2, marginal(3, {1}, 0.0)));
}

// ---------------------------------------------------------------------------------------------
// Malformed and foreign input

TEST(PeerNetwork, GarbageAndOversizedFramesCloseOnlyThatConnection) {
  Pair pair;
  ASSERT_TRUE(pair.connect());
  const std::uint16_t port = pair.a->port();

  RawClient garbage(port);  // not a channel hello: the handshake fails
  garbage.write(std::string("\x00\x00\x00\x06", 4) + std::string(6, '\xff'));
  EXPECT_TRUE(garbage.read_until_closed());
  EXPECT_EQ(pair.a->totals().rejected_unauthenticated, 1u);
  EXPECT_EQ(pair.a->totals().rejected_handshake, 1u);

  RawClient zero(port);
  zero.write(std::string(4, '\0'));
  EXPECT_TRUE(zero.read_until_closed());
  EXPECT_EQ(pair.a->totals().rejected_garbage, 1u);

  RawClient oversized(port);  // 16 MiB + 1 announced, nothing more sent
  oversized.write(std::string("\x01\x00\x00\x01", 4));
  EXPECT_TRUE(oversized.read_until_closed());
  EXPECT_EQ(pair.a->totals().rejected_oversized, 1u);

  // After a valid handshake, garbage is also a protocol error of that robot.
  RawClient handshaken(port);
  ASSERT_TRUE(handshaken.secure(*test_key()));
  handshaken.send(raw_hello(7));
  ASSERT_TRUE(pair.waiter.until([&] { return pair.a->is_up(7); }));
  // 3 bytes that are not a sealed message: authentication fails.
  handshaken.write(std::string("\x00\x00\x00\x03", 4) + std::string(3, '\xff'));
  EXPECT_TRUE(handshaken.read_until_closed());
  EXPECT_EQ(pair.a->totals().rejected_garbage, 2u);
  EXPECT_EQ(pair.a->totals().rejected_unauthenticated, 2u);
  EXPECT_EQ(pair.a->stats(7)->protocol_errors, 1u);
  EXPECT_TRUE(pair.waiter.until([&] { return !pair.a->is_up(7); }));

  // The real peer link never noticed.
  EXPECT_TRUE(pair.a->is_up(2));
  EXPECT_EQ(pair.a->peer_events().front(), (std::pair<int, bool>{2, true}));
  EXPECT_EQ(pair.a->stats(2)->reconnects, 0u);
  ASSERT_TRUE(pair.b->network().send(1, marginal(1, {4}, 4.0)));
  ASSERT_TRUE(pair.waiter.until([&] { return pair.a->messages().size() == 1; }));
  EXPECT_EQ(pair.a->totals().open_connections, 1u);
}

TEST(PeerNetwork, HelloAnnouncesTheHttpEndpointAndUnusableOnesAreIgnored) {
  Waiter waiter;
  PeerNetworkOptions options_a = test_options(1);
  options_a.http_address = "0.0.0.0";  // unspecified: the peer uses the connection's source
  options_a.http_port = 8123;
  Node a(options_a, waiter);
  a.start();
  PeerNetworkOptions options_b = test_options(2);
  options_b.peers = {loopback(a.port())};
  options_b.http_address = "127.0.0.5";
  options_b.http_port = 9000;
  Node b(options_b, waiter);
  b.start();
  ASSERT_TRUE(waiter.until([&] { return a.is_up(2) && b.is_up(1); }));
  EXPECT_EQ(b.stats(1)->http_endpoint, "127.0.0.1:8123");
  EXPECT_EQ(a.stats(2)->http_endpoint, "127.0.0.5:9000");

  // A peer's word is never a host name to resolve, nor a port out of range: no endpoint.
  struct Case {
    int robot;
    const char* address;
    std::uint32_t port;
    const char* expected;
  };
  for (const Case& c : {Case{7, "robot7.example.com", 80, ""}, Case{8, "127.0.0.8", 70000, ""},
                        Case{9, "", 8080, "127.0.0.1:8080"}, Case{10, "127.0.0.9", 0, ""}}) {
    SCOPED_TRACE(c.robot);
    RawClient raw(a.port());
    ASSERT_TRUE(raw.secure(*test_key()));
    v1::Envelope hello = raw_hello(c.robot);
    hello.mutable_hello()->set_http_address(c.address);
    hello.mutable_hello()->set_http_port(c.port);
    raw.send(hello);
    ASSERT_TRUE(waiter.until([&] { return a.is_up(c.robot); }));  // still a peer
    EXPECT_EQ(a.stats(c.robot)->http_endpoint, c.expected);
  }
}

TEST(PeerNetwork, HandshakeViolationsAreRejectedAndCounted) {
  Waiter waiter;
  Node a(test_options(1), waiter);
  a.start();
  struct Case {
    const char* what;
    v1::Envelope first;
  };
  v1::Envelope not_hello = raw_hello(7);
  not_hello.mutable_goodbye()->set_reason("hi");
  v1::Envelope mismatched = raw_hello(7);
  mismatched.set_sender(8);
  const std::vector<Case> cases = {
      {"other team", raw_hello(7, "bravo")},
      {"other protocol version", raw_hello(7, "test", 1)},
      {"our own robot id", raw_hello(1)},
      {"first message not a Hello", not_hello},
      {"Hello robot id differs from sender", mismatched},
  };
  std::uint64_t expected = 0;
  for (const Case& c : cases) {
    SCOPED_TRACE(c.what);
    RawClient raw(a.port());
    ASSERT_TRUE(raw.secure(*test_key()));
    raw.send(c.first);
    EXPECT_TRUE(raw.read_until_closed());
    EXPECT_EQ(a.totals().rejected_handshake, ++expected);
  }
  {
    SCOPED_TRACE("a plaintext Hello, without the channel");
    RawClient raw(a.port());
    raw.send(raw_hello(7));
    EXPECT_TRUE(raw.read_until_closed());
    EXPECT_EQ(a.totals().rejected_handshake, ++expected);
  }
  {
    SCOPED_TRACE("another key");
    RawClient raw(a.port());
    EXPECT_FALSE(raw.secure(TeamKey::from_seed_for_tests("intruder")));
    EXPECT_TRUE(raw.read_until_closed());
    EXPECT_EQ(a.totals().rejected_handshake, ++expected);
    EXPECT_TRUE(raw.frames().empty());  // nothing about the team was sent to it
  }
  RawClient silent(a.port());  // says nothing: closed after hello_timeout
  EXPECT_TRUE(silent.read_until_closed());
  EXPECT_EQ(a.totals().rejected_handshake, ++expected);
  EXPECT_TRUE(a.network().live_peers().empty());
  EXPECT_TRUE(a.network().peers().empty());
}

TEST(PeerNetwork, DaemonsOfDifferentTeamsNeverConnect) {
  Waiter waiter;
  Node a(test_options(1), waiter);
  a.start();
  PeerNetworkOptions options = test_options(2);
  options.team = "bravo";
  options.peers = {loopback(a.port())};
  Node b(options, waiter);
  b.start();
  ASSERT_TRUE(waiter.until(
      [&] { return a.totals().rejected_handshake >= 1 && b.totals().rejected_handshake >= 1; }));
  EXPECT_TRUE(a.network().live_peers().empty());
  EXPECT_TRUE(b.network().live_peers().empty());
  EXPECT_TRUE(a.peer_events().empty());
}

TEST(PeerNetwork, DaemonsWithAnotherKeyNeverConnectNorLearnTheTeam) {
  Waiter waiter;
  Node a(test_options(1), waiter);
  a.start();
  PeerNetworkOptions options = test_options(2);
  options.team_key = std::make_shared<const TeamKey>(TeamKey::from_seed_for_tests("intruder"));
  options.peers = {loopback(a.port())};
  Node intruder(options, waiter);
  intruder.start();
  ASSERT_TRUE(waiter.until([&] {
    return a.totals().rejected_unauthenticated >= 1 &&
           intruder.totals().rejected_unauthenticated >= 1;
  }));
  EXPECT_TRUE(a.network().live_peers().empty());
  EXPECT_TRUE(a.network().peers().empty());
  EXPECT_TRUE(intruder.network().peers().empty());
}

TEST(PeerNetwork, MembershipListRefusesOtherRobotIds) {
  Waiter waiter;
  PeerNetworkOptions options = test_options(1);
  options.members = {1, 2};
  Node a(options, waiter);
  a.start();
  RawClient outsider(a.port());
  ASSERT_TRUE(outsider.secure(*test_key()));  // a key holder, but robot 7 is not a member
  outsider.send(raw_hello(7));
  EXPECT_TRUE(outsider.read_until_closed());
  EXPECT_EQ(a.totals().rejected_handshake, 1u);
  EXPECT_TRUE(a.network().peers().empty());
}

// ---------------------------------------------------------------------------------------------
// Per-robot identities

/// Robot `robot`'s identity in these tests.
std::shared_ptr<const RobotIdentity> identity_of(int robot) {
  return std::make_shared<const RobotIdentity>(
      RobotIdentity::from_seed_for_tests("robot " + std::to_string(robot)));
}

/// test_options with identities: robots 1-3 are members, each with its key.
PeerNetworkOptions signed_options(int robot) {
  PeerNetworkOptions options = test_options(robot);
  options.members = {1, 2, 3};
  options.identity = identity_of(robot);
  for (const int member : options.members)
    options.member_keys.emplace(member, identity_of(member)->public_key());
  return options;
}

/// A Hello of `robot` signed by `signer` over `binding` as the dialer.
v1::Envelope signed_hello(int robot, const RobotIdentity& signer, const std::string& binding) {
  v1::Envelope envelope = raw_hello(robot);
  envelope.mutable_hello()->set_identity_signature(
      signer.sign(hello_signing_bytes(binding, /*signer_dialed=*/true, robot)));
  return envelope;
}

TEST(PeerNetworkOptions, MemberKeysNeedThisRobotsOwnIdentity) {
  EXPECT_TRUE(signed_options(1).validate().empty());
  auto problems_of = [](const PeerNetworkOptions& options) {
    std::string all;
    for (const std::string& problem : options.validate()) all += problem + "\n";
    return all;
  };
  PeerNetworkOptions no_identity = signed_options(1);
  no_identity.identity.reset();
  EXPECT_NE(problems_of(no_identity).find("identity: required"), std::string::npos);
  PeerNetworkOptions someone_else = signed_options(1);
  someone_else.identity = identity_of(2);
  EXPECT_NE(problems_of(someone_else).find("not this robot's identity key"), std::string::npos);
  PeerNetworkOptions missing_member = signed_options(1);
  missing_member.member_keys.erase(3);
  EXPECT_NE(problems_of(missing_member).find("no key for member 3"), std::string::npos);
}

TEST(PeerNetwork, MembersWithIdentitiesConnectBySignedHellos) {
  Waiter waiter;
  Node a(signed_options(1), waiter);
  a.start();
  PeerNetworkOptions options = signed_options(2);
  options.peers = {loopback(a.port())};
  Node b(options, waiter);
  b.start();
  ASSERT_TRUE(waiter.until([&] { return a.is_up(2) && b.is_up(1); }));
  EXPECT_EQ(a.totals().rejected_identity, 0u);
  EXPECT_EQ(b.totals().rejected_identity, 0u);
}

TEST(PeerNetwork, AKeyHolderCannotTakeAnotherMembersId) {
  Waiter waiter;
  Node a(signed_options(1), waiter);
  a.start();
  const RobotIdentity robot3 = *identity_of(3);
  // Robot 3 (a member with the team key) claims robot 2's id: signed with its own key, with none,
  // and with robot 2's signature of another connection (replayed).
  std::string other_binding;
  {
    RawClient first(a.port());
    ASSERT_TRUE(first.secure(*test_key()));
    other_binding = first.binding();
    first.send(signed_hello(2, robot3, first.binding()));
    EXPECT_TRUE(first.read_until_closed());
  }
  {
    RawClient unsigned_hello(a.port());
    ASSERT_TRUE(unsigned_hello.secure(*test_key()));
    unsigned_hello.send(raw_hello(2));
    EXPECT_TRUE(unsigned_hello.read_until_closed());
  }
  {
    RawClient replay(a.port());
    ASSERT_TRUE(replay.secure(*test_key()));
    EXPECT_NE(replay.binding(), other_binding);  // fresh for every connection
    replay.send(signed_hello(2, *identity_of(2), other_binding));
    EXPECT_TRUE(replay.read_until_closed());
  }
  EXPECT_EQ(a.totals().rejected_identity, 3u);
  EXPECT_EQ(a.totals().rejected_handshake, 3u);
  EXPECT_TRUE(a.network().peers().empty());
  // Under its own id, signed over this connection, robot 3 is admitted.
  RawClient honest(a.port());
  ASSERT_TRUE(honest.secure(*test_key()));
  honest.send(signed_hello(3, robot3, honest.binding()));
  ASSERT_TRUE(waiter.until([&] { return a.is_up(3); }));
  EXPECT_EQ(a.totals().rejected_identity, 3u);
}

TEST(PeerNetwork, AMemberWithoutIdentitiesIsRefusedByOneThatRequiresThem) {
  Waiter waiter;
  Node a(signed_options(1), waiter);
  a.start();
  PeerNetworkOptions options = test_options(2);  // the team key, no identity
  options.peers = {loopback(a.port())};
  Node b(options, waiter);
  b.start();
  ASSERT_TRUE(waiter.until([&] { return a.totals().rejected_identity >= 1; }));
  EXPECT_FALSE(a.is_up(2));
}

TEST(PeerNetwork, AdmissionCapClosesConnectionsBeyondThePendingHandshakes) {
  Waiter waiter;
  PeerNetworkOptions options = test_options(1);
  options.max_pending_handshakes = 2;
  options.hello_timeout = 2s;
  Node a(options, waiter);
  a.start();
  std::vector<std::unique_ptr<RawClient>> silent;
  for (int i = 0; i < 2; ++i) silent.push_back(std::make_unique<RawClient>(a.port()));
  ASSERT_TRUE(waiter.until([&] { return a.totals().connections_accepted == 2; }));
  RawClient third(a.port());
  EXPECT_TRUE(third.read_until_closed());
  EXPECT_EQ(a.totals().rejected_admission, 1u);
}

TEST(PeerNetwork, SendQueueDropsTheOldestWhenThePeerDoesNotRead) {
  Waiter waiter;
  PeerNetworkOptions options = test_options(1);
  options.send_queue_limit = 4;
  // The silent reader (it sends nothing after its hello) must stay up while the queue overflows
  // and while it then reads everything: on a loaded machine that took more than 3 s once.
  options.heartbeat_timeout = 10s;
  Node a(options, waiter);
  a.start();
  RawClient reader_that_never_reads(a.port());
  ASSERT_TRUE(reader_that_never_reads.secure(*test_key()));
  reader_that_never_reads.send(raw_hello(7));
  ASSERT_TRUE(waiter.until([&] { return a.is_up(7); }));
  // 300 messages of 64 KiB: more than the loopback socket buffers hold, so the queue overflows.
  v1::Envelope payload = marginal(0, {}, 0.0);
  for (int i = 0; i < 8000; ++i) payload.mutable_marginal()->add_mean(i);
  for (std::uint64_t round = 0; round < 300; ++round) {
    payload.set_round(round);
    ASSERT_TRUE(a.network().send(7, payload)) << round;
  }
  ASSERT_TRUE(waiter.until([&] { return a.totals().send_drops > 0; }));
  EXPECT_TRUE(a.is_live(7));  // dropped for overflow, not because the peer went down

  // Now read everything: the newest message arrives (the oldest queued ones were dropped), in
  // order, with a gap in the middle.
  auto rounds = [&] {
    std::vector<std::uint64_t> result;
    for (const v1::Envelope& envelope : reader_that_never_reads.frames())
      if (envelope.has_marginal()) result.push_back(envelope.round());
    return result;
  };
  ASSERT_TRUE(reader_that_never_reads.read([&] {
    const std::vector<std::uint64_t> so_far = rounds();
    return !so_far.empty() && so_far.back() == 299;
  })) << rounds().size()
      << " marginals received";
  const std::vector<std::uint64_t> received = rounds();
  EXPECT_TRUE(std::is_sorted(received.begin(), received.end()));
  // Which of the oldest rounds go out depends on when the writes start (a loaded machine may
  // queue dozens before the first one); the newest send_queue_limit ones are never dropped, since
  // nothing newer came after them, and what is missing was counted.
  ASSERT_GE(received.size(), 4u);
  EXPECT_EQ(std::vector<std::uint64_t>(received.end() - 4, received.end()),
            (std::vector<std::uint64_t>{296, 297, 298, 299}));
  EXPECT_LT(received.size(), 300u);
  ASSERT_TRUE(a.stop());  // after the 300 queued sends: the counts are final
  EXPECT_EQ(a.stats(7)->drops, a.totals().send_drops);
  EXPECT_EQ(a.stats(7)->drops + received.size(), 300u);
}

TEST(PeerNetwork, AWriteWithoutProgressClosesTheConnection) {
  Waiter waiter;
  PeerNetworkOptions options = test_options(1);
  // Room for the talking client to be descheduled on a loaded machine without looking silent.
  options.heartbeat_timeout = 1s;
  Node a(options, waiter);
  a.start();
  RawClient alive_but_not_reading(a.port());
  ASSERT_TRUE(alive_but_not_reading.secure(*test_key()));
  alive_but_not_reading.send(raw_hello(7));
  ASSERT_TRUE(waiter.until([&] { return a.is_up(7); }));
  v1::Envelope payload = marginal(0, {}, 0.0);
  for (int i = 0; i < 8000; ++i) payload.mutable_marginal()->add_mean(i);
  for (int i = 0; i < 300; ++i) a.network().send(7, payload);
  // It keeps talking (so it is not silent) but never reads: a's write stops making progress.
  v1::Envelope heartbeat = raw_hello(7);
  heartbeat.mutable_heartbeat()->set_time_ns(1);
  ASSERT_TRUE(waiter.until([&] {
    alive_but_not_reading.try_send(heartbeat);
    return !a.is_up(7);
  }));
  EXPECT_EQ(a.totals().write_stalls, 1u);
  EXPECT_EQ(a.totals().heartbeat_timeouts, 0u);
}

// ---------------------------------------------------------------------------------------------
// Discovery

std::uint16_t free_udp_port() {
  asio::io_context io;
  asio::ip::udp::socket socket(io, asio::ip::udp::endpoint(asio::ip::udp::v4(), 0));
  return socket.local_endpoint().port();
}

TEST(PeerNetwork, BeaconDiscoveryConnectsRobotsWithoutStaticPeers) {
  Waiter waiter;
  const std::uint16_t port = free_udp_port();
  auto with_discovery = [&](int robot, const std::string& team) {
    PeerNetworkOptions options = test_options(robot);
    options.team = team;
    options.discovery.enabled = true;
    options.discovery.address = "239.255.76.1";
    options.discovery.port = port;
    options.discovery.interval = 50ms;
    options.discovery.interface_address = "127.0.0.1";  // stay on loopback
    return options;
  };
  Node a(with_discovery(1, "test"), waiter);
  Node b(with_discovery(2, "test"), waiter);
  Node other(with_discovery(3, "bravo"), waiter);
  try {
    a.start();
  } catch (const std::runtime_error& error) {
    GTEST_SKIP() << "no multicast on loopback here: " << error.what();
  }
  b.start();
  other.start();
  ASSERT_TRUE(waiter.until([&] { return a.is_up(2) && b.is_up(1); }));
  ASSERT_TRUE(waiter.until(
      [&] { return a.totals().beacons_received >= 1 && a.totals().beacons_rejected >= 1; }));
  EXPECT_TRUE(other.network().live_peers().empty());
  EXPECT_FALSE(a.is_up(3));
  ASSERT_TRUE(waiter.until(
      [&] { return a.totals().open_connections == 1 && b.totals().open_connections == 1; }));
}

// ---------------------------------------------------------------------------------------------
// Ingest listener

v1::Envelope sensor_frame(std::int64_t frame) {
  v1::Envelope envelope;
  envelope.set_protocol_version(kProtocolVersion);
  envelope.set_sender(1);
  envelope.mutable_sensor_frame()->set_frame(frame);
  envelope.mutable_sensor_frame()->set_timestamp(0.1 * static_cast<double>(frame));
  return envelope;
}

struct ListenerFixture {
  explicit ListenerFixture(FrameListenerOptions options) : listener(io, std::move(options)) {
    listener.set_envelope_handler([this](std::uint64_t connection, const v1::Envelope& envelope) {
      {
        std::lock_guard lock(mutex);
        if (busy) return false;
        frames.emplace_back(connection, envelope.sensor_frame().frame());
      }
      waiter.notify();
      return true;
    });
    listener.set_close_handler([this](std::uint64_t connection, const std::string& reason) {
      {
        std::lock_guard lock(mutex);
        closed.emplace_back(connection, reason);
      }
      waiter.notify();
    });
    listener.start();
    thread = std::thread([this] { io.run(); });
  }
  ~ListenerFixture() {
    listener.stop();
    if (!waiter.until([this] { return io.stopped(); })) io.stop();
    thread.join();
  }
  std::size_t frame_count() {
    std::lock_guard lock(mutex);
    return frames.size();
  }
  asio::io_context io;
  FrameListener listener;
  Waiter waiter;
  std::mutex mutex;
  std::vector<std::pair<std::uint64_t, std::int64_t>> frames;
  std::vector<std::pair<std::uint64_t, std::string>> closed;
  bool busy = false;  // the handler refuses envelopes (a full queue)
  std::thread thread;
};

TEST(FrameListener, DeliversFramesAndClosesOnlyBadConnections) {
  FrameListenerOptions options;
  options.max_frame_bytes = 1024;
  ListenerFixture fixture(options);
  RawClient source(fixture.listener.port());
  const std::string two = encode_frame(sensor_frame(1)) + encode_frame(sensor_frame(2));
  const std::string third = encode_frame(sensor_frame(3));
  source.write(two + third.substr(0, 5));
  source.write(third.substr(5));
  ASSERT_TRUE(fixture.waiter.until([&] { return fixture.frame_count() == 3; }));

  RawClient oversized(fixture.listener.port());
  oversized.write(std::string("\x00\x00\x04\x01", 4));  // 1025 > 1024
  EXPECT_TRUE(oversized.read_until_closed());
  RawClient garbage(fixture.listener.port());
  garbage.write(std::string("\x00\x00\x00\x02\xff\xff", 6));
  EXPECT_TRUE(garbage.read_until_closed());

  source.send(sensor_frame(4));  // the good source is unaffected
  ASSERT_TRUE(fixture.waiter.until([&] { return fixture.frame_count() == 4; }));
  const FrameListenerCounters counters = fixture.listener.counters();
  EXPECT_EQ(counters.frames, 4u);
  EXPECT_EQ(counters.rejected_oversized, 1u);
  EXPECT_EQ(counters.rejected_garbage, 1u);
  EXPECT_EQ(counters.connections_accepted, 3u);
  std::lock_guard lock(fixture.mutex);
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(fixture.frames[i].first, 1u);
    EXPECT_EQ(fixture.frames[i].second, static_cast<std::int64_t>(i + 1));
  }
  EXPECT_EQ(fixture.closed.size(), 2u);
}

TEST(FrameListener, ClosesIdleConnectionsAndChecksTheTeamWhenGiven) {
  FrameListenerOptions options;
  options.idle_timeout = 100ms;
  options.team = "test";
  ListenerFixture fixture(options);
  RawClient idle(fixture.listener.port());
  EXPECT_TRUE(idle.read_until_closed());
  EXPECT_EQ(fixture.listener.counters().idle_timeouts, 1u);

  RawClient foreign(fixture.listener.port());
  foreign.send(sensor_frame(1));  // no team: rejected
  EXPECT_TRUE(foreign.read_until_closed());
  EXPECT_EQ(fixture.listener.counters().rejected_garbage, 1u);
  EXPECT_EQ(fixture.frame_count(), 0u);
}

TEST(FrameListener, ABusyHandlerPausesTheSenderAndLosesNothing) {
  ListenerFixture fixture(FrameListenerOptions{});
  {
    std::lock_guard lock(fixture.mutex);
    fixture.busy = true;
  }
  RawClient source(fixture.listener.port());
  for (int k = 0; k < 5; ++k) source.send(sensor_frame(k));
  ASSERT_TRUE(fixture.waiter.until([&] { return fixture.listener.counters().busy_pauses >= 2; }));
  EXPECT_EQ(fixture.frame_count(), 0u);
  {
    std::lock_guard lock(fixture.mutex);
    fixture.busy = false;
  }
  ASSERT_TRUE(fixture.waiter.until([&] { return fixture.frame_count() == 5; }));
  std::lock_guard lock(fixture.mutex);
  for (int k = 0; k < 5; ++k) EXPECT_EQ(fixture.frames[k].second, k);
}

TEST(FrameListener, WithAKeyOnlyAuthenticatedSendersAreHeard) {
  FrameListenerOptions options;
  options.team_key = test_key();
  ListenerFixture fixture(options);
  RawClient plaintext(fixture.listener.port());
  plaintext.send(sensor_frame(1));
  EXPECT_TRUE(plaintext.read_until_closed());
  RawClient intruder(fixture.listener.port());
  EXPECT_FALSE(intruder.secure(TeamKey::from_seed_for_tests("intruder")));
  RawClient sensor(fixture.listener.port());
  ASSERT_TRUE(sensor.secure(*test_key()));
  sensor.send(sensor_frame(2));
  ASSERT_TRUE(fixture.waiter.until([&] { return fixture.frame_count() == 1; }));
  EXPECT_EQ(fixture.listener.counters().rejected_unauthenticated, 2u);
}

}  // namespace
}  // namespace concord::net

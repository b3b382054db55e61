// PeerNetwork: sessions (one TCP connection each), the peer table (one entry per robot), dial
// targets (addresses to dial, with their backoff), the heartbeat watchdog and UDP discovery.
// Everything below runs on one strand; only the public entry points at the end of the file are
// called from other threads, and they either post to the strand or read the statistics under
// stats_mutex_.
#include "concord/net/peer_network.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <boost/asio.hpp>
#include <deque>
#include <map>
#include <mutex>
#include <optional>
#include <random>
#include <sstream>
#include <stdexcept>

#include "concord/net/log_limiter.h"
#include "concord/net/reconnect_backoff.h"
#include "concord/net/secure_channel.h"
#include "concord/v1/concord.pb.h"

namespace concord::net {

namespace {

namespace asio = boost::asio;
using tcp = asio::ip::tcp;
using udp = asio::ip::udp;
using Clock = std::chrono::steady_clock;
using Strand = asio::strand<asio::io_context::executor_type>;
using ErrorCode = boost::system::error_code;

constexpr std::size_t kReadChunkBytes = 64 * 1024;
constexpr std::size_t kWriteBatchBytes = 1 << 20;  // frames coalesced into one async_write
constexpr std::size_t kMaxBeaconBytes = 1400;      // fits one Ethernet datagram
constexpr auto kAcceptRetryDelay = std::chrono::milliseconds(100);
constexpr auto kOverflowLogPeriod = std::chrono::seconds(5);  // at most one overflow line per peer

/// Monotonic clock in ns for heartbeats; never 0 (0 means "no heartbeat" in echo_time_ns).
std::uint64_t monotonic_ns() {
  const auto ns =
      std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch());
  return std::max<std::uint64_t>(1, static_cast<std::uint64_t>(ns.count()));
}

std::string endpoint_string(const asio::ip::address& address, std::uint16_t port) {
  return HostPort{address.to_string(), port}.to_string();
}

/// Where a robot accepts connections, from its Hello (or beacon): the address it announces, or the
/// source address of its connection/datagram when it announces none or an unspecified one.
HostPort announced_address(const v1::Hello& hello, const asio::ip::address& source) {
  ErrorCode error;
  const auto announced = asio::ip::make_address(hello.listen_address(), error);
  const bool use_source = hello.listen_address().empty() || (!error && announced.is_unspecified());
  return {use_source ? source.to_string() : hello.listen_address(),
          static_cast<std::uint16_t>(hello.listen_port())};
}

std::int64_t milliseconds(std::chrono::nanoseconds duration) {
  return std::chrono::duration_cast<std::chrono::milliseconds>(duration).count();
}

/// Calls a user callback; an exception never leaves an Asio handler.
template <class Function>
void invoke_user_callback(const char* what, Function&& function) {
  try {
    function();
  } catch (const std::exception& error) {
    spdlog::error("net: {} threw: {}", what, error.what());
  } catch (...) {
    spdlog::error("net: {} threw a non-standard exception", what);
  }
}

enum class Origin { kAccepted, kDialed };

std::string_view to_string(Origin origin) {
  return origin == Origin::kAccepted ? "accepted" : "dialed";
}

enum class SessionState {
  kConnecting,   // dialed: resolving and connecting
  kHandshaking,  // Hello sent, waiting for the peer's Hello
  kEstablished,  // handshake done
  kRetiring,     // lost the tie-break: no new messages; half-closed once released, reads on
  kClosing,      // stop(): Goodbye queued, flushing, half-closed, reading until the peer closes
  kClosed,
};

}  // namespace

// ---------------------------------------------------------------------------------------------
// Options

std::vector<std::string> PeerNetworkOptions::validate() const {
  std::vector<std::string> problems;
  auto problem = [&](const std::string& message) { problems.push_back(message); };
  auto count = [](std::chrono::milliseconds duration) {
    return std::to_string(duration.count()) + " ms";
  };
  if (!team_key) problem("team_key: required (every connection proves the team key)");
  if (team.empty()) problem("team: must not be empty");
  for (const int member : members)
    if (member < 0) problem("members: robot id " + std::to_string(member) + " is negative");
  if (max_pending_handshakes == 0) problem("max_pending_handshakes: must be at least 1");
  if (receive_bytes_per_second < max_frame_bytes / 2)
    problem("receive_bytes_per_second: " + std::to_string(receive_bytes_per_second) +
            " is below half of max_frame_bytes (" + std::to_string(max_frame_bytes) + ")");
  if (receive_messages_per_second == 0) problem("receive_messages_per_second: must be positive");
  if (robot_id < 0) problem("robot_id: " + std::to_string(robot_id) + " is negative");
  ErrorCode error;
  asio::ip::make_address(listen_address, error);
  if (error) problem("listen_address: '" + listen_address + "' is not an IP address");
  for (const std::string& peer : peers)
    if (!parse_host_port(peer)) problem("peers: '" + peer + "' is not host:port");
  if (max_frame_bytes < 1024 || max_frame_bytes > (std::size_t{1} << 30))
    problem("max_frame_bytes: " + std::to_string(max_frame_bytes) +
            " is outside [1024, 1073741824]");
  if (send_queue_limit == 0) problem("send_queue_limit: must be at least 1");
  if (heartbeat_interval.count() <= 0)
    problem("heartbeat_interval: " + count(heartbeat_interval) + " must be positive");
  if (heartbeat_timeout <= heartbeat_interval)
    problem("heartbeat_timeout: " + count(heartbeat_timeout) + " must exceed heartbeat_interval (" +
            count(heartbeat_interval) + ")");
  if (hello_timeout.count() <= 0)
    problem("hello_timeout: " + count(hello_timeout) + " must be positive");
  if (reconnect_initial.count() <= 0)
    problem("reconnect_initial: " + count(reconnect_initial) + " must be positive");
  if (reconnect_max < reconnect_initial)
    problem("reconnect_max: " + count(reconnect_max) + " is below reconnect_initial (" +
            count(reconnect_initial) + ")");
  if (!(reconnect_jitter >= 0.0 && reconnect_jitter < 1.0))
    problem("reconnect_jitter: " + std::to_string(reconnect_jitter) + " is outside [0, 1)");
  if (stop_linger.count() < 0) problem("stop_linger: " + count(stop_linger) + " is negative");
  if (discovery.enabled) {
    asio::ip::make_address_v4(discovery.address, error);
    if (error) problem("discovery.address: '" + discovery.address + "' is not an IPv4 address");
    if (discovery.port == 0) problem("discovery.port: must not be 0");
    if (discovery.interval.count() <= 0)
      problem("discovery.interval: " + count(discovery.interval) + " must be positive");
    if (!discovery.interface_address.empty()) {
      asio::ip::make_address_v4(discovery.interface_address, error);
      if (error)
        problem("discovery.interface_address: '" + discovery.interface_address +
                "' is not an IPv4 address");
    }
  }
  return problems;
}

std::string PeerNetworkOptions::describe() const {
  std::ostringstream out;
  out << "team=" << team << " robot_id=" << robot_id << " members=[";
  for (std::size_t i = 0; i < members.size(); ++i) out << (i ? "," : "") << members[i];
  out << "] max_pending_handshakes=" << max_pending_handshakes
      << " receive_budget=" << receive_bytes_per_second << "B/s," << receive_messages_per_second
      << "msg/s" << " listen=" << listen_address << ":"
      << listen_port;
  if (!advertised_address.empty()) out << " advertised_address=" << advertised_address;
  out << " peers=[";
  for (std::size_t i = 0; i < peers.size(); ++i) out << (i ? "," : "") << peers[i];
  out << "] max_frame_bytes=" << max_frame_bytes << " send_queue_limit=" << send_queue_limit
      << " heartbeat=" << heartbeat_interval.count() << "/" << heartbeat_timeout.count() << "ms"
      << " hello_timeout=" << hello_timeout.count() << "ms"
      << " reconnect=" << reconnect_initial.count() << ".." << reconnect_max.count() << "ms+-"
      << reconnect_jitter * 100 << "%"
      << " stop_linger=" << stop_linger.count() << "ms capabilities=[";
  for (std::size_t i = 0; i < capabilities.size(); ++i) out << (i ? "," : "") << capabilities[i];
  out << "] discovery=";
  if (discovery.enabled)
    out << discovery.address << ":" << discovery.port << "/" << discovery.interval.count() << "ms";
  else
    out << "off";
  return out.str();
}

// ---------------------------------------------------------------------------------------------
// Impl

class PeerNetwork::Impl : public std::enable_shared_from_this<PeerNetwork::Impl> {
 public:
  class Session;

  Impl(asio::io_context& io, PeerNetworkOptions options);

  // Public API (any thread).
  void start();
  void stop(std::string reason, std::uint64_t last_round);
  /// From the destructor: no callback runs any more, then stop().
  void detach_and_stop();
  void add_peer(HostPort address);
  std::uint16_t listen_port() const { return listen_port_.load(); }
  bool send(int robot, const v1::Envelope& envelope);
  int broadcast(const v1::Envelope& envelope);
  std::vector<PeerStats> peers() const;
  NetworkCounters totals() const;
  std::vector<int> live_peers() const;
  const PeerNetworkOptions& options() const { return options_; }

  MessageHandler message_handler;  // set before start(), then only read on the strand
  PeerHandler peer_handler;

  // Called by sessions, on the strand.
  v1::Envelope make_hello() const;
  void fill_heartbeat(const Session& session, v1::Envelope& envelope) const;
  void on_connected(Session& session);
  void on_bytes_in(const Session& session, std::size_t bytes);
  void on_written(const Session& session, std::size_t bytes, std::size_t messages);
  void on_envelope(const std::shared_ptr<Session>& session, const v1::Envelope& envelope);
  void on_frame_error(const std::shared_ptr<Session>& session, const FrameError& error);
  void on_channel_failed(const std::shared_ptr<Session>& session, const std::string& reason);
  void count_budget_pause() {
    update_counters([](NetworkCounters& counters) { ++counters.budget_pauses; });
  }
  /// A warning caused by a remote party, at most a few per key and period (see LogLimiter).
  template <class... Args>
  void warn_limited(const std::string& key, spdlog::format_string_t<Args...> format,
                    Args&&... args) {
    std::uint64_t suppressed = 0;
    if (!log_limiter_.allow(key, suppressed)) return;
    spdlog::warn("{}{}", fmt::format(format, std::forward<Args>(args)...),
                 suppressed_note(suppressed));
  }
  void on_session_closed(const std::shared_ptr<Session>& session, SessionState previous,
                         std::string_view reason);

 private:
  /// One robot, once a handshake with it completed (strand only; statistics are in records_).
  struct Peer {
    std::weak_ptr<Session> active;  // the one connection used to send to this robot
    bool up = false;
    bool ever_up = false;
    bool goodbye_received = false;  // no redial until it comes back
    std::uint64_t goodbye_instance = 0;
    std::optional<Clock::time_point> last_overflow_log;  // queue overflow: one line per 5 s
    std::uint64_t drops_since_log = 0;
    std::string dial_key;  // targets_ key this robot is redialed at ("" = unknown)
    /// Connections that lost the tie-break, half-closed once the kept one is confirmed.
    std::vector<std::weak_ptr<Session>> retiring;
  };

  /// An address we dial: a static peer, or learned from a Hello or a beacon (strand only).
  struct DialTarget {
    DialTarget(HostPort address, bool configured, const ReconnectBackoffOptions& backoff,
               std::uint64_t seed, const Strand& strand)
        : address(std::move(address)),
          configured(configured),
          backoff(backoff, seed),
          timer(strand) {}
    HostPort address;
    bool configured;
    int robot = -1;        // learned from the first handshake
    bool is_self = false;  // we dialed ourselves: never again
    ReconnectBackoff backoff;
    asio::steady_timer timer;
    bool timer_armed = false;
    std::uint64_t session_id = 0;  // the session dialed from here while it lives (0: none)
  };

  /// Statistics of one robot, guarded by stats_mutex_.
  struct PeerRecord {
    PeerStats stats;
    double rtt_mean_ns = 0.0;
  };

  // Stamps protocol_version, team and sender.
  void stamp(v1::Envelope& envelope) const;
  void begin();
  void do_accept();
  void on_accepted(tcp::socket socket);
  std::shared_ptr<Session> make_session(Origin origin, std::string dial_key, tcp::socket socket);
  DialTarget& ensure_target(const HostPort& address, bool configured);
  bool wants_dial(const std::string& key, const DialTarget& target) const;
  void dial(const std::string& key);
  void schedule_dial(const std::string& key);
  void handle_hello(const std::shared_ptr<Session>& session, const v1::Envelope& envelope);
  void activate(int robot, Peer& peer, const std::shared_ptr<Session>& session);
  void resolve_duplicate(int robot, Peer& peer, const std::shared_ptr<Session>& active,
                         const std::shared_ptr<Session>& fresh);
  void handle_heartbeat(Session& session, const v1::Heartbeat& heartbeat);
  void handle_goodbye(const std::shared_ptr<Session>& session, const v1::Envelope& envelope);
  void reject_handshake(const std::shared_ptr<Session>& session, const std::string& reason);
  void mark_down(int robot, Peer& peer, std::string_view reason);
  void enqueue_data(int robot, const std::shared_ptr<const v1::Envelope>& envelope);
  void arm_tick();
  void on_tick();
  void do_stop(const std::string& reason, std::uint64_t last_round);
  void open_discovery();
  void arm_beacon();
  void do_receive_beacon();
  void on_beacon(std::size_t bytes);
  std::uint32_t degree() const;
  void count_send_drop(int robot);
  template <class Function>
  void update_record(int robot, Function&& function);
  template <class Function>
  void update_counters(Function&& function);

  Strand strand_;
  const PeerNetworkOptions options_;
  const ReconnectBackoffOptions backoff_options_;
  const std::uint64_t instance_;
  std::mt19937_64 random_;  // seeds of the backoff jitter

  std::atomic<bool> start_called_{false};
  std::atomic<std::uint16_t> listen_port_{0};
  std::atomic<bool> oversize_send_logged_{false};

  // Strand only.
  bool running_ = false;
  bool stopping_ = false;
  tcp::acceptor acceptor_;
  asio::steady_timer accept_retry_timer_;
  asio::steady_timer tick_timer_;
  asio::steady_timer linger_timer_;
  udp::socket discovery_socket_;
  udp::endpoint beacon_destination_;
  asio::steady_timer beacon_timer_;
  std::string beacon_out_;
  bool beacon_in_flight_ = false;
  std::array<char, kMaxBeaconBytes> beacon_in_{};
  udp::endpoint beacon_sender_;
  std::uint64_t next_session_id_ = 1;
  std::map<std::uint64_t, std::weak_ptr<Session>> sessions_;
  std::map<int, Peer> peers_;
  std::map<std::string, std::unique_ptr<DialTarget>> targets_;

  LogLimiter log_limiter_;  // thread-safe

  // Any thread, under stats_mutex_.
  mutable std::mutex stats_mutex_;
  std::map<int, PeerRecord> records_;
  NetworkCounters counters_;
};

// ---------------------------------------------------------------------------------------------
// Session: one TCP connection. It only moves bytes: the network decides what messages mean.

class PeerNetwork::Impl::Session : public std::enable_shared_from_this<Session> {
 public:
  struct Outgoing {
    enum class Kind { kChannel, kControl, kHeartbeat, kData };
    Kind kind;
    std::shared_ptr<const v1::Envelope> envelope;  // null for kHeartbeat (built when written)
    std::string channel_payload;                   // kChannel: a handshake message, unencrypted
  };

  Session(std::shared_ptr<Impl> network, std::uint64_t id, Origin origin, std::string dial_key,
          tcp::socket socket)
      : id(id),
        origin(origin),
        dial_key(std::move(dial_key)),
        created(Clock::now()),
        state_since(created),
        last_received(created),
        network_(std::move(network)),
        socket_(std::move(socket)),
        decoder_(FrameDecoderOptions{network_->options_.max_frame_bytes, network_->options_.team}),
        channel_(*network_->options_.team_key, origin == Origin::kDialed
                                                   ? SecureChannel::Role::kInitiator
                                                   : SecureChannel::Role::kResponder),
        read_buffer_(kReadChunkBytes),
        resume_timer_(socket_.get_executor()),
        byte_tokens_(2.0 * static_cast<double>(network_->options_.receive_bytes_per_second)),
        message_tokens_(2.0 * static_cast<double>(network_->options_.receive_messages_per_second)),
        tokens_refilled_(created) {}

  /// Dialed sessions: connect, then begin().
  void connect(const HostPort& address) {
    remote = address.to_string();
    auto self = shared_from_this();
    auto on_connect = [self](const ErrorCode& error) {
      if (self->state == SessionState::kClosed) return;
      if (error) return self->close("connect failed: " + error.message());
      self->network_->on_connected(*self);
      self->begin();
    };
    ErrorCode not_literal;
    const auto literal = asio::ip::make_address(address.host, not_literal);
    if (!not_literal) {  // an IP literal: no resolver (and no resolver thread)
      socket_.async_connect(tcp::endpoint(literal, address.port), on_connect);
      return;
    }
    resolver_ = std::make_unique<tcp::resolver>(socket_.get_executor());
    resolver_->async_resolve(
        address.host, std::to_string(address.port),
        [self, on_connect](const ErrorCode& error, const tcp::resolver::results_type& results) {
          if (self->state == SessionState::kClosed) return;
          if (error) return self->close("cannot resolve: " + error.message());
          asio::async_connect(self->socket_, results,
                              [on_connect](const ErrorCode& connect_error, const tcp::endpoint&) {
                                on_connect(connect_error);
                              });
        });
  }

  /// Connected (accepted or dialed): Hello out, reads in.
  void begin() {
    ErrorCode error;
    const tcp::endpoint endpoint = socket_.remote_endpoint(error);
    if (error) return close("connection lost before the handshake: " + error.message());
    remote_address = endpoint.address();
    remote = endpoint_string(endpoint.address(), endpoint.port());
    socket_.set_option(tcp::no_delay(true), error);
    set_state(SessionState::kHandshaking);
    // 1. The channel handshake first: nothing about the team before the peer proved the key.
    enqueue({Outgoing::Kind::kChannel, nullptr, channel_.hello()});
    do_read();
  }

  /// Queues one message; returns the number of application messages dropped for it (0 or 1).
  /// Queue policy: control messages always go in (heartbeats coalesce: one is queued at most);
  /// application messages beyond the limit push out the oldest queued application message.
  std::size_t enqueue(Outgoing item) {
    if (state == SessionState::kClosed || shutdown_after_flush_) return 0;
    std::size_t dropped = 0;
    if (item.kind == Outgoing::Kind::kHeartbeat) {
      if (heartbeat_queued_) return 0;
      heartbeat_queued_ = true;
    } else if (item.kind == Outgoing::Kind::kData) {
      if (data_queued_ >= network_->options_.send_queue_limit) {
        const auto oldest = std::find_if(queue_.begin(), queue_.end(), [](const Outgoing& o) {
          return o.kind == Outgoing::Kind::kData;
        });
        queue_.erase(oldest);
        --data_queued_;
        dropped = 1;
      }
      ++data_queued_;
    }
    queue_.push_back(std::move(item));
    do_write();
    return dropped;
  }

  /// Removes and returns the queued (not yet written) application messages.
  std::deque<Outgoing> take_queued_data() {
    std::deque<Outgoing> data, rest;
    for (Outgoing& item : queue_)
      (item.kind == Outgoing::Kind::kData ? data : rest).push_back(std::move(item));
    queue_ = std::move(rest);
    data_queued_ = 0;
    return data;
  }

  /// Lost the tie-break: no new messages go out; received ones are still delivered.
  void retire() {
    if (state == SessionState::kEstablished) set_state(SessionState::kRetiring);
  }

  /// A retired connection the peer no longer uses: finish the write in flight, half-close, read
  /// until the peer closes.
  void release() {
    if (state != SessionState::kRetiring || shutdown_after_flush_) return;
    shutdown_after_flush_ = true;
    do_write();
  }

  /// stop(): send Goodbye after what is queued, half-close, read until the peer closes. Also
  /// during the handshake: our Hello is out, so the peer may already count us as up.
  void finish(std::shared_ptr<const v1::Envelope> goodbye) {
    if (state != SessionState::kEstablished && state != SessionState::kHandshaking)
      return close("stopping");
    queue_.push_back({Outgoing::Kind::kControl, std::move(goodbye), {}});
    set_state(SessionState::kClosing);
    shutdown_after_flush_ = true;
    do_write();
  }

  void close(std::string_view reason) {
    if (state == SessionState::kClosed) return;
    const SessionState previous = state;
    state = SessionState::kClosed;
    ErrorCode ignored;
    socket_.shutdown(tcp::socket::shutdown_both, ignored);
    socket_.close(ignored);
    resume_timer_.cancel();
    if (resolver_) resolver_->cancel();
    queue_.clear();
    network_->on_session_closed(shared_from_this(), previous, reason);
  }

  void set_state(SessionState next) {
    state = next;
    state_since = Clock::now();
  }

  bool writing() const { return writing_; }

  const std::uint64_t id;
  const Origin origin;
  const std::string dial_key;  // targets_ key it was dialed from ("" when accepted)
  SessionState state = SessionState::kConnecting;
  Clock::time_point created;
  Clock::time_point state_since;
  Clock::time_point last_received;
  Clock::time_point write_progress;  // last time bytes of the write in flight went out
  std::string remote;                // "ip:port" once connected, the dialed address before
  asio::ip::address remote_address;
  int robot = -1;  // from its Hello
  std::uint64_t instance = 0;
  bool confirmed = false;  // a message after the Hello arrived: the peer has it established
  std::uint64_t peer_heartbeat_ns = 0;  // time_ns of its last heartbeat (0: none yet)
  Clock::time_point peer_heartbeat_received;

 private:
  void do_read() {
    socket_.async_read_some(asio::buffer(read_buffer_),
                            [self = shared_from_this()](const ErrorCode& error, std::size_t bytes) {
                              self->on_read(error, bytes);
                            });
  }

  void on_read(const ErrorCode& error, std::size_t bytes) {
    if (state == SessionState::kClosed) return;
    if (error)
      return close(error == asio::error::eof ? std::string("connection closed by the peer")
                                             : "read failed: " + error.message());
    last_received = Clock::now();
    network_->on_bytes_in(*this, bytes);
    decoder_.feed(std::string_view(read_buffer_.data(), bytes));
    const auto self = shared_from_this();
    std::size_t frames = 0;
    while (state != SessionState::kClosed) {
      const FrameDecoder::Status status = decoder_.next_payload(payload_);
      if (status == FrameDecoder::Status::kNeedMore) break;
      if (status == FrameDecoder::Status::kError)
        return network_->on_frame_error(self, decoder_.error());
      ++frames;
      if (!channel_.established()) {
        on_channel_message();
        continue;
      }
      std::string error;
      const std::optional<std::string> plaintext = channel_.open(payload_, error);
      if (!plaintext)
        return network_->on_frame_error(self, {FrameErrorKind::kUnauthenticated, error});
      FrameError check = parse_envelope(*plaintext, network_->options_.team, envelope_);
      if (check.kind != FrameErrorKind::kNone) return network_->on_frame_error(self, check);
      network_->on_envelope(self, envelope_);
    }
    if (state == SessionState::kClosed) return;
    // 2. Receive budget: a connection over its bytes or messages per second pauses reading.
    const auto pause = spend_budget(bytes, frames);
    if (pause <= Clock::duration::zero()) return do_read();
    network_->count_budget_pause();
    resume_timer_.expires_after(pause);
    resume_timer_.async_wait([self](const ErrorCode& error) {
      if (!error && self->state != SessionState::kClosed) self->do_read();
    });
  }

  /// Channel handshake messages (before the channel is established).
  void on_channel_message() {
    const auto self = shared_from_this();
    std::string error;
    if (channel_.stage() == SecureChannel::Stage::kAwaitingHello) {
      std::optional<std::string> proof = channel_.accept_hello(payload_, error);
      if (!proof) return network_->on_channel_failed(self, error);
      enqueue({Outgoing::Kind::kChannel, nullptr, std::move(*proof)});
      return;
    }
    if (!channel_.accept_proof(payload_, error)) return network_->on_channel_failed(self, error);
    // 3. The peer proved the key: now the (encrypted) Hello.
    enqueue(
        {Outgoing::Kind::kControl, std::make_shared<const v1::Envelope>(network_->make_hello()), {}});
  }

  /// Takes `bytes` and `frames` from the token buckets; how long to pause reading (<= 0: none).
  Clock::duration spend_budget(std::size_t bytes, std::size_t frames) {
    const auto now = Clock::now();
    const double elapsed = std::chrono::duration<double>(now - tokens_refilled_).count();
    tokens_refilled_ = now;
    const auto byte_rate = static_cast<double>(network_->options_.receive_bytes_per_second);
    const auto message_rate = static_cast<double>(network_->options_.receive_messages_per_second);
    byte_tokens_ = std::min(2.0 * byte_rate, byte_tokens_ + elapsed * byte_rate) -
                   static_cast<double>(bytes);
    message_tokens_ = std::min(2.0 * message_rate, message_tokens_ + elapsed * message_rate) -
                      static_cast<double>(frames);
    const double wait = std::max(-byte_tokens_ / byte_rate, -message_tokens_ / message_rate);
    return std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(wait));
  }

  void do_write() {
    if (writing_ || state == SessionState::kClosed) return;
    if (queue_.empty()) {
      if (shutdown_after_flush_ && !half_closed_) {
        half_closed_ = true;
        ErrorCode ignored;
        socket_.shutdown(tcp::socket::shutdown_send, ignored);
      }
      return;
    }
    write_buffer_.clear();
    std::size_t messages = 0;
    if (queue_.empty()) return;
    while (!queue_.empty() && write_buffer_.size() < kWriteBatchBytes) {
      Outgoing item = std::move(queue_.front());
      queue_.pop_front();
      if (item.kind == Outgoing::Kind::kChannel) {
        append_raw_frame(item.channel_payload, write_buffer_);
        continue;
      }
      if (!channel_.established()) {  // stop() during the handshake: nothing else may go out
        if (item.kind == Outgoing::Kind::kData) --data_queued_;
        if (item.kind == Outgoing::Kind::kHeartbeat) heartbeat_queued_ = false;
        continue;
      }
      if (item.kind == Outgoing::Kind::kHeartbeat) {
        heartbeat_queued_ = false;
        scratch_.Clear();
        network_->fill_heartbeat(*this, scratch_);
      } else {
        if (item.kind == Outgoing::Kind::kData) --data_queued_;
        scratch_ = *item.envelope;
      }
      scratch_.set_seq(++seq_out_);
      scratch_.SerializeToString(&plaintext_);
      append_raw_frame(channel_.seal(plaintext_), write_buffer_);
      ++messages;
    }
    writing_ = true;
    write_progress = Clock::now();
    // The completion condition runs after every partial write: a slow link that moves is not
    // a stalled one.
    auto record_progress = [this](const ErrorCode& error, std::size_t) -> std::size_t {
      write_progress = Clock::now();
      return error ? 0 : kReadChunkBytes;
    };
    asio::async_write(
        socket_, asio::buffer(write_buffer_), record_progress,
        [self = shared_from_this(), messages](const ErrorCode& error, std::size_t bytes) {
          self->on_write(error, bytes, messages);
        });
  }

  void on_write(const ErrorCode& error, std::size_t bytes, std::size_t messages) {
    writing_ = false;
    if (state == SessionState::kClosed) return;
    if (error) return close("write failed: " + error.message());
    network_->on_written(*this, bytes, messages);
    do_write();
  }

  std::shared_ptr<Impl> network_;
  tcp::socket socket_;
  std::unique_ptr<tcp::resolver> resolver_;  // only for host names
  FrameDecoder decoder_;
  SecureChannel channel_;
  std::vector<char> read_buffer_;
  asio::steady_timer resume_timer_;  // reading paused over the receive budget
  double byte_tokens_;
  double message_tokens_;
  Clock::time_point tokens_refilled_;
  std::string payload_;    // last frame payload
  std::string plaintext_;  // envelope being sealed
  v1::Envelope envelope_;  // last decoded
  std::deque<Outgoing> queue_;
  std::size_t data_queued_ = 0;
  bool heartbeat_queued_ = false;
  bool writing_ = false;
  bool shutdown_after_flush_ = false;
  bool half_closed_ = false;
  std::string write_buffer_;
  v1::Envelope scratch_;  // envelope being encoded
  std::uint64_t seq_out_ = 0;
};

// ---------------------------------------------------------------------------------------------
// Impl: setup

PeerNetwork::Impl::Impl(asio::io_context& io, PeerNetworkOptions options)
    : strand_(asio::make_strand(io)),
      options_(std::move(options)),
      backoff_options_{options_.reconnect_initial, options_.reconnect_max, 2.0,
                       options_.reconnect_jitter},
      instance_(std::random_device{}() * (std::uint64_t{1} << 32) ^ std::random_device{}() ^
                static_cast<std::uint64_t>(Clock::now().time_since_epoch().count())),
      random_(instance_),
      acceptor_(strand_),
      accept_retry_timer_(strand_),
      tick_timer_(strand_),
      linger_timer_(strand_),
      discovery_socket_(strand_),
      beacon_timer_(strand_) {}

void PeerNetwork::Impl::stamp(v1::Envelope& envelope) const {
  envelope.set_protocol_version(kProtocolVersion);
  envelope.set_team(options_.team);
  envelope.set_sender(static_cast<std::uint32_t>(options_.robot_id));
}

template <class Function>
void PeerNetwork::Impl::update_record(int robot, Function&& function) {
  std::lock_guard lock(stats_mutex_);
  PeerRecord& record = records_[robot];
  record.stats.robot = robot;
  function(record);
}

template <class Function>
void PeerNetwork::Impl::update_counters(Function&& function) {
  std::lock_guard lock(stats_mutex_);
  function(counters_);
}

void PeerNetwork::Impl::start() {
  if (start_called_.exchange(true)) throw std::logic_error("PeerNetwork::start called twice");
  const std::vector<std::string> problems = options_.validate();
  if (!problems.empty()) {
    std::string message = "invalid network options:";
    for (const std::string& problem : problems) message += "\n  " + problem;
    throw std::invalid_argument(message);
  }
  // Bind now, on the caller's thread (nothing else uses the acceptor yet), so that the port is
  // known when start() returns and a busy port is reported to the caller.
  const tcp::endpoint endpoint(asio::ip::make_address(options_.listen_address),
                               options_.listen_port);
  ErrorCode error;
  acceptor_.open(endpoint.protocol(), error);
  if (!error) acceptor_.set_option(tcp::acceptor::reuse_address(true), error);
  if (!error) acceptor_.bind(endpoint, error);
  if (!error) acceptor_.listen(asio::socket_base::max_listen_connections, error);
  if (error)
    throw std::runtime_error("net: cannot listen on " +
                             endpoint_string(endpoint.address(), endpoint.port()) + ": " +
                             error.message());
  listen_port_ = acceptor_.local_endpoint().port();
  if (options_.discovery.enabled) open_discovery();
  spdlog::info("net: robot {} listening on port {} (instance {:016x}); {}", options_.robot_id,
               listen_port_.load(), instance_, options_.describe());
  asio::post(strand_, [self = shared_from_this()] { self->begin(); });
}

void PeerNetwork::Impl::begin() {
  if (stopping_) return;
  running_ = true;
  do_accept();
  for (const std::string& text : options_.peers) ensure_target(*parse_host_port(text), true);
  for (const auto& [key, target] : targets_) dial(key);
  arm_tick();
  if (options_.discovery.enabled) {
    do_receive_beacon();
    arm_beacon();
  }
}

void PeerNetwork::Impl::add_peer(HostPort address) {
  asio::post(strand_, [self = shared_from_this(), address = std::move(address)] {
    if (self->stopping_) return;
    self->ensure_target(address, true);
    self->dial(address.to_string());
  });
}

// ---------------------------------------------------------------------------------------------
// Impl: connections

void PeerNetwork::Impl::do_accept() {
  acceptor_.async_accept([self = shared_from_this()](const ErrorCode& error, tcp::socket socket) {
    if (self->stopping_) return;
    if (error) {
      if (error == asio::error::operation_aborted) return;
      // E.g. out of file descriptors: retry shortly instead of spinning.
      spdlog::warn("net: accept failed: {}", error.message());
      self->accept_retry_timer_.expires_after(kAcceptRetryDelay);
      self->accept_retry_timer_.async_wait([self](const ErrorCode& wait_error) {
        if (!wait_error && !self->stopping_) self->do_accept();
      });
      return;
    }
    self->on_accepted(std::move(socket));
    self->do_accept();
  });
}

void PeerNetwork::Impl::on_accepted(tcp::socket socket) {
  update_counters([](NetworkCounters& counters) { ++counters.connections_accepted; });
  // Admission cap: connections that have not proven the key yet are few and short-lived.
  const auto pending = std::count_if(sessions_.begin(), sessions_.end(), [](const auto& entry) {
    const auto session = entry.second.lock();
    return session && (session->state == SessionState::kHandshaking ||
                       session->state == SessionState::kConnecting);
  });
  if (static_cast<std::size_t>(pending) >= options_.max_pending_handshakes) {
    update_counters([](NetworkCounters& counters) { ++counters.rejected_admission; });
    ErrorCode ignored;
    const auto remote = socket.remote_endpoint(ignored);
    warn_limited("admission " + remote.address().to_string(),
                 "net: refused a connection from {}: {} connections in the handshake (limit {})",
                 remote.address().to_string(), pending, options_.max_pending_handshakes);
    socket.close(ignored);
    return;
  }
  const auto session = make_session(Origin::kAccepted, "", std::move(socket));
  session->begin();
  if (session->state != SessionState::kClosed)
    spdlog::debug("net: accepted connection #{} from {}", session->id, session->remote);
}

std::shared_ptr<PeerNetwork::Impl::Session> PeerNetwork::Impl::make_session(Origin origin,
                                                                            std::string dial_key,
                                                                            tcp::socket socket) {
  const std::uint64_t id = next_session_id_++;
  auto session = std::make_shared<Session>(shared_from_this(), id, origin, std::move(dial_key),
                                           std::move(socket));
  sessions_[id] = session;
  update_counters([&](NetworkCounters& counters) { counters.open_connections = sessions_.size(); });
  return session;
}

PeerNetwork::Impl::DialTarget& PeerNetwork::Impl::ensure_target(const HostPort& address,
                                                                bool configured) {
  auto& target = targets_[address.to_string()];
  if (!target)
    target =
        std::make_unique<DialTarget>(address, configured, backoff_options_, random_(), strand_);
  target->configured = target->configured || configured;
  return *target;
}

bool PeerNetwork::Impl::wants_dial(const std::string& key, const DialTarget& target) const {
  if (!running_ || stopping_ || target.is_self || target.session_id != 0) return false;
  if (target.robot < 0) return true;
  const auto peer = peers_.find(target.robot);
  if (peer == peers_.end()) return true;
  // One address per robot is dialed: the one chosen for it (static peers take precedence).
  return peer->second.dial_key == key && !peer->second.up && !peer->second.goodbye_received;
}

void PeerNetwork::Impl::dial(const std::string& key) {
  const auto found = targets_.find(key);
  if (found == targets_.end()) return;
  DialTarget& target = *found->second;
  if (!wants_dial(key, target)) return;
  const auto session = make_session(Origin::kDialed, key, tcp::socket(strand_));
  target.session_id = session->id;
  spdlog::debug("net: dialing {} (connection #{})", key, session->id);
  session->connect(target.address);
}

void PeerNetwork::Impl::schedule_dial(const std::string& key) {
  const auto found = targets_.find(key);
  if (found == targets_.end()) return;
  DialTarget& target = *found->second;
  if (target.timer_armed || !wants_dial(key, target)) return;
  const auto delay = target.backoff.next();
  spdlog::debug("net: redialing {} in {} ms", key, delay.count());
  target.timer_armed = true;
  target.timer.expires_after(delay);
  target.timer.async_wait([self = shared_from_this(), key](const ErrorCode& error) {
    const auto again = self->targets_.find(key);
    if (again == self->targets_.end()) return;
    again->second->timer_armed = false;
    if (!error) self->dial(key);
  });
}

void PeerNetwork::Impl::on_connected(Session& session) {
  update_counters([](NetworkCounters& counters) { ++counters.connections_dialed; });
  spdlog::debug("net: connected to {} (connection #{})", session.dial_key, session.id);
}

void PeerNetwork::Impl::on_session_closed(const std::shared_ptr<Session>& session,
                                          SessionState previous, std::string_view reason) {
  sessions_.erase(session->id);
  update_counters([&](NetworkCounters& counters) {
    counters.open_connections = sessions_.size();
    if (previous == SessionState::kConnecting) ++counters.dial_failures;
  });
  if (previous == SessionState::kConnecting || previous == SessionState::kHandshaking)
    spdlog::debug("net: {} connection #{} {} closed before the handshake: {}",
                  to_string(session->origin), session->id, session->remote, reason);
  else
    spdlog::debug("net: connection #{} to robot {} closed: {}", session->id, session->robot,
                  reason);

  if (session->robot >= 0) {
    const auto peer = peers_.find(session->robot);
    if (peer != peers_.end() && peer->second.active.lock() == session) {
      peer->second.active.reset();
      mark_down(session->robot, peer->second, reason);
      if (!peer->second.dial_key.empty()) schedule_dial(peer->second.dial_key);
    }
  }
  if (session->origin == Origin::kDialed) {
    const auto target = targets_.find(session->dial_key);
    if (target != targets_.end() && target->second->session_id == session->id) {
      target->second->session_id = 0;
      schedule_dial(session->dial_key);
    }
  }
  if (stopping_ && sessions_.empty()) linger_timer_.cancel();
}

// ---------------------------------------------------------------------------------------------
// Impl: messages

v1::Envelope PeerNetwork::Impl::make_hello() const {
  v1::Envelope envelope;
  stamp(envelope);
  v1::Hello& hello = *envelope.mutable_hello();
  hello.set_robot_id(static_cast<std::uint32_t>(options_.robot_id));
  hello.set_listen_address(options_.advertised_address.empty() ? options_.listen_address
                                                               : options_.advertised_address);
  hello.set_listen_port(listen_port_.load());
  for (const std::string& capability : options_.capabilities) hello.add_capabilities(capability);
  hello.set_degree(degree());
  hello.set_instance(instance_);
  return envelope;
}

void PeerNetwork::Impl::fill_heartbeat(const Session& session, v1::Envelope& envelope) const {
  stamp(envelope);
  v1::Heartbeat& heartbeat = *envelope.mutable_heartbeat();
  heartbeat.set_time_ns(monotonic_ns());
  if (session.peer_heartbeat_ns != 0) {
    heartbeat.set_echo_time_ns(session.peer_heartbeat_ns);
    const auto held = Clock::now() - session.peer_heartbeat_received;
    heartbeat.set_echo_delay_ns(static_cast<std::uint64_t>(
        std::chrono::duration_cast<std::chrono::nanoseconds>(held).count()));
  }
  heartbeat.set_degree(degree());
}

std::uint32_t PeerNetwork::Impl::degree() const {
  return static_cast<std::uint32_t>(std::count_if(
      peers_.begin(), peers_.end(), [](const auto& entry) { return entry.second.up; }));
}

void PeerNetwork::Impl::on_bytes_in(const Session& session, std::size_t bytes) {
  std::lock_guard lock(stats_mutex_);
  counters_.bytes_in += bytes;
  if (session.robot < 0) return;
  PeerStats& stats = records_[session.robot].stats;
  stats.bytes_in += bytes;
  stats.last_seen = session.last_received;
}

void PeerNetwork::Impl::on_written(const Session& session, std::size_t bytes,
                                   std::size_t messages) {
  std::lock_guard lock(stats_mutex_);
  counters_.bytes_out += bytes;
  counters_.messages_out += messages;
  if (session.robot < 0) return;
  PeerStats& stats = records_[session.robot].stats;
  stats.bytes_out += bytes;
  stats.messages_out += messages;
}

void PeerNetwork::Impl::on_envelope(const std::shared_ptr<Session>& session,
                                    const v1::Envelope& envelope) {
  update_counters([](NetworkCounters& counters) { ++counters.messages_in; });
  switch (session->state) {
    case SessionState::kHandshaking:
      if (envelope.body_case() != v1::Envelope::kHello)
        return reject_handshake(session, "first message is not a Hello");
      return handle_hello(session, envelope);
    case SessionState::kEstablished:
    case SessionState::kRetiring:
      break;
    default:  // stopping: nothing is delivered any more
      return;
  }
  const int robot = session->robot;
  update_record(robot, [](PeerRecord& record) { ++record.stats.messages_in; });
  if (!session->confirmed) {
    session->confirmed = true;
    Peer& peer = peers_[robot];
    if (peer.active.lock() == session) {
      for (const auto& weak : peer.retiring)
        if (const auto retired = weak.lock()) retired->release();
      peer.retiring.clear();
    }
  }
  if (envelope.sender() != static_cast<std::uint32_t>(robot)) {
    update_counters([](NetworkCounters& counters) { ++counters.rejected_garbage; });
    update_record(robot, [](PeerRecord& record) { ++record.stats.protocol_errors; });
    warn_limited("sender " + std::to_string(robot),
                 "net: closing connection #{} to robot {} ({}): envelope from sender {}",
                 session->id, robot, session->remote, envelope.sender());
    return session->close("wrong sender");
  }
  switch (envelope.body_case()) {
    case v1::Envelope::kHello:  // repeated Hello: only the degree may have changed
      update_record(robot,
                    [&](PeerRecord& record) { record.stats.degree = envelope.hello().degree(); });
      return;
    case v1::Envelope::kHeartbeat:
      return handle_heartbeat(*session, envelope.heartbeat());
    case v1::Envelope::kGoodbye:
      return handle_goodbye(session, envelope);
    default:  // application messages, and bodies added by a later minor revision
      if (message_handler)
        invoke_user_callback("message handler", [&] { message_handler(robot, envelope); });
      return;
  }
}

void PeerNetwork::Impl::handle_hello(const std::shared_ptr<Session>& session,
                                     const v1::Envelope& envelope) {
  const v1::Hello& hello = envelope.hello();
  if (hello.robot_id() != envelope.sender())
    return reject_handshake(session, "Hello robot id " + std::to_string(hello.robot_id()) +
                                         " differs from its sender " +
                                         std::to_string(envelope.sender()));
  if (hello.robot_id() > static_cast<std::uint32_t>(std::numeric_limits<int>::max()))
    return reject_handshake(session,
                            "robot id " + std::to_string(hello.robot_id()) + " out of range");
  if (hello.listen_port() > 65535)
    return reject_handshake(session,
                            "listen port " + std::to_string(hello.listen_port()) + " out of range");
  const int robot = static_cast<int>(hello.robot_id());
  if (!options_.members.empty() &&
      std::find(options_.members.begin(), options_.members.end(), robot) == options_.members.end())
    return reject_handshake(session, "robot id " + std::to_string(robot) +
                                         " is not in the membership list");
  if (robot == options_.robot_id) {
    if (hello.instance() == instance_ && session->origin == Origin::kDialed) {
      const auto target = targets_.find(session->dial_key);
      if (target != targets_.end()) target->second->is_self = true;
      spdlog::info("net: {} is this daemon itself; not dialing it again", session->dial_key);
      return session->close("connected to ourselves");
    }
    if (hello.instance() == instance_) return session->close("connected to ourselves");
    return reject_handshake(session, "peer claims our own robot id " + std::to_string(robot));
  }

  session->robot = robot;
  session->instance = hello.instance();
  session->set_state(SessionState::kEstablished);
  Peer& peer = peers_[robot];
  peer.goodbye_received = false;  // it talks to us again: it came back

  // Where to redial it: the static address we dialed, else the address it announces.
  std::string dial_address;
  if (session->origin == Origin::kDialed) {
    DialTarget& target = *targets_.at(session->dial_key);
    target.robot = robot;
    target.backoff.reset();
    const auto current = targets_.find(peer.dial_key);
    if (current == targets_.end() || (!current->second->configured && target.configured))
      peer.dial_key = session->dial_key;
  } else if (peer.dial_key.empty() && hello.listen_port() != 0) {
    const HostPort address = announced_address(hello, session->remote_address);
    DialTarget& target = ensure_target(address, false);
    if (target.robot < 0) target.robot = robot;
    peer.dial_key = address.to_string();
  }
  if (!peer.dial_key.empty()) dial_address = peer.dial_key;

  update_counters([](NetworkCounters& counters) { ++counters.handshakes_completed; });
  update_record(robot, [&](PeerRecord& record) {
    ++record.stats.messages_in;
    record.stats.dial_address = dial_address;
    record.stats.degree = hello.degree();
    record.stats.capabilities.assign(hello.capabilities().begin(), hello.capabilities().end());
    record.stats.last_seen = session->last_received;
  });

  const auto active = peer.active.lock();
  if (!active)
    activate(robot, peer, session);
  else
    resolve_duplicate(robot, peer, active, session);
}

void PeerNetwork::Impl::activate(int robot, Peer& peer, const std::shared_ptr<Session>& session) {
  peer.active = session;
  const bool again = peer.ever_up;
  peer.up = true;
  peer.ever_up = true;
  update_record(robot, [&](PeerRecord& record) {
    record.stats.up = true;
    record.stats.connected_since = Clock::now();
    record.stats.address = session->remote;
    record.stats.instance = session->instance;
    if (again) ++record.stats.reconnects;
  });
  if (const auto target = targets_.find(peer.dial_key); target != targets_.end())
    target->second->backoff.reset();
  spdlog::info("net: robot {} up ({} connection #{} {}, instance {:016x}{})", robot,
               to_string(session->origin), session->id, session->remote, session->instance,
               again ? ", reconnected" : "");
  if (peer_handler) invoke_user_callback("peer handler", [&] { peer_handler(robot, true); });
}

void PeerNetwork::Impl::resolve_duplicate(int robot, Peer& peer,
                                          const std::shared_ptr<Session>& active,
                                          const std::shared_ptr<Session>& fresh) {
  if (fresh->instance != active->instance) {
    // The robot restarted: the old connection belongs to a process that no longer exists.
    spdlog::info("net: robot {} restarted (instance {:016x} -> {:016x}); dropping connection #{}",
                 robot, active->instance, fresh->instance, active->id);
    peer.active.reset();
    mark_down(robot, peer, "restarted");
    activate(robot, peer, fresh);
    active->close("robot restarted");
    return;
  }
  // Tie-break, computed identically on both ends: keep the connection dialed by the lower robot
  // id. Two connections dialed by the same side (rare: two addresses of one robot) keep the older.
  const int lower = std::min(robot, options_.robot_id);
  auto dialer = [&](const Session& session) {
    return session.origin == Origin::kDialed ? options_.robot_id : robot;
  };
  const bool keep_fresh = dialer(*fresh) == lower && dialer(*active) != lower;
  const std::shared_ptr<Session>& keep = keep_fresh ? fresh : active;
  const std::shared_ptr<Session>& retire = keep_fresh ? active : fresh;
  update_counters([](NetworkCounters& counters) { ++counters.duplicates_closed; });
  spdlog::info("net: two connections with robot {}: keeping #{} (dialed by robot {}), retiring #{}",
               robot, keep->id, dialer(*keep), retire->id);
  if (keep_fresh) {
    // Nothing is lost: messages not yet written move to the kept connection.
    for (Session::Outgoing& item : active->take_queued_data()) fresh->enqueue(std::move(item));
    peer.active = fresh;
    update_record(robot, [&](PeerRecord& record) { record.stats.address = fresh->remote; });
  }
  // The peer makes the same choice, but possibly later: closing the loser before the peer has
  // the kept connection established would look like a lost link to it. So the loser is
  // half-closed only once the kept connection carried something after the peer's Hello.
  retire->retire();
  if (keep->confirmed)
    retire->release();
  else
    peer.retiring.push_back(retire);
}

void PeerNetwork::Impl::handle_heartbeat(Session& session, const v1::Heartbeat& heartbeat) {
  session.peer_heartbeat_ns = heartbeat.time_ns();
  session.peer_heartbeat_received = Clock::now();
  std::int64_t rtt_ns = -1;
  if (heartbeat.echo_time_ns() != 0)  // RTT = now - echo_time_ns - echo_delay_ns
    rtt_ns = static_cast<std::int64_t>(monotonic_ns() - heartbeat.echo_time_ns() -
                                       heartbeat.echo_delay_ns());
  update_record(session.robot, [&](PeerRecord& record) {
    record.stats.degree = heartbeat.degree();
    if (rtt_ns < 0) return;
    ++record.stats.rtt_samples;
    record.rtt_mean_ns += (static_cast<double>(rtt_ns) - record.rtt_mean_ns) /
                          static_cast<double>(record.stats.rtt_samples);
    record.stats.rtt_last = std::chrono::nanoseconds(rtt_ns);
    record.stats.rtt_mean = std::chrono::nanoseconds(static_cast<std::int64_t>(record.rtt_mean_ns));
  });
}

void PeerNetwork::Impl::handle_goodbye(const std::shared_ptr<Session>& session,
                                       const v1::Envelope& envelope) {
  const int robot = session->robot;
  const std::string& reason = envelope.goodbye().reason();
  Peer& peer = peers_[robot];
  peer.goodbye_received = true;
  peer.goodbye_instance = session->instance;
  update_record(robot, [&](PeerRecord& record) { record.stats.last_goodbye = reason; });
  // The application sees the Goodbye (reason, last round) first, then the robot going down.
  if (message_handler)
    invoke_user_callback("message handler", [&] { message_handler(robot, envelope); });
  if (peer.active.lock() == session) {
    peer.active.reset();
    mark_down(robot, peer, "goodbye: " + reason);
  }
  session->close("goodbye: " + reason);
}

void PeerNetwork::Impl::reject_handshake(const std::shared_ptr<Session>& session,
                                         const std::string& reason) {
  update_counters([](NetworkCounters& counters) { ++counters.rejected_handshake; });
  warn_limited("handshake " + session->remote_address.to_string(),
               "net: rejected {} connection #{} {}: {}", to_string(session->origin), session->id,
               session->remote, reason);
  session->close(reason);
}

void PeerNetwork::Impl::on_channel_failed(const std::shared_ptr<Session>& session,
                                          const std::string& reason) {
  update_counters([](NetworkCounters& counters) { ++counters.rejected_unauthenticated; });
  reject_handshake(session, "channel handshake failed: " + reason);
}

void PeerNetwork::Impl::on_frame_error(const std::shared_ptr<Session>& session,
                                       const FrameError& error) {
  const bool handshaking = session->state == SessionState::kHandshaking;
  const bool mismatch =
      error.kind == FrameErrorKind::kWrongVersion || error.kind == FrameErrorKind::kWrongTeam;
  if (handshaking && mismatch) return reject_handshake(session, error.reason);
  update_counters([&](NetworkCounters& counters) {
    if (error.kind == FrameErrorKind::kOversized)
      ++counters.rejected_oversized;
    else
      ++counters.rejected_garbage;
    if (error.kind == FrameErrorKind::kUnauthenticated) ++counters.rejected_unauthenticated;
  });
  if (session->robot >= 0)
    update_record(session->robot, [](PeerRecord& record) { ++record.stats.protocol_errors; });
  warn_limited("frame " + session->remote_address.to_string() + " " +
                   std::string(to_string(error.kind)),
               "net: closing {} connection #{} {} (robot {}): {} frame: {}",
               to_string(session->origin), session->id, session->remote, session->robot,
               to_string(error.kind), error.reason);
  session->close(error.reason);
}

void PeerNetwork::Impl::mark_down(int robot, Peer& peer, std::string_view reason) {
  if (!peer.up) return;
  peer.up = false;
  update_record(robot, [](PeerRecord& record) { record.stats.up = false; });
  spdlog::info("net: robot {} down: {}", robot, reason);
  if (peer_handler) invoke_user_callback("peer handler", [&] { peer_handler(robot, false); });
}

// ---------------------------------------------------------------------------------------------
// Impl: sending

void PeerNetwork::Impl::count_send_drop(int robot) {
  std::lock_guard lock(stats_mutex_);
  ++counters_.send_drops;
  if (const auto record = records_.find(robot); record != records_.end())
    ++record->second.stats.drops;
}

bool PeerNetwork::Impl::send(int robot, const v1::Envelope& envelope) {
  auto stamped = std::make_shared<v1::Envelope>(envelope);
  stamp(*stamped);
  const std::size_t bytes = stamped->ByteSizeLong();
  if (bytes > options_.max_frame_bytes) {
    if (!oversize_send_logged_.exchange(true))
      spdlog::error(
          "net: not sending an envelope of {} bytes (max_frame_bytes {}); further such "
          "envelopes are dropped silently and counted",
          bytes, options_.max_frame_bytes);
    count_send_drop(robot);
    return false;
  }
  {
    std::lock_guard lock(stats_mutex_);
    const auto record = records_.find(robot);
    if (record == records_.end() || !record->second.stats.up) {
      ++counters_.send_drops;
      if (record != records_.end()) ++record->second.stats.drops;
      return false;
    }
  }
  asio::post(strand_, [self = shared_from_this(), robot,
                       envelope = std::shared_ptr<const v1::Envelope>(std::move(stamped))] {
    self->enqueue_data(robot, envelope);
  });
  return true;
}

int PeerNetwork::Impl::broadcast(const v1::Envelope& envelope) {
  int queued = 0;
  for (const int robot : live_peers()) queued += send(robot, envelope) ? 1 : 0;
  return queued;
}

void PeerNetwork::Impl::enqueue_data(int robot,
                                     const std::shared_ptr<const v1::Envelope>& envelope) {
  const auto peer = peers_.find(robot);
  const auto session =
      peer != peers_.end() && peer->second.up ? peer->second.active.lock() : nullptr;
  if (!session || stopping_) return count_send_drop(robot);
  if (session->enqueue({Session::Outgoing::Kind::kData, envelope, {}}) == 0) return;
  count_send_drop(robot);
  Peer& overflowing = peer->second;
  ++overflowing.drops_since_log;
  const auto now = Clock::now();
  if (overflowing.last_overflow_log && now - *overflowing.last_overflow_log < kOverflowLogPeriod)
    return;
  spdlog::warn("net: send queue to robot {} full ({} messages): dropped the oldest {} message(s)",
               robot, options_.send_queue_limit, overflowing.drops_since_log);
  overflowing.last_overflow_log = now;
  overflowing.drops_since_log = 0;
}

// ---------------------------------------------------------------------------------------------
// Impl: watchdog (hello deadline, heartbeats, silence, stalled writes)

void PeerNetwork::Impl::arm_tick() {
  tick_timer_.expires_after(options_.heartbeat_interval);
  tick_timer_.async_wait([self = shared_from_this()](const ErrorCode& error) {
    if (!error && !self->stopping_) self->on_tick();
  });
}

void PeerNetwork::Impl::on_tick() {
  const auto now = Clock::now();
  std::vector<std::shared_ptr<Session>> sessions;
  for (const auto& [id, weak] : sessions_)
    if (auto session = weak.lock()) sessions.push_back(std::move(session));
  for (const auto& session : sessions) {
    switch (session->state) {
      case SessionState::kConnecting:
        if (now - session->created > options_.hello_timeout)
          session->close("connect timed out after " +
                         std::to_string(options_.hello_timeout.count()) + " ms");
        break;
      case SessionState::kHandshaking:
        if (now - session->created > options_.hello_timeout)
          reject_handshake(
              session, "no Hello within " + std::to_string(options_.hello_timeout.count()) + " ms");
        break;
      case SessionState::kEstablished:
        if (now - session->last_received > options_.heartbeat_timeout) {
          update_counters([](NetworkCounters& counters) { ++counters.heartbeat_timeouts; });
          spdlog::warn("net: robot {} silent for {} ms on connection #{}; closing it",
                       session->robot, milliseconds(now - session->last_received), session->id);
          session->close("heartbeat timeout");
        } else if (session->writing() &&
                   now - session->write_progress > options_.heartbeat_timeout) {
          update_counters([](NetworkCounters& counters) { ++counters.write_stalls; });
          spdlog::warn("net: write to robot {} stalled for {} ms on connection #{}; closing it",
                       session->robot, milliseconds(now - session->write_progress), session->id);
          session->close("write stalled");
        } else {
          session->enqueue({Session::Outgoing::Kind::kHeartbeat, nullptr, {}});
        }
        break;
      case SessionState::kRetiring:
        if (now - session->state_since > options_.heartbeat_timeout)
          session->close("retired connection not closed by the peer");
        break;
      case SessionState::kClosing:
      case SessionState::kClosed:
        break;
    }
  }
  arm_tick();
}

// ---------------------------------------------------------------------------------------------
// Impl: stop

void PeerNetwork::Impl::stop(std::string reason, std::uint64_t last_round) {
  asio::post(strand_, [self = shared_from_this(), reason = std::move(reason), last_round] {
    self->do_stop(reason, last_round);
  });
}

void PeerNetwork::Impl::detach_and_stop() {
  asio::post(strand_, [self = shared_from_this()] {
    self->message_handler = nullptr;
    self->peer_handler = nullptr;
    self->do_stop("shutting down", 0);
  });
}

void PeerNetwork::Impl::do_stop(const std::string& reason, std::uint64_t last_round) {
  if (stopping_) return;
  stopping_ = true;
  ErrorCode ignored;
  acceptor_.close(ignored);
  discovery_socket_.close(ignored);
  if (!running_) return;
  spdlog::info("net: robot {} stopping: {}", options_.robot_id, reason);
  accept_retry_timer_.cancel();
  tick_timer_.cancel();
  beacon_timer_.cancel();
  for (const auto& [key, target] : targets_) target->timer.cancel();

  auto goodbye = std::make_shared<v1::Envelope>();
  stamp(*goodbye);
  goodbye->mutable_goodbye()->set_reason(reason);
  goodbye->mutable_goodbye()->set_last_round(last_round);
  std::vector<std::shared_ptr<Session>> sessions;
  for (const auto& [id, weak] : sessions_)
    if (auto session = weak.lock()) sessions.push_back(std::move(session));
  for (const auto& session : sessions) session->finish(goodbye);  // closes unestablished ones
  for (auto& [robot, peer] : peers_) {
    peer.active.reset();
    mark_down(robot, peer, "stopping: " + reason);
  }
  if (sessions_.empty()) return;
  // Peers close when they read the Goodbye; whoever does not is closed after stop_linger.
  linger_timer_.expires_after(options_.stop_linger);
  linger_timer_.async_wait([self = shared_from_this()](const ErrorCode& error) {
    if (error) return;
    std::vector<std::shared_ptr<Session>> remaining;
    for (const auto& [id, weak] : self->sessions_)
      if (auto session = weak.lock()) remaining.push_back(std::move(session));
    for (const auto& session : remaining) session->close("stop linger expired");
  });
}

// ---------------------------------------------------------------------------------------------
// Impl: UDP beacon discovery

void PeerNetwork::Impl::open_discovery() {
  const DiscoveryOptions& discovery = options_.discovery;
  const auto destination = asio::ip::make_address_v4(discovery.address);
  ErrorCode error;
  discovery_socket_.open(udp::v4(), error);
  if (!error) discovery_socket_.set_option(udp::socket::reuse_address(true), error);
  if (!error) discovery_socket_.bind(udp::endpoint(udp::v4(), discovery.port), error);
  if (!error && destination.is_multicast()) {
    if (discovery.interface_address.empty()) {
      discovery_socket_.set_option(asio::ip::multicast::join_group(destination), error);
    } else {
      const auto local_interface = asio::ip::make_address_v4(discovery.interface_address);
      discovery_socket_.set_option(asio::ip::multicast::join_group(destination, local_interface),
                                   error);
      if (!error)
        discovery_socket_.set_option(asio::ip::multicast::outbound_interface(local_interface),
                                     error);
    }
    if (!error) discovery_socket_.set_option(asio::ip::multicast::enable_loopback(true), error);
    if (!error) discovery_socket_.set_option(asio::ip::multicast::hops(1), error);
  } else if (!error) {
    discovery_socket_.set_option(udp::socket::broadcast(true), error);
  }
  if (error)
    throw std::runtime_error("net: cannot open discovery on " + discovery.address + ":" +
                             std::to_string(discovery.port) + ": " + error.message());
  beacon_destination_ = udp::endpoint(destination, discovery.port);
}

void PeerNetwork::Impl::arm_beacon() {
  if (stopping_) return;
  if (!beacon_in_flight_) {
    // Sealed with the team key: an outsider learns nothing from a beacon.
    beacon_out_ = seal_beacon(*options_.team_key, make_hello().SerializeAsString());
    beacon_in_flight_ = true;
    discovery_socket_.async_send_to(
        asio::buffer(beacon_out_), beacon_destination_,
        [self = shared_from_this()](const ErrorCode& error, std::size_t) {
          self->beacon_in_flight_ = false;
          if (error == asio::error::operation_aborted) return;
          if (error)
            spdlog::debug("net: beacon to {} failed: {}",
                          self->beacon_destination_.address().to_string(), error.message());
          else
            self->update_counters([](NetworkCounters& counters) { ++counters.beacons_sent; });
        });
  }
  beacon_timer_.expires_after(options_.discovery.interval);
  beacon_timer_.async_wait([self = shared_from_this()](const ErrorCode& error) {
    if (!error) self->arm_beacon();
  });
}

void PeerNetwork::Impl::do_receive_beacon() {
  discovery_socket_.async_receive_from(
      asio::buffer(beacon_in_), beacon_sender_,
      [self = shared_from_this()](const ErrorCode& error, std::size_t bytes) {
        if (self->stopping_ || error == asio::error::operation_aborted) return;
        if (!error) self->on_beacon(bytes);
        self->do_receive_beacon();
      });
}

void PeerNetwork::Impl::on_beacon(std::size_t bytes) {
  v1::Envelope envelope;
  const std::optional<std::string> plaintext =
      open_beacon(*options_.team_key, std::string_view(beacon_in_.data(), bytes));
  const FrameError error =
      plaintext ? parse_envelope(*plaintext, options_.team, envelope)
                : FrameError{FrameErrorKind::kUnauthenticated, "not sealed with the team key"};
  const bool valid =
      error.kind == FrameErrorKind::kNone && envelope.body_case() == v1::Envelope::kHello &&
      envelope.hello().robot_id() == envelope.sender() && envelope.hello().listen_port() != 0 &&
      envelope.hello().listen_port() <= 65535 &&
      envelope.sender() <= static_cast<std::uint32_t>(std::numeric_limits<int>::max());
  if (!valid) {
    update_counters([](NetworkCounters& counters) { ++counters.beacons_rejected; });
    spdlog::debug("net: ignored beacon from {}: {}", beacon_sender_.address().to_string(),
                  error.kind != FrameErrorKind::kNone ? error.reason
                                                      : std::string("not a valid Hello"));
    return;
  }
  const int robot = static_cast<int>(envelope.sender());
  if (robot == options_.robot_id) return;  // our own beacon, looped back
  update_counters([](NetworkCounters& counters) { ++counters.beacons_received; });
  const v1::Hello& hello = envelope.hello();
  const auto peer = peers_.find(robot);
  if (peer != peers_.end()) {
    if (peer->second.up) return;
    if (peer->second.goodbye_received) {
      if (hello.instance() == peer->second.goodbye_instance) return;  // still the one that left
      peer->second.goodbye_received = false;                          // it came back
    }
  }
  std::string key;
  if (peer != peers_.end() && !peer->second.dial_key.empty()) {
    key = peer->second.dial_key;
  } else {
    const HostPort address = announced_address(hello, beacon_sender_.address());
    key = address.to_string();
    DialTarget& target = ensure_target(address, false);
    if (target.robot < 0) target.robot = robot;
    if (peer != peers_.end()) peer->second.dial_key = key;
  }
  DialTarget& target = *targets_.at(key);
  if (target.timer_armed || !wants_dial(key, target)) return;
  spdlog::info("net: beacon from robot {}: dialing {}", robot, key);
  dial(key);
}

// ---------------------------------------------------------------------------------------------
// Impl: snapshots

std::vector<PeerStats> PeerNetwork::Impl::peers() const {
  std::lock_guard lock(stats_mutex_);
  std::vector<PeerStats> result;
  result.reserve(records_.size());
  for (const auto& [robot, record] : records_) result.push_back(record.stats);
  return result;
}

NetworkCounters PeerNetwork::Impl::totals() const {
  NetworkCounters counters;
  {
    std::lock_guard lock(stats_mutex_);
    counters = counters_;
  }
  counters.log_lines_suppressed = log_limiter_.suppressed_total();
  return counters;
}

std::vector<int> PeerNetwork::Impl::live_peers() const {
  std::lock_guard lock(stats_mutex_);
  std::vector<int> result;
  for (const auto& [robot, record] : records_)
    if (record.stats.up) result.push_back(robot);
  return result;
}

// ---------------------------------------------------------------------------------------------
// PeerNetwork

PeerNetwork::PeerNetwork(boost::asio::io_context& io, PeerNetworkOptions options)
    : impl_(std::make_shared<Impl>(io, std::move(options))) {}

PeerNetwork::~PeerNetwork() { impl_->detach_and_stop(); }

void PeerNetwork::set_message_handler(MessageHandler handler) {
  impl_->message_handler = std::move(handler);
}

void PeerNetwork::set_peer_handler(PeerHandler handler) {
  impl_->peer_handler = std::move(handler);
}

void PeerNetwork::start() { impl_->start(); }

void PeerNetwork::stop(std::string reason, std::uint64_t last_round) {
  impl_->stop(std::move(reason), last_round);
}

void PeerNetwork::add_peer(HostPort address) { impl_->add_peer(std::move(address)); }

std::uint16_t PeerNetwork::listen_port() const { return impl_->listen_port(); }

bool PeerNetwork::send(int robot, const v1::Envelope& envelope) {
  return impl_->send(robot, envelope);
}

int PeerNetwork::broadcast(const v1::Envelope& envelope) { return impl_->broadcast(envelope); }

std::vector<PeerStats> PeerNetwork::peers() const { return impl_->peers(); }

NetworkCounters PeerNetwork::totals() const { return impl_->totals(); }

std::vector<int> PeerNetwork::live_peers() const { return impl_->live_peers(); }

const PeerNetworkOptions& PeerNetwork::options() const { return impl_->options(); }

}  // namespace concord::net

#pragma once
// Internal to net/: the PeerNetwork implementation shared by its source files, split along its
// seams: peer_network.cc (options, setup, sending, watchdog, stop, snapshots, the public API),
// peer_handshake.cc (connections, the Hello handshake and the peer table), peer_discovery.cc
// (UDP beacons). The Session class (one TCP connection) is defined here.
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

#include "concord/net/frame_codec.h"
#include "concord/net/log_limiter.h"
#include "concord/net/peer_network.h"
#include "concord/net/reconnect_backoff.h"
#include "concord/net/secure_channel.h"
#include "concord/v1/concord.pb.h"

namespace concord::net {

namespace peer_detail {

namespace asio = boost::asio;
using tcp = asio::ip::tcp;
using udp = asio::ip::udp;
using Clock = std::chrono::steady_clock;
using Strand = asio::strand<asio::io_context::executor_type>;
using ErrorCode = boost::system::error_code;

constexpr std::size_t kWriteBatchBytes = 1 << 20;  // frames coalesced into one async_write
constexpr std::size_t kMaxBeaconBytes = 1400;      // fits one Ethernet datagram
constexpr auto kAcceptRetryDelay = std::chrono::milliseconds(100);
constexpr auto kOverflowLogPeriod = std::chrono::seconds(5);  // at most one overflow line per peer

/// Monotonic clock in ns for heartbeats; never 0 (0 means "no heartbeat" in echo_time_ns).
inline std::uint64_t monotonic_ns() {
  const auto ns =
      std::chrono::duration_cast<std::chrono::nanoseconds>(Clock::now().time_since_epoch());
  return std::max<std::uint64_t>(1, static_cast<std::uint64_t>(ns.count()));
}

inline std::string endpoint_string(const asio::ip::address& address, std::uint16_t port) {
  return HostPort{address.to_string(), port}.to_string();
}

/// Where a robot accepts connections, from its Hello (or beacon): the address it announces, or the
/// source address of its connection/datagram when it announces none or an unspecified one.
inline HostPort announced_address(const v1::Hello& hello, const asio::ip::address& source) {
  ErrorCode error;
  const auto announced = asio::ip::make_address(hello.listen_address(), error);
  const bool use_source = hello.listen_address().empty() || (!error && announced.is_unspecified());
  return {use_source ? source.to_string() : hello.listen_address(),
          static_cast<std::uint16_t>(hello.listen_port())};
}

/// The HTTP endpoint "host:port" a Hello announces ("" for none, a port out of range or an
/// address that is not an IP literal: a peer's word is never a host name to resolve).
inline std::string announced_http_endpoint(const v1::Hello& hello,
                                           const asio::ip::address& source) {
  if (hello.http_port() == 0 || hello.http_port() > 65535) return {};
  ErrorCode error;
  const auto announced = asio::ip::make_address(hello.http_address(), error);
  if (!hello.http_address().empty() && error) return {};
  const bool use_source = hello.http_address().empty() || announced.is_unspecified();
  return HostPort{use_source ? source.to_string() : announced.to_string(),
                  static_cast<std::uint16_t>(hello.http_port())}
      .to_string();
}

inline std::int64_t milliseconds(std::chrono::nanoseconds duration) {
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

inline std::string_view to_string(Origin origin) {
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

}  // namespace peer_detail

using namespace peer_detail;

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
  void set_static_peers(std::vector<HostPort> addresses);
  std::uint16_t listen_port() const { return listen_port_.load(); }
  /// Stamps `envelope` (sender, team, version) and queues it to `robot`.
  bool send(int robot, std::shared_ptr<v1::Envelope> envelope);
  int broadcast(const v1::Envelope& envelope);
  std::vector<PeerStats> peers() const;
  NetworkCounters totals() const;
  std::vector<int> live_peers() const;
  const PeerNetworkOptions& options() const { return options_; }

  MessageHandler message_handler;  // set before start(), then only read on the strand
  PeerHandler peer_handler;

  // Called by sessions, on the strand.
  /// Our Hello: on a connection whose channel is established, signed with our identity if any;
  /// in a discovery beacon (no channel), unsigned.
  v1::Envelope make_hello(const SecureChannel* channel) const;
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
    bool retired = false;  // removed from the static list (SIGHUP): not dialed until learned again
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
  void enqueue_data(int robot, const std::shared_ptr<v1::Envelope>& envelope);
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
    // Null for kHeartbeat (built when written). Its seq is set on the strand just before it is
    // serialized (a Goodbye shared by every session gets each session's seq in turn).
    std::shared_ptr<v1::Envelope> envelope;
    std::string channel_payload;  // kChannel: a handshake message, unencrypted
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
  void finish(std::shared_ptr<v1::Envelope> goodbye) {
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

  const SecureChannel& channel() const { return channel_; }

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
      if (!channel_.open(payload_, plaintext_in_, error))
        return network_->on_frame_error(self, {FrameErrorKind::kUnauthenticated, error});
      FrameError check = parse_envelope(plaintext_in_, network_->options_.team, envelope_);
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
    enqueue({Outgoing::Kind::kControl,
             std::make_shared<v1::Envelope>(network_->make_hello(&channel_)),
             {}});
  }

  /// Takes `bytes` and `frames` from the token buckets; how long to pause reading (<= 0: none).
  Clock::duration spend_budget(std::size_t bytes, std::size_t frames) {
    const auto now = Clock::now();
    const double elapsed = std::chrono::duration<double>(now - tokens_refilled_).count();
    tokens_refilled_ = now;
    const auto byte_rate = static_cast<double>(network_->options_.receive_bytes_per_second);
    const auto message_rate = static_cast<double>(network_->options_.receive_messages_per_second);
    byte_tokens_ =
        std::min(2.0 * byte_rate, byte_tokens_ + elapsed * byte_rate) - static_cast<double>(bytes);
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
      v1::Envelope* envelope = item.envelope.get();
      if (item.kind == Outgoing::Kind::kHeartbeat) {
        heartbeat_queued_ = false;
        scratch_.Clear();
        network_->fill_heartbeat(*this, scratch_);
        envelope = &scratch_;
      } else if (item.kind == Outgoing::Kind::kData) {
        --data_queued_;
      }
      envelope->set_seq(++seq_out_);
      envelope->SerializeToString(&plaintext_);
      // Sealed straight into the write buffer, behind its frame header.
      channel_.seal(plaintext_, append_raw_frame_space(plaintext_.size() + kChannelOverheadBytes,
                                                       write_buffer_));
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
  std::string payload_;       // last frame payload
  std::string plaintext_;     // envelope being sealed
  std::string plaintext_in_;  // envelope just opened (its storage kept between messages)
  v1::Envelope envelope_;     // last decoded
  std::deque<Outgoing> queue_;
  std::size_t data_queued_ = 0;
  bool heartbeat_queued_ = false;
  bool writing_ = false;
  bool shutdown_after_flush_ = false;
  bool half_closed_ = false;
  std::string write_buffer_;
  v1::Envelope scratch_;  // heartbeat being encoded
  std::uint64_t seq_out_ = 0;
};

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

}  // namespace concord::net

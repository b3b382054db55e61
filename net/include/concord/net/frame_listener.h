#pragma once
/// \file
/// A TCP port that accepts framed envelopes one way (live ingest of SensorFrame envelopes from a
/// sensor process): same framing and maximum frame size as the peer network; with a team key,
/// the same authenticated channel as peer connections (the sender dials, so it initiates), and
/// otherwise plaintext (loopback only: the daemon refuses plaintext on another address).
/// Backpressure: when the handler cannot take an envelope, that connection stops reading until
/// it can, so a sender that outruns the daemon is slowed down by TCP, never silently dropped. Each
/// connection is read frame by frame and every valid envelope goes to one handler; a bad frame
/// closes only that connection. Runs on a caller-owned io_context (one strand), like PeerNetwork.
/// This header includes neither Asio nor protobuf.

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "concord/net/frame_codec.h"
#include "concord/net/team_key.h"

namespace boost::asio {
class io_context;
}  // namespace boost::asio

namespace concord::v1 {
class Envelope;
}  // namespace concord::v1

namespace concord::net {

struct FrameListenerOptions {
  std::string listen_address = "127.0.0.1";  ///< IP literal; loopback by default
  std::uint16_t port = 0;                    ///< 0: an ephemeral port, see port()
  std::size_t max_frame_bytes = kDefaultMaxFrameBytes;
  std::string team;  ///< envelopes must carry this team; "" accepts any team
  /// A connection silent for this long is closed; 0 disables the deadline.
  std::chrono::milliseconds idle_timeout{0};
  std::size_t max_connections = 16;  ///< further connections are closed at once
  /// When set, every connection must run the authenticated channel with this key first.
  std::shared_ptr<const TeamKey> team_key;
  /// While the handler refuses an envelope (busy), it is offered again after this long.
  std::chrono::milliseconds busy_retry{5};

  /// Problems with the options, one message per bad field; empty if OK.
  std::vector<std::string> validate() const;
};

struct FrameListenerCounters {
  std::uint64_t connections_accepted = 0;
  std::uint64_t connections_refused = 0;  ///< above max_connections
  std::uint64_t open_connections = 0;
  std::uint64_t frames = 0;  ///< envelopes delivered
  std::uint64_t bytes = 0;
  std::uint64_t rejected_oversized = 0;  ///< connections closed for a frame above the maximum
  std::uint64_t rejected_garbage = 0;    ///< ... for a zero-length, unparsable or foreign frame
  std::uint64_t idle_timeouts = 0;
  std::uint64_t rejected_unauthenticated = 0;  ///< failed channel handshakes and messages
  std::uint64_t busy_pauses = 0;  ///< times a connection paused reading: the handler was busy
  std::uint64_t log_lines_suppressed = 0;  ///< rate-limited log lines about senders
};

class FrameListener {
 public:
  /// One valid envelope from connection `connection` (a per-listener serial number). Returns
  /// false if it cannot take the envelope now (e.g. a full queue): the connection stops reading
  /// and offers the same envelope again after busy_retry (backpressure to the sender).
  using EnvelopeHandler = std::function<bool(std::uint64_t connection, const v1::Envelope&)>;
  /// A connection ended ("connection closed by the peer", a frame error, idle timeout, stop).
  using CloseHandler = std::function<void(std::uint64_t connection, const std::string& reason)>;

  /// `io` must outlive this object.
  FrameListener(boost::asio::io_context& io, FrameListenerOptions options);
  /// Requests stop(); destroy only once the io_context no longer runs its handlers.
  ~FrameListener();
  FrameListener(const FrameListener&) = delete;
  FrameListener& operator=(const FrameListener&) = delete;

  /// Set before start(); called on the io_context.
  void set_envelope_handler(EnvelopeHandler handler);
  void set_close_handler(CloseHandler handler);

  /// Validates (std::invalid_argument), binds (std::runtime_error), starts accepting. Once.
  void start();
  /// Closes the port and every connection; the io_context then runs out of its work. Any thread.
  void stop();

  /// The bound port (after start()).
  std::uint16_t port() const;
  /// Snapshot. Any thread.
  FrameListenerCounters counters() const;

 private:
  class Impl;
  std::shared_ptr<Impl> impl_;
};

}  // namespace concord::net

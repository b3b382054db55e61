#pragma once
/// \file
/// The robot-to-robot network of one daemon: a TCP peer-to-peer mesh carrying concord.v1
/// envelopes (see docs/network.md for the protocol and its behaviour).
///
/// A `PeerNetwork` accepts connections, dials configured and discovered peers, performs the Hello
/// handshake, keeps exactly one connection per robot pair, sends heartbeats (liveness and RTT),
/// reconnects with exponential backoff and delivers every application message to one handler.
/// It runs on an io_context that the caller owns and runs; all its handlers and callbacks run on
/// that io_context (serialized by one strand, so running the io_context on several threads is
/// allowed). This header includes neither Asio nor protobuf.

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "concord/net/frame_codec.h"
#include "concord/net/host_port.h"
#include "concord/net/identity.h"
#include "concord/net/team_key.h"

namespace boost::asio {
class io_context;
}  // namespace boost::asio

namespace concord::v1 {
class Envelope;
}  // namespace concord::v1

namespace concord::net {

/// UDP beacon discovery. Each daemon periodically sends a beacon (one frame holding an Envelope
/// with a Hello: team, robot id, listen port, instance) to `address:port` and listens on `port`;
/// on hearing a beacon of its team from a robot it is not connected to, it dials that robot.
struct DiscoveryOptions {
  bool enabled = false;                      ///< off by default
  std::string address = "239.255.76.1";      ///< multicast group, or a broadcast address
  std::uint16_t port = 47600;                ///< UDP port beacons are sent to and heard on
  std::chrono::milliseconds interval{1000};  ///< time between beacons
  /// Local IPv4 address of the interface used for multicast ("" = the system's choice).
  std::string interface_address;
};

/// Configuration of one daemon's network. Every field has a usable default except robot_id.
struct PeerNetworkOptions {
  /// The team's pre-shared key (required). Every connection runs the authenticated channel of
  /// secure_channel.h; nothing about the team is sent before the peer proved this key.
  std::shared_ptr<const TeamKey> team_key;
  std::string team = "concord";            ///< daemons of different teams never talk
  int robot_id = 0;                        ///< this robot's id, unique in the team (>= 0)
  std::string listen_address = "0.0.0.0";  ///< IP literal to accept connections on
  std::uint16_t listen_port = 0;           ///< 0: an ephemeral port, see listen_port()
  /// Address announced in Hello and beacons ("" = listen_address; peers replace an unspecified
  /// address such as 0.0.0.0 by the source address of the connection).
  std::string advertised_address;
  std::vector<std::string> peers;  ///< static peers, "host:port"; robot ids learned from Hello
  std::size_t max_frame_bytes = kDefaultMaxFrameBytes;  ///< hard maximum of a received frame
  /// Application messages queued per peer; when full, the oldest queued application message is
  /// dropped (and counted). Control messages (Hello, Heartbeat, Goodbye) are never dropped.
  std::size_t send_queue_limit = 256;
  std::chrono::milliseconds heartbeat_interval{1000};  ///< heartbeat period and watchdog tick
  std::chrono::milliseconds heartbeat_timeout{5000};  ///< silence after which a peer is down
  std::chrono::milliseconds hello_timeout{2000};      ///< connect + handshake deadline
  std::chrono::milliseconds reconnect_initial{100};   ///< first reconnect delay
  std::chrono::milliseconds reconnect_max{5000};      ///< cap of the reconnect delay
  double reconnect_jitter = 0.2;                      ///< +-20% on every reconnect delay
  /// How long stop() waits for peers to read the Goodbye and close before closing anyway.
  std::chrono::milliseconds stop_linger{500};
  std::vector<std::string> capabilities;  ///< announced in Hello, e.g. "consensus.lockstep"
  /// This daemon's HTTP endpoint, announced in Hello (http_port 0: none). An unspecified
  /// http_address (0.0.0.0, "") is replaced by the peer with the connection's source address.
  std::string http_address;
  std::uint16_t http_port = 0;
  DiscoveryOptions discovery;
  /// The membership list: robot ids allowed in the team. A Hello with another id is refused
  /// (counted in rejected_handshake). Empty = any id (tests; a daemon always sets it).
  std::vector<int> members;
  /// Per-robot identities (identity.h). With member_keys set, every Hello must carry its robot's
  /// signature of the channel binding, verified with that robot's key here: a robot without a
  /// key, or whose signature does not verify, is refused (rejected_identity). identity (required
  /// then, its public key the one listed for robot_id) signs this daemon's Hello. Empty = the
  /// team key alone admits any member id.
  std::shared_ptr<const RobotIdentity> identity;
  MemberKeys member_keys;
  /// Admission cap: connections not yet through the handshake, at most; a further connection is
  /// closed at once (counted in rejected_admission).
  std::size_t max_pending_handshakes = 16;
  /// Receive budget of one connection: bytes per second. Reading pauses while a connection is
  /// over budget (bursts of two seconds' worth pass), so a flooding peer is slowed by TCP.
  std::size_t receive_bytes_per_second = std::size_t{32} << 20;
  /// Receive budget of one connection: envelopes per second (same rule).
  std::size_t receive_messages_per_second = 4000;

  /// Problems with the options, one message per bad field naming it and its value; empty if OK.
  std::vector<std::string> validate() const;
  /// One line listing every option, for the start-up log.
  std::string describe() const;
};

/// What the network knows about one robot (a snapshot).
struct PeerStats {
  int robot = -1;
  std::string address;       ///< remote endpoint of the current (or last) connection
  std::string dial_address;  ///< where this robot is redialed ("" if unknown)
  bool up = false;
  std::chrono::steady_clock::time_point connected_since{};  ///< when it last came up
  std::chrono::steady_clock::time_point last_seen{};        ///< last byte received from it
  std::uint64_t bytes_in = 0;  ///< including frame headers and control messages
  std::uint64_t bytes_out = 0;
  std::uint64_t messages_in = 0;  ///< envelopes of every kind
  std::uint64_t messages_out = 0;
  std::uint64_t drops = 0;  ///< messages to this robot dropped (queue full, or sent while down)
  std::chrono::nanoseconds rtt_last{0};  ///< last heartbeat round trip
  std::chrono::nanoseconds rtt_mean{0};  ///< mean over all round trips measured
  std::uint64_t rtt_samples = 0;
  std::uint64_t reconnects = 0;       ///< times it came up again after having been up
  std::uint64_t protocol_errors = 0;  ///< its connections closed for a protocol violation
  std::uint32_t degree = 0;           ///< its live neighbours, from its last Hello/Heartbeat
  std::uint64_t instance = 0;         ///< its per-process nonce, from Hello
  std::vector<std::string> capabilities;
  /// Its HTTP endpoint "host:port" from Hello ("" if it serves none or announced an unusable
  /// address): what the live map page follows to draw the neighbours.
  std::string http_endpoint;
  std::string last_goodbye;  ///< reason of its last Goodbye ("" if none)
};

/// Totals over all connections since start().
struct NetworkCounters {
  std::uint64_t connections_accepted = 0;
  std::uint64_t connections_dialed = 0;  ///< outgoing TCP connections established
  std::uint64_t dial_failures = 0;       ///< resolve/connect errors and connect timeouts
  std::uint64_t handshakes_completed = 0;
  std::uint64_t rejected_oversized = 0;  ///< connections closed for a frame above the maximum
  std::uint64_t rejected_garbage = 0;    ///< ... for a zero-length or unparsable frame, or a
                                         ///< bad envelope after the handshake
  /// Connections closed during the handshake: other team or protocol version, our own robot id,
  /// first message not a Hello, no Hello within hello_timeout.
  std::uint64_t rejected_handshake = 0;
  /// Connections closed at once because max_pending_handshakes were in the handshake.
  std::uint64_t rejected_admission = 0;
  /// Connections whose peer failed the channel handshake (no key, wrong key, not Concord v2) or
  /// sent a message that failed authentication. Also counted in rejected_handshake/garbage.
  std::uint64_t rejected_unauthenticated = 0;
  /// Connections whose Hello was not signed by the identity key of the robot id it claims
  /// (member_keys set). Also counted in rejected_handshake.
  std::uint64_t rejected_identity = 0;
  /// Times reading from a connection paused because it was over its receive budget.
  std::uint64_t budget_pauses = 0;
  /// Log lines held back by the per-peer, per-kind rate limit.
  std::uint64_t log_lines_suppressed = 0;
  std::uint64_t duplicates_closed = 0;   ///< second connections to a robot closed by tie-break
  std::uint64_t heartbeat_timeouts = 0;  ///< connections closed for silence
  std::uint64_t write_stalls = 0;        ///< ... for a write without progress for heartbeat_timeout
  std::uint64_t bytes_in = 0;
  std::uint64_t bytes_out = 0;
  std::uint64_t messages_in = 0;
  std::uint64_t messages_out = 0;
  std::uint64_t send_drops = 0;  ///< messages not sent: queue full, peer down or unknown, too big
  std::uint64_t beacons_sent = 0;
  std::uint64_t beacons_received = 0;  ///< valid beacons of our team from other robots
  std::uint64_t beacons_rejected = 0;  ///< unreadable beacons or beacons of another team
  std::uint64_t open_connections = 0;  ///< current TCP connections (any state)
};

class PeerNetwork {
 public:
  /// Every application message (anything but Hello and Heartbeat; Goodbye is forwarded too).
  using MessageHandler = std::function<void(int robot, const v1::Envelope& envelope)>;
  /// A robot came up (handshake done) or went down (connection lost, timeout, Goodbye, stop).
  using PeerHandler = std::function<void(int robot, bool up)>;

  /// `io` must outlive this object. Nothing happens before start().
  PeerNetwork(boost::asio::io_context& io, PeerNetworkOptions options);
  /// Requests stop() if it was not called. Destroy only once the io_context no longer runs this
  /// network's handlers (after stop() and the io_context ran out of work, or after it stopped):
  /// callbacks may still run until then.
  ~PeerNetwork();
  PeerNetwork(const PeerNetwork&) = delete;
  PeerNetwork& operator=(const PeerNetwork&) = delete;

  /// Set before start().
  void set_message_handler(MessageHandler handler);
  void set_peer_handler(PeerHandler handler);

  /// Validates the options (std::invalid_argument listing the problems), binds the listening
  /// socket and the discovery socket (std::runtime_error on failure, e.g. port in use), then
  /// starts accepting, dialing and heartbeats on the io_context. Any thread; once per object.
  void start();

  /// Sends Goodbye{reason, last_round} to every connected peer, closes all connections (after at
  /// most stop_linger), cancels all timers and reports every live peer down; afterwards the
  /// io_context runs out of this network's work. Any thread; idempotent.
  void stop(std::string reason, std::uint64_t last_round = 0);

  /// Adds a static peer at run time (dialed now if started). Any thread.
  void add_peer(HostPort address);

  /// Replaces the static peer list at run time (SIGHUP): addresses new to the list are dialed
  /// now; addresses no longer in it are not dialed again (a live connection to them stays up until
  /// it drops, and such a robot can still dial us or be found by its beacons). Any thread.
  void set_static_peers(std::vector<HostPort> addresses);

  /// The bound TCP port (after start()).
  std::uint16_t listen_port() const;

  /// Queues `envelope` to `robot`, filling protocol_version, team and sender (seq is set per
  /// connection when written). Returns false, and counts a drop, if the robot is unknown or down.
  /// Any thread.
  bool send(int robot, const v1::Envelope& envelope);
  /// The same, taking the envelope over instead of copying it.
  bool send(int robot, v1::Envelope&& envelope);

  /// send() to every live peer; returns how many it was queued for. Any thread.
  int broadcast(const v1::Envelope& envelope);

  /// Snapshot of every robot ever seen, sorted by robot id. Any thread.
  std::vector<PeerStats> peers() const;
  /// Snapshot of the totals. Any thread.
  NetworkCounters totals() const;
  /// Robot ids currently up, ascending. Any thread.
  std::vector<int> live_peers() const;

  const PeerNetworkOptions& options() const;

 private:
  class Impl;
  std::shared_ptr<Impl> impl_;
};

}  // namespace concord::net

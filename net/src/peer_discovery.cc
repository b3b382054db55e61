// PeerNetwork: UDP beacon discovery (beacons sealed with the team key). On the strand.
#include "peer_network_impl.h"

namespace concord::net {

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
    beacon_out_ = seal_beacon(*options_.team_key, make_hello(nullptr).SerializeAsString());
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
    spdlog::debug(
        "net: ignored beacon from {}: {}", beacon_sender_.address().to_string(),
        error.kind != FrameErrorKind::kNone ? error.reason : std::string("not a valid Hello"));
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
  target.retired = false;  // found by its beacon: dialed again even if no longer a static peer
  if (target.timer_armed || !wants_dial(key, target)) return;
  spdlog::info("net: beacon from robot {}: dialing {}", robot, key);
  dial(key);
}

}  // namespace concord::net

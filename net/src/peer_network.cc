// PeerNetwork: options, setup, sending, the heartbeat watchdog, stop, snapshots and the public
// API. Everything runs on one strand; only the public entry points at the end of the file are
// called from other threads, and they either post to the strand or read the statistics under
// stats_mutex_. The handshake and peer table are in peer_handshake.cc, discovery in
// peer_discovery.cc, the shared declarations in peer_network_impl.h.
#include "peer_network_impl.h"

#include <set>

namespace concord::net {

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
  if (!member_keys.empty()) {
    if (!identity) {
      problem("identity: required with member_keys (this robot signs its Hello)");
    } else {
      const auto own = member_keys.find(robot_id);
      if (own == member_keys.end())
        problem("member_keys: no key for this robot's id " + std::to_string(robot_id));
      else if (!(own->second == identity->public_key()))
        problem("member_keys: the key listed for robot " + std::to_string(robot_id) +
                " is not this robot's identity key (its public key is " +
                identity->public_key().hex() + ")");
    }
    for (const int member : members)
      if (member_keys.find(member) == member_keys.end())
        problem("member_keys: no key for member " + std::to_string(member));
    for (const auto& [robot, key] : member_keys)
      if (robot < 0) problem("member_keys: robot id " + std::to_string(robot) + " is negative");
  }
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
      << "msg/s"
      << " listen=" << listen_address << ":" << listen_port;
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

void PeerNetwork::Impl::set_static_peers(std::vector<HostPort> addresses) {
  asio::post(strand_, [self = shared_from_this(), addresses = std::move(addresses)] {
    if (self->stopping_) return;
    std::set<std::string> wanted;
    for (const HostPort& address : addresses) wanted.insert(address.to_string());
    int removed = 0;
    int added = 0;
    for (auto& [key, target] : self->targets_) {
      if (!target->configured || wanted.count(key)) continue;
      target->configured = false;
      target->retired = true;
      target->timer.cancel();
      ++removed;
    }
    for (const HostPort& address : addresses) {
      const auto known = self->targets_.find(address.to_string());
      if (known == self->targets_.end() || !known->second->configured) ++added;
      self->ensure_target(address, true);
      self->dial(address.to_string());
    }
    spdlog::info("net: static peers replaced: {} listed, {} new, {} no longer dialed",
                 addresses.size(), added, removed);
  });
}

// ---------------------------------------------------------------------------------------------
// Impl: sending

void PeerNetwork::Impl::count_send_drop(int robot) {
  std::lock_guard lock(stats_mutex_);
  ++counters_.send_drops;
  if (const auto record = records_.find(robot); record != records_.end())
    ++record->second.stats.drops;
}

bool PeerNetwork::Impl::send(int robot, std::shared_ptr<v1::Envelope> stamped) {
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
  asio::post(strand_, [self = shared_from_this(), robot, envelope = std::move(stamped)] {
    self->enqueue_data(robot, envelope);
  });
  return true;
}

int PeerNetwork::Impl::broadcast(const v1::Envelope& envelope) {
  int queued = 0;
  for (const int robot : live_peers())
    queued += send(robot, std::make_shared<v1::Envelope>(envelope)) ? 1 : 0;
  return queued;
}

void PeerNetwork::Impl::enqueue_data(int robot, const std::shared_ptr<v1::Envelope>& envelope) {
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
void PeerNetwork::set_static_peers(std::vector<HostPort> addresses) {
  impl_->set_static_peers(std::move(addresses));
}

std::uint16_t PeerNetwork::listen_port() const { return impl_->listen_port(); }

bool PeerNetwork::send(int robot, const v1::Envelope& envelope) {
  return impl_->send(robot, std::make_shared<v1::Envelope>(envelope));
}

bool PeerNetwork::send(int robot, v1::Envelope&& envelope) {
  return impl_->send(robot, std::make_shared<v1::Envelope>(std::move(envelope)));
}

int PeerNetwork::broadcast(const v1::Envelope& envelope) { return impl_->broadcast(envelope); }

std::vector<PeerStats> PeerNetwork::peers() const { return impl_->peers(); }

NetworkCounters PeerNetwork::totals() const { return impl_->totals(); }

std::vector<int> PeerNetwork::live_peers() const { return impl_->live_peers(); }

const PeerNetworkOptions& PeerNetwork::options() const { return impl_->options(); }

}  // namespace concord::net

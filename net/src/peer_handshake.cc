// PeerNetwork: connections (accept, dial, redial), the channel and Hello handshake, and the peer
// table (one entry per robot, one connection per pair, restarts, Goodbye). On the strand.
#include "peer_network_impl.h"

namespace concord::net {

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
  target->retired = false;  // listed or learned again
  return *target;
}

bool PeerNetwork::Impl::wants_dial(const std::string& key, const DialTarget& target) const {
  if (!running_ || stopping_ || target.is_self || target.retired || target.session_id != 0)
    return false;
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

v1::Envelope PeerNetwork::Impl::make_hello(const SecureChannel* channel) const {
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
  if (options_.http_port != 0) {
    hello.set_http_address(options_.http_address);
    hello.set_http_port(options_.http_port);
  }
  if (options_.identity && channel) {
    hello.set_identity_signature(options_.identity->sign(
        hello_signing_bytes(channel->binding(), channel->role() == SecureChannel::Role::kInitiator,
                            options_.robot_id)));
  }
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
    return reject_handshake(session,
                            "robot id " + std::to_string(robot) + " is not in the membership list");
  if (robot != options_.robot_id && !options_.member_keys.empty()) {
    // The id it claims must be its own: signed with that robot's identity key over this
    // connection's binding (the peer dialed if we accepted).
    const auto key = options_.member_keys.find(robot);
    const bool signed_by_robot =
        key != options_.member_keys.end() &&
        key->second.verify(hello_signing_bytes(session->channel().binding(),
                                               session->origin == Origin::kAccepted, robot),
                           hello.identity_signature());
    if (!signed_by_robot) {
      update_counters([](NetworkCounters& counters) { ++counters.rejected_identity; });
      return reject_handshake(
          session,
          key == options_.member_keys.end()
              ? "robot " + std::to_string(robot) + " has no key in member_keys"
              : "Hello of robot " + std::to_string(robot) + " is not signed with its identity key");
    }
  }
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
  const std::string http_endpoint = announced_http_endpoint(hello, session->remote_address);

  update_counters([](NetworkCounters& counters) { ++counters.handshakes_completed; });
  update_record(robot, [&](PeerRecord& record) {
    ++record.stats.messages_in;
    record.stats.dial_address = dial_address;
    record.stats.degree = hello.degree();
    record.stats.capabilities.assign(hello.capabilities().begin(), hello.capabilities().end());
    record.stats.http_endpoint = http_endpoint;
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
  warn_limited(
      "frame " + session->remote_address.to_string() + " " + std::string(to_string(error.kind)),
      "net: closing {} connection #{} {} (robot {}): {} frame: {}", to_string(session->origin),
      session->id, session->remote, session->robot, to_string(error.kind), error.reason);
  session->close(error.reason);
}

void PeerNetwork::Impl::mark_down(int robot, Peer& peer, std::string_view reason) {
  if (!peer.up) return;
  peer.up = false;
  update_record(robot, [](PeerRecord& record) { record.stats.up = false; });
  spdlog::info("net: robot {} down: {}", robot, reason);
  if (peer_handler) invoke_user_callback("peer handler", [&] { peer_handler(robot, false); });
}

}  // namespace concord::net

#include "concord/daemon/consensus_exchange.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <iterator>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>

#include "concord/daemon/association_session.h"
#include "concord/daemon/negotiation_wire.h"
#include "concord/daemon/wire.h"
#include "concord/dataset/radio.h"
#include "concord/estimator/consensus.h"
#include "concord/estimator/estimator.h"
#include "concord/net/log_limiter.h"
#include "concord/v1/concord.pb.h"
#include "link_budget.h"
#include "steady_time.h"

namespace concord::daemon {

namespace {

std::vector<LandmarkId> intersection(const std::vector<LandmarkId>& a,
                                     const std::vector<LandmarkId>& b) {
  std::vector<LandmarkId> out;
  std::set_intersection(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(out));
  return out;
}

bool sorted_unique(const std::vector<LandmarkId>& ids) {
  return std::adjacent_find(ids.begin(), ids.end(), std::greater_equal<>()) == ids.end();
}

/// A warning caused by a peer, at most a few per (peer, kind) and period.
template <class... Args>
void warn_limited(net::LogLimiter& limiter, int robot, const char* kind,
                  spdlog::format_string_t<Args...> format, Args&&... args) {
  std::uint64_t suppressed = 0;
  if (!limiter.allow("robot " + std::to_string(robot) + " " + kind, suppressed)) return;
  spdlog::warn("{}{}", fmt::format(format, std::forward<Args>(args)...),
               net::suppressed_note(suppressed));
}

}  // namespace

struct ConsensusExchange::Peer {
  struct Received {
    Marginal marginal;
    int degree = 0;
    bool used = false;
    bool rejected = false;  ///< malformed: the peer's answer for its round, nothing to fuse
    /// Negotiated association: the receiver's id of each landmark and the sender's frame.
    std::optional<std::pair<std::vector<LandmarkId>, int>> relabelling;
  };
  bool up = false;
  /// Lockstep liveness: deadlines missed in a row, and whether it left the waits.
  int missed_in_a_row = 0;
  bool excluded = false;
  bool goodbye = false;
  /// Highest round the peer announced (LandmarkSet or Marginal); -1 before any.
  std::int64_t last_round = -1;
  /// consensus.radio: the last round the simulated radio linked this robot to it (-1: none on
  /// this connection). A peer that announced no round since then is behind.
  std::int64_t linked_before = -1;
  /// Its current landmark set (full sets and deltas applied in order).
  std::vector<LandmarkId> ids;
  bool ids_known = false;
  std::map<std::uint64_t, std::vector<LandmarkId>> landmark_sets;
  /// Lockstep: its newest LandmarkSet beyond the future-round window, held until the window
  /// reaches it (promote_deferred).
  struct Deferred {
    std::uint64_t round = 0;
    std::vector<LandmarkId> ids;
    std::optional<association::NegotiationMessage> negotiation;
  };
  std::optional<Deferred> deferred;
  std::map<std::uint64_t, Received> marginals;
  /// Negotiated association: its negotiation message of each round (checked on arrival).
  std::map<std::uint64_t, association::NegotiationMessage> negotiations;
  /// A new connection: the owner records sent to its previous life are sent again.
  bool fresh = true;
  /// Event-triggered sharing: what this connection delivered of the peer's landmarks, and
  /// whether the sending end (estimator thread) must start afresh on it.
  MarginalReceiver receiver;
  bool sender_reset = true;
  /// Async: the newest marginal received, and the robot's own round when it arrived (rounds of
  /// different robots need not be aligned: a restarted robot, or live sensors numbering frames
  /// independently).
  std::optional<Received> latest;
  std::int64_t latest_received_at = -1;
  /// Poisoning defence: suspicious rounds in a row, and the round its quarantine ends (-1: none).
  int suspicious_in_a_row = 0;
  std::int64_t quarantined_until = -1;
  PeerTrust trust;
};

ConsensusExchange::ConsensusExchange(ConsensusConfig config, Send send,
                                     ExchangeFailpoints failpoints)
    : config_(std::move(config)),
      send_(std::move(send)),
      failpoints_(failpoints),
      log_limiter_(std::make_unique<net::LogLimiter>()),
      budget_(std::make_unique<LinkBudget>(config_.link_budget_bytes_per_second)) {}

ConsensusExchange::~ConsensusExchange() = default;

std::set<int> ring_neighbours(int robot, std::vector<int> members) {
  std::sort(members.begin(), members.end());
  members.erase(std::unique(members.begin(), members.end()), members.end());
  const auto at = std::find(members.begin(), members.end(), robot);
  std::set<int> out;
  if (at == members.end() || members.size() < 2) return out;
  const auto n = static_cast<std::ptrdiff_t>(members.size());
  const std::ptrdiff_t i = at - members.begin();
  out.insert(members[static_cast<std::size_t>((i + 1) % n)]);
  out.insert(members[static_cast<std::size_t>((i + n - 1) % n)]);
  return out;
}

RadioGraph::RadioGraph(std::vector<int> members, ConsensusGraph base, RadioConfig limits,
                       std::vector<std::vector<Eigen::Vector3d>> positions, int max_frames)
    : members_(std::move(members)),
      base_(base),
      limits_(std::move(limits)),
      positions_(std::move(positions)),
      max_frames_(max_frames) {
  if (!std::is_sorted(members_.begin(), members_.end()) ||
      std::adjacent_find(members_.begin(), members_.end()) != members_.end())
    throw std::invalid_argument("radio: members must be sorted and unique");
  if (positions_.size() != members_.size())
    throw std::invalid_argument("radio: " + std::to_string(positions_.size()) +
                                " position tracks for " + std::to_string(members_.size()) +
                                " members");
}

std::set<int> RadioGraph::neighbours(int robot, std::uint64_t round) const {
  const auto at = std::lower_bound(members_.begin(), members_.end(), robot);
  if (at == members_.end() || *at != robot) return {};
  const auto n = static_cast<int>(members_.size());
  // The members still running at this frame, and the base graph over them.
  std::vector<bool> active(members_.size());
  std::vector<Eigen::Vector3d> where(members_.size(), Eigen::Vector3d::Zero());
  for (int m = 0; m < n; ++m) {
    const auto& track = positions_[static_cast<std::size_t>(m)];
    active[m] = round < track.size() &&
                (max_frames_ <= 0 || round < static_cast<std::uint64_t>(max_frames_));
    if (active[m]) where[m] = track[round];
  }
  std::vector<std::vector<int>> candidates(members_.size());
  for (int m = 0; m < n; ++m) {
    if (!active[m]) continue;
    if (base_ == ConsensusGraph::kRing) {
      for (const int other : ring_neighbours(members_[m], members_)) {
        const auto index = static_cast<int>(
            std::lower_bound(members_.begin(), members_.end(), other) - members_.begin());
        if (active[index]) candidates[m].push_back(index);
      }
    } else {
      for (int o = 0; o < n; ++o)
        if (o != m && active[o]) candidates[m].push_back(o);
    }
  }
  dataset::RadioLimits limits;
  limits.range_m = limits_.range_m;
  limits.nearest = limits_.nearest;
  limits.max_degree = limits_.max_degree;
  const auto graph = dataset::limit_graph(candidates, where, limits);
  std::set<int> out;
  for (const int index : graph[static_cast<std::size_t>(at - members_.begin())])
    out.insert(members_[static_cast<std::size_t>(index)]);
  return out;
}

void ConsensusExchange::restrict_to(std::set<int> peers) { allowed_ = std::move(peers); }

void ConsensusExchange::set_radio(std::function<std::set<int>(std::uint64_t round)> radio) {
  radio_ = std::move(radio);
}

bool ConsensusExchange::takes_part(int robot, const std::optional<std::set<int>>& in_range) const {
  return (!allowed_ || allowed_->count(robot)) && (!in_range || in_range->count(robot));
}

void ConsensusExchange::set_association(AssociationSession* session) {
  std::lock_guard lock(mutex_);
  association_ = session;
}

void ConsensusExchange::set_record_signer(std::shared_ptr<const RecordSigner> signer) {
  std::lock_guard lock(mutex_);
  record_signer_ = std::move(signer);
}

void ConsensusExchange::on_peer(int robot, bool up) {
  std::lock_guard lock(mutex_);
  auto& slot = peers_[robot];
  if (!slot) {
    slot = std::make_unique<Peer>();
    // A peer cannot grow what is kept of its marginals beyond one marginal's limit.
    slot->receiver = MarginalReceiver(static_cast<std::size_t>(config_.max_marginal_landmarks));
  }
  Peer& peer = *slot;
  if (up) {
    // A new connection: whatever the peer announced before is from its previous life.
    if (peer.excluded && counters_.excluded_peers > 0) --counters_.excluded_peers;
    peer = Peer{};
    peer.receiver = MarginalReceiver(static_cast<std::size_t>(config_.max_marginal_landmarks));
    peer.up = true;
  } else {
    peer.up = false;
  }
  changed_.notify_all();
}

void ConsensusExchange::on_message(int robot, const v1::Envelope& envelope) {
  std::lock_guard lock(mutex_);
  auto& slot = peers_[robot];
  if (!slot) {
    slot = std::make_unique<Peer>();
    // A peer cannot grow what is kept of its marginals beyond one marginal's limit.
    slot->receiver = MarginalReceiver(static_cast<std::size_t>(config_.max_marginal_landmarks));
  }
  Peer& peer = *slot;
  switch (envelope.body_case()) {
    case v1::Envelope::kLandmarkSet: {
      const v1::LandmarkSet& message = envelope.landmark_set();
      const auto limit = static_cast<std::size_t>(config_.max_marginal_landmarks);
      if (static_cast<std::size_t>(message.ids_size()) > limit ||
          static_cast<std::size_t>(message.added_size()) > limit ||
          static_cast<std::size_t>(message.removed_size()) > limit) {
        ++counters_.malformed;
        warn_limited(*log_limiter_, robot, "landmark-set",
                     "consensus: robot {} sent a landmark set above {} ids; ignored", robot, limit);
        return;
      }
      std::vector<LandmarkId> ids;
      if (!message.delta()) {
        ids.assign(message.ids().begin(), message.ids().end());
      } else if (peer.ids_known) {
        std::vector<LandmarkId> added(message.added().begin(), message.added().end());
        std::vector<LandmarkId> removed(message.removed().begin(), message.removed().end());
        std::sort(added.begin(), added.end());
        std::sort(removed.begin(), removed.end());
        std::vector<LandmarkId> kept;
        std::set_difference(peer.ids.begin(), peer.ids.end(), removed.begin(), removed.end(),
                            std::back_inserter(kept));
        std::set_union(kept.begin(), kept.end(), added.begin(), added.end(),
                       std::back_inserter(ids));
      } else {
        ++counters_.malformed;
        warn_limited(*log_limiter_, robot, "landmark-set",
                     "consensus: robot {} sent a landmark delta without a base set; ignored",
                     robot);
        return;
      }
      if (!sorted_unique(ids) || ids.size() > limit) {
        ++counters_.malformed;
        warn_limited(*log_limiter_, robot, "landmark-set",
                     "consensus: robot {} sent landmark ids that are not sorted and unique, or "
                     "too many; ignored",
                     robot);
        return;
      }
      peer.ids = ids;
      peer.ids_known = true;
      peer.last_round = std::max<std::int64_t>(peer.last_round,
                                               static_cast<std::int64_t>(message.round()));
      // Async mode uses the current set only; lockstep keeps the set of each round.
      if (config_.mode == ConsensusMode::kAsync) break;
      if (static_cast<std::int64_t>(message.round()) <= forgotten_up_to_) {
        ++counters_.stale_dropped;
        break;
      }
      std::optional<association::NegotiationMessage> negotiation;
      if (association_ && message.has_negotiation()) {
        std::string error;
        const double decode_start = thread_cpu_seconds();
        negotiation = from_wire(message.negotiation(), robot, config_.negotiation_limits, error,
                                record_signer_.get(), &counters_.records_unsigned);
        count_negotiation_seconds(&ExchangeCounters::negotiation_decode_seconds,
                                  thread_cpu_seconds() - decode_start);
        if (!negotiation) {
          // Refused whole; the LandmarkSet still answers the round, so nobody waits for it.
          ++counters_.negotiations_refused;
          warn_limited(*log_limiter_, robot, "negotiation",
                       "association: robot {} round {}: {}; refused", robot, message.round(),
                       error);
        }
      }
      if (beyond_window(message.round())) {
        // A peer ahead of us: a restarted robot rejoining, or (with a simulated radio) one
        // whose part of the team ran ahead while the link was down. Only its newest such set
        // is kept (bounded memory), until our rounds come within reach of it; an older one it
        // replaces is dropped (the peer went on without us in that round).
        if (peer.deferred) ++counters_.future_dropped;
        peer.deferred = Peer::Deferred{message.round(), std::move(ids), std::move(negotiation)};
        notify_waiter();
        return;
      }
      if (negotiation) peer.negotiations[message.round()] = std::move(*negotiation);
      peer.landmark_sets[message.round()] = std::move(ids);
      break;
    }
    case v1::Envelope::kMarginal: {
      const v1::Marginal& message = envelope.marginal();
      const bool lockstep = config_.mode != ConsensusMode::kAsync;
      if (lockstep && beyond_window(message.round())) {
        ++counters_.future_dropped;
        peer.last_round =
            std::max<std::int64_t>(peer.last_round, static_cast<std::int64_t>(message.round()));
        notify_waiter();
        return;
      }
      std::string error;
      Marginal marginal;  // read into a spare's storage when there is one
      if (!spare_marginals_.empty()) {
        marginal = std::move(spare_marginals_.back());
        spare_marginals_.pop_back();
      }
      bool read = false;
      if (message.landmark_ids_size() > config_.max_marginal_landmarks)
        error = "marginal of " + std::to_string(message.landmark_ids_size()) +
                " landmarks, above the limit of " + std::to_string(config_.max_marginal_landmarks);
      else
        read = from_wire(message, error, marginal);
      peer.last_round =
          std::max<std::int64_t>(peer.last_round, static_cast<std::int64_t>(message.round()));
      if (!read) {
        ++counters_.malformed;
        warn_limited(*log_limiter_, robot, "marginal", "consensus: robot {} round {}: {}", robot,
                     message.round(), error);
        // A rejected marginal is the peer's answer for its round: nothing to fuse, no waiting.
        if (lockstep && static_cast<std::int64_t>(message.round()) > forgotten_up_to_) {
          Peer::Received rejected;
          rejected.rejected = true;
          peer.marginals[message.round()] = std::move(rejected);
          notify_waiter();
        }
        return;
      }
      // Every marginal that arrives is what the sender counts as delivered, fused or not.
      if (sharing()) peer.receiver.ingest(marginal);
      if (config_.mode == ConsensusMode::kAsync) {
        peer.latest = Peer::Received{std::move(marginal), static_cast<int>(message.degree()), false, false, std::nullopt};
        peer.latest_received_at = current_round_;
        break;
      }
      if (static_cast<std::int64_t>(message.round()) <= forgotten_up_to_) {
        ++counters_.stale_dropped;
        break;
      }
      Peer::Received received{std::move(marginal), static_cast<int>(message.degree()), false, false, std::nullopt};
      if (association_) {
        const auto& relabelling = message.relabelling();
        if (message.has_relabelling() &&
            relabelling.receiver_ids_size() == message.landmark_ids_size()) {
          received.relabelling.emplace(
              std::vector<LandmarkId>(relabelling.receiver_ids().begin(),
                                      relabelling.receiver_ids().end()),
              relabelling.frame());
        } else if (!received.marginal.ids.empty()) {
          ++counters_.relabellings_refused;
          warn_limited(*log_limiter_, robot, "relabelling",
                       "association: robot {} round {}: a marginal without the receiver's ids; "
                       "not fused",
                       robot, message.round());
        }
      }
      peer.marginals[message.round()] = std::move(received);
      break;
    }
    case v1::Envelope::kGoodbye:
      peer.goodbye = true;
      break;
    default:
      return;
  }
  notify_waiter();
}

void ConsensusExchange::notify_waiter() {
  if (wake_condition_.holds == nullptr || wake_condition_.holds(wake_condition_.context)) {
    changed_.notify_all();
  }
}

template <typename Ready>
void ConsensusExchange::wait_for_round(std::unique_lock<std::mutex>& lock,
                                       std::chrono::steady_clock::time_point deadline,
                                       const Ready& ready) {
  wake_condition_ = {[](const void* context) { return (*static_cast<const Ready*>(context))(); },
                     &ready};
  changed_.wait_until(lock, deadline, ready);
  wake_condition_ = {};
}

int ConsensusExchange::wait_for_peers(int count, std::chrono::milliseconds timeout) {
  std::unique_lock lock(mutex_);
  auto live = [&] {
    return static_cast<int>(std::count_if(peers_.begin(), peers_.end(),
                                          [](const auto& entry) { return entry.second->up; }));
  };
  changed_.wait_for(lock, timeout, [&] { return stopped_ || live() >= count; });
  return live();
}

void ConsensusExchange::stop() {
  std::lock_guard lock(mutex_);
  stopped_ = true;
  changed_.notify_all();
}

bool ConsensusExchange::beyond_window(std::uint64_t round) const {
  const std::int64_t base = std::max<std::int64_t>({current_round_, forgotten_up_to_, 0});
  return static_cast<std::int64_t>(round) > base + config_.future_rounds;
}

void ConsensusExchange::count_miss(int robot, Peer& peer, std::uint64_t round) {
  ++peer.missed_in_a_row;
  if (peer.excluded || peer.missed_in_a_row < config_.miss_limit) return;
  peer.excluded = true;
  ++counters_.exclusions;
  ++counters_.excluded_peers;
  spdlog::warn(
      "consensus: round {}: robot {} missed {} round(s) in a row; it leaves the lockstep waits "
      "until it answers in time again",
      round, robot, peer.missed_in_a_row);
}

void ConsensusExchange::count_answer(int robot, Peer& peer, std::uint64_t round) {
  peer.missed_in_a_row = 0;
  if (!peer.excluded) return;
  peer.excluded = false;
  if (counters_.excluded_peers > 0) --counters_.excluded_peers;
  spdlog::info("consensus: round {}: robot {} answered in time; back in the lockstep waits", round,
               robot);
}

std::int64_t ConsensusExchange::wait_for_team_round(std::chrono::milliseconds timeout) {
  std::unique_lock lock(mutex_);
  auto round = [&] {
    std::int64_t highest = -1;
    for (const auto& [robot, peer] : peers_)
      if (peer->up && !peer->goodbye) highest = std::max(highest, peer->last_round);
    return highest;
  };
  changed_.wait_for(lock, timeout, [&] { return stopped_ || round() >= 0; });
  return round();
}

void ConsensusExchange::resume_at(std::uint64_t round) {
  std::lock_guard lock(mutex_);
  current_round_ = static_cast<std::int64_t>(round);
}

std::vector<int> ConsensusExchange::live_peers() const {
  std::lock_guard lock(mutex_);
  std::vector<int> live;
  for (const auto& [robot, peer] : peers_)
    if (peer->up) live.push_back(robot);
  return live;
}

ExchangeCounters ConsensusExchange::counters() const {
  std::lock_guard lock(mutex_);
  ExchangeCounters counters = counters_;
  counters.log_lines_suppressed = log_limiter_->suppressed_total();
  return counters;
}

RoundReport ConsensusExchange::run_round(std::uint64_t round, Estimator& estimator) {
  {
    std::lock_guard lock(mutex_);
    current_round_ = static_cast<std::int64_t>(round);
    if (config_.mode != ConsensusMode::kAsync) promote_deferred();
  }
  RoundReport report = config_.mode == ConsensusMode::kAsync ? async_round(round, estimator)
                                                             : lockstep_round(round, estimator);
  std::lock_guard lock(mutex_);
  ++counters_.rounds;
  counters_.marginals_fused += static_cast<std::uint64_t>(report.fused);
  counters_.deadline_misses += static_cast<std::uint64_t>(report.timed_out);
  return report;
}

void ConsensusExchange::send_landmark_sets(const std::vector<int>& robots, std::uint64_t round,
                                           const std::vector<LandmarkId>& ids) {
  std::vector<v1::Envelope> envelopes(robots.size());
  for (v1::Envelope& envelope : envelopes) {
    envelope.set_round(round);
    v1::LandmarkSet* message = envelope.mutable_landmark_set();
    message->set_round(round);
    message->mutable_ids()->Assign(ids.begin(), ids.end());
  }
  if (association_ && !robots.empty()) {
    // Every neighbour's negotiation in one timed pass (a thread-CPU clock read costs about as
    // much as a small message).
    const double negotiation_start = thread_cpu_seconds();
    std::size_t bytes = 0;
    for (std::size_t n = 0; n < robots.size(); ++n) {
      const association::NegotiationMessage negotiation =
          association_->negotiation_for(robots[n], round);
      if (negotiation.map && negotiation.map != wired_map_source_) {
        if (!wired_map_) wired_map_ = std::make_unique<v1::MapDescription>();
        to_wire(*negotiation.map, *wired_map_);
        wired_map_source_ = negotiation.map;
      }
      v1::Negotiation* out = envelopes[n].mutable_landmark_set()->mutable_negotiation();
      to_wire(negotiation, negotiation.map ? *wired_map_ : v1::MapDescription::default_instance(),
              *out, record_signer_.get());
      bytes += out->ByteSizeLong();
    }
    const double seconds = thread_cpu_seconds() - negotiation_start;
    std::lock_guard lock(mutex_);
    counters_.negotiation_bytes += bytes;
    count_negotiation_seconds(&ExchangeCounters::negotiation_encode_seconds, seconds);
  }
  for (std::size_t n = 0; n < robots.size(); ++n) send_counted(robots[n], std::move(envelopes[n]));
}

bool ConsensusExchange::send_counted(int robot, v1::Envelope&& envelope) {
  // Encryption (secretstream) and the length prefix come on top of the envelope.
  const std::size_t bytes = envelope.ByteSizeLong() + 21;
  if (!send_(robot, std::move(envelope))) return false;
  budget_->spend(bytes);
  std::lock_guard lock(mutex_);
  counters_.bytes_sent += bytes;
  return true;
}

void ConsensusExchange::send_marginal(int robot, std::uint64_t round, const Estimator& estimator,
                                      const std::vector<LandmarkId>& own_ids,
                                      const std::vector<LandmarkId>& peer_ids, int degree,
                                      int links_left) {
  v1::Envelope envelope;
  envelope.set_round(round);
  v1::Marginal* message = envelope.mutable_marginal();
  message->set_round(round);
  message->set_degree(static_cast<std::uint32_t>(degree));
  if (failpoints_.marginal_silence) return;  // failpoint: heartbeats and LandmarkSets only
  if (association_) {
    // Negotiated: the objects shared with this neighbour, with its ids and this robot's frame.
    // (The link budget does not trim negotiated marginals: their relabelling is per message.)
    const association::SharedCut& cut = shared_cuts_.at(robot);
    const std::vector<LandmarkId>& receiver_ids = cut.receiver_ids;
    Marginal marginal;
    Consensus::select(held_, cut.ids, marginal);
    if (!marginal.ids.empty()) to_wire(marginal, *message);
    v1::Relabelling* relabelling = message->mutable_relabelling();
    relabelling->mutable_receiver_ids()->Assign(receiver_ids.begin(), receiver_ids.end());
    relabelling->set_frame(association_->frame());
  } else {
    std::vector<LandmarkId> common = intersection(own_ids, peer_ids);
    if (!budget_->unlimited() && !common.empty()) {
      // Under the link budget: what fits in this neighbour's share, least valuable left out.
      const double allowance = budget_->share(links_left);
      if (static_cast<double>(estimated_marginal_bytes(common.size(), 0)) > allowance) {
        std::vector<std::pair<LandmarkId, bool>> candidates;
        candidates.reserve(common.size());
        for (const LandmarkId id : common)
          candidates.emplace_back(id, estimator.state().landmark_slot(id) >= 0);
        std::map<LandmarkId, std::uint64_t>& sent = last_sent_[robot];
        std::vector<LandmarkId> chosen = choose_within_budget(candidates, sent, allowance);
        {
          std::lock_guard lock(mutex_);
          ++(chosen.empty() ? counters_.budget_marginals_empty : counters_.budget_marginals_trimmed);
          counters_.budget_landmarks_dropped += common.size() - chosen.size();
        }
        // Forget ids no longer shared (bounded memory), then remember what goes out now.
        for (auto it = sent.begin(); it != sent.end();)
          it = std::binary_search(common.begin(), common.end(), it->first) ? std::next(it)
                                                                            : sent.erase(it);
        common = std::move(chosen);
      }
      for (const LandmarkId id : common) last_sent_[robot][id] = round;
    }
    if (!sharing()) {
      if (!common.empty()) {
        Consensus::kept_by(held_, common, outgoing_);
        to_wire(held_, outgoing_, *message);  // the cut, encoded without a copy
      }
    } else {
      // Event-triggered and compact: the landmarks that moved since this connection last
      // carried them; recorded as delivered once the message is handed to the connection.
      MarginalSender& sender = senders_[robot];
      {
        std::lock_guard lock(mutex_);
        const auto found = peers_.find(robot);
        if (found != peers_.end() && found->second->sender_reset) {
          sender.reset();
          found->second->sender_reset = false;
        }
      }
      Marginal cut;
      if (!common.empty()) Consensus::select(held_, common, cut);
      Marginal sent = sender.select(cut, config_.share_kl_threshold,
                                    link_landmark_cap(config_.share_max_landmarks, degree));
      sent = split_blocks(sent, config_.share_block_landmarks);
      if (config_.share_float32) {
        const CompactMarginal wire = compact(sent);
        if (!sent.ids.empty()) to_wire(wire, *message);
        sent = expand(wire);
      } else if (!sent.ids.empty()) {
        to_wire(sent, *message);
      }
      if (!failpoints_.marginal_garbage && send_counted(robot, std::move(envelope))) sender.delivered(sent);
      if (!failpoints_.marginal_garbage) return;
    }
  }
  if (failpoints_.marginal_garbage) {  // failpoint: one mean value too many
    message->add_landmark_ids(1);
    message->add_mean(0.0);
  }
  (void)send_counted(robot, std::move(envelope));
}

RoundReport ConsensusExchange::lockstep_round(std::uint64_t round, Estimator& estimator) {
  RoundReport report;
  report.round = round;
  const auto start = Clock::now();
  const auto k = static_cast<std::int64_t>(round);
  // Negotiated: private ids mean nothing to a neighbour; the LandmarkSet carries the negotiation.
  const std::vector<LandmarkId> ids =
      association_ ? std::vector<LandmarkId>{} : estimator.object_ids();
  std::vector<int> reconnected;

  // Live peers take part; those that missed miss_limit rounds in a row are not waited for (they
  // take part when their messages are there in time, and are waited for again once they are).
  std::vector<int> candidates;
  std::set<int> waited;
  const std::optional<std::set<int>> in_range =
      radio_ ? std::optional<std::set<int>>(radio_(round)) : std::nullopt;
  {
    std::lock_guard lock(mutex_);
    for (const auto& [robot, peer] : peers_) {
      if (!peer->up || peer->goodbye) continue;
      if (!takes_part(robot, in_range)) continue;
      candidates.push_back(robot);
      if (peer->fresh) reconnected.push_back(robot);
      peer->fresh = false;
      if (peer->excluded)
        ++report.excluded;
      else
        waited.insert(robot);
    }
  }
  report.live = static_cast<int>(candidates.size());
  if (association_) {
    const double negotiation_start = thread_cpu_seconds();
    for (int robot : reconnected) association_->missed(robot);
    association_->begin_round(round, estimator);
    add_negotiation_seconds(&ExchangeCounters::negotiation_decide_seconds,
                            thread_cpu_seconds() - negotiation_start);
  }
  send_landmark_sets(candidates, round, ids);

  // Phase 1: every waited-for candidate's LandmarkSet(k), or evidence it is not in round k.
  std::vector<int> neighbours;
  std::map<int, std::vector<LandmarkId>> neighbour_ids;
  std::set<int> missed;
  {
    std::unique_lock lock(mutex_);
    // Behind: it announced no round since the last one we were linked in (every round, unless
    // a simulated radio left some out).
    auto settled = [&](int robot) {
      const Peer& peer = *peers_.at(robot);
      const std::int64_t linked_before = in_range ? peer.linked_before : k - 1;
      return !peer.up || peer.goodbye || peer.landmark_sets.count(round) > 0 ||
             peer.last_round > k || peer.last_round < linked_before;
    };
    const auto ready = [&] {
      return stopped_ || std::all_of(waited.begin(), waited.end(), settled);
    };
    wait_for_round(lock, start + config_.round_deadline, ready);
    for (int robot : candidates) {
      const Peer& peer = *peers_.at(robot);
      const auto it = peer.landmark_sets.find(round);
      if (peer.up && it != peer.landmark_sets.end()) {
        neighbours.push_back(robot);
        neighbour_ids[robot] = it->second;
      } else if (waited.count(robot) && !settled(robot) && !stopped_) {
        ++report.timed_out;
        missed.insert(robot);
        warn_limited(*log_limiter_, robot, "deadline",
                     "consensus: round {}: no landmark set from robot {} within {} ms", round,
                     robot, config_.round_deadline.count());
      }
    }
    for (int robot : candidates) peers_.at(robot)->linked_before = k;
  }
  const int degree = static_cast<int>(neighbours.size());
  report.neighbours = degree;
  budget_->refill(Clock::now());
  int links_left = degree;
  if (association_) {
    const double negotiation_start = thread_cpu_seconds();
    negotiate(round, estimator, candidates, neighbours);
    add_negotiation_seconds(&ExchangeCounters::negotiation_decide_seconds,
                            thread_cpu_seconds() - negotiation_start);
  }
  // The marginal of everything the robot holds, once; each neighbour's is cut out of it.
  const double send_start = thread_cpu_seconds();
  if (!neighbours.empty()) estimator.marginal(association_ ? estimator.object_ids() : ids, held_);
  if (association_) {
    // What each neighbour's marginal is cut by, with the neighbour's ids: work only private ids
    // need (a cut by given ids is the consensus's), so the negotiation's, in one timed pass.
    const double relabel_start = thread_cpu_seconds();
    shared_cuts_.clear();
    for (int robot : neighbours) shared_cuts_[robot] = association_->shared_cut(robot, held_);
    add_negotiation_seconds(&ExchangeCounters::negotiation_relabel_seconds,
                            thread_cpu_seconds() - relabel_start);
  }
  for (int robot : neighbours) {
    send_marginal(robot, round, estimator, ids, neighbour_ids[robot], degree, links_left--);
  }
  report.send_cpu_seconds = thread_cpu_seconds() - send_start;

  // Phase 2: every waited-for neighbour's Marginal(k) (a rejected one is its answer too).
  std::vector<WeightedMarginal> inbox;
  std::vector<WeightedMarginal> witnessed;  // a quarantined sender's: tested, not fused
  {
    std::unique_lock lock(mutex_);
    auto settled = [&](int robot) {
      const Peer& peer = *peers_.at(robot);
      return !peer.up || peer.goodbye || peer.marginals.count(round) > 0 || peer.last_round > k;
    };
    const auto phase_start = Clock::now();
    const auto ready = [&] {
      return stopped_ || std::all_of(neighbours.begin(), neighbours.end(), [&](int robot) {
               return !waited.count(robot) || settled(robot);
             });
    };
    wait_for_round(lock, phase_start + config_.round_deadline, ready);
    for (int robot : neighbours) {
      Peer& peer = *peers_.at(robot);
      const auto it = peer.marginals.find(round);
      if (it == peer.marginals.end()) {
        if (waited.count(robot) && !settled(robot) && !stopped_) {
          ++report.timed_out;
          missed.insert(robot);
          warn_limited(*log_limiter_, robot, "deadline",
                       "consensus: round {}: no marginal from robot {} within {} ms", round, robot,
                       config_.round_deadline.count());
        }
        continue;
      }
      it->second.used = true;
      if (it->second.rejected) {
        ++report.bad_messages;
        continue;
      }
      if (sharing()) {
        // The landmarks that came this round, and the last ones received of the others.
        it->second.marginal =
            peer.receiver.build(it->second.marginal, intersection(ids, neighbour_ids[robot]));
      }
      if (it->second.marginal.ids.empty()) continue;
      const bool out = quarantined(robot, peer, round);
      if (association_) {
        // Negotiated: the pairs both robots' views agree on, in this robot's ids, one frame.
        if (!it->second.relabelling) continue;
        const double relabel_start = thread_cpu_seconds();
        std::optional<Marginal> relabelled = association_->accept_marginal(
            robot, std::move(it->second.marginal), it->second.relabelling->first,
            it->second.relabelling->second);
        // Work there only because the ids are private: the negotiation's (mutex_ is held).
        count_negotiation_seconds(&ExchangeCounters::negotiation_relabel_seconds,
                                  thread_cpu_seconds() - relabel_start);
        if (!relabelled) continue;
        it->second.marginal = std::move(*relabelled);
      }
      (out ? witnessed : inbox)
          .push_back({Consensus::metropolis_weight(degree, it->second.degree),
                      std::move(it->second.marginal), robot});
    }
    // Liveness bookkeeping: a waited-for peer that missed the deadline; a peer (waited for or
    // not) whose LandmarkSet and Marginal were both there in time answered.
    for (int robot : candidates) {
      const auto found = peers_.find(robot);
      if (found == peers_.end()) continue;
      Peer& peer = *found->second;
      if (missed.count(robot)) {
        count_miss(robot, peer, round);
      } else if (std::find(neighbours.begin(), neighbours.end(), robot) != neighbours.end() &&
                 peer.marginals.count(round) > 0) {
        count_answer(robot, peer, round);
      }
    }
  }
  report.wait_seconds = seconds_between(start, Clock::now());
  if (!inbox.empty()) {
    const double fuse_start = thread_cpu_seconds();
    report.consensus = estimator.fuse(inbox);
    report.fuse_cpu_seconds = thread_cpu_seconds() - fuse_start;
    report.fused = static_cast<int>(inbox.size());
    judge(round, inbox, report.consensus);
    recycle(inbox);
  }
  witness(estimator, witnessed);
  forget_rounds_up_to(round);
  return report;
}

void ConsensusExchange::recycle(std::vector<WeightedMarginal>& inbox) {
  std::lock_guard lock(mutex_);
  spare_marginals_.clear();
  for (WeightedMarginal& used : inbox) spare_marginals_.push_back(std::move(used.marginal));
}

RoundReport ConsensusExchange::async_round(std::uint64_t round, Estimator& estimator) {
  RoundReport report;
  report.round = round;
  const auto k = static_cast<std::int64_t>(round);
  const std::vector<LandmarkId> ids = estimator.object_ids();
  std::vector<int> live;
  std::map<int, std::vector<LandmarkId>> known_ids;
  const std::optional<std::set<int>> in_range =
      radio_ ? std::optional<std::set<int>>(radio_(round)) : std::nullopt;
  {
    std::lock_guard lock(mutex_);
    for (const auto& [robot, peer] : peers_) {
      if (!peer->up || peer->goodbye) continue;
      if (!takes_part(robot, in_range)) continue;
      live.push_back(robot);
      if (peer->ids_known) known_ids[robot] = peer->ids;
    }
  }
  const int degree = static_cast<int>(live.size());
  report.live = report.neighbours = degree;
  budget_->refill(Clock::now());
  send_landmark_sets(live, round, ids);
  auto links_left = static_cast<int>(known_ids.size());
  const double send_start = thread_cpu_seconds();
  if (!known_ids.empty()) estimator.marginal(ids, held_);
  for (int robot : live) {
    if (const auto it = known_ids.find(robot); it != known_ids.end()) {
      send_marginal(robot, round, estimator, ids, it->second, degree, links_left--);
    }
  }
  report.send_cpu_seconds = thread_cpu_seconds() - send_start;
  std::vector<WeightedMarginal> inbox;
  std::vector<WeightedMarginal> witnessed;  // a quarantined sender's: tested, not fused
  {
    std::lock_guard lock(mutex_);
    for (int robot : live) {
      Peer& peer = *peers_.at(robot);
      // The newest marginal, if it arrived within the last staleness_rounds of our own rounds
      // and was not fused before.
      if (!peer.latest || peer.latest->used ||
          peer.latest_received_at < k - config_.staleness_rounds) {
        continue;
      }
      peer.latest->used = true;
      if (sharing()) {
        const auto known = known_ids.find(robot);
        peer.latest->marginal = peer.receiver.build(
            peer.latest->marginal,
            known != known_ids.end() ? intersection(ids, known->second) : std::vector<LandmarkId>{});
      }
      if (!peer.latest->marginal.ids.empty()) {
        (quarantined(robot, peer, round) ? witnessed : inbox)
            .push_back({Consensus::metropolis_weight(degree, peer.latest->degree),
                        std::move(peer.latest->marginal), robot});
      }
    }
  }
  if (!inbox.empty()) {
    const double fuse_start = thread_cpu_seconds();
    report.consensus = estimator.fuse(inbox);
    report.fuse_cpu_seconds = thread_cpu_seconds() - fuse_start;
    report.fused = static_cast<int>(inbox.size());
    judge(round, inbox, report.consensus);
    recycle(inbox);
  }
  witness(estimator, witnessed);
  return report;
}

void ConsensusExchange::witness(Estimator& estimator, const std::vector<WeightedMarginal>& out) {
  if (out.empty()) return;
  const int refused = estimator.witness(out);
  std::lock_guard lock(mutex_);
  counters_.quarantined_refused += static_cast<std::uint64_t>(refused);
}

bool ConsensusExchange::quarantined(int robot, Peer& peer, std::uint64_t round) {
  if (peer.quarantined_until < 0) return false;
  if (static_cast<std::int64_t>(round) > peer.quarantined_until) {
    peer.quarantined_until = -1;
    peer.trust.quarantined = false;
    --counters_.quarantined_peers;
    spdlog::info("consensus: robot {} leaves quarantine at round {}", robot, round);
    return false;
  }
  ++counters_.quarantined_dropped;
  return true;
}

void ConsensusExchange::judge(std::uint64_t round, const std::vector<WeightedMarginal>& inbox,
                              const ConsensusReport& report) {
  std::lock_guard lock(mutex_);
  for (std::size_t j = 0; j < inbox.size(); ++j) {
    const int sender = inbox[j].sender;
    const auto found = peers_.find(sender);
    if (found == peers_.end() || j >= report.refused_per_neighbour.size()) continue;
    Peer& peer = *found->second;
    const int refused = report.refused_per_neighbour[j];
    const int tested = report.tested_per_neighbour[j];
    peer.trust.landmarks_refused += static_cast<std::uint64_t>(refused);
    peer.trust.landmarks_tested += static_cast<std::uint64_t>(tested);
    counters_.landmarks_refused += static_cast<std::uint64_t>(refused);
    const bool suspicious =
        refused >= 2 && refused > config_.suspicious_refusal_fraction * tested;
    peer.suspicious_in_a_row = suspicious ? peer.suspicious_in_a_row + 1 : 0;
    if (suspicious) {
      warn_limited(*log_limiter_, sender, "refused",
                   "consensus: round {}: {} of {} landmarks from robot {} refused (beyond the "
                   "chi-square bound of this robot's estimates or of its own earlier claims)",
                   round, refused, tested, sender);
    }
    if (peer.suspicious_in_a_row >= config_.quarantine_after && config_.quarantine_rounds > 0 &&
        peer.quarantined_until < 0) {
      // A repeat offender stays out longer: each quarantine twice the one before, up to
      // 2^quarantine_doublings times quarantine_rounds.
      const auto doublings = std::min<std::uint64_t>(
          peer.trust.quarantines, static_cast<std::uint64_t>(config_.quarantine_doublings));
      peer.quarantined_until = static_cast<std::int64_t>(round) +
                               (static_cast<std::int64_t>(config_.quarantine_rounds) << doublings);
      peer.suspicious_in_a_row = 0;
      peer.trust.quarantined = true;
      ++peer.trust.quarantines;
      ++counters_.quarantines;
      ++counters_.quarantined_peers;
      spdlog::warn(
          "consensus: robot {} quarantined until round {}: its marginals were refused "
          "in {} rounds in a row",
          sender, peer.quarantined_until, config_.quarantine_after);
    }
  }
}

std::map<int, PeerTrust> ConsensusExchange::peer_trust() const {
  std::lock_guard lock(mutex_);
  std::map<int, PeerTrust> out;
  for (const auto& [robot, peer] : peers_) out[robot] = peer->trust;
  return out;
}

void ConsensusExchange::forget_rounds_up_to(std::uint64_t round) {
  std::lock_guard lock(mutex_);
  forgotten_up_to_ = std::max(forgotten_up_to_, static_cast<std::int64_t>(round));
  for (auto& [robot, peer] : peers_) {
    peer->landmark_sets.erase(peer->landmark_sets.begin(),
                              peer->landmark_sets.upper_bound(round));
    peer->marginals.erase(peer->marginals.begin(), peer->marginals.upper_bound(round));
    peer->negotiations.erase(peer->negotiations.begin(), peer->negotiations.upper_bound(round));
  }
  promote_deferred();
}

void ConsensusExchange::promote_deferred() {
  for (auto& [robot, peer] : peers_) {
    if (!peer->deferred || beyond_window(peer->deferred->round)) continue;
    Peer::Deferred& deferred = *peer->deferred;
    if (static_cast<std::int64_t>(deferred.round) > forgotten_up_to_) {
      if (deferred.negotiation)
        peer->negotiations[deferred.round] = std::move(*deferred.negotiation);
      peer->landmark_sets[deferred.round] = std::move(deferred.ids);
    } else {
      ++counters_.stale_dropped;
    }
    peer->deferred.reset();
  }
}

void ConsensusExchange::count_negotiation_seconds(double ExchangeCounters::*part, double seconds) {
  counters_.*part += seconds;
  counters_.negotiation_seconds += seconds;
}

void ConsensusExchange::add_negotiation_seconds(double ExchangeCounters::*part, double seconds) {
  std::lock_guard lock(mutex_);
  count_negotiation_seconds(part, seconds);
}

void ConsensusExchange::negotiate(std::uint64_t round, Estimator& estimator,
                                  const std::vector<int>& candidates,
                                  const std::vector<int>& neighbours) {
  // Messages of this round's neighbours, in ascending robot id (the replay's order).
  std::vector<association::NegotiationMessage> messages;
  {
    std::lock_guard lock(mutex_);
    for (int robot : neighbours) {
      Peer& peer = *peers_.at(robot);
      const auto it = peer.negotiations.find(round);
      if (it == peer.negotiations.end()) continue;
      messages.push_back(std::move(it->second));
      peer.negotiations.erase(it);
    }
  }
  for (const auto& message : messages) {
    const association::NegotiationCounters before = association_->counters();
    association_->receive(message, round);
    const association::NegotiationCounters& after = association_->counters();
    if (after.records_refused != before.records_refused) {
      warn_limited(*log_limiter_, message.sender, "records",
                   "association: robot {} round {}: {} owner records of robots outside this "
                   "robot's members refused (does every robot list the same members?)",
                   message.sender, round, after.records_refused - before.records_refused);
    }
    if (after.records_not_owned != before.records_not_owned) {
      warn_limited(*log_limiter_, message.sender, "records_not_owned",
                   "association: robot {} round {}: {} owner records refused for deciding pairs "
                   "their owner does not own, or with robots outside this robot's members",
                   message.sender, round, after.records_not_owned - before.records_not_owned);
    }
  }
  for (int robot : candidates) {
    if (std::find(neighbours.begin(), neighbours.end(), robot) == neighbours.end())
      association_->missed(robot);
  }
  if (const auto move = association_->finish_round(round, estimator)) {
    if (move->from_frame == move->to_frame) {
      spdlog::warn("association: round {}: a frame edge was corrected; moved within frame {}",
                   round, move->to_frame);
    } else {
      spdlog::info("association: round {}: moved from frame {} into the team frame {}", round,
                   move->from_frame, move->to_frame);
    }
  }
}

}  // namespace concord::daemon

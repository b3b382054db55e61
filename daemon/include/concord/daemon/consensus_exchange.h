#pragma once
/// \file
/// The consensus protocol of one daemon (docs/daemon.md): per round k, after the frame-k update,
///
///   1. send LandmarkSet(k) (the ids the robot holds; a delta after the first on a link) to every
///      live peer;
///   2. lockstep: wait (up to round_deadline) for every live peer's LandmarkSet(k); the peers
///      heard from are this round's neighbours Q and |Q| the robot's degree;
///   3. send each neighbour the Marginal(k) of the common ids, carrying the degree;
///   4. lockstep: wait for each neighbour's Marginal(k); fuse them with Metropolis weights
///      1 / (1 + max(own degree, its degree)), in robot-id order (the order of concord replay).
///
/// A peer that goes down, says Goodbye, or shows it is in another round (a restarted robot far
/// behind, or one that gave up on us and went ahead) stops being waited for at once. Async mode
/// sends the same messages but never waits: it fuses each live peer's newest marginal if it
/// arrived within the robot's last staleness_rounds rounds and was not fused before (arrival, not
/// the sender's round number, decides: robots' frame numbers need not be aligned).
///
/// A peer takes part in a round when it is live and the graph allows it: restrict_to (a ring) and,
/// with a simulated radio (set_radio, RadioGraph), that round's links from the true positions.
///
/// Network callbacks (on_message, on_peer) run on the network thread; run_round on the estimator
/// thread. Messages go out through a Send function, so the protocol is testable without sockets.

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <vector>

#include "concord/association/relabelling.h"
#include "concord/daemon/config.h"
#include "concord/estimator/consensus.h"
#include "concord/estimator/marginal_sharing.h"
#include "concord/estimator/types.h"

namespace concord {
class Estimator;
}  // namespace concord

namespace concord::association {
struct MapDescription;
}  // namespace concord::association

namespace concord::v1 {
class Envelope;
class MapDescription;
}  // namespace concord::v1

namespace concord::net {
class LogLimiter;
}  // namespace concord::net

namespace concord::daemon {

class AssociationSession;
class RecordSigner;  // negotiation_wire.h

/// What one round did.
struct RoundReport {
  std::uint64_t round = 0;
  int live = 0;          ///< live peers at the start of the round
  int neighbours = 0;    ///< peers taking part (lockstep: LandmarkSet heard in time)
  int fused = 0;         ///< non-empty marginals fused
  int timed_out = 0;     ///< peers given up on at the deadline
  int bad_messages = 0;  ///< malformed marginals dropped in this round
  int excluded = 0;      ///< live peers not waited for (they missed miss_limit rounds in a row)
  double wait_seconds = 0.0;
  /// This thread's CPU time in the round's consensus step, waiting and negotiation left out:
  /// the robot's marginal and each neighbour's message (cut, encoded, handed to the network),
  /// and the fuse of what arrived (its check included).
  double send_cpu_seconds = 0.0;
  double fuse_cpu_seconds = 0.0;
  ConsensusReport consensus;
};

/// Totals since start.
struct ExchangeCounters {
  std::uint64_t rounds = 0;
  std::uint64_t marginals_fused = 0;
  std::uint64_t deadline_misses = 0;  ///< (peer, round) pairs given up on at the deadline
  std::uint64_t stale_dropped = 0;    ///< messages of past rounds dropped on arrival
  std::uint64_t malformed = 0;        ///< LandmarkSets and Marginals that could not be used
  std::uint64_t future_dropped = 0;   ///< messages beyond the future-round window, dropped
  std::uint64_t exclusions = 0;       ///< times a peer left the lockstep waits
  std::uint64_t excluded_peers = 0;   ///< peers out of the lockstep waits now (a gauge)
  std::uint64_t log_lines_suppressed = 0;
  /// Poisoning defence: neighbours' landmarks refused by the estimator's chi-square test,
  /// quarantines started, marginals not fused because their sender was in quarantine, the claims
  /// of those marginals refused against the sender's own earlier ones (tested, not fused: the
  /// estimator keeps the sender's history meanwhile), and the peers in quarantine now (a gauge).
  std::uint64_t landmarks_refused = 0;
  std::uint64_t quarantines = 0;
  std::uint64_t quarantined_dropped = 0;
  std::uint64_t quarantined_refused = 0;
  std::uint64_t quarantined_peers = 0;
  /// Link budget (consensus.link_budget_bytes_per_second): marginals trimmed to fit, marginals
  /// sent empty (nothing fitted), landmarks left out, and the bytes consensus sent.
  std::uint64_t budget_marginals_trimmed = 0;
  std::uint64_t budget_marginals_empty = 0;
  std::uint64_t budget_landmarks_dropped = 0;
  std::uint64_t bytes_sent = 0;
  /// Negotiated association: peers' negotiation messages refused (malformed, over the bounds:
  /// consensus.max_description_objects ...), marginals without a usable relabelling, and the
  /// bytes of this robot's negotiation messages.
  std::uint64_t negotiations_refused = 0;
  std::uint64_t relabellings_refused = 0;
  /// Per-robot identities: owner records left out of peers' negotiation messages because their
  /// owner did not sign them (forged, altered or unsigned).
  std::uint64_t records_unsigned = 0;
  std::uint64_t negotiation_bytes = 0;
  /// Negotiated association: CPU seconds of the threads doing it (not wall-clock: on a busy
  /// machine that counts other processes' turns), as concord replay's negotiation phase plus the
  /// wire: the sum of the four parts below.
  double negotiation_seconds = 0.0;
  /// Building and encoding the messages out.
  double negotiation_encode_seconds = 0.0;
  /// Decoding and checking the messages in (network thread).
  double negotiation_decode_seconds = 0.0;
  /// Describing the map, taking the messages in, the decisions and the move into the team frame.
  double negotiation_decide_seconds = 0.0;
  /// Work there only because ids are private: each neighbour's cut of the marginal and the
  /// relabelling of the marginals in.
  double negotiation_relabel_seconds = 0.0;
};

/// Per-peer poisoning-defence counters (for /metrics and /peers).
struct PeerTrust {
  std::uint64_t landmarks_tested = 0;
  std::uint64_t landmarks_refused = 0;
  std::uint64_t quarantines = 0;
  bool quarantined = false;
};

class LinkBudget;  // link_budget.h

/// Fault injection for tests (concordd --failpoint, docs/daemon.md).
struct ExchangeFailpoints {
  bool marginal_silence = false;  ///< LandmarkSets go out, Marginals never
  bool marginal_garbage = false;  ///< Marginals go out malformed
};

/// The ring neighbours of `robot` among `members` (sorted, ids unique): the members before and
/// after it, wrapping around; every other member when there are at most three.
std::set<int> ring_neighbours(int robot, std::vector<int> members);

/// consensus.radio (RadioConfig): a simulated radio over a team whose robot ids are a dataset's
/// robot indices. Each round the links of the base graph (complete, or the ring over `members`)
/// among the members that still have frames, limited by range, nearest and degree from the
/// members' true positions at that frame, exactly as `concord replay --range/--nearest/
/// --max-degree` (concord/dataset/radio.h). Every robot computes the same graph.
class RadioGraph {
 public:
  /// `positions`: each member's true positions, parallel to `members` (sorted, unique);
  /// max_frames: the frames each robot runs (0 = as many as its ground truth has).
  /// std::invalid_argument on mismatched sizes or unsorted members.
  RadioGraph(std::vector<int> members, ConsensusGraph base, RadioConfig limits,
             std::vector<std::vector<Eigen::Vector3d>> positions, int max_frames);
  /// The robots linked to `robot` in round `round` (empty for a non-member).
  std::set<int> neighbours(int robot, std::uint64_t round) const;

 private:
  std::vector<int> members_;
  ConsensusGraph base_;
  RadioConfig limits_;
  std::vector<std::vector<Eigen::Vector3d>> positions_;
  int max_frames_;
};

class ConsensusExchange {
 public:
  /// Queues an envelope (its body and round set) to a robot; false if it could not be queued.
  using Send = std::function<bool(int robot, v1::Envelope&& envelope)>;

  ConsensusExchange(ConsensusConfig config, Send send, ExchangeFailpoints failpoints = {});
  ~ConsensusExchange();

  /// Network thread: a LandmarkSet, Marginal or Goodbye from `robot` (other bodies ignored).
  void on_message(int robot, const v1::Envelope& envelope);
  /// Network thread: `robot` came up or went down.
  void on_peer(int robot, bool up);

  /// Estimator thread: waits until at least `count` peers are live, stop() or `timeout`.
  /// Returns the number of live peers.
  int wait_for_peers(int count, std::chrono::milliseconds timeout);

  /// Negotiated association (lockstep): the session that rides on the rounds (LandmarkSets carry
  /// its messages, consensus runs over team ids). Call before the network starts; not owned.
  void set_association(AssociationSession* session);
  /// Per-robot identities: own owner records go out signed, and a negotiation carrying a record
  /// its owner did not sign is left out (records_unsigned). Call before the network starts.
  void set_record_signer(std::shared_ptr<const RecordSigner> signer);

  /// Consensus only with these peers (others stay connected, and are not sent landmark sets or
  /// marginals); call before the network starts. Default: every live peer.
  void restrict_to(std::set<int> peers);
  /// consensus.radio: each round, consensus only with the peers `radio(round)` returns (and
  /// restrict_to allows). It must be symmetric between robots (RadioGraph is). Call before the
  /// network starts; called on the estimator thread.
  void set_radio(std::function<std::set<int>(std::uint64_t round)> radio);

  /// Estimator thread: consensus round `round` on `estimator` (after its update of that frame).
  RoundReport run_round(std::uint64_t round, Estimator& estimator);

  /// Wakes any wait; later rounds do not wait.
  void stop();

  std::vector<int> live_peers() const;
  ExchangeCounters counters() const;
  /// Poisoning-defence counters of every peer heard from, by robot id.
  std::map<int, PeerTrust> peer_trust() const;

  /// The highest round any live peer announced, waiting up to `timeout` until one announced a
  /// round (-1 if none did): where a restarted robot rejoins the lockstep.
  std::int64_t wait_for_team_round(std::chrono::milliseconds timeout);
  /// Before the first run_round of a resumed robot: rounds up to `round` are over.
  void resume_at(std::uint64_t round);

 private:
  struct Peer;
  using Clock = std::chrono::steady_clock;

  /// Each robot's LandmarkSet of the round, with its negotiation when association is on.
  void send_landmark_sets(const std::vector<int>& robots, std::uint64_t round,
                          const std::vector<LandmarkId>& ids);
  RoundReport lockstep_round(std::uint64_t round, Estimator& estimator);
  RoundReport async_round(std::uint64_t round, Estimator& estimator);
  /// `links_left`: marginals still to send this round, this one included (their budget share).
  void send_marginal(int robot, std::uint64_t round, const Estimator& estimator,
                     const std::vector<LandmarkId>& own_ids,
                     const std::vector<LandmarkId>& peer_ids, int degree, int links_left);
  /// Sends (the envelope is taken over) and charges the link budget (estimator thread).
  bool send_counted(int robot, v1::Envelope&& envelope);
  /// Whether marginals go compact and event-triggered (marginal_sharing.h; given association).
  bool sharing() const {
    return association_ == nullptr &&
           (config_.share_kl_threshold > 0.0 || config_.share_float32 ||
            config_.share_max_landmarks > 0 || config_.share_block_landmarks > 0);
  }
  void forget_rounds_up_to(std::uint64_t round);
  /// Whether a message of `round` is beyond the future-round window (lockstep; mutex held).
  bool beyond_window(std::uint64_t round) const;
  /// Peers' deferred LandmarkSets that the window now reaches become this round's (mutex held).
  void promote_deferred();
  /// A waited-for peer missed the deadline (mutex held).
  void count_miss(int robot, Peer& peer, std::uint64_t round);
  /// A peer answered round `round` in time (mutex held).
  void count_answer(int robot, Peer& peer, std::uint64_t round);
  /// Whether `robot` is in quarantine at `round` (mutex held); counts the dropped marginal.
  bool quarantined(int robot, Peer& peer, std::uint64_t round);
  /// After a fuse: a quarantined sender's marginals tested against its own earlier claims
  /// without fusing them (Estimator::witness), so that its history outlasts the quarantine.
  void witness(Estimator& estimator, const std::vector<WeightedMarginal>& out);
  /// After a fuse: the estimator's refusals of each inbox entry's landmarks (by its sender),
  /// towards quarantine.
  void judge(std::uint64_t round, const std::vector<WeightedMarginal>& inbox,
             const ConsensusReport& report);

  /// Negotiated rounds: phase 1's negotiation messages in, the move into the team frame.
  void negotiate(std::uint64_t round, Estimator& estimator, const std::vector<int>& candidates,
                 const std::vector<int>& neighbours);
  /// Adds to one part of the negotiation's seconds and to their sum (the caller holds mutex_).
  void count_negotiation_seconds(double ExchangeCounters::*part, double seconds);
  /// The same, taking the mutex.
  void add_negotiation_seconds(double ExchangeCounters::*part, double seconds);

  /// Whether `robot` takes part this round: restrict_to() and the radio's links allow it.
  bool takes_part(int robot, const std::optional<std::set<int>>& in_range) const;

  ConsensusConfig config_;
  AssociationSession* association_ = nullptr;
  std::shared_ptr<const RecordSigner> record_signer_;  ///< set_record_signer()
  std::optional<std::set<int>> allowed_;  ///< restrict_to()
  std::function<std::set<int>(std::uint64_t)> radio_;  ///< set_radio()
  Send send_;
  ExchangeFailpoints failpoints_;
  std::unique_ptr<net::LogLimiter> log_limiter_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  /// While run_round waits for its neighbours, the condition it waits for (guarded by mutex_):
  /// a message wakes it only when the condition holds, not once for every neighbour's message.
  struct WakeCondition {
    bool (*holds)(const void* context) = nullptr;
    const void* context = nullptr;
  };
  WakeCondition wake_condition_;
  /// Wakes the waiter for a message that arrived (mutex_ held): see wake_condition_.
  void notify_waiter();
  /// changed_.wait_until(lock, deadline, ready) with ready registered as wake_condition_.
  template <typename Ready>
  void wait_for_round(std::unique_lock<std::mutex>& lock,
                      std::chrono::steady_clock::time_point deadline, const Ready& ready);
  std::map<int, std::unique_ptr<Peer>> peers_;
  /// The marginals the last fuse consumed (guarded by mutex_): the next ones received are read
  /// into their storage (from_wire), not allocated again. At most one round's inbox is kept.
  std::vector<Marginal> spare_marginals_;
  /// After a fuse: its marginals become the spares (the ones kept before are let go).
  void recycle(std::vector<WeightedMarginal>& inbox);
  bool stopped_ = false;
  /// Rounds up to this one are over: their messages are dropped on arrival (lockstep).
  std::int64_t forgotten_up_to_ = -1;
  /// The round run_round is in (or last ran); -1 before the first.
  std::int64_t current_round_ = -1;
  ExchangeCounters counters_;
  /// Estimator thread only: the link budget, and per neighbour the round each landmark was last
  /// sent in (what it received most recently is the least valuable to send again).
  std::unique_ptr<LinkBudget> budget_;
  std::map<int, std::map<LandmarkId, std::uint64_t>> last_sent_;
  /// Estimator thread only: per neighbour, what it holds of this robot's landmarks (sharing()).
  std::map<int, MarginalSender> senders_;
  /// Estimator thread only: which of held_'s landmarks the message being sent carries.
  std::vector<bool> outgoing_;
  /// The round's marginal of every object the robot holds (given ids), built once before the
  /// marginals go out; each neighbour's is cut out of it (Consensus::select).
  Marginal held_;
  /// Negotiated, estimator thread only: per neighbour this round, the own ids its marginal is cut
  /// by and the neighbour's id of each landmark kept (AssociationSession::shared_cut).
  std::map<int, association::SharedCut> shared_cuts_;
  /// Estimator thread only: the last map description the negotiation sent, written for the wire
  /// once and copied into each neighbour's message.
  std::shared_ptr<const association::MapDescription> wired_map_source_;
  std::unique_ptr<v1::MapDescription> wired_map_;
};

}  // namespace concord::daemon

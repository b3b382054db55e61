#pragma once
/// \file
/// A daemon's side of the negotiated association (docs/association.md): the same
/// association::Negotiator as concord replay, driven by the lockstep rounds of ConsensusExchange.
/// Per round k (the order of tools/replay/team_replay.h):
///   - observe() the frame's detections (the tally of observations and classes);
///   - begin_round(): on describing rounds, describe the map in the frame the state is in;
///   - negotiation_for() each live peer: the message riding on its LandmarkSet(k);
///   - receive() each neighbour's message (ascending robot id), missed() for a peer that did not
///     take part (the owner records it may not have are sent again);
///   - finish_round(): pairs, team ids, and the move of the state into the team frame;
///   - shared_cut() each neighbour: the objects shared with it (the cut of the marginal it is
///     sent), with the neighbour's ids; accept_marginal() of a neighbour's: the pairs both views
///     agree on, relabelled with this robot's ids, when both are in one frame.
/// Estimator thread only; pure apart from the estimator it is handed.

#include <cstdint>
#include <memory>
#include <optional>
#include <utility>
#include <vector>

#include "concord/association/map_description.h"
#include "concord/association/negotiation.h"
#include "concord/association/relabelling.h"
#include "concord/estimator/types.h"

namespace concord {
class Estimator;
}  // namespace concord

namespace concord::daemon {

/// Where the robot's estimates are: what alignment.json and /status report.
struct AlignmentState {
  /// The frame the state is in (association::kWorldFrame or a robot's start frame).
  int frame = association::kWorldFrame;
  /// Maps the robot's start frame into `frame`, with its covariance (left perturbation).
  Eigen::Isometry3d T_frame_start = Eigen::Isometry3d::Identity();
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
  /// The round of the last move into another frame (0 if it never moved; a correction, a move
  /// within the frame, keeps it).
  std::int64_t aligned_at_round = 0;
  bool moved = false;
};

class AssociationSession {
 public:
  /// Robot `robot` starting in `start_frame` (its own id for an unknown start,
  /// association::kWorldFrame for a known one), in a team of `members` (owner records of others
  /// are refused; empty: any). Throws std::invalid_argument on bad options.
  AssociationSession(int robot, int start_frame, association::NegotiationOptions options,
                     std::vector<int> members = {});

  /// The frame's detections, after the estimator's step on the frame (the tally's misses are
  /// counted at its newest pose).
  void observe(const std::vector<StereoObservation>& objects, const std::vector<int>& classes,
               const Estimator& estimator);
  void begin_round(std::uint64_t round, const Estimator& estimator);
  association::NegotiationMessage negotiation_for(int robot, std::uint64_t round);
  void receive(const association::NegotiationMessage& message, std::uint64_t round);
  void missed(int robot);
  /// The move applied to `estimator`, if any.
  std::optional<association::Reanchoring> finish_round(std::uint64_t round, Estimator& estimator);

  /// The objects shared with `robot`: this robot's ids, ascending (what Consensus::select cuts
  /// out of `held` for it), and the neighbour's id of each landmark that cut keeps, in the cut's
  /// order (held's). `held`: the marginal of every object the robot holds (built once a round
  /// for all neighbours, Estimator::marginal of object_ids()).
  association::SharedCut shared_cut(int robot, const Marginal& held) const;
  /// What this robot fuses of `robot`'s marginal sent in `frame` with `receiver_ids` (parallel to
  /// its ids): nullopt when the frames differ or no pair is agreed. Takes the marginal (moved
  /// from only when the frames and sizes match).
  std::optional<Marginal> accept_marginal(int robot, Marginal&& marginal,
                                          const std::vector<LandmarkId>& receiver_ids,
                                          int frame) const;

  int frame() const { return negotiator_.frame(); }
  /// Team id of each of `objects` (-1 while unshared).
  std::vector<LandmarkId> team_ids(const std::vector<ObjectEstimate>& objects) const;
  /// The detector's class of each of `objects` (the most frequent of its detections' classes),
  /// association::kUnknownClass when its detections carried none.
  std::vector<int> object_classes(const std::vector<ObjectEstimate>& objects) const;
  const AlignmentState& alignment() const { return alignment_; }
  const association::NegotiationCounters& counters() const { return negotiator_.counters(); }

 private:
  association::Negotiator negotiator_;
  association::ObservationTally tally_;
  AlignmentState alignment_;
};

}  // namespace concord::daemon

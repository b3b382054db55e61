#include "concord/daemon/association_session.h"

#include <algorithm>
#include <map>

#include "concord/association/relabelling.h"
#include "concord/estimator/consensus.h"
#include "concord/estimator/estimator.h"

namespace concord::daemon {

AssociationSession::AssociationSession(int robot, int start_frame,
                                       association::NegotiationOptions options,
                                       std::vector<int> members)
    : negotiator_(robot, start_frame, std::move(options)) {
  negotiator_.set_members(std::move(members));
  alignment_.frame = start_frame;
}

void AssociationSession::observe(const std::vector<StereoObservation>& objects,
                                 const std::vector<int>& classes, const Estimator& estimator) {
  tally_.add(objects, classes, estimator.state(), estimator.camera());
}

void AssociationSession::begin_round(std::uint64_t round, const Estimator& estimator) {
  const int k = static_cast<int>(round);
  if (!negotiator_.describes(k)) return;
  negotiator_.set_own_map(
      association::describe_map(estimator.state(), negotiator_.robot(), negotiator_.frame(), tally_,
                                negotiator_.options().association.min_observations,
                                negotiator_.options().association.min_detection_ratio),
      k);
}

association::NegotiationMessage AssociationSession::negotiation_for(int robot,
                                                                    std::uint64_t round) {
  return negotiator_.message_for(robot, static_cast<int>(round));
}

void AssociationSession::receive(const association::NegotiationMessage& message,
                                 std::uint64_t round) {
  negotiator_.receive(message, static_cast<int>(round));
}

void AssociationSession::missed(int robot) { negotiator_.forget_sent(robot); }

std::optional<association::Reanchoring> AssociationSession::finish_round(std::uint64_t round,
                                                                         Estimator& estimator) {
  const std::size_t corrections = negotiator_.corrections_seen();
  auto move = negotiator_.finish_round(static_cast<int>(round));
  // A correction moved some robots within the team frame: their claims jump.
  if (negotiator_.corrections_seen() != corrections) estimator.forget_claims();
  if (move) {
    estimator.reanchor(move->T_new_old, move->covariance, move->pose_frame, move->independent);
    // The first round in the final frame: a correction (a move within it) keeps it.
    if (move->from_frame != move->to_frame) {
      alignment_.aligned_at_round = static_cast<std::int64_t>(round);
    }
    alignment_.moved = true;
  }
  alignment_.frame = negotiator_.frame();
  alignment_.T_frame_start = negotiator_.T_frame_start();
  alignment_.covariance = negotiator_.covariance_frame_start();
  return move;
}

association::SharedCut AssociationSession::shared_cut(int robot, const Marginal& held) const {
  return association::shared_cut(negotiator_.shared_objects(robot), held.ids);
}

std::optional<Marginal> AssociationSession::accept_marginal(
    int robot, Marginal&& marginal, const std::vector<LandmarkId>& receiver_ids, int frame) const {
  if (frame != negotiator_.frame() || receiver_ids.size() != marginal.ids.size())
    return std::nullopt;
  Marginal relabelled = association::relabel_agreed(std::move(marginal), receiver_ids,
                                                    negotiator_.shared_view(robot));
  if (relabelled.ids.empty()) return std::nullopt;
  return relabelled;
}

std::vector<int> AssociationSession::object_classes(
    const std::vector<ObjectEstimate>& objects) const {
  std::vector<int> classes;
  classes.reserve(objects.size());
  for (const ObjectEstimate& object : objects) classes.push_back(tally_.object_class(object.id));
  return classes;
}

std::vector<LandmarkId> AssociationSession::team_ids(
    const std::vector<ObjectEstimate>& objects) const {
  std::vector<LandmarkId> ids;
  ids.reserve(objects.size());
  for (const ObjectEstimate& object : objects) ids.push_back(negotiator_.team_id(object.id));
  return ids;
}

}  // namespace concord::daemon

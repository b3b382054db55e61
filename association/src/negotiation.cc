#include "concord/association/negotiation.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <deque>
#include <numbers>
#include <set>
#include <stdexcept>

#include "concord/association/alignment.h"
#include "concord/association/relabelling.h"
#include "concord/estimator/updater_helper.h"

namespace concord::association {

namespace {

const NegotiationOptions& validated(const NegotiationOptions& options) {
  const auto problems = options.validate();
  if (!problems.empty()) {
    std::string message = "invalid association options:";
    for (const auto& problem : problems) message += "\n  " + problem;
    throw std::invalid_argument(message);
  }
  return options;
}

/// Whether two transforms of one pair agree: the 6-D difference log(T_1 T_0^-1) within the
/// chi-square bound under the sum of their covariances.
bool transforms_agree(const PairAlignment& previous, const PairAlignment& current, double bound) {
  const lie::Vector6d difference = lie::se3_log(current.T_a_b * previous.T_a_b.inverse());
  const Eigen::LLT<lie::Matrix6d> llt(previous.covariance + current.covariance);
  if (llt.info() != Eigen::Success) return false;
  return difference.dot(llt.solve(difference)) <= bound;
}

const ObjectDescription* find_object(const MapDescription& map, LandmarkId id) {
  const auto it = std::lower_bound(
      map.objects.begin(), map.objects.end(), id,
      [](const ObjectDescription& object, LandmarkId key) { return object.id < key; });
  return it != map.objects.end() && it->id == id ? &*it : nullptr;
}

}  // namespace

std::vector<std::string> NegotiationOptions::validate() const {
  std::vector<std::string> problems = association.validate();
  const auto require = [&](bool ok, const std::string& key, double value, const std::string& rule) {
    if (!ok) {
      problems.push_back("association." + key + " = " + std::to_string(value) + ": must be " +
                         rule);
    }
  };
  require(description_interval >= 1, "description_interval", description_interval, ">= 1");
  require(confirmations >= 1, "confirmations", confirmations, ">= 1");
  require(confirmation_new_matches >= 0, "confirmation_new_matches", confirmation_new_matches,
          ">= 0");
  require(transform_agreement_chi2_probability > 0.0 && transform_agreement_chi2_probability < 1.0,
          "transform_agreement_chi2_probability", transform_agreement_chi2_probability,
          "in (0, 1)");
  require(split_chi2_probability > 0.0 && split_chi2_probability < 1.0, "split_chi2_probability",
          split_chi2_probability, "in (0, 1)");
  require(split_after >= 1, "split_after", split_after, ">= 1");
  require(revisit_descriptions >= 0, "revisit_descriptions", revisit_descriptions, ">= 0");
  require(revisit_interval >= 1, "revisit_interval", revisit_interval, ">= 1");
  require(revisit_confirmations >= 1, "revisit_confirmations", revisit_confirmations, ">= 1");
  require(revisit_chi2_probability > 0.0 && revisit_chi2_probability < 1.0,
          "revisit_chi2_probability", revisit_chi2_probability, "in (0, 1)");
  require(revisit_ambiguity_ratio > 0.0, "revisit_ambiguity_ratio", revisit_ambiguity_ratio, "> 0");
  require(max_corrections >= 0, "max_corrections", max_corrections, ">= 0");
  require(relay_delay >= 0, "relay_delay", relay_delay, ">= 0");
  return problems;
}

lie::Matrix6d transform_error_covariance(const Eigen::Isometry3d& T_a_b, const lie::Matrix6d& fit,
                                         const lie::Matrix6d& drift_a,
                                         const lie::Matrix6d& drift_b) {
  const lie::Matrix6d adjoint = lie::adjoint(T_a_b);
  const lie::Matrix6d full = fit + drift_a + adjoint * drift_b * adjoint.transpose();
  return 0.5 * (full + full.transpose());
}

lie::Matrix6d FrameEdge::full_covariance(bool omit_a, bool omit_b) const {
  return transform_error_covariance(T_a_b, covariance,
                                    omit_a ? lie::Matrix6d::Zero().eval() : drift_a,
                                    omit_b ? lie::Matrix6d::Zero().eval() : drift_b);
}

std::size_t OwnerRecord::wire_size() const {
  std::size_t size = 12 + 20 * links.size() + 324 * frame_edges.size() + signature.size();
  for (const FrameEdge& edge : frame_edges) size += 144 * edge.corrections.size();
  return size;
}

std::size_t NegotiationMessage::wire_size() const {
  std::size_t size = 8 + 8 * held.size();
  if (map) size += map->wire_size();
  for (const auto& record : records) size += record->wire_size();
  return size;
}

bool decides_own_pairs_only(const OwnerRecord& record) {
  const int owner = record.owner;
  const auto owned = [owner](int other) { return other != owner && owns_pair(owner, other); };
  for (const ObjectLink& link : record.links) {
    const int a = robot_of(link.a);
    const int b = robot_of(link.b);
    if (a == b || (a != owner && b != owner) || !owned(a == owner ? b : a)) return false;
  }
  for (const FrameEdge& edge : record.frame_edges) {
    if (edge.owner != owner || !owned(edge.robot_b)) return false;
  }
  return true;
}

Negotiator::Negotiator(int robot, int start_frame, NegotiationOptions options)
    : robot_(robot),
      start_frame_(start_frame),
      frame_(start_frame),
      options_(validated(options)),
      split_bound_(UpdaterHelper::chi2_quantile(options_.split_chi2_probability, 3)),
      revisit_bound_(UpdaterHelper::chi2_quantile(options_.revisit_chi2_probability, 6)),
      agreement_bound_(
          UpdaterHelper::chi2_quantile(options_.transform_agreement_chi2_probability, 6)),
      team_ids_(robot) {
  records_[robot_] = std::make_shared<const OwnerRecord>(OwnerRecord{robot_, 0, {}, {}, {}});
}

void Negotiator::set_own_map(MapDescription map, int round) {
  own_map_ = std::make_shared<const MapDescription>(std::move(map));
  own_map_round_ = round;
  own_prepared_.reset();
}

const PreparedMap& Negotiator::own_prepared() {
  if (!own_prepared_)
    own_prepared_ = std::make_unique<PreparedMap>(*own_map_, options_.association);
  return *own_prepared_;
}

NegotiationMessage Negotiator::message_for(int neighbour, int round) {
  NegotiationMessage message;
  message.sender = robot_;
  message.frame = frame_;
  if (describes(round) && own_map_ && own_map_round_ == round) message.map = own_map_;
  boost::container::flat_map<int, int>& sent = sent_versions_[neighbour];
  message.held.reserve(records_.size());
  // records_ and sent both ascend by owner: one walk along both.
  auto known = sent.begin();  // the first entry of `sent` not below the current owner
  for (const auto& [owner, record] : records_) {
    if (record->version == 0) continue;  // nothing decided yet
    if (owner == neighbour) continue;    // it knows its own decisions
    message.held.emplace_back(owner, record->version);
    while (known != sent.end() && known->first < owner) ++known;
    const bool listed = known != sent.end() && known->first == owner;
    if (listed && known->second >= record->version) continue;
    // Another owner's record waits relay_delay rounds: the neighbour may have it from its owner
    // and say so meanwhile.
    if (owner != robot_) {
      const auto arrived = record_round_.find(owner);
      if (arrived != record_round_.end() && round - arrived->second < options_.relay_delay) {
        continue;
      }
    }
    message.records.push_back(record);
    if (listed) {
      known->second = record->version;
    } else {
      known = sent.emplace_hint(known, owner, record->version);
    }
  }
  ++counters_.messages;
  counters_.bytes_sent += static_cast<long long>(message.wire_size());
  if (message.map) counters_.description_bytes += static_cast<long long>(message.map->wire_size());
  return message;
}

void Negotiator::set_members(std::vector<int> members) {
  std::sort(members.begin(), members.end());
  members.erase(std::unique(members.begin(), members.end()), members.end());
  members_ = std::move(members);
}

bool Negotiator::member(int owner) const {
  return members_.empty() || std::binary_search(members_.begin(), members_.end(), owner);
}

bool Negotiator::decides_for_members(const OwnerRecord& record) const {
  if (!decides_own_pairs_only(record)) return false;
  for (const ObjectLink& link : record.links) {
    const int other = robot_of(link.a) == record.owner ? robot_of(link.b) : robot_of(link.a);
    if (!member(other)) return false;
  }
  for (const FrameEdge& edge : record.frame_edges) {
    if (!member(edge.robot_b)) return false;
  }
  return true;
}

void Negotiator::receive(const NegotiationMessage& message, int round) {
  neighbour_frames_[message.sender] = message.frame;
  if (message.map) neighbour_maps_[message.sender] = {round, message.map};
  for (const auto& record : message.records) {
    if (!record || record->owner == robot_) continue;  // its own decisions are authoritative here
    if (!member(record->owner)) {
      ++counters_.records_refused;
      continue;
    }
    if (!decides_for_members(*record)) {
      ++counters_.records_not_owned;
      continue;
    }
    auto it = records_.find(record->owner);
    if (it == records_.end() || it->second->version < record->version) {
      records_[record->owner] = record;
      record_round_[record->owner] = round;
      team_ids_.stage(record->owner, record->links);
    } else {
      ++counters_.records_redundant;
    }
  }
  // The sender has every record it sent and every one it says it holds: it need not get them
  // (or older ones) from this robot.
  boost::container::flat_map<int, int>& sent = sent_versions_[message.sender];
  for (const auto& record : message.records) {
    if (!record || !member(record->owner)) continue;
    int& version = sent[record->owner];
    version = std::max(version, record->version);
  }
  // Claims on owners this robot holds no record of are left out: it has nothing of theirs to
  // send, and a peer must not grow the table with owners that do not exist (it says what it
  // holds again in every message).
  // An honest sender lists them ascending, as records_ and sent are: one walk along all three
  // (a descent is searched for).
  auto record = records_.begin();
  auto known = sent.begin();
  bool started = false;
  int previous = 0;
  for (const auto& [owner, version] : message.held) {
    if (started && owner < previous) {
      record = records_.lower_bound(owner);
      known = sent.lower_bound(owner);
    } else {
      while (record != records_.end() && record->first < owner) ++record;
      while (known != sent.end() && known->first < owner) ++known;
    }
    started = true;
    previous = owner;
    if (record == records_.end() || record->first != owner) continue;
    if (known != sent.end() && known->first == owner) {
      known->second = std::max(known->second, version);
    } else {
      known = sent.emplace_hint(known, owner, std::max(0, version));
    }
  }
}

std::optional<Reanchoring> Negotiator::finish_round(int round) {
  // 1. Owner work on this round's descriptions.
  bool own_changed = false;
  if (own_map_ && own_map_round_ == round) {
    for (const auto& [neighbour, received] : neighbour_maps_) {
      if (!owns_pair(robot_, neighbour) || received.round != round) continue;
      own_changed = process_pair(neighbour, *received.map, round) || own_changed;
    }
  }
  if (own_changed) rebuild_own_record();

  // 2. Team ids over every known owner's links (kept up to date as records came in).
  if (team_ids_.commit()) {
    counters_.team_id_conflicts = team_ids_.ids().conflicts;
    // Every neighbour's shared objects at once, from the teams of this robot's own objects (its
    // keys are one range of team_of: the robot is a key's high bits).
    shared_.clear();
    const TeamIds& ids = team_ids_.ids();
    for (auto it = ids.team_of.lower_bound(object_key(robot_, 0));
         it != ids.team_of.end() && robot_of(it->first) == robot_; ++it) {
      const auto& [own, team] = *it;
      for (const ObjectKey key : ids.members.at(team)) {
        if (key != own) shared_[robot_of(key)].emplace_back(id_of(own), id_of(key));
      }
    }
    shared_views_.clear();
    for (auto& [neighbour, pairs] : shared_) {
      std::sort(pairs.begin(), pairs.end());
      shared_views_.emplace(neighbour, receiver_view(pairs));
    }
  }

  // 3. Corrections of the edges the robot's state came through, then the team frame.
  const std::optional<Reanchoring> correction = take_corrections();
  const FrameTarget target = team_frame_of(frame_);
  if (target.frame == frame_) return correction;
  Reanchoring move{frame_,
                   target.frame,
                   target.T_target_frame,
                   target.covariance,
                   target.pose_frame,
                   target.independent};
  if (correction) {
    // (A correction first: the transform is no longer the one the pose's drift entered.)
    move.T_new_old = target.T_target_frame * correction->T_new_old;
    move.covariance =
        compose_covariance(target.T_target_frame, target.covariance, correction->covariance);
    move.pose_frame = -1;
    move.independent.setZero();
  }
  covariance_frame_start_ =
      compose_covariance(target.T_target_frame, target.covariance, covariance_frame_start_);
  T_frame_start_ = target.T_target_frame * T_frame_start_;
  frame_ = target.frame;
  ++counters_.reanchorings;
  return move;
}

std::optional<Reanchoring> Negotiator::take_corrections() {
  std::optional<Reanchoring> move;
  std::set<std::tuple<int, int, int, int, std::size_t>> seen;
  for (const auto& [owner, record] : records_) {
    for (const FrameEdge& edge : record->frame_edges) {
      for (std::size_t k = 0; k < edge.corrections.size(); ++k) {
        const auto key = std::make_tuple(edge.owner, edge.round, edge.frame_a, edge.frame_b, k);
        if (!seen.insert(key).second || corrections_seen_.contains(key)) continue;
        ++corrections_count_;
        // A robot in another frame joins through the corrected edge later, if at all.
        const FrameCorrection& correction = edge.corrections[k];
        if (correction.frame != frame_) continue;
        const int moving = correction.moves_b_side ? edge.frame_b : edge.frame_a;
        const int staying = correction.moves_b_side ? edge.frame_a : edge.frame_b;
        const std::set<int> side = component_of(moving, &edge);
        if (!side.contains(start_frame_) || side.contains(staying)) continue;
        if (!move) {
          move = Reanchoring{frame_, frame_, Eigen::Isometry3d::Identity(), lie::Matrix6d::Zero()};
        }
        move->covariance =
            compose_covariance(correction.T, correction.covariance, move->covariance);
        move->T_new_old = correction.T * move->T_new_old;
      }
    }
  }
  corrections_seen_ = std::move(seen);
  if (!move) return std::nullopt;
  covariance_frame_start_ =
      compose_covariance(move->T_new_old, move->covariance, covariance_frame_start_);
  T_frame_start_ = move->T_new_old * T_frame_start_;
  ++counters_.reanchorings;
  return move;
}

bool Negotiator::process_pair(int neighbour, const MapDescription& theirs, int round) {
  PairState& pair = pairs_[neighbour];
  const MapDescription& own = *own_map_;
  if (own.frame != theirs.frame) {
    // Frames already joined by a known edge: wait for the robots to move into the team frame.
    if (frames_connected(own.frame, theirs.frame)) return false;
    ++counters_.searches;
    const PairAlignment found =
        align_maps(own_prepared(), PreparedMap(theirs, options_.association), options_.association);
    if (search_listener_) {
      SearchTrace trace;
      trace.round = round;
      trace.robot = robot_;
      trace.neighbour = neighbour;
      trace.own = &own;
      trace.theirs = &theirs;
      trace.found = &found;
      search_listener_(trace);
    }
    if (found.status == AlignmentStatus::kAmbiguous) ++counters_.ambiguous;
    if (found.status == AlignmentStatus::kTilted) ++counters_.tilted;
    if (found.status != AlignmentStatus::kAligned) {
      pair.streak = 0;
      pair.last.reset();
      return false;
    }
    ++counters_.aligned;
    const bool agrees = pair.last && pair.last_frame_a == own.frame &&
                        pair.last_frame_b == theirs.frame &&
                        transforms_agree(*pair.last, found, agreement_bound_);
    pair.streak = agrees ? pair.streak + 1 : 1;
    if (pair.streak == 1) {
      pair.streak_first_matches.clear();
      for (const Match& match : found.matches) {
        pair.streak_first_matches.emplace(match.id_a, match.id_b);
      }
    }
    int new_matches = 0;
    for (const Match& match : found.matches) {
      new_matches += pair.streak_first_matches.contains({match.id_a, match.id_b}) ? 0 : 1;
    }
    const bool confirmed = pair.streak >= options_.confirmations &&
                           new_matches >= options_.confirmation_new_matches;
    bool changed = false;
    if (confirmed) changed = accept_frames(pair, theirs, found, round);
    pair.last = found;
    pair.last_frame_a = own.frame;
    pair.last_frame_b = theirs.frame;
    if (confirmed) {
      pair.streak = 0;
      pair.last.reset();
    }
    return changed;
  }
  pair.streak = 0;
  pair.last.reset();
  if (pair.edge >= 0 && ++pair.since_edge <= options_.revisit_descriptions &&
      pair.since_edge % options_.revisit_interval == 0 && revisit_edge(pair, theirs, round)) {
    return true;
  }
  return match_in_frame(pair, theirs);
}

bool Negotiator::revisit_edge(PairState& pair, const MapDescription& theirs, int round) {
  const MapDescription& own = *own_map_;
  ++counters_.revisits;
  const PairAlignment found =
      align_maps(own_prepared(), PreparedMap(theirs, options_.association), options_.association);
  const auto aligned_as_accepted = [&pair] {
    pair.revisit_streak = 0;
    pair.revisit_last.reset();
    return false;
  };
  SearchTrace trace;
  trace.round = round;
  trace.robot = robot_;
  trace.neighbour = theirs.robot;
  trace.revisit = true;
  trace.own = &own;
  trace.theirs = &theirs;
  trace.found = &found;
  if (found.status != AlignmentStatus::kAligned) {
    if (search_listener_) search_listener_(trace);
    return aligned_as_accepted();
  }
  // 1. The maps are in one frame: a right edge leaves them aligned up to what the two robots know
  //    of their maps there. The same correspondences fitted on the marginal covariances (each
  //    object in the common frame, the moves' and the drift's uncertainty included) say how far
  //    from the identity that is; the local ones (the search's fit) would call a map's drift a
  //    misalignment.
  std::vector<PointPair> pairs;
  pairs.reserve(found.matches.size());
  for (const Match& match : found.matches) {
    const ObjectDescription* mine = find_object(own, match.id_a);
    const ObjectDescription* other = find_object(theirs, match.id_b);
    if (mine == nullptr || other == nullptr) continue;
    pairs.push_back({mine->position, other->position, mine->covariance, other->covariance});
  }
  const std::optional<RigidAlignment> in_frame = align_points(pairs);
  if (!in_frame) {
    if (search_listener_) search_listener_(trace);
    return aligned_as_accepted();
  }
  const lie::Vector6d offset = lie::se3_log(in_frame->T_target_source);
  const Eigen::LLT<lie::Matrix6d> llt(in_frame->covariance);
  const double distance = llt.info() == Eigen::Success ? offset.dot(llt.solve(offset)) : 0.0;
  // 2. The accepted alignment is a hypothesis too: the correspondences it supports as it stands
  //    (the identity, matched as the search matches its own transform's). One with at least
  //    revisit_ambiguity_ratio of the found transform's makes the revisit ambiguous, as a rival
  //    clique makes a search: maps that fit two ways are no evidence that the accepted way is
  //    wrong, and one robot's map gone wrong on its own is no reason to move every robot behind
  //    the edge.
  //    Only a revisit beyond the gate needs it.
  const std::size_t supported =
      distance > revisit_bound_
          ? match_with_transform(own, theirs, Eigen::Isometry3d::Identity(),
                                 Covariances::kTransform, options_.association)
                .size()
          : 0;
  const bool rivalled =
      distance > revisit_bound_ &&
      static_cast<double>(supported) >=
          options_.revisit_ambiguity_ratio * static_cast<double>(found.matches.size());
  if (rivalled) ++counters_.revisits_ambiguous;
  if (search_listener_) {
    trace.revisit_distance = distance;
    trace.revisit_degrees = offset.tail<3>().norm() * 180.0 / std::numbers::pi;
    trace.matched_as_they_stand = supported;
    search_listener_(trace);
  }
  if (distance <= revisit_bound_ || rivalled) return aligned_as_accepted();
  const bool agrees =
      pair.revisit_last && transforms_agree(*pair.revisit_last, found, agreement_bound_);
  pair.revisit_streak = agrees ? pair.revisit_streak + 1 : 1;
  pair.revisit_last = found;
  if (pair.revisit_streak < options_.revisit_confirmations) return false;
  pair.revisit_streak = 0;
  pair.revisit_last.reset();
  FrameEdge& edge = own_frame_edges_[static_cast<std::size_t>(pair.edge)];
  if (static_cast<int>(edge.corrections.size()) >= options_.max_corrections) return false;

  // 3. The side of the edge away from the team frame moves; an edge that closes a cycle of edges
  //    has no such side (the others hold its frames together) and is left as it is.
  const std::set<int> staying = component_of(own.frame, &edge);
  const bool a_stays = staying.contains(edge.frame_a);
  if (a_stays == staying.contains(edge.frame_b)) return false;
  const FrameTarget to_a = team_frame_of(edge.frame_a);
  const FrameTarget to_b = team_frame_of(edge.frame_b);
  if (to_a.frame != own.frame || to_b.frame != own.frame) return false;
  FrameCorrection correction;
  correction.frame = own.frame;
  correction.moves_b_side = a_stays;
  correction.round = round;
  // found.T_a_b maps the neighbour's map onto this robot's: the neighbour's side moves by it, or
  // this robot's side by its inverse. Its error holds both maps' drift in the frame (their
  // poses' covariances), as a search's does (FrameEdge::full_covariance).
  const lie::Matrix6d found_covariance = transform_error_covariance(
      found.T_a_b, found.covariance, own.pose_covariance, theirs.pose_covariance);
  if (staying.contains(start_frame_)) {
    correction.T = found.T_a_b;
    correction.covariance = found_covariance;
  } else {
    correction.T = found.T_a_b.inverse();
    correction.covariance = inverse_covariance(found.T_a_b, found_covariance);
  }
  // 4. The edge as it should have been: T_team_a^-1 C T_team_b with C on the moving side's path.
  //    Its covariance is the correction's, taken into frame_a (what the found transform knows of
  //    the two maps' relative pose; the accepted one was wrong).
  const Eigen::Isometry3d T_team_a =
      a_stays ? to_a.T_target_frame : correction.T * to_a.T_target_frame;
  const Eigen::Isometry3d T_team_b =
      a_stays ? correction.T * to_b.T_target_frame : to_b.T_target_frame;
  const lie::Matrix6d adjoint = lie::adjoint(T_team_a.inverse());
  edge.T_a_b = T_team_a.inverse() * T_team_b;
  edge.covariance = adjoint * correction.covariance * adjoint.transpose();
  // The correction's covariance holds the maps' drift as they were revisited.
  edge.drift_a.setZero();
  edge.drift_b.setZero();
  edge.pose_frame_a = edge.pose_frame_b = -1;
  edge.corrections.push_back(correction);
  ++counters_.frame_corrections;
  pair.since_edge = 0;

  // 5. The pair's correspondences become the found ones (the accepted ones came from the wrong
  //    transform, or from in-frame matching under it).
  std::set<std::pair<LandmarkId, LandmarkId>> kept;
  for (const Match& match : found.matches) kept.emplace(match.id_a, match.id_b);
  for (auto it = pair.accepted.begin(); it != pair.accepted.end();) {
    if (kept.contains(it->first)) {
      ++it;
      continue;
    }
    pair.disagreement.erase(it->first);
    it = pair.accepted.erase(it);
    ++counters_.links_split;
  }
  adopt_matches(pair, found.matches, false);
  pair.candidate_streak.clear();
  return true;
}

bool Negotiator::accept_frames(PairState& pair, const MapDescription& theirs,
                               const PairAlignment& found, int round) {
  FrameEdge edge;
  edge.frame_a = own_map_->frame;
  edge.frame_b = theirs.frame;
  edge.T_a_b = found.T_a_b;
  edge.covariance = found.covariance;
  edge.round = round;
  edge.owner = robot_;
  edge.robot_b = theirs.robot;
  edge.drift_a = own_map_->pose_covariance;
  edge.drift_b = theirs.pose_covariance;
  edge.pose_frame_a = own_map_->pose_frame;
  edge.pose_frame_b = theirs.pose_frame;
  own_frame_edges_.push_back(std::move(edge));
  pair.edge = static_cast<int>(own_frame_edges_.size()) - 1;
  pair.since_edge = 0;
  ++counters_.frame_edges;
  // Correspondences found in both of the last two transforms (confirmations >= 2), or in this one.
  adopt_matches(pair, found.matches, options_.confirmations >= 2);
  return true;
}

void Negotiator::adopt_matches(PairState& pair, const std::vector<Match>& matches,
                               bool also_in_last) {
  std::set<std::pair<LandmarkId, LandmarkId>> previous;
  if (also_in_last && pair.last) {
    for (const Match& match : pair.last->matches) previous.emplace(match.id_a, match.id_b);
  }
  std::set<LandmarkId> own_linked, their_linked;
  for (const auto& [ids, d2] : pair.accepted) {
    own_linked.insert(ids.first);
    their_linked.insert(ids.second);
  }
  for (const Match& match : matches) {
    const std::pair<LandmarkId, LandmarkId> ids{match.id_a, match.id_b};
    if (also_in_last && !previous.contains(ids)) continue;
    if (pair.accepted.contains(ids)) continue;
    if (own_linked.contains(ids.first) || their_linked.contains(ids.second)) {
      ++counters_.link_conflicts;
      continue;
    }
    pair.accepted[ids] = match.mahalanobis_squared;
    own_linked.insert(ids.first);
    their_linked.insert(ids.second);
    ++counters_.links_accepted;
  }
}

std::optional<RigidAlignment> Negotiator::relative_pose(
    const std::vector<LinkedObjects>& linked) const {
  if (!options_.in_frame_fit) return std::nullopt;
  std::vector<PointPair> points;
  points.reserve(linked.size());
  for (const auto& [mine, other] : linked) {
    if (mine == nullptr || other == nullptr) continue;
    // As a search fits its transform: the covariances relative to each robot's current pose
    // (an archived object's marginal stands for its drift since; on the recorded covariances
    // the old parts of the maps pull the fit, measured in docs/association.md, "A move that
    // keeps the map's drift").
    points.push_back(point_pair(*mine, *other, true, options_.association.distance_noise));
  }
  if (static_cast<int>(points.size()) < options_.association.min_inliers) return std::nullopt;
  // One Gauss-Newton step from the weighted closed form: the fit only centres a gate. Five steps
  // changed no match on the development sets (11-13) and cost about a tenth more negotiation.
  std::optional<RigidAlignment> fit = align_points(points, 1);
  // The gate wants the fit's own uncertainty, (J^T W J)^-1 scaled by the residuals' excess:
  // align_points reports n times that (covariance intersection over the n correspondences,
  // for moving a state whatever their correlations), which would open the gate of an object
  // a few tens of metres from the fitted ones to metres and let unrelated objects in.
  if (fit) fit->covariance /= static_cast<double>(points.size());
  return fit;
}

std::optional<RigidAlignment> Negotiator::current_offset(const PairState& pair,
                                                         const std::vector<LinkedObjects>& linked,
                                                         const std::vector<Match>& matches,
                                                         const MapDescription& theirs) const {
  const MapDescription& own = *own_map_;
  std::vector<Eigen::Vector3d> offsets;
  const auto add = [&](const ObjectDescription* mine, const ObjectDescription* other) {
    if (mine == nullptr || other == nullptr || mine->archived || other->archived) return;
    offsets.push_back(mine->position - other->position);
  };
  for (const auto& [mine, other] : linked) add(mine, other);
  for (const Match& match : matches) {
    if (!pair.accepted.contains({match.id_a, match.id_b})) {
      add(find_object(own, match.id_a), find_object(theirs, match.id_b));
    }
  }
  if (static_cast<int>(offsets.size()) < options_.association.min_inliers) return std::nullopt;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& offset : offsets) mean += offset;
  mean /= static_cast<double>(offsets.size());
  Eigen::Matrix3d spread = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3d& offset : offsets) {
    spread += (offset - mean) * (offset - mean).transpose();
  }
  // The spread of one more object's offset about the mean: the sample covariance and the mean's.
  const auto n = static_cast<double>(offsets.size());
  spread *= (1.0 + 1.0 / n) / (n - 1.0);
  RigidAlignment found;
  found.T_target_source = Eigen::Translation3d(mean) * Eigen::Isometry3d::Identity();
  found.covariance.setZero();
  found.covariance.topLeftCorner<3, 3>() = spread;
  return found;
}

bool Negotiator::match_in_frame(PairState& pair, const MapDescription& theirs) {
  const MapDescription& own = *own_map_;
  bool changed = false;
  // 1. Accepted correspondences whose objects now disagree are undone after split_after times.
  //    The objects of the links kept, in the order of `accepted`, for the steps below. `accepted`
  //    ascends by own id, as the description's objects do: the own side is a forward search.
  const double split_bound = split_bound_;
  std::vector<LinkedObjects> linked;
  linked.reserve(pair.accepted.size());
  auto own_from = own.objects.begin();
  for (auto it = pair.accepted.begin(); it != pair.accepted.end();) {
    own_from = std::lower_bound(
        own_from, own.objects.end(), it->first.first,
        [](const ObjectDescription& object, LandmarkId key) { return object.id < key; });
    const ObjectDescription* mine =
        own_from != own.objects.end() && own_from->id == it->first.first ? &*own_from : nullptr;
    const ObjectDescription* other = find_object(theirs, it->first.second);
    const bool disagree = mine != nullptr && other != nullptr &&
                          mahalanobis_squared(*mine, *other, options_.association) > split_bound;
    // Only links that disagree now have a count (most agree: no entry to look up or make).
    if (!disagree) {
      if (!pair.disagreement.empty()) pair.disagreement.erase(it->first);
      linked.push_back({mine, other});
      ++it;
      continue;
    }
    int& count = pair.disagreement[it->first];
    if (++count >= options_.split_after) {
      pair.disagreement.erase(it->first);
      it = pair.accepted.erase(it);
      ++counters_.links_split;
      changed = true;
    } else {
      linked.push_back({mine, other});
      ++it;
    }
  }
  // 2. New correspondences, confirmed over consecutive descriptions: under the maps' relative
  //    pose fitted to the accepted ones where there are enough (in_frame_fit; then 3.), else under
  //    a search's transform (in_frame_search) or as the maps stand in the common frame.
  std::optional<RigidAlignment> relative = relative_pose(linked);
  if (!relative && options_.in_frame_fit && options_.in_frame_search) {
    //    Too few to fit: the first ones from a consistent set (in_frame_search). Without one, as
    //    the maps stand only while no map has been moved into the frame (known starts): a move
    //    gives a map an error that all its objects share, which the marginals cannot tell from a
    //    neighbour's place.
    ++counters_.in_frame_searches;
    const PairAlignment found = align_in_frame(
        own_prepared(), PreparedMap(theirs, options_.association), options_.association);
    if (found.status == AlignmentStatus::kAligned) {
      ++counters_.in_frame_aligned;
      // As relative_pose's: the fit's own uncertainty, not the n-fold one that moves a state
      // (align_maps fits its final transform to all its matches).
      relative = RigidAlignment{};
      relative->T_target_source = found.T_a_b;
      relative->covariance = found.covariance / static_cast<double>(found.matches.size());
    } else if (found.status == AlignmentStatus::kAmbiguous ||
               found.status == AlignmentStatus::kTilted || component_of(own.frame).size() > 1) {
      pair.candidate_streak.clear();
      return changed;
    }
  }
  std::vector<Match> matches =
      relative ? match_with_transform(own, theirs, relative->T_target_source, Covariances::kLocal,
                                      options_.association, &relative->covariance)
               : match_with_transform(own, theirs, Eigen::Isometry3d::Identity(),
                                      Covariances::kMarginal, options_.association);
  if (relative && options_.in_frame_current_pass) {
    // 3. Objects in both joint states that the fit's pass left without a partner, under the maps'
    //    offset where the robots are, or as the maps stand on their marginals while too few
    //    links there measure it (NegotiationOptions::in_frame_current_pass).
    std::vector<LandmarkId> own_taken, their_taken;
    own_taken.reserve(matches.size() + pair.accepted.size());
    their_taken.reserve(matches.size() + pair.accepted.size());
    for (const Match& match : matches) {
      own_taken.push_back(match.id_a);
      their_taken.push_back(match.id_b);
    }
    for (const auto& [ids, d2] : pair.accepted) {
      own_taken.push_back(ids.first);
      their_taken.push_back(ids.second);
    }
    std::sort(own_taken.begin(), own_taken.end());
    std::sort(their_taken.begin(), their_taken.end());
    const auto current = [](const MapDescription& map, const std::vector<LandmarkId>& taken) {
      MapDescription left;
      left.robot = map.robot;
      left.frame = map.frame;
      for (const ObjectDescription& object : map.objects) {
        if (!object.archived && !std::binary_search(taken.begin(), taken.end(), object.id)) {
          left.objects.push_back(object);
        }
      }
      return left;
    };
    const std::optional<RigidAlignment> offset = current_offset(pair, linked, matches, theirs);
    const std::vector<Match> more =
        match_with_transform(current(own, own_taken), current(theirs, their_taken),
                             offset ? offset->T_target_source : Eigen::Isometry3d::Identity(),
                             offset ? Covariances::kLocal : Covariances::kMarginal,
                             options_.association, offset ? &offset->covariance : nullptr);
    if (!more.empty()) {
      matches.insert(matches.end(), more.begin(), more.end());
      std::sort(matches.begin(), matches.end(),
                [](const Match& x, const Match& y) { return x.id_a < y.id_a; });
    }
  }
  // The objects already linked on either side, ascending (`accepted` is ordered by own id).
  std::vector<LandmarkId> own_linked, their_linked;
  own_linked.reserve(pair.accepted.size());
  their_linked.reserve(pair.accepted.size());
  for (const auto& [ids, d2] : pair.accepted) {
    own_linked.push_back(ids.first);
    their_linked.push_back(ids.second);
  }
  std::sort(their_linked.begin(), their_linked.end());
  const auto holds = [](const std::vector<LandmarkId>& sorted, LandmarkId id) {
    return std::binary_search(sorted.begin(), sorted.end(), id);
  };
  const auto insert = [](std::vector<LandmarkId>& sorted, LandmarkId id) {
    sorted.insert(std::lower_bound(sorted.begin(), sorted.end(), id), id);
  };
  IdPairTable<int> streaks;
  streaks.reserve(matches.size());
  for (const Match& match : matches) {
    const std::pair<LandmarkId, LandmarkId> ids{match.id_a, match.id_b};
    if (pair.accepted.contains(ids)) continue;
    const auto previous = pair.candidate_streak.find(ids);
    const int streak = previous == pair.candidate_streak.end() ? 1 : previous->second + 1;
    if (streak < options_.confirmations) {
      streaks[ids] = streak;
      continue;
    }
    if (holds(own_linked, ids.first) || holds(their_linked, ids.second)) {
      ++counters_.link_conflicts;
      continue;
    }
    pair.accepted[ids] = match.mahalanobis_squared;
    insert(own_linked, ids.first);
    insert(their_linked, ids.second);
    ++counters_.links_accepted;
    changed = true;
  }
  pair.candidate_streak = std::move(streaks);
  return changed;
}

void Negotiator::rebuild_own_record() {
  // A new record (the old one may still be on its way in messages).
  auto made = std::make_shared<OwnerRecord>();
  OwnerRecord& record = *made;
  record.owner = robot_;
  record.version = records_.at(robot_)->version + 1;
  for (const auto& [neighbour, pair] : pairs_) {
    for (const auto& [ids, d2] : pair.accepted) {
      record.links.push_back(
          ObjectLink::make(object_key(robot_, ids.first), object_key(neighbour, ids.second), d2));
    }
  }
  // In key order: what every receiver's team-id index wants (it need not sort them again).
  std::sort(record.links.begin(), record.links.end(), [](const ObjectLink& x, const ObjectLink& y) {
    return x.a != y.a ? x.a < y.a : x.b < y.b;
  });
  record.frame_edges = own_frame_edges_;
  team_ids_.stage(robot_, record.links);
  records_[robot_] = std::move(made);
}

Negotiator::FrameTarget Negotiator::team_frame_of(int frame) const {
  // Every known edge, in a canonical order (round, owner, frames).
  std::vector<const FrameEdge*> edges;
  for (const auto& [owner, record] : records_) {
    for (const FrameEdge& edge : record->frame_edges) edges.push_back(&edge);
  }
  std::sort(edges.begin(), edges.end(), [](const FrameEdge* x, const FrameEdge* y) {
    if (x->round != y->round) return x->round < y->round;
    if (x->owner != y->owner) return x->owner < y->owner;
    if (x->frame_a != y->frame_a) return x->frame_a < y->frame_a;
    return x->frame_b < y->frame_b;
  });
  FrameTarget target;
  target.frame = *component_of(frame).begin();
  if (target.frame == frame) return target;
  // Breadth-first from the team frame, neighbours in ascending frame id, the first edge between
  // two frames in the canonical order: T_target_x and its covariance for every reached frame.
  // Each edge's error holds both maps' drift (FrameEdge::full_covariance).
  struct Step {
    const FrameEdge* edge = nullptr;
    bool forward = true;  ///< from frame_a to frame_b
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  };
  const auto step_covariance = [](const Step& step, bool omit_far) {
    const lie::Matrix6d full =
        step.edge->full_covariance(!step.forward && omit_far, step.forward && omit_far);
    return step.forward ? full : inverse_covariance(step.edge->T_a_b, full);
  };
  struct Reached {
    Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
    lie::Matrix6d covariance = lie::Matrix6d::Zero();
    int from = kWorldFrame;
    Step step;
  };
  std::map<int, Reached> reached;
  reached[target.frame] = {};
  std::deque<int> queue{target.frame};
  while (!queue.empty() && !reached.contains(frame)) {
    const int current = queue.front();
    queue.pop_front();
    std::map<int, Step> next;  // neighbour -> the step current -> neighbour
    for (const FrameEdge* edge : edges) {
      int other;
      Step step;
      step.edge = edge;
      if (edge->frame_a == current) {
        other = edge->frame_b;
        step.T = edge->T_a_b;
      } else if (edge->frame_b == current) {
        other = edge->frame_a;
        step.forward = false;
        step.T = edge->T_a_b.inverse();
      } else {
        continue;
      }
      if (reached.contains(other) || next.contains(other)) continue;
      next[other] = step;
    }
    const Reached here = reached.at(current);
    for (const auto& [other, step] : next) {
      reached[other] = {here.T * step.T,
                        compose_covariance(here.T, here.covariance, step_covariance(step, false)),
                        current, step};
      queue.push_back(other);
    }
  }
  const Reached& end = reached.at(frame);
  target.T_target_frame = end.T;
  target.covariance = end.covariance;
  // The last edge's map on this frame's side was this robot's: its drift is this robot's pose
  // error then, which the state holds (Reanchoring::pose_frame).
  const FrameEdge& last = *end.step.edge;
  const int far_robot = end.step.forward ? last.robot_b : last.owner;
  const int far_pose = end.step.forward ? last.pose_frame_b : last.pose_frame_a;
  if (far_robot == robot_ && far_pose >= 0) {
    const Reached& before = reached.at(end.from);
    target.pose_frame = far_pose;
    target.independent =
        compose_covariance(before.T, before.covariance, step_covariance(end.step, true));
  }
  return target;
}

std::set<int> Negotiator::component_of(int frame, const FrameEdge* skip) const {
  std::set<int> component{frame};
  for (bool grown = true; grown;) {
    grown = false;
    for (const auto& [owner, record] : records_) {
      for (const FrameEdge& edge : record->frame_edges) {
        if (skip != nullptr && edge.owner == skip->owner && edge.round == skip->round &&
            edge.frame_a == skip->frame_a && edge.frame_b == skip->frame_b) {
          continue;
        }
        const bool has_a = component.contains(edge.frame_a);
        const bool has_b = component.contains(edge.frame_b);
        if (has_a != has_b) {
          component.insert(has_a ? edge.frame_b : edge.frame_a);
          grown = true;
        }
      }
    }
  }
  return component;
}

bool Negotiator::frames_connected(int a, int b) const {
  return a == b || component_of(a).contains(b);
}

namespace {
const std::vector<std::pair<LandmarkId, LandmarkId>> kNoPairs;
}  // namespace

const std::vector<std::pair<LandmarkId, LandmarkId>>& Negotiator::shared_objects(
    int neighbour) const {
  const auto it = shared_.find(neighbour);
  return it == shared_.end() ? kNoPairs : it->second;
}

const std::vector<std::pair<LandmarkId, LandmarkId>>& Negotiator::shared_view(int neighbour) const {
  const auto it = shared_views_.find(neighbour);
  return it == shared_views_.end() ? kNoPairs : it->second;
}

std::optional<int> Negotiator::frame_of(int neighbour) const {
  const auto it = neighbour_frames_.find(neighbour);
  if (it == neighbour_frames_.end()) return std::nullopt;
  return it->second;
}

}  // namespace concord::association

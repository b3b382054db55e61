#pragma once
/// \file
/// One robot's side of the negotiation with its neighbours: which of their objects are the same
/// (team ids) and how their frames relate. Pure and deterministic (no I/O, clocks or threads); the
/// replay runs one Negotiator per robot in synchronous rounds, and a daemon can run the same object
/// with its messages on the wire.
///
/// Per round (the order of team_replay.h):
///   1. On describing rounds (multiples of description_interval) the robot describes its map
///      (set_own_map, describe_map) in the frame its state is in.
///   2. It sends each neighbour of the round message_for(neighbour): its description on describing
///      rounds, the frame it is in, and the owner records the neighbour has not had yet (gossip).
///   3. It receive()s its neighbours' messages.
///   4. finish_round(): for each neighbour whose pair the robot owns (owns_pair) and whose
///      description arrived with its own:
///        - maps in different frames: align_maps; a transform found in `confirmations`
///          consecutive descriptions that agree (chi-square on the 6-D difference) is accepted:
///          a frame edge plus the correspondences found in both of the last two;
///        - maps in one frame: match_with_transform (identity); a correspondence found in
///          `confirmations` consecutive descriptions is accepted (unless one of its objects already
///          has a partner of that robot: a conflict, counted); an accepted one whose objects then
///          disagree beyond the split gate in `split_after` consecutive descriptions is undone
///          (a split, counted), and consensus keeps their marginals apart again.
///        - maps in one frame joined by the pair's own edge (on some of the descriptions that
///          follow its acceptance, NegotiationOptions::revisit_descriptions): align_maps again;
///          maps clearly misaligned in the common frame in revisit_confirmations agreeing
///          revisits correct the edge (a FrameCorrection in the owner's record).
///      Corrections of edges the robot's start frame lies behind move its state within its frame
///      (a Reanchoring from a frame to itself).
///      Then the team ids (a TeamIdIndex over every owner's links it knows, brought up to date
///      with the records that came in), and the frame: the smallest frame id connected to its
///      current frame by frame edges is the team frame (the start frame of the lowest robot of the
///      team, or the world); if that is not its current frame, the robot must move its state by
///      the returned Reanchoring (the composed transform and covariance along the edges).
///
/// Owners: one robot of a pair decides for it (owns_pair: the lower index when the two indices
/// add up to an even number, the higher one otherwise, so that every robot of a complete graph
/// owns as many pairs as the next, give or take one) and publishes its decisions (links and
/// frame edges) in its OwnerRecord, versioned; every robot keeps the newest record of every
/// owner it has heard of and relays records its neighbours have not had. Two robots that know the
/// same records compute the same team ids and team frames.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <boost/container/flat_map.hpp>
#include <boost/container/flat_set.hpp>
#include <cstddef>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "concord/association/alignment.h"
#include "concord/association/map_description.h"
#include "concord/association/options.h"
#include "concord/association/pairwise_association.h"
#include "concord/association/team_ids.h"
#include "concord/estimator/lie.h"

namespace concord::association {

/// A later correction of an accepted frame edge: its owner, revisiting the pair once both robots
/// were in one frame, found their maps still turned and shifted against each other there
/// (NegotiationOptions::revisit_descriptions). The robots whose start frames lie on the moving
/// side of the edge (the side away from the team frame) move by T within `frame`.
struct FrameCorrection {
  /// The team frame the correction is expressed in (robots in another frame ignore it: they go
  /// through the corrected edge when they join).
  int frame = kWorldFrame;
  /// Whether frame_b's side of the edge moves (else frame_a's).
  bool moves_b_side = true;
  /// p_corrected = T p, in `frame`.
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  /// Left perturbation in `frame`.
  lie::Matrix6d covariance = lie::Matrix6d::Identity();
  int round = 0;
};

/// The covariance of the error of a transform T_a_b fitted on two maps' local covariances: the
/// fit's own plus each map's drift (its robot's pose covariance, a left perturbation in its
/// frame): fit + drift_a + Ad(T_a_b) drift_b Ad(T_a_b)^T, a left perturbation in frame a.
lie::Matrix6d transform_error_covariance(const Eigen::Isometry3d& T_a_b, const lie::Matrix6d& fit,
                                         const lie::Matrix6d& drift_a,
                                         const lie::Matrix6d& drift_b);

/// A transform between two frames, accepted by the owner of the pair whose maps gave it.
struct FrameEdge {
  int frame_a = 0;
  int frame_b = 0;
  /// Maps frame_b coordinates into frame_a.
  Eigen::Isometry3d T_a_b = Eigen::Isometry3d::Identity();
  /// The fit's own covariance, a left perturbation in frame_a (alignment.h): what the two maps'
  /// local geometry knows of their relative pose.
  lie::Matrix6d covariance = lie::Matrix6d::Identity();
  int round = 0;
  int owner = 0;    ///< whose map was frame_a's side
  int robot_b = 0;  ///< whose map was frame_b's side
  /// The drift of each side's map when it was described (MapDescription::pose_covariance: the
  /// robot's pose covariance, a left perturbation in frame_a and frame_b) and that pose's frame
  /// index. The transform's error is -drift_a + Ad(T_a_b) drift_b + the fit's error
  /// (full_covariance()).
  lie::Matrix6d drift_a = lie::Matrix6d::Zero();
  lie::Matrix6d drift_b = lie::Matrix6d::Zero();
  int pose_frame_a = -1;
  int pose_frame_b = -1;
  /// Corrections since it was accepted, oldest first (T_a_b and covariance are the corrected ones:
  /// a robot that joins through the edge later needs none of them).
  std::vector<FrameCorrection> corrections;

  /// The covariance of T_a_b's error, a left perturbation in frame_a: the fit's and both maps'
  /// drift, leaving out side a's drift (omit_a) or side b's (omit_b).
  lie::Matrix6d full_covariance(bool omit_a = false, bool omit_b = false) const;
};

/// An owner's decisions: its current links and frame edges, versioned (newer replaces older).
struct OwnerRecord {
  int owner = 0;
  int version = 0;
  std::vector<ObjectLink> links;  ///< ascending by (a, b) as the owner makes them
  std::vector<FrameEdge> frame_edges;
  /// The owner's signature of the record, opaque here: a daemon with per-robot identities signs
  /// its own records and checks others' as they cross the wire (daemon/negotiation_wire.h);
  /// relayed unchanged. Empty in concord replay.
  std::string signature;

  /// Bytes in a fixed-width encoding: 12 bytes of header, 20 per link (two keys, a float), 324
  /// per frame edge (frames, round, owner, the other robot, two pose frames, 12 + 3 x 21 floats)
  /// and 144 per correction (frame, side, round, 12 + 21 floats), and the signature's.
  std::size_t wire_size() const;
};

/// What a robot sends one neighbour in a round.
struct NegotiationMessage {
  int sender = 0;
  /// The frame the sender's state is in.
  int frame = kWorldFrame;
  /// The sender's map, on its describing rounds (shared, not copied, between the messages of a
  /// round and their receivers: a description is never changed once made).
  std::shared_ptr<const MapDescription> map;
  /// Owner records the neighbour has not had from the sender (shared like the map: a record is
  /// never changed once made, a newer version is a new record).
  std::vector<std::shared_ptr<const OwnerRecord>> records;
  /// (owner, version) of every owner record the sender holds (its own included, the receiver's
  /// left out): the receiver sends it none of those again, nor an older one. On a graph with
  /// cycles most robots hear of a record from its owner and from their other neighbours; without
  /// this every robot would relay every record to every neighbour (NegotiationOptions::
  /// relay_delay).
  std::vector<std::pair<int, int>> held;

  /// 8 bytes of header, the description, the records and 8 bytes a held version.
  std::size_t wire_size() const;
};

/// A move of the robot's state into another frame: p_new = T_new_old p_old, with the covariance
/// of T_new_old as a left perturbation in the new frame.
struct Reanchoring {
  int from_frame = kWorldFrame;
  int to_frame = kWorldFrame;
  Eigen::Isometry3d T_new_old = Eigen::Isometry3d::Identity();
  /// The whole covariance of T_new_old's error.
  lie::Matrix6d covariance = lie::Matrix6d::Zero();
  /// When the transform came from this robot's own map (the last edge of its path has its map
  /// on the robot's side), its error holds the error of the robot's pose of that frame index:
  /// Estimator::reanchor(T_new_old, covariance, pose_frame, independent). -1: none.
  int pose_frame = -1;
  /// The error's part independent of the robot's state (pose_frame >= 0).
  lie::Matrix6d independent = lie::Matrix6d::Zero();
};

/// What a negotiator did, counted over its life.
struct NegotiationCounters {
  long long searches = 0;           ///< align_maps calls (maps in different frames)
  long long aligned = 0;            ///< of which found a transform
  long long ambiguous = 0;          ///< of which were ambiguous
  long long tilted = 0;             ///< of which tilted the start frames (start_up_axis)
  long long frame_edges = 0;        ///< transforms accepted (as owner)
  long long revisits = 0;           ///< align_maps calls on pairs already in one frame
  /// align_in_frame calls: pairs in one frame with too few accepted correspondences to fit
  /// (NegotiationOptions::in_frame_search).
  long long in_frame_searches = 0;
  long long in_frame_aligned = 0;  ///< of which found a transform
  /// Revisits beyond the gate left alone because the accepted alignment matched as many
  /// correspondences (NegotiationOptions::revisit_ambiguity_ratio).
  long long revisits_ambiguous = 0;
  /// Owner records received that were not newer than the one held (sent before the sender knew
  /// the receiver had it).
  long long records_redundant = 0;
  /// Owner records received whose owner is not a team member (set_members): dropped, neither
  /// held, relayed nor counted as held by their sender.
  long long records_refused = 0;
  /// Owner records received from a member that decide a pair their owner does not own (a link
  /// or frame edge with another robot for which owns_pair is false, or with a robot outside the
  /// members): dropped whole, neither held, relayed nor used. An honest owner never makes one; a
  /// member could otherwise overrule the owner of a pair it belongs to, or join another
  /// robot's objects into its teams against that robot's own decisions.
  long long records_not_owned = 0;
  long long frame_corrections = 0;  ///< accepted transforms corrected (as owner)
  long long reanchorings = 0;       ///< moves of its own state into another frame
  long long links_accepted = 0;     ///< correspondences accepted (as owner)
  long long links_split = 0;        ///< accepted correspondences undone (as owner)
  long long link_conflicts = 0;     ///< correspondences refused: an object already linked
  /// Links left out by the union-find (current), in the parts that hold the robot's objects.
  int team_id_conflicts = 0;
  long long messages = 0;           ///< messages produced
  long long bytes_sent = 0;         ///< their wire sizes
  long long description_bytes = 0;  ///< of which map descriptions
};

/// One search of a pair by its owner, for diagnostics (Negotiator::set_search_listener): what
/// the two descriptions were and what align_maps found. The pointers are valid during the call
/// only.
struct SearchTrace {
  int round = 0;
  int robot = 0;  ///< the pair's owner
  int neighbour = 0;
  /// A revisit of the pair's accepted frame edge (the maps in one frame), not a search across
  /// frames.
  bool revisit = false;
  const MapDescription* own = nullptr;
  const MapDescription* theirs = nullptr;
  const PairAlignment* found = nullptr;
  /// A revisit that found a transform, refitted on the marginal covariances: its squared
  /// distance from the identity (6 dof), its angle (degrees), and how many of the found
  /// transform's matches the maps match as they stand (counted only beyond the revisit gate).
  double revisit_distance = 0.0;
  double revisit_degrees = 0.0;
  std::size_t matched_as_they_stand = 0;
};

/// Whether `robot` decides for its pair with `other` (robot != other): the lower index when
/// robot + other is even, the higher one when it is odd. Exactly one of the two owns a pair, and on
/// the complete graph of n robots each owns (n - 1) / 2 pairs (n odd) or n / 2 - 1 or n / 2
/// (n even): the searches, which cost most of the negotiation, fall evenly on the team.
constexpr bool owns_pair(int robot, int other) {
  return ((robot + other) % 2 == 0) == (robot < other);
}

/// Whether every decision in `record` is one its owner makes: each link joins one of the owner's
/// objects with one of another robot's, each frame edge is the owner's with another robot, and
/// the owner owns each of those pairs (owns_pair). An honest owner's record always is.
bool decides_own_pairs_only(const OwnerRecord& record);

class Negotiator {
 public:
  /// A robot starting in frame start_frame (its own index for an unknown start, kWorldFrame for a
  /// known one). Throws std::invalid_argument if options.validate() reports a problem.
  Negotiator(int robot, int start_frame, NegotiationOptions options);

  int robot() const { return robot_; }
  /// The frame the robot's state is in.
  int frame() const { return frame_; }
  /// Whether the robot describes its map in this round.
  bool describes(int round) const { return round % options_.description_interval == 0; }

  /// The robot's description of this round (call on describing rounds, before message_for).
  void set_own_map(MapDescription map, int round);
  /// The message to a neighbour in this round (records it has not had are marked as sent).
  NegotiationMessage message_for(int neighbour, int round);
  /// A neighbour's message of this round. Owner records that decide pairs their owner does not
  /// own are dropped (decides_for_members; counters().records_not_owned).
  void receive(const NegotiationMessage& message, int round);
  /// The neighbour may not have had what was sent to it (it missed a round, or reconnected): every
  /// owner record goes to it again (receivers ignore versions they have).
  void forget_sent(int neighbour) { sent_versions_.erase(neighbour); }
  /// The team's membership list (the daemon's `members`): owner records of other owners are
  /// refused (counters().records_refused). A key holder could otherwise make every robot hold,
  /// and relay, a record for each of millions of made-up owners, each up to the wire limits'
  /// links. Empty (the default, `concord replay`): every owner is taken.
  void set_members(std::vector<int> members);
  /// Pairs, team ids and frame (see the file comment); the move to apply to the state, if any.
  std::optional<Reanchoring> finish_round(int round);

  /// Objects of this robot and of `neighbour` that share a team id: (own id, neighbour's id),
  /// sorted by own id (valid until the next finish_round).
  const std::vector<std::pair<LandmarkId, LandmarkId>>& shared_objects(int neighbour) const;
  /// receiver_view(shared_objects(neighbour)) (relabelling.h), kept with it: what this robot, as
  /// the receiver, agrees a neighbour's marginal against.
  const std::vector<std::pair<LandmarkId, LandmarkId>>& shared_view(int neighbour) const;
  /// Team id of one of the robot's objects, or -1 while unshared.
  ObjectKey team_id(LandmarkId own_id) const {
    return team_ids_.ids().team_id(object_key(robot_, own_id));
  }
  /// Team ids of the parts of the link graph that hold this robot's objects (others' objects
  /// linked only among themselves are absent).
  const TeamIds& team_ids() const { return team_ids_.ids(); }
  /// The frame a neighbour last said it is in (nullopt before its first message).
  std::optional<int> frame_of(int neighbour) const;
  /// Corrections of frame edges seen so far, whether or not they moved this robot: when it
  /// grows, some robots may have moved within the team frame (their claims about landmarks
  /// jump; see Estimator::forget_claims).
  std::size_t corrections_seen() const { return corrections_count_; }
  /// Corrections it remembers having seen: those of the frame edges in the records it holds.
  std::size_t corrections_held() const { return corrections_seen_.size(); }
  const NegotiationCounters& counters() const { return counters_; }
  const NegotiationOptions& options() const { return options_; }
  /// Called after every search and revisit this robot makes as a pair's owner (none by
  /// default): for tools that log or dump what the searches saw. It must not call back into the
  /// negotiator.
  void set_search_listener(std::function<void(const SearchTrace&)> listener) {
    search_listener_ = std::move(listener);
  }

  /// T_frame_start: maps the robot's start frame into its current frame, with its covariance
  /// (left perturbation in the current frame; zero while it has not moved).
  const Eigen::Isometry3d& T_frame_start() const { return T_frame_start_; }
  const lie::Matrix6d& covariance_frame_start() const { return covariance_frame_start_; }

 private:
  struct NeighbourMap {
    int round = -1;
    std::shared_ptr<const MapDescription> map;
  };
  /// Tables keyed by a correspondence (own id, their id), as sorted vectors: match_in_frame
  /// walks them several times a description.
  using IdPair = std::pair<LandmarkId, LandmarkId>;
  template <typename T>
  using IdPairTable = boost::container::flat_map<IdPair, T>;
  /// What the owner of a pair remembers between descriptions.
  struct PairState {
    int streak = 0;  ///< consecutive agreeing transforms across frames
    /// The correspondences of the streak's first transform (confirmation_new_matches).
    boost::container::flat_set<IdPair> streak_first_matches;
    std::optional<PairAlignment> last;
    int last_frame_a = kWorldFrame, last_frame_b = kWorldFrame;
    /// In one frame: consecutive sightings of each candidate correspondence (own id, their id).
    IdPairTable<int> candidate_streak;
    /// The frame edge this pair's owner accepted (index in own_frame_edges_), -1 before.
    int edge = -1;
    /// Descriptions of the pair since its edge was accepted or corrected (revisit_descriptions).
    int since_edge = 0;
    /// Consecutive revisits that found the maps misaligned, and the last of them.
    int revisit_streak = 0;
    std::optional<PairAlignment> revisit_last;
    /// Accepted correspondences with their squared Mahalanobis distance when accepted.
    IdPairTable<double> accepted;
    /// Consecutive disagreements of accepted correspondences (those that disagree now only).
    IdPairTable<int> disagreement;
  };

  /// Whether owner records of `owner` are taken (set_members).
  bool member(int owner) const;
  /// decides_own_pairs_only, and every other robot of its decisions a member.
  bool decides_for_members(const OwnerRecord& record) const;
  /// Owner work for one neighbour; true when the robot's record changed.
  bool process_pair(int neighbour, const MapDescription& theirs, int round);
  /// The own map of the round, prepared for align_maps once for all the pairs searched.
  const PreparedMap& own_prepared();
  bool accept_frames(PairState& pair, const MapDescription& theirs, const PairAlignment& found,
                     int round);
  bool match_in_frame(PairState& pair, const MapDescription& theirs);
  /// An accepted correspondence's two objects in this round's descriptions (nullptr: not
  /// described), looked up once a description for the steps of match_in_frame.
  struct LinkedObjects {
    const ObjectDescription* mine = nullptr;
    const ObjectDescription* other = nullptr;
  };
  /// The offset of the neighbour's map from this robot's where both robots are now: the mean
  /// difference of the positions of the objects both hold in their joint states among the
  /// pair's accepted correspondences (`linked`) and `matches`, with their spread as the
  /// translation's covariance; none with fewer than min_inliers such objects.
  std::optional<RigidAlignment> current_offset(const PairState& pair,
                                               const std::vector<LinkedObjects>& linked,
                                               const std::vector<Match>& matches,
                                               const MapDescription& theirs) const;
  /// The pose of the neighbour's map relative to this robot's in their common frame, fitted to
  /// the pair's accepted correspondences (`linked`) on the covariances relative to each robot
  /// (NegotiationOptions::in_frame_fit); nullopt when off, with fewer than min_inliers of them
  /// in both maps, or when their layout does not fix it.
  std::optional<RigidAlignment> relative_pose(const std::vector<LinkedObjects>& linked) const;
  /// Accepts the matches (only those also in pair.last when also_in_last) that conflict with no
  /// accepted correspondence.
  void adopt_matches(PairState& pair, const std::vector<Match>& matches, bool also_in_last);
  /// Maps in one frame joined by the pair's own edge: a search as across frames; a transform away
  /// from the identity in `confirmations` agreeing descriptions corrects the edge. True when it
  /// did.
  bool revisit_edge(PairState& pair, const MapDescription& theirs, int round);
  /// The frames connected to `frame` by the known edges, leaving out the edge `skip` if given.
  std::set<int> component_of(int frame, const FrameEdge* skip = nullptr) const;
  /// The move (within the robot's frame) of the corrections not yet seen, if any apply to it.
  std::optional<Reanchoring> take_corrections();
  void rebuild_own_record();
  /// Frames connected to `frame` by the known frame edges: the smallest and the transform from
  /// `frame` into it with its covariance.
  struct FrameTarget {
    int frame = kWorldFrame;
    Eigen::Isometry3d T_target_frame = Eigen::Isometry3d::Identity();
    lie::Matrix6d covariance = lie::Matrix6d::Zero();
    /// When the edge into `frame` had this robot's map on frame's side: the frame index of the
    /// robot's pose whose drift that map had, and the covariance without that drift
    /// (Reanchoring::pose_frame and independent).
    int pose_frame = -1;
    lie::Matrix6d independent = lie::Matrix6d::Zero();
  };
  FrameTarget team_frame_of(int frame) const;
  bool frames_connected(int a, int b) const;

  int robot_;
  int start_frame_;
  int frame_;
  NegotiationOptions options_;
  /// The split gate: the chi-square quantile of split_chi2_probability, 3 degrees of freedom.
  double split_bound_;
  /// The revisit's gate (revisit_chi2_probability, 6 dof) and the transform agreement bound.
  double revisit_bound_;
  double agreement_bound_;
  std::shared_ptr<const MapDescription> own_map_;
  int own_map_round_ = -1;
  /// own_map_ prepared for searches, made at the first search of it (own_prepared()).
  std::unique_ptr<PreparedMap> own_prepared_;
  std::map<int, NeighbourMap> neighbour_maps_;
  std::map<int, int> neighbour_frames_;
  std::map<int, PairState> pairs_;
  // The tables every message walks are sorted vectors (a team's worth of owners): a tree's
  // nodes, scattered over the heap, cost a cache miss a step.
  /// Newest record of every owner heard of (including its own).
  boost::container::flat_map<int, std::shared_ptr<const OwnerRecord>> records_;
  /// Per neighbour: version of each owner's record last sent to it, or that it said it holds.
  boost::container::flat_map<int, boost::container::flat_map<int, int>> sent_versions_;
  /// Round in which the record held of each other owner arrived (relay_delay).
  boost::container::flat_map<int, int> record_round_;
  std::vector<FrameEdge> own_frame_edges_;
  /// set_members, sorted and unique (empty: any owner).
  std::vector<int> members_;
  /// Corrections already seen: (owner, edge round, frame_a, frame_b, index), of the edges in
  /// records_ only. An honest owner never drops an edge from its record, so an edge no longer
  /// there is one a key holder made up, and forgetting it bounds the set by what records_ holds.
  std::set<std::tuple<int, int, int, int, std::size_t>> corrections_seen_;
  /// Corrections seen over the negotiator's life (corrections_seen()).
  std::size_t corrections_count_ = 0;
  /// Team ids over the links of every record in records_, of the parts of the link graph that
  /// hold this robot's objects (TeamIdIndex(robot)).
  TeamIdIndex team_ids_;
  /// shared_objects of every neighbour, rebuilt with the team ids, and their receiver views.
  std::map<int, std::vector<std::pair<LandmarkId, LandmarkId>>> shared_;
  std::map<int, std::vector<std::pair<LandmarkId, LandmarkId>>> shared_views_;
  NegotiationCounters counters_;
  std::function<void(const SearchTrace&)> search_listener_;
  Eigen::Isometry3d T_frame_start_ = Eigen::Isometry3d::Identity();
  lie::Matrix6d covariance_frame_start_ = lie::Matrix6d::Zero();
};

}  // namespace concord::association

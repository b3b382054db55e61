#pragma once
/// \file
/// The whole team in one process, frame by frame, in a fixed deterministic order (the paper's
/// experiments). Step k is a synchronous round that a network of daemons can reproduce exactly:
///   1. every robot processes its frame k (propagation from k-1, updates, initialization);
///   2. every robot's marginals of the objects it shares with each neighbour are taken;
///   3. every robot fuses its neighbours' marginals (Metropolis weights from this round's graph);
///   4. every robot records its estimate of frame k.
/// A robot whose frames are exhausted leaves the team (its last estimates stay its output).
///
/// Association. Given (the dataset's ids are global and its start poses known): robots share the
/// objects whose ids they both hold, as the paper does. Negotiated (otherwise): every robot runs an
/// association::Negotiator; in step 2 neighbours exchange its messages (map descriptions, owner
/// records), a robot whose team frame changed moves its state there (Estimator::reanchor), and
/// consensus runs between neighbours in one frame over the objects they share a team id for (the
/// sender's marginal relabelled with the receiver's ids). The negotiation never sees ground truth:
/// run_team gets dataset::TeamInputs.

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "concord/association/negotiation.h"
#include "concord/dataset/dataset.h"
#include "concord/dataset/radio.h"
#include "concord/estimator/options.h"
#include "concord/estimator/types.h"

namespace concord::replay {

enum class GraphKind { kComplete, kRing, kRandom };

/// Parses "complete", "ring" or "random"; throws std::invalid_argument naming the bad value.
GraphKind parse_graph_kind(const std::string& text);
std::string to_string(GraphKind kind);

/// Adjacency lists of an undirected communication graph over n robots. kRandom: a random
/// spanning tree (connected) plus every other edge with probability 0.3, from seed.
std::vector<std::vector<int>> make_graph(GraphKind kind, int robots, std::uint64_t seed);

/// The simulated radio (concord/dataset/radio.h), shared with the daemons' consensus.radio.
using dataset::limit_graph;
using dataset::RadioLimits;

enum class AssociationMode { kGiven, kNegotiated };

/// "given" / "negotiated"; parse throws std::invalid_argument naming the bad value.
AssociationMode parse_association_mode(const std::string& text);
std::string to_string(AssociationMode mode);

struct ReplayOptions {
  /// false: the paper's "Separate" rows (no consensus step).
  bool consensus = true;
  GraphKind graph = GraphKind::kComplete;
  /// Probability that an edge is dropped in a round, independently per edge and round (Fig. 4).
  double link_loss = 0.0;
  /// Radio limits on each round's graph (docs/results-graphs.md), from the robots' true positions at
  /// that frame (a simulation of who can hear whom; needs ground truth): an edge only while the
  /// two robots are within range_m (0: no limit); only to each robot's `nearest` closest robots
  /// (an edge when either is among the other's; 0: no limit); at most max_degree edges a robot,
  /// the shortest first (0: no limit).
  RadioLimits radio;
  std::uint64_t seed = 1;
  /// nullopt: given when the dataset's object ids are global and its start poses known,
  /// negotiated otherwise.
  std::optional<AssociationMode> association;
  /// Options of the negotiation (negotiated runs).
  association::NegotiationOptions negotiation;
  /// A diagnosis of what one anchor costs (docs/association.md, "The gap taken apart"): when
  /// set, every robot but robot 0 starts at its given start pose with this standard deviation
  /// ({metres, radians}: initial_position_sigma and initial_rotation_sigma for that robot only),
  /// so that robot 0's start is the team's only anchor, as in a negotiated team, while the
  /// others' starts are right and no association is needed. Both must be positive and finite
  /// (checked as every start sigma is: std::invalid_argument from the estimator).
  std::optional<std::pair<double, double>> unanchored_start_sigma;
  /// Given to every robot's negotiator (Negotiator::set_search_listener) when set: diagnostics of
  /// the searches; it changes nothing in the run.
  std::function<void(const association::SearchTrace&)> search_listener;
};

/// One robot's online output.
struct RobotOutput {
  /// Estimate of frame k right after step k, never revised later (one per frame).
  std::vector<Eigen::Isometry3d> trajectory;
  /// Covariance of the right perturbation of each trajectory pose, taken with it.
  std::vector<Eigen::Matrix<double, 6, 6>> pose_covariances;
  /// The frame each trajectory pose is in: association::kWorldFrame, or the index of the robot
  /// whose start frame (negotiated runs; a robot starts in its own, or in the world when its
  /// start pose is known).
  std::vector<int> trajectory_frames;
  std::vector<ObjectEstimate> objects;
  /// The estimated disparity offset and its standard deviation (image units) at the end, when
  /// the config makes it a state (disparity_offset_sigma > 0).
  std::optional<std::pair<double, double>> disparity_offset;
  /// Team id of each object (parallel to objects): -1 while unshared. Given runs: the object's
  /// global id.
  std::vector<LandmarkId> team_ids;
  /// T_frame_start: maps the robot's start frame into its final frame (the team frame), with
  /// its covariance (left perturbation in that frame), and the first frame from which its
  /// trajectory is in it.
  Eigen::Isometry3d T_team_own = Eigen::Isometry3d::Identity();
  Eigen::Matrix<double, 6, 6> alignment_covariance = Eigen::Matrix<double, 6, 6>::Zero();
  int aligned_at_frame = 0;
  /// Whether the robot moved into another robot's frame (alignment found).
  bool moved = false;
};

/// Counters and timings of a run (timings are wall-clock seconds, for reports only).
struct ReplayStatistics {
  int steps = 0;
  long long robot_steps = 0;            ///< (robot, frame) pairs processed
  long long consensus_robot_steps = 0;  ///< (robot, round) pairs that fused at least one marginal
  long long landmarks_fused = 0;
  long long landmarks_settled = 0;  ///< left out by consensus.fuse_kl_threshold
  long long neighbours_skipped = 0;
  long long landmarks_refused = 0;  ///< neighbours' landmarks refused by the chi-square test
  /// Of those, refused as inconsistent with the neighbour's earlier claims
  /// (consensus.claim_history_rounds).
  long long claims_refused = 0;
  long long object_initializations_gated = 0;
  long long object_rejoins_refused = 0;  ///< archived objects not fused back (chi-square)
  long long objects_reactivated = 0;
  long long update_failures = 0;  ///< Kalman updates refused (objects and point features)
  long long objects_initialized = 0;
  long long object_observations_rejected = 0;
  long long feature_tracks_used = 0;
  long long feature_tracks_rejected = 0;  ///< by the chi-square gate
  double update_seconds = 0.0;     ///< process() over all robots and frames
  double consensus_seconds = 0.0;  ///< marginals + fuse over all robots and rounds
  /// Negotiated runs: descriptions, messages, finish_round and re-anchoring, all robots.
  double negotiation_seconds = 0.0;
  double total_seconds = 0.0;
  /// Negotiated runs: rounds robots took part in, messages and their bytes (fixed-width encoding,
  /// association::NegotiationMessage::wire_size), of which map descriptions.
  long long negotiation_robot_rounds = 0;
  long long negotiation_messages = 0;
  long long negotiation_bytes = 0;
  long long description_bytes = 0;
  /// Bytes of the marginals sent (8 per id, 8 per number of the mean and of each block's upper
  /// triangle; with consensus.share_float32, 4 per number and a 24-byte origin), all runs.
  long long marginal_bytes = 0;
  /// Bytes of the marginals each robot sent in each round it took part in consensus (robot-major
  /// within a round), for the median and largest a robot sends a round.
  std::vector<long long> marginal_bytes_per_robot_round;
  /// Sum over rounds of the number of edges of that round's graph.
  long long edge_rounds = 0;
  /// Sums of the negotiators' counters (association::NegotiationCounters).
  long long searches = 0;
  long long in_frame_searches = 0;
  long long in_frame_aligned = 0;
  long long ambiguous = 0;
  long long tilted = 0;
  long long frame_edges = 0;
  long long revisits = 0;
  long long revisits_ambiguous = 0;
  /// Owner records received that the receiver already held (NegotiationCounters).
  long long records_redundant = 0;
  /// Owner records dropped for deciding pairs their owner does not own (NegotiationCounters): 0
  /// in a replay, whose robots are all honest.
  long long records_not_owned = 0;
  long long frame_corrections = 0;
  long long reanchorings = 0;
  long long links_accepted = 0;
  long long links_split = 0;
  long long link_conflicts = 0;
  long long team_id_conflicts = 0;
};

struct ReplayResult {
  std::vector<RobotOutput> robots;
  ReplayStatistics statistics;
  AssociationMode association = AssociationMode::kGiven;
};

/// Called after every step with (step, steps in total).
using ProgressCallback = std::function<void(int, int)>;

/// Runs the team on what its robots measure (never the ground truth: dataset::sensor_inputs).
/// A robot whose start pose is unknown starts at the identity of its own frame. Throws
/// std::invalid_argument on bad options.
ReplayResult run_team(const dataset::TeamInputs& team, const EstimatorOptions& estimator_options,
                      const ReplayOptions& options, const ProgressCallback& progress = {});

/// run_team on dataset::sensor_inputs(dataset).
ReplayResult run_team(const dataset::Dataset& dataset, const EstimatorOptions& estimator_options,
                      const ReplayOptions& options, const ProgressCallback& progress = {});
/// (With radio limits and no true positions given, this one fills them from the ground truth.)

}  // namespace concord::replay

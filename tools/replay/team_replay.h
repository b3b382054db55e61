#pragma once
/// \file
/// The whole team in one process, frame by frame, in a fixed deterministic order (the paper's
/// experiments). Step k is a synchronous round that a network of daemons can reproduce exactly:
///   1. every robot processes its frame k (propagation from k-1, updates, initialization);
///   2. every robot's marginals of the objects it shares with each neighbour are taken;
///   3. every robot fuses its neighbours' marginals (Metropolis weights from this round's graph);
///   4. every robot records its estimate of frame k.
/// A robot whose frames are exhausted leaves the team (its last estimates stay its output).

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "concord/dataset/dataset.h"
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

struct ReplayOptions {
  /// false: the paper's "Separate" rows (no consensus step).
  bool consensus = true;
  GraphKind graph = GraphKind::kComplete;
  /// Probability that an edge is dropped in a round, independently per edge and round (Fig. 4).
  double link_loss = 0.0;
  std::uint64_t seed = 1;
};

/// One robot's online output.
struct RobotOutput {
  /// Estimate of frame k right after step k, never revised later (one per frame).
  std::vector<Eigen::Isometry3d> trajectory;
  /// Covariance of the right perturbation of each trajectory pose, taken with it.
  std::vector<Eigen::Matrix<double, 6, 6>> pose_covariances;
  std::vector<ObjectEstimate> objects;
};

/// Counters and timings of a run (timings are wall-clock seconds, for reports only).
struct ReplayStatistics {
  int steps = 0;
  long long robot_steps = 0;            ///< (robot, frame) pairs processed
  long long consensus_robot_steps = 0;  ///< (robot, round) pairs that fused at least one marginal
  long long landmarks_fused = 0;
  long long neighbours_skipped = 0;
  long long landmarks_refused = 0;  ///< neighbours' landmarks refused by the chi-square test
  long long object_initializations_gated = 0;
  long long objects_reactivated = 0;
  long long update_failures = 0;  ///< Kalman updates refused (objects and point features)
  long long objects_initialized = 0;
  long long object_observations_rejected = 0;
  long long feature_tracks_used = 0;
  double update_seconds = 0.0;     ///< process() over all robots and frames
  double consensus_seconds = 0.0;  ///< marginals + fuse over all robots and rounds
  double total_seconds = 0.0;
};

struct ReplayResult {
  std::vector<RobotOutput> robots;
  ReplayStatistics statistics;
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

}  // namespace concord::replay

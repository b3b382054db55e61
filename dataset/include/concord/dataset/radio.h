#pragma once
/// \file
/// A simulated radio: who can hear whom in a round, from the robots' true positions (a dataset's
/// ground truth). `concord replay --range/--nearest/--max-degree` and the daemons'
/// consensus.radio use the same rule, so a team of daemons reproduces the replay. The robots'
/// filters never see these positions: they only decide which links are up.

#include <filesystem>
#include <vector>

#include <Eigen/Core>

namespace concord::dataset {

struct Dataset;

struct RadioLimits {
  /// A link only while the two robots are within range_m (0: no limit).
  double range_m = 0.0;
  /// Only to each robot's `nearest` closest robots: a link when either is among the other's
  /// (0: no limit).
  int nearest = 0;
  /// At most max_degree links a robot, the shortest first (0: no limit).
  int max_degree = 0;
  /// The robots' true positions, [robot][frame]. Required when any limit is set.
  std::vector<std::vector<Eigen::Vector3d>> true_positions;
  bool any() const { return range_m > 0.0 || nearest > 0 || max_degree > 0; }
  /// From a dataset's ground truth; std::invalid_argument if a robot lacks some of its frames.
  static std::vector<std::vector<Eigen::Vector3d>> positions_of(const Dataset& dataset);
};

/// The true positions of the given robots of a dataset folder (parallel to `robots`), from their
/// robot_NN/groundtruth.kitti only (a daemon's radio needs no other file of the other robots).
/// Throws DatasetError naming the file that is missing or malformed.
std::vector<std::vector<Eigen::Vector3d>> read_true_positions(const std::filesystem::path& dataset,
                                                              const std::vector<int>& robots);

/// This round's graph: the edges of `candidates` (adjacency lists, symmetric) that `limits`
/// keep, given the robots' positions. Symmetric, deterministic (ties broken by robot ids).
std::vector<std::vector<int>> limit_graph(const std::vector<std::vector<int>>& candidates,
                                          const std::vector<Eigen::Vector3d>& positions,
                                          const RadioLimits& limits);

}  // namespace concord::dataset

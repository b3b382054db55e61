#pragma once
/// \file
/// What a robot knows of part of its state relative to itself: covariances conditioned on the
/// newest pose, P_oo - P_op P_pp^-1 P_po, without the uncertainty of that pose in the robot's
/// frame (the drift its whole map shares). Used when an object is archived
/// (State::archived_local_covariance) and when a map is described to neighbours.

#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <optional>

#include "concord/estimator/state.h"

namespace concord {

class NewestPoseConditioning {
 public:
  /// Factors the newest pose's covariance block once for every later call.
  explicit NewestPoseConditioning(const State& state);

  /// The 3x3 block at covariance index `index` conditioned on the newest pose, given that
  /// block's marginal (symmetric); symmetrized. nullopt when the pose block or the result is not
  /// positive definite (round-off).
  std::optional<Eigen::Matrix3d> of(int index, const Eigen::Matrix3d& marginal) const;

 private:
  const State& state_;
  int pose_;
  Eigen::LLT<Eigen::Matrix<double, 6, 6>> pose_llt_;
};

}  // namespace concord

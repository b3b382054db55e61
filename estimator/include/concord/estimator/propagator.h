#pragma once
/// \file
/// State propagation from a relative-pose odometry measurement (§V-C, eq. 22-23).

#include <Eigen/Geometry>

#include "concord/estimator/options.h"
#include "concord/estimator/state.h"

namespace concord {

class Propagator {
 public:
  explicit Propagator(const EstimatorOptions& options);

  /// Appends the pose of `frame` = newest pose * T_previous_current, drops the oldest pose
  /// beyond the window, and propagates the covariance (eq. 23 in the state's left perturbation):
  ///   eps_new = eps_newest - Ad(T_new) w,  w ~ N(0, W) the right perturbation of the odometry.
  /// `noise`, when given, replaces W for this step.
  void propagate(State& state, const Eigen::Isometry3d& T_previous_current, int frame,
                 const Eigen::Matrix<double, 6, 6>* noise = nullptr) const;

  /// W, the per-frame odometry noise covariance on [rho; phi] (right perturbation of dT).
  const Eigen::Matrix<double, 6, 6>& odometry_noise() const { return odometry_noise_; }

 private:
  int window_size_;
  Eigen::Matrix<double, 6, 6> odometry_noise_;
};

}  // namespace concord

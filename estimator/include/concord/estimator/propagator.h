#pragma once
/// \file
/// State propagation from a relative-pose odometry measurement (§V-C, eq. 22-23).

#include <Eigen/Geometry>

#include "concord/estimator/options.h"
#include "concord/estimator/state.h"

namespace concord {

/// Odometry composed over several frames (a gap, skipped or rejected frames) with the covariance
/// of the composed motion's right perturbation: for M = S_1 ... S_n with S_j = S_j_hat exp(-w_j^),
/// M = M_hat exp(-w^) with w = sum_j Ad((S_j+1 ... S_n)^-1) w_j to first order.
struct ComposedMotion {
  Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
  int steps = 0;

  /// Appends one step with the covariance of its right perturbation.
  void then(const Eigen::Isometry3d& step, const Eigen::Matrix<double, 6, 6>& step_covariance);
};

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

#include "concord/estimator/estimator.h"

#include <Eigen/Cholesky>
#include <array>
#include <stdexcept>
#include <string>

#include "concord/estimator/lie.h"
#include "concord/estimator/state_helper.h"

namespace concord {

namespace {
const EstimatorOptions& validated(const EstimatorOptions& options) {
  const auto problems = options.validate();
  if (!problems.empty()) {
    std::string message = "invalid estimator options:";
    for (const auto& problem : problems) message += "\n  " + problem;
    throw std::invalid_argument(message);
  }
  return options;
}
}  // namespace

Eigen::Vector4d StereoCamera::normalize(const Eigen::Vector4d& uv) const {
  const double fx = K(0, 0), fy = K(1, 1), cx = K(0, 2), cy = K(1, 2), skew = K(0, 1);
  const double y_left = (uv(1) - cy) / fy;
  const double y_right = (uv(3) - cy) / fy;
  return {(uv(0) - cx - skew * y_left) / fx, y_left, (uv(2) - cx - skew * y_right) / fx, y_right};
}

Eigen::Vector4d StereoCamera::denormalize(const Eigen::Vector4d& xy) const {
  const Eigen::Vector3d left = K * Eigen::Vector3d(xy(0), xy(1), 1.0);
  const Eigen::Vector3d right = K * Eigen::Vector3d(xy(2), xy(3), 1.0);
  return {left.x(), left.y(), right.x(), right.y()};
}

Estimator::Estimator(const EstimatorOptions& options, const StereoCamera& camera,
                     const Eigen::Isometry3d& T_world_body_start, int first_frame)
    : options_(validated(options)),
      camera_(camera),
      propagator_(options_),
      object_updater_(options_, camera_),
      feature_updater_(options_, camera_) {
  state_.poses.push_back({first_frame, T_world_body_start});
  // The start pose's uncertainty is given in the body frame (right perturbation).
  lie::Matrix6d start = lie::Matrix6d::Zero();
  start.diagonal().head<3>().setConstant(options_.initial_position_sigma *
                                         options_.initial_position_sigma);
  start.diagonal().tail<3>().setConstant(options_.initial_rotation_sigma *
                                         options_.initial_rotation_sigma);
  state_.covariance = lie::left_from_right_covariance(T_world_body_start, start);
  if (options_.disparity_offset_sigma > 0.0) {
    // The calibration state sits after the poses: [eps_start, d].
    state_.calibration_dim = 1;
    state_.disparity_offset = 0.0;
    state_.covariance.conservativeResize(7, 7);
    state_.covariance.row(6).setZero();
    state_.covariance.col(6).setZero();
    state_.covariance(6, 6) = options_.disparity_offset_sigma * options_.disparity_offset_sigma;
  }
}

Estimator::Estimator(const EstimatorOptions& options, const StereoCamera& camera, State state,
                     PendingObjects pending)
    : options_(validated(options)),
      camera_(camera),
      state_(std::move(state)),
      propagator_(options_),
      object_updater_(options_, camera_, std::move(pending)),
      feature_updater_(options_, camera_),
      started_(true) {
  // A state from outside (a checkpoint): its shapes must agree before anything reads it.
  const auto n = static_cast<Eigen::Index>(state_.dimension());
  bool consecutive = !state_.poses.empty();
  for (std::size_t k = 1; consecutive && k < state_.poses.size(); ++k) {
    consecutive = state_.poses[k].frame == state_.poses[k - 1].frame + 1;
  }
  if (state_.calibration_dim != (options_.disparity_offset_sigma > 0.0 ? 1 : 0)) {
    throw std::invalid_argument(
        "Estimator: the state was made with a different disparity_offset_sigma (a disparity "
        "offset state is there in one and not in the other)");
  }
  if (!consecutive || state_.num_poses() > options_.window_size || state_.covariance.rows() != n ||
      state_.covariance.cols() != n || !state_.covariance.allFinite()) {
    throw std::invalid_argument(
        "Estimator: the state's poses, landmarks and covariance do not agree");
  }
  for (const auto& [id, object] : state_.archived) {
    if (!object.p_world.allFinite() || !object.covariance.allFinite()) {
      throw std::invalid_argument("Estimator: archived object " + std::to_string(id) +
                                  " is not finite");
    }
  }
  state_.rebuild_landmark_index();
}

FrameReport Estimator::process(const FrameInput& input) {
  FrameReport report;
  report.frame = input.frame;
  if (!started_ && input.frame == frame()) {
    // The start frame: nothing to propagate.
  } else {
    if (input.frame != frame() + 1 || !input.T_previous_current) {
      throw std::invalid_argument("Estimator::process: expected frame " +
                                  std::to_string(frame() + 1) + " with odometry, got frame " +
                                  std::to_string(input.frame));
    }
    Eigen::Isometry3d motion = *input.T_previous_current;
    motion.translation() *= options_.odometry_translation_scale;
    const Eigen::Matrix<double, 6, 6>* noise =
        input.odometry_covariance ? &*input.odometry_covariance : nullptr;
    if (noise != nullptr) {
      const Eigen::LLT<Eigen::Matrix<double, 6, 6>> llt(*noise);
      if (!noise->allFinite() || llt.info() != Eigen::Success) {
        throw std::invalid_argument("Estimator::process: frame " + std::to_string(input.frame) +
                                    ": odometry covariance is not finite and positive definite");
      }
    }
    propagator_.propagate(state_, motion, input.frame, noise);
    if (options_.level_sigma > 0.0 && input.frame % options_.level_every_frames == 0) {
      report.level_applied = true;
      report.level_failed = !level_update();
    }
  }
  started_ = true;
  if (options_.use_point_features) {
    report.features = feature_updater_.process(state_, input.features);
  }
  if (options_.use_objects) report.objects = object_updater_.process(state_, input.objects);
  return report;
}

bool Estimator::level_update() {
  // The body's up axis u, seen in the world as g = R u, measures the world's up axis (the same
  // axis u of the level world frame) with noise level_sigma on its two horizontal components.
  // With the left perturbation R = exp(phi^) R_hat, g = g_hat + phi x g_hat, so the rows of the
  // measurement along two unit vectors a, b perpendicular to u are -[a b]^T g_hat^ on phi.
  const std::array<double, 3> axis = body_axis_vector(options_.level_up_axis);
  const Eigen::Vector3d up(axis[0], axis[1], axis[2]);
  const Eigen::Vector3d a = up.unitOrthogonal();
  const Eigen::Vector3d b = up.cross(a);
  Eigen::Matrix<double, 2, 3> horizontal;
  horizontal.row(0) = a.transpose();
  horizontal.row(1) = b.transpose();
  const int slot = state_.num_poses() - 1;
  const Eigen::Vector3d g = state_.poses[static_cast<std::size_t>(slot)].T_world_body.linear() * up;
  Eigen::MatrixXd H = Eigen::MatrixXd::Zero(2, state_.dimension());
  H.block<2, 3>(0, state_.pose_index(slot) + 3) = -horizontal * lie::skew(g);
  const Eigen::VectorXd residual = -horizontal * g;  // the measurement, 0, minus the prediction
  const Eigen::MatrixXd noise =
      Eigen::Matrix2d::Identity() * (options_.level_sigma * options_.level_sigma);
  return StateHelper::update(state_, H, residual, noise);
}

Marginal Estimator::marginal(const std::vector<LandmarkId>& ids) const {
  return Consensus::marginal(state_, ids);
}

void Estimator::marginal(const std::vector<LandmarkId>& ids, Marginal& out) const {
  Consensus::marginal(state_, ids, out);
}

const ConsensusReport& Estimator::fuse(const std::vector<WeightedMarginal>& neighbours) {
  return Consensus::fuse(state_, neighbours, options_.consensus, consensus_workspace_);
}

void Estimator::reanchor(const Eigen::Isometry3d& T_new_old,
                         const Eigen::Matrix<double, 6, 6>& covariance) {
  StateHelper::reanchor(state_, T_new_old, covariance);
}

Eigen::Matrix<double, 6, 6> Estimator::current_pose_covariance() const {
  const int index = state_.pose_index(state_.num_poses() - 1);
  return lie::right_from_left_covariance(current_pose(),
                                         state_.covariance.block<6, 6>(index, index));
}

}  // namespace concord

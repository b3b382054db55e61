#include "concord/estimator/estimator.h"

#include <Eigen/Cholesky>
#include <array>
#include <stdexcept>
#include <string>

#include "concord/estimator/lie.h"
#include "concord/estimator/state_helper.h"
#include "concord/estimator/updater_helper.h"

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
  // The calibration entries sit after the poses, uncorrelated with the start: [eps_start, d, t].
  state_.has_disparity_offset = options_.disparity_offset_sigma > 0.0;
  state_.has_world_up = options_.level_sigma > 0.0;
  const int dimension = state_.dimension();
  state_.covariance.conservativeResize(dimension, dimension);
  state_.covariance.rightCols(dimension - 6).setZero();
  state_.covariance.bottomRows(dimension - 6).setZero();
  if (state_.has_disparity_offset) {
    const int index = state_.disparity_offset_index();
    state_.covariance(index, index) =
        options_.disparity_offset_sigma * options_.disparity_offset_sigma;
  }
  if (state_.has_world_up) {
    // The start's level axis is the world's up axis, up to the start's own tilt.
    state_.world_up = WorldUp::around(T_world_body_start.linear() * level_axis());
    state_.covariance.block<2, 2>(state_.world_up_index(), state_.world_up_index()) =
        Eigen::Matrix2d::Identity() * (options_.level_sigma * options_.level_sigma);
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
  if (state_.has_disparity_offset != (options_.disparity_offset_sigma > 0.0)) {
    throw std::invalid_argument(
        "Estimator: the state was made with a different disparity_offset_sigma (a disparity "
        "offset state is there in one and not in the other)");
  }
  if (state_.has_world_up != (options_.level_sigma > 0.0)) {
    throw std::invalid_argument(
        "Estimator: the state was made with a different level_sigma (a world up axis state is "
        "there in one and not in the other)");
  }
  for (const ObjectLandmark& landmark : state_.landmarks) {
    if (!landmark.detection_offset) continue;
    using Kind = EstimatorOptions::DetectionErrorState;
    if (options_.detection_error_state() !=
        (landmark.displacement ? Kind::kDisplacement : Kind::kImageOffset)) {
      throw std::invalid_argument(
          std::string("Estimator: the state holds a detection ") +
          (landmark.displacement ? "displacement (object_displacement_sigma)"
                                 : "offset in the image (object_offset_sigma)") +
          " for object " + std::to_string(landmark.id) +
          " and the options do not make one: the state was made with another detector model");
    }
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

Eigen::Vector3d Estimator::level_axis() const {
  const std::array<double, 3>& axis = options_.level_up_axis;
  return Eigen::Vector3d(axis[0], axis[1], axis[2]).normalized();
}

bool Estimator::level_update() {
  Eigen::MatrixXd H;
  Eigen::VectorXd residual;
  UpdaterHelper::linearize_level(state_, level_axis(), H, residual);
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

const ConsensusReport& Estimator::fuse(std::span<const WeightedShare> neighbours) {
  return Consensus::fuse(state_, neighbours, options_.consensus, consensus_workspace_);
}

int Estimator::witness(const std::vector<WeightedMarginal>& neighbours) {
  return Consensus::witness(state_, neighbours, options_.consensus, consensus_workspace_);
}

void Estimator::reanchor(const Eigen::Isometry3d& T_new_old,
                         const Eigen::Matrix<double, 6, 6>& covariance) {
  reanchor(T_new_old, covariance, -1, covariance);
}

bool Estimator::reanchor(const Eigen::Isometry3d& T_new_old,
                         const Eigen::Matrix<double, 6, 6>& covariance, int pose_frame,
                         const Eigen::Matrix<double, 6, 6>& independent) {
  const int slot = state_.pose_slot(pose_frame);
  StateHelper::reanchor(state_, T_new_old, covariance, slot, independent);
  // The neighbours' earlier claims were in the old frame.
  forget_claims();
  return slot >= 0;
}

void Estimator::forget_claims() { consensus_workspace_ = ConsensusWorkspace(); }

Eigen::Matrix<double, 6, 6> Estimator::current_pose_covariance() const {
  const int index = state_.pose_index(state_.num_poses() - 1);
  return lie::right_from_left_covariance(current_pose(),
                                         state_.covariance.block<6, 6>(index, index));
}

}  // namespace concord

#pragma once
/// \file
/// Value types at the estimator's edges: what goes in (odometry, stereo observations, the camera)
/// and what comes out (object estimates, marginals for consensus). Frames are in the names:
/// T_a_b maps coordinates in frame b into frame a; p_a is a point in frame a.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstdint>
#include <optional>
#include <utility>
#include <vector>

namespace concord {

/// A stereo observation at one frame in normalized image coordinates (x_l, y_l, x_r, y_r).
struct TrackObservation {
  int frame = 0;
  Eigen::Vector4d xy = Eigen::Vector4d::Zero();
  /// The observation's own noise, image units (StereoObservation::sigma); zero: the configured.
  Eigen::Vector2d sigma = Eigen::Vector2d::Zero();
};


/// Global object id (data association is given; the same id is the same object for every robot)
/// or a robot-private point-feature track id.
using LandmarkId = std::int64_t;

/// A calibrated stereo pair, rectified or not.
struct StereoCamera {
  /// Intrinsics shared by both cameras; observations are in the image units K maps to
  /// (pixels, or normalized coordinates when K is the identity).
  Eigen::Matrix3d K = Eigen::Matrix3d::Identity();
  /// Maps body coordinates into the left optical frame: p_cam0 = T_cam0_body * p_body.
  Eigen::Isometry3d T_cam0_body = Eigen::Isometry3d::Identity();
  /// Pose of the right camera in the left camera frame.
  Eigen::Isometry3d T_cam0_cam1 = Eigen::Isometry3d::Identity();

  /// Maps body coordinates into the right optical frame.
  Eigen::Isometry3d T_cam1_body() const { return T_cam0_cam1.inverse() * T_cam0_body; }
  /// Image units per normalized unit (mean focal length), to convert noise and thresholds.
  double focal_length() const { return 0.5 * (K(0, 0) + K(1, 1)); }
  /// Stereo baseline in metres.
  double baseline() const { return T_cam0_cam1.translation().norm(); }
  /// Image coordinates (u_left, v_left, u_right, v_right) to normalized coordinates.
  Eigen::Vector4d normalize(const Eigen::Vector4d& uv) const;
  /// Normalized coordinates back to image coordinates.
  Eigen::Vector4d denormalize(const Eigen::Vector4d& xy) const;
};

/// One stereo observation of a landmark, in image units: (u_left, v_left, u_right, v_right).
struct StereoObservation {
  LandmarkId id = 0;
  Eigen::Vector4d uv = Eigen::Vector4d::Zero();
  /// This observation's own noise when its tracker measured it: the standard deviation of each
  /// coordinate of the left image's position and of the right image's, independent, in image
  /// units. Zero (the default): the configured noise (feature_noise). Point features only; an
  /// object observation's noise is its model's (object_noise and the rest).
  Eigen::Vector2d sigma = Eigen::Vector2d::Zero();
};

/// The range of an observation's own noise (image units): a sigma far below it would make the
/// observation's whitened rows overflow (one bad input poisoning the filter).
inline constexpr double kMinObservationSigma = 1e-6;
inline constexpr double kMaxObservationSigma = 1e6;

/// Whether `sigma` may be a StereoObservation::sigma: both 0 (the configured noise), or both
/// within [kMinObservationSigma, kMaxObservationSigma] (NaN is neither).
inline bool valid_observation_sigma(const Eigen::Vector2d& sigma) {
  const auto within = [](double s) { return s >= kMinObservationSigma && s <= kMaxObservationSigma; };
  return sigma.isZero(0.0) || (within(sigma(0)) && within(sigma(1)));
}

/// Everything a robot measures at one frame.
struct FrameInput {
  int frame = 0;
  /// Measured motion from the previous frame to this one, T_body(k-1)_body(k). Absent at the
  /// first frame (the known start).
  std::optional<Eigen::Isometry3d> T_previous_current;
  /// Covariance of that motion's right perturbation [rho; phi] (T_true = T_measured exp(-w^)),
  /// when the odometry reports one; it replaces the configured W for this frame.
  std::optional<Eigen::Matrix<double, 6, 6>> odometry_covariance;
  /// Object detections with global ids (persistent features, kept in the state).
  std::vector<StereoObservation> objects;
  /// Point-feature observations with robot-private track ids (opportunistic, MSCKF update).
  std::vector<StereoObservation> features;
};

/// An object landmark estimate: world position and its marginal covariance.
struct ObjectEstimate {
  LandmarkId id = 0;
  Eigen::Vector3d p_world = Eigen::Vector3d::Zero();
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
};

/// A Gaussian marginal over a set of object landmarks: what robots exchange (§V-B).
/// mean stacks the positions in the order of ids. The covariance is block diagonal: blocks[b] is
/// the joint covariance of the next blocks[b].rows() / 3 landmarks (in ids order); a marginal
/// makes no claim about the correlation of landmarks in different blocks (a receiver averages
/// them separately). A robot's in-state objects form one dense block and each archived object its
/// own 3x3 block, so a marginal costs O(in-state^2 + archived), not O(objects^2), to build, send
/// and fuse.

struct Marginal {
  std::vector<LandmarkId> ids;
  Eigen::VectorXd mean;
  std::vector<Eigen::MatrixXd> blocks;

  Marginal() = default;
  /// A marginal with one dense covariance block over all ids.
  Marginal(std::vector<LandmarkId> ids_, Eigen::VectorXd mean_, Eigen::MatrixXd covariance)
      : ids(std::move(ids_)), mean(std::move(mean_)) {
    blocks.push_back(std::move(covariance));
  }

  std::size_t size() const { return ids.size(); }
  /// Whether every entry is finite, in one vectorized sum: x * 0 is 0 for a finite x and NaN for
  /// an infinite or NaN one (Eigen's allFinite tests entry by entry, and a receiver checks every
  /// marginal of every round).
  template <typename Derived>
  static bool all_finite(const Eigen::DenseBase<Derived>& values) {
    return (values.derived().array() * 0.0).sum() == 0.0;
  }
  /// Whether the shapes agree: mean of 3k finite numbers, square finite blocks whose sizes are
  /// multiples of 3 and add up to 3k (k = number of ids).
  bool well_formed() const { return shapes_agree(ids, mean, blocks); }
  static bool shapes_agree(const std::vector<LandmarkId>& ids, const Eigen::VectorXd& mean,
                           const std::vector<Eigen::MatrixXd>& blocks) {
    const auto d = static_cast<Eigen::Index>(3 * ids.size());
    if (mean.size() != d || !all_finite(mean)) return false;
    Eigen::Index covered = 0;
    for (const Eigen::MatrixXd& block : blocks) {
      if (block.rows() != block.cols() || block.rows() == 0 || block.rows() % 3 != 0) return false;
      // Most blocks are one archived object's 3x3: summed with fixed-size code.
      const bool finite = block.rows() == 3
                              ? all_finite(Eigen::Map<const Eigen::Matrix3d>(block.data()))
                              : all_finite(block);
      if (!finite) return false;
      covered += block.rows();
    }
    return covered == d;
  }

  /// The full 3k x 3k covariance (zeros between blocks). For tests and small marginals.
  Eigen::MatrixXd dense_covariance() const {
    Eigen::MatrixXd dense = Eigen::MatrixXd::Zero(mean.size(), mean.size());
    Eigen::Index offset = 0;
    for (const Eigen::MatrixXd& block : blocks) {
      dense.block(offset, offset, block.rows(), block.cols()) = block;
      offset += block.rows();
    }
    return dense;
  }
};

/// A neighbour's marginal with its consensus weight A_ij (eq. 19).
struct WeightedMarginal {
  double weight = 0.0;
  Marginal marginal;
  /// The neighbour's robot id, under which its claims are remembered and tested against its
  /// earlier ones (ConsensusOptions::claim_history_rounds); -1: not tested.
  int sender = -1;
};

}  // namespace concord

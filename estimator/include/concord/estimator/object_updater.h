#pragma once
/// \file
/// Object landmarks (persistent features): the update of in-state objects from stereo
/// detections (§V-D) and the initialization of new ones (§V-E, eq. 29-30).

#include <map>
#include <vector>

#include "concord/estimator/options.h"
#include "concord/estimator/state.h"
#include "concord/estimator/updater_helper.h"

namespace concord {

/// What one frame's object processing did (counters for logs and metrics).
struct ObjectUpdateStats {
  int observations = 0;
  int updated = 0;          ///< observations used in the update
  int rejected = 0;         ///< observations rejected by the chi-square gate or not projectable
  int initialized = 0;      ///< new objects added to the state
  int init_failed = 0;      ///< initialization attempts rejected (triangulation, depth, error)
  int init_gated = 0;       ///< initializations rejected by the chi-square test of their other rows
  int reactivated = 0;      ///< archived objects seen again (consider: active again; marginal:
                            ///< rejoined the state, fused back by CI)
  /// archived objects whose old marginal disagreed with the fresh estimate beyond the object
  /// gate when they rejoined (marginal mode): the old marginal is dropped, not fused
  int rejoins_refused = 0;
  int archived = 0;         ///< objects archived this frame (object_archive_mode)
  int update_failures = 0;  ///< Kalman updates refused (innovation not positive definite)
  int offsets_added = 0;    ///< detection offsets added to the state (object_offset_sigma)
};

/// Observations of objects not yet in the state, by object id (normalized coordinates).
using PendingObjects = std::map<LandmarkId, std::vector<TrackObservation>>;

class ObjectUpdater {
 public:
  ObjectUpdater(const EstimatorOptions& options, const StereoCamera& camera,
                PendingObjects pending = {});

  /// Processes the objects observed at the state's newest frame: 1. update with observations
  /// of in-state objects (chi-square gated; an archived consider state among them is active
  /// again), 2. initialize objects with enough observations in the window (with
  /// object_archive_mode marginal, archived ones among them rejoin: initialized afresh, then
  /// their archived marginal fused in by covariance intersection), 3. archive objects not
  /// observed for object_archive_after_frames.
  ObjectUpdateStats process(State& state, const std::vector<StereoObservation>& objects);

  /// The observations waiting for an initialization (part of what a checkpoint must keep for
  /// the filter to continue exactly).
  const PendingObjects& pending() const { return pending_; }

 private:
  enum class InitResult { kInitialized, kFailed, kGated };
  InitResult try_initialize(State& state, LandmarkId id, const std::vector<TrackObservation>& track,
                            ObjectUpdateStats& stats);
  /// Chi-square quantile for `dof` (infinity when the gate is off).
  double gate(int dof) const;
  void archive_stale(State& state, int frame, ObjectUpdateStats& stats) const;
  /// Detection offsets (object_offset_sigma): whether they are states; each one's random walk
  /// over a frame; appending object `id`'s (zero, with its prior, uncorrelated); its Jacobian on
  /// a linearized track's rows (each 4-row block: +du on both x, +dv on both y, -dd on the right
  /// x) with its value taken out of the residuals.
  /// With object_displacement_sigma the offset is a displacement in the world frame instead:
  /// its prior and walk are turned from the newest camera's axes into the world's, and its
  /// Jacobian on a track's rows is the object's own (H_point), its value taken out of the
  /// residuals through it (first order: a displacement is small against the object's depth).
  bool has_offsets() const {
    return options_.detection_error_state() != EstimatorOptions::DetectionErrorState::kNone;
  }
  void walk_offsets(State& state) const;
  int add_offset(State& state, LandmarkId id, int frame, ObjectUpdateStats& stats) const;
  void apply_offset(const State& state, int offset_slot, LinearizedTrack& linearized) const;
  /// A camera-axes variance (diagonal) in the world frame at the newest pose.
  Eigen::Matrix3d newest_camera_to_world(const State& state, const Eigen::Vector3d& variances) const;
  /// The joint covariance (normalized units) of the errors of a track's observations: the
  /// independent part on the diagonal blocks, the constant part in every block, the persistent
  /// part correlated by object_noise_correlation^(frame difference).
  Eigen::MatrixXd track_noise(const std::vector<TrackObservation>& track) const;
  /// With a persistent error: replaces a linearized track (its earlier observations, then the
  /// newest) by the whitened conditional of its newest observation given the earlier ones (four
  /// rows of unit noise). False when their joint covariance is not positive definite.
  /// added_noise (normalized units, the newest observation's) is added to the conditional's
  /// covariance before whitening.
  bool condition_on_earlier(const std::vector<TrackObservation>& track, LinearizedTrack& linearized,
                            const Eigen::Matrix4d& added_noise) const;
  /// object_first_estimate_noise's term for an observation at the newest pose of the in-state
  /// object in `slot`, whose point Jacobian (normalized units) is jacobian_point:
  /// scale J [p_lin - p_hat]x P_phi [p_lin - p_hat]x^T J^T.
  Eigen::Matrix4d first_estimate_noise(const State& state, int slot,
                                       const Eigen::Matrix<double, 4, 3>& jacobian_point) const;

  EstimatorOptions options_;
  StereoCamera camera_;
  /// Whitens an observation's four rows (normalized units): its noise becomes the identity.
  Eigen::Matrix4d whitening_;
  /// Covariances of an observation's independent, constant and persistent errors (normalized
  /// units); persistent_ is false when the last two are zero (each observation is then
  /// independent).
  Eigen::Matrix4d independent_covariance_;
  Eigen::Matrix4d constant_covariance_;
  Eigen::Matrix4d persistent_covariance_;
  bool persistent_ = false;
  /// Detection offsets' prior and walk variances a frame (normalized units: du, dv, dd).
  Eigen::Vector3d offset_prior_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d offset_walk_ = Eigen::Vector3d::Zero();
  /// Detection displacements (object_displacement_sigma): prior and walk variances a frame,
  /// metres squared along the camera's x, y, z.
  bool displacement_ = false;
  Eigen::Vector3d displacement_prior_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d displacement_walk_ = Eigen::Vector3d::Zero();
  /// The conditional's gain and whitening for a pattern of frames (each earlier observation's
  /// frame relative to the newest): a continuous track repeats the same pattern frame after frame.
  struct Conditional {
    Eigen::MatrixXd gain;  ///< S_ne S_ee^-1, 4 x 4 (observations - 1)
    Eigen::Matrix4d covariance;  ///< S_nn - G S_en
    Eigen::Matrix4d whitening;
  };
  mutable std::map<std::vector<int>, Conditional> conditionals_;
  /// Observations of objects not yet in the state, within the window.
  PendingObjects pending_;
};

}  // namespace concord

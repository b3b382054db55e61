#pragma once
/// \file
/// One robot's distributed MSCKF (Algorithm 1): a thin orchestrator of the propagator, the
/// point-feature and object updaters and the consensus step. No I/O, no clocks, deterministic.
///
/// Per frame k a robot calls process(frame k) (propagation from k-1, feature and object updates,
/// object initialization), then exchanges marginals and calls fuse() (consensus round k). Doing
/// the consensus after the update of frame k is Algorithm 1's consensus-before-propagation of
/// frame k+1.

#include <memory>
#include <span>
#include <vector>

#include "concord/estimator/consensus.h"
#include "concord/estimator/feature_updater.h"
#include "concord/estimator/object_updater.h"
#include "concord/estimator/options.h"
#include "concord/estimator/propagator.h"
#include "concord/estimator/state.h"
#include "concord/estimator/types.h"

namespace concord {

/// What process() did for one frame.
struct FrameReport {
  int frame = 0;
  ObjectUpdateStats objects;
  FeatureUpdateStats features;
  /// The level prior (EstimatorOptions::level_sigma) was applied this frame / its update was
  /// refused (innovation covariance not positive definite).
  bool level_applied = false;
  bool level_failed = false;
};

class Estimator {
 public:
  /// Starts at the known pose T_world_body of first_frame (the paper's known start). Throws
  /// std::invalid_argument if options.validate() reports a problem.
  Estimator(const EstimatorOptions& options, const StereoCamera& camera,
            const Eigen::Isometry3d& T_world_body_start, int first_frame = 0);

  /// Resumes from a state taken earlier with state() (a checkpoint): the next process() must
  /// carry the frame after the state's newest pose, with odometry. Throws
  /// std::invalid_argument if the options are invalid or the state's shapes do not agree.
  /// `pending` are the object observations waiting for an initialization (pending_objects());
  /// with them the filter continues exactly as the one the state was taken from. (Point-feature
  /// tracks in progress are not kept: they start afresh.)
  Estimator(const EstimatorOptions& options, const StereoCamera& camera, State state,
            PendingObjects pending = {});

  /// Propagates to input.frame (which must be the next frame, with odometry) and updates.
  /// The first call may carry the start frame itself without odometry.
  FrameReport process(const FrameInput& input);

  /// Every object held (joint and archived), sorted by id: what a robot announces.
  std::vector<LandmarkId> object_ids() const { return state_.object_ids(); }
  /// Joint marginal of the given objects (unknown ids skipped): what a robot sends.
  Marginal marginal(const std::vector<LandmarkId>& ids) const;
  /// The same into `out`, reusing its storage (Consensus::marginal).
  void marginal(const std::vector<LandmarkId>& ids, Marginal& out) const;
  /// Consensus step with neighbours' marginals and weights A_ij (eq. 19-21). The report is
  /// valid until the next call (the buffers are kept from round to round).
  const ConsensusReport& fuse(const std::vector<WeightedMarginal>& neighbours);
  /// The same with shared marginals (Consensus::fuse on SharedMarginal).
  const ConsensusReport& fuse(std::span<const WeightedShare> neighbours);
  /// Tests neighbours' claims without fusing them (Consensus::witness); how many were refused.
  int witness(const std::vector<WeightedMarginal>& neighbours);
  /// Moves the state into another frame, p_new = T_new_old p_old, with the transform's covariance
  /// (left perturbation in the new frame) folded in (StateHelper::reanchor).
  void reanchor(const Eigen::Isometry3d& T_new_old, const Eigen::Matrix<double, 6, 6>& covariance);
  /// The same for a transform whose error holds the error of the state's pose of `pose_frame`
  /// besides an independent part of covariance `independent` (StateHelper::reanchor's
  /// correlated form); `covariance` is the error's whole covariance. When that pose has left
  /// the window the move takes `covariance` as independent of the state (counting that pose's
  /// error twice, on the safe side) and returns false, as it does for pose_frame -1.
  bool reanchor(const Eigen::Isometry3d& T_new_old, const Eigen::Matrix<double, 6, 6>& covariance,
                int pose_frame, const Eigen::Matrix<double, 6, 6>& independent);
  /// Forgets the neighbours' earlier claims (ConsensusOptions::claim_history_rounds), as
  /// reanchor does: for when neighbours moved into another frame, or within one.
  void forget_claims();

  const State& state() const { return state_; }
  const EstimatorOptions& options() const { return options_; }
  int frame() const { return state_.newest_pose().frame; }
  /// Latest pose estimate T_world_body and its 6x6 covariance on [rho; phi].
  Eigen::Isometry3d current_pose() const { return state_.newest_pose().T_world_body; }
  const StereoCamera& camera() const { return camera_; }
  Eigen::Matrix<double, 6, 6> current_pose_covariance() const;
  std::vector<ObjectEstimate> objects() const { return state_.objects(); }
  const PendingObjects& pending_objects() const { return object_updater_.pending(); }

 private:
  EstimatorOptions options_;
  StereoCamera camera_;
  State state_;
  Propagator propagator_;
  ObjectUpdater object_updater_;
  FeatureUpdater feature_updater_;
  ConsensusWorkspace consensus_workspace_;
  bool started_ = false;

  /// The level prior on the newest pose against the world's up axis (EstimatorOptions::
  /// level_sigma); false if the update was refused.
  bool level_update();
  /// The body's level axis (EstimatorOptions::level_up_axis), normalized.
  Eigen::Vector3d level_axis() const;
};

}  // namespace concord

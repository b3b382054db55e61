#pragma once
/// \file
/// Every tunable of the estimator in one place, with defaults in-class. Loaded from YAML by
/// config/ (keys are the field names), validated by validate(). Noise values and thresholds on
/// observations are in image units: the units of the observations (pixels for KITTI, normalized
/// coordinates where K is the identity).

#include <array>
#include <string>
#include <vector>

namespace concord {

/// Safeguards and parameters of the consensus step (§V-B, eq. 19-21).
struct ConsensusOptions {
  /// consensus.max_condition_number: a neighbour's marginal whose covariance is not positive
  /// definite or whose condition number exceeds this is skipped (its weight goes to the robot
  /// itself) and counted.
  double max_condition_number = 1e12;
  /// consensus.neighbour_chi2_probability: a neighbour's landmark whose mean disagrees with the
  /// robot's own beyond this chi-square quantile (3 degrees of freedom) of the Mahalanobis
  /// distance under the sum of both covariances is left out of that landmark's average (its
  /// weight goes to the robot) and counted per neighbour. Two consistent estimates of one object
  /// pass it with at least this probability (more when their errors are correlated, as
  /// neighbours' are after consensus). 0 disables the test.
  double neighbour_chi2_probability = 0.999;
  /// consensus.claim_history_rounds: a neighbour's claim about a landmark (its 3x3 marginal) is
  /// also tested against what the same neighbour claimed about it in the last this many rounds:
  /// two consistent estimates a and b of one static object, however correlated, differ by an
  /// error whose covariance is at most 2 (P_a + P_b), so a claim whose mean moved beyond the
  /// chi-square bound (neighbour_chi2_probability) of that is refused like a disagreement,
  /// and counted (ConsensusReport::claims_refused). It catches a neighbour that claims a
  /// certainty it does not have whose estimate moves (a filter grown overconfident, a
  /// covariance scaled down), which the test against the robot's own covariance cannot see
  /// where the robot's own is wide. The claims kept are a ladder, each at least twice as
  /// certain (trace) as the one before, up to 8 a landmark and neighbour. Needs the
  /// neighbours' robot ids (WeightedMarginal::sender); the history is forgotten when the robot
  /// moves its state into another frame (Estimator::reanchor). 0 disables the test.
  int claim_history_rounds = 200;
  /// consensus.fuse_kl_threshold: event-triggered fusion. A landmark whose consensus step would
  /// move it by at most this Kullback-Leibler divergence KL(average || own) (nats, from the 3x3
  /// marginals of the robot and the neighbours that hold it) is left out of the round: not
  /// averaged, not carried into the state by Proposition 2. It stays within that distance of
  /// its neighbours' average and is fused again when it drifts beyond it. Proposition 2 costs
  /// in proportion to the landmarks fused, so this cuts the consensus step's CPU where most
  /// landmarks have settled. 0 (the default) fuses every landmark every round.
  double fuse_kl_threshold = 0.0;
  /// consensus.share_kl_threshold: event-triggered sharing (marginal_sharing.h). A robot sends a
  /// neighbour only the landmarks whose marginal moved by more than this Kullback-Leibler
  /// divergence (nats) since it last sent them to it; the neighbour fuses the last one it got
  /// of the others. 0 (the default) sends every landmark every round.
  double share_kl_threshold = 0.0;
  /// consensus.share_max_landmarks: at most this many landmarks a robot sends in one round (0:
  /// no cap), split evenly over the neighbours it sends to (at least one each, see
  /// link_landmark_cap); on a link, those never sent first, then the ones that moved most (KL).
  /// The others wait for a later round (the neighbour fuses the last marginal it got of them).
  /// Bounds the largest rounds, e.g. the first messages to new neighbours, whose joint blocks
  /// grow with the square of their landmarks, like a radio's budget per round.
  int share_max_landmarks = 0;
  /// consensus.share_float32: marginals travel in float32 (means as offsets from an origin,
  /// covariances as Cholesky factors), half the bytes; the receiver fuses exactly what arrived.
  bool share_float32 = false;
  /// consensus.share_block_landmarks: a message's covariance blocks hold at most this many
  /// landmarks each (split_blocks in marginal_sharing.h: a joint block cut into consecutive
  /// runs, the correlations between runs left out); 1 sends every landmark as its own 3x3
  /// block, 0 (the default) the joint blocks whole. The bytes of a message then grow with its
  /// landmarks, not with their square (a joint block of k landmarks is 3k(3k+1)/2 numbers), and
  /// the receiver averages each block on its own, as it does archived objects: consistent,
  /// since a block structure claims nothing about correlations between blocks
  /// (Consensus::fuse), at the cost of what those correlations told it (measured in
  /// docs/results-sharing.md).
  int share_block_landmarks = 0;
};

/// Noise of a stereo observation (u_left, v_left, u_right, v_right), in image units, as four
/// independent components: the common-mode position of the pair (horizontal, vertical) and the
/// differences between the images (disparity u_left - u_right, and v_left - v_right, zero on
/// ideally rectified images). Bounding-box centres, for instance, are off by tens of pixels in the
/// same way in both images while their disparity is accurate to a pixel or two. Independent noise
/// of sigma per coordinate is horizontal = vertical = sigma / sqrt(2) and
/// disparity = vertical_disparity = sigma * sqrt(2) (StereoNoise::isotropic).
struct StereoNoise {
  double horizontal = 1.0;
  double vertical = 1.0;
  double disparity = 1.0;
  double vertical_disparity = 1.0;

  /// Independent noise of `sigma` on each of the four coordinates.
  static StereoNoise isotropic(double sigma);
};

struct EstimatorOptions {
  /// window_size: c, the number of body poses kept in the sliding window (eq. 18).
  int window_size = 20;

  /// initial_position_sigma / initial_rotation_sigma: standard deviation of the start pose the
  /// filter is given (metres, radians). The default (1e-6) takes it as exact: a robot's start
  /// pose defines its frame (its own start, or a known start in the team's world frame, as in
  /// every simulated, rendered and KITTI set). Set them to what a deployment knows of its start
  /// (a surveyed start line: centimetres) when the start is uncertain in the team's frame: the
  /// filter, and through the objects the consensus, may then move the robot's whole frame.
  /// A prior larger than the start's actual error is no harmless padding: consensus reads the
  /// objects' noise as evidence against it (docs/estimator.md, "The start pose").
  double initial_position_sigma = 1e-6;
  double initial_rotation_sigma = 1e-6;

  /// odometry_translation_sigma / odometry_rotation_sigma: per-frame standard deviation of the
  /// odometry right perturbation, W of eq. (23) (metres, radians), per axis.
  double odometry_translation_sigma = 0.1;
  double odometry_rotation_sigma = 0.1;
  /// odometry_translation_scale: factor applied to every measured translation (a calibration of
  /// the odometry's scale, e.g. stereo VO with a slightly wrong baseline; measured on a
  /// calibration segment by `concord calibrate`). 1 leaves the odometry as it is.
  double odometry_translation_scale = 1.0;
  /// disparity_offset_sigma: prior standard deviation (image units) of a constant offset of the
  /// right image's horizontal coordinate, the stereo calibration's error (rectification, a
  /// principal point or baseline slightly off). Positive: the offset is a state of the filter,
  /// starting at 0 with this uncertainty and estimated online from every stereo observation
  /// (as OpenVINS estimates its camera calibration); its uncertainty enters every update, so an
  /// error shared by all tracks of a frame is not averaged away as if it were independent
  /// noise. 0 (the default): the calibration is taken as exact.
  double disparity_offset_sigma = 0.0;
  /// level_sigma: a ground vehicle's level prior (radians; 0, the default, disables it). On every
  /// level_every_frames-th frame the newest pose's level axis (level_up_axis, in the body) is
  /// taken as a measurement of the world's up axis with this standard deviation on each of its
  /// two horizontal components. A car on roads tilts by the road's grade and its suspension: a
  /// few degrees, correlated over tens of frames. So the value is the tilt's spread and the
  /// spacing the lag at which its autocorrelation has died out, both measured on a calibration
  /// segment (docs/tuning.md): the measurements are then about independent, each as uncertain as
  /// the tilt really is. It bounds the pitch and roll that odometry alone lets drift, and with
  /// them the height. The world's up axis is a state of the filter (State::world_up): the start
  /// frame is level only up to the slope the robot started on, one draw of the same tilt, so it
  /// starts at the start pose's level axis with level_sigma on each tilt angle. Off for a robot
  /// that tilts freely (a drone, a hand-held rig).
  double level_sigma = 0.0;
  int level_every_frames = 1;
  /// level_up_axis: the body direction that points up when the robot travels on level ground;
  /// in a config a named axis ("+x", "-x", "+y", "-y", "+z", "-z") or a vector [x, y, z]
  /// (normalized when used). A camera mounted with a small pitch has a level axis a little off
  /// the body's nominal one; `concord calibrate` measures it on the calibration segment as the
  /// nominal axis made perpendicular to the direction of travel.
  std::array<double, 3> level_up_axis = {0.0, 0.0, 1.0};

  // --- Objects (persistent landmarks, §V-D and §V-E) ---
  /// use_objects: process object detections at all.
  bool use_objects = true;
  /// object_noise: noise of an object detection (image units), a StereoNoise; in a config either
  /// one number (independent noise of that sigma per coordinate) or a map with the keys
  /// horizontal, vertical, disparity, vertical_disparity.
  StereoNoise object_noise = StereoNoise::isotropic(5.0);
  /// object_noise_constant, object_noise_persistent, object_noise_correlation: parts of a
  /// detection's error that do not change independently from frame to frame, on top of
  /// object_noise's independent part (a detector's box is off the object's centre by about the
  /// same amount while the view changes little: the box is the silhouette's, partly occluded,
  /// ...). Standard deviations in image units (StereoNoise; zero, the default, leaves a part
  /// out): a part constant along an object's track, and a part whose correlation from one frame
  /// to the next is object_noise_correlation (rho^k after k frames). With either, each new
  /// observation of an in-state object is weighed by what it adds to the object's earlier
  /// observations still in the window (the conditional of the joint Gaussian of their errors),
  /// and a new object by the joint covariance of its observations, instead of as independent.
  /// Measure them on a calibration segment (docs/tuning.md); the window bounds what is
  /// conditioned on, so an error that persists longer than the window is counted once a window.
  StereoNoise object_noise_constant = StereoNoise::isotropic(0.0);
  StereoNoise object_noise_persistent = StereoNoise::isotropic(0.0);
  double object_noise_correlation = 0.9;
  /// object_offset_sigma, object_offset_walk: an offset of this robot's detections of each
  /// object, a state of the filter (ObjectLandmark::detection_offset): [du, dv, dd] added to the
  /// predicted box centre's left x and y and subtracted from its disparity, for as long as the
  /// object stays in the joint state. It starts at zero with standard deviations
  /// object_offset_sigma (image units; the horizontal, vertical and disparity components of a
  /// StereoNoise, vertical_disparity unused) and moves as a random walk of object_offset_walk a
  /// frame. It is the part of a detector's box error that follows the robot's view of the object
  /// (which side of it shows, how much of its top): an error of this robot's, not of the object,
  /// so the object's marginal that consensus averages leaves it out and a neighbour's better
  /// object does not drag the robot's poses to fit its own biased boxes. Zero (the default)
  /// leaves it out. Not with object_noise_constant or object_noise_persistent (two models of one
  /// error).
  StereoNoise object_offset_sigma = StereoNoise::isotropic(0.0);
  StereoNoise object_offset_walk = StereoNoise::isotropic(0.0);
  /// object_displacement_sigma, object_displacement_walk: the same offset as a displacement in
  /// space (metres): the point this robot's detections of an object are centred on is the
  /// object's centre plus a 3-vector d, a state of the filter in the world frame
  /// (ObjectLandmark::detection_offset), observed as pi(T, p + d). It starts at zero with
  /// standard deviations object_displacement_sigma along the x (right), y (down) and z (forward)
  /// axes of the camera that first sees it and walks by object_displacement_walk a frame along
  /// the axes of the newest camera. A box's centre, back-projected at the depth measured in it,
  /// is a point of the object's visible side: off its centre by a vector that depends on the
  /// view, and whose image offset grows as the robot nears the object, which an offset in the
  /// image (object_offset_sigma) takes for a walk. Zero (the default) leaves it out. Not with
  /// object_offset_sigma, object_noise_constant or object_noise_persistent.
  std::array<double, 3> object_displacement_sigma{};
  std::array<double, 3> object_displacement_walk{};
  /// object_min_observations: stereo observations in the window needed to initialize.
  int object_min_observations = 3;
  /// object_min_distance / object_max_distance: accepted depth of a new object (metres).
  double object_min_distance = 5.0;
  double object_max_distance = 30.0;
  /// object_max_relative_sigma: a new object whose position uncertainty (the largest standard
  /// deviation of its initial covariance, along the viewing ray for a stereo point) exceeds this
  /// fraction of its distance waits for better observations: beyond it a Gaussian in x, y, z is a
  /// poor model of a stereo point (depth error grows with the square of the depth) and the
  /// linearized filter becomes overconfident. 0 disables.
  double object_max_relative_sigma = 0.0;
  /// object_init_max_reprojection_error: largest RMS reprojection error of a refined new object
  /// (image units).
  double object_init_max_reprojection_error = 2.0;
  /// object_chi2_probability: chi-square gate on the Mahalanobis distance of each object
  /// observation under its full innovation covariance, and of the rows of a new object's
  /// initialization that do not involve the object (0 disables).
  double object_chi2_probability = 0.95;
  /// object_first_estimate_noise: an in-state object's pose Jacobians are taken at its first
  /// estimate (ObjectLandmark::p_linearization), which keeps the robot's frame unobservable, but
  /// they then differ from the Jacobians at the current estimate by J [p_lin - p_hat]x on the
  /// newest pose's rotation error. That difference, times the rotation's covariance, is what the
  /// first estimate leaves out of the prediction's uncertainty; each observation's noise gains
  /// this many times it (J [d]x P_phi [d]x^T J^T, d = p_lin - p_hat). 1 is the first-order size
  /// of the mismatch; 0 leaves it out (the filter before 2026-11-28). docs/estimator.md, "The
  /// first estimate's mismatch".
  double object_first_estimate_noise = 1.0;
  /// object_archive_after_frames: an object not observed for this many frames leaves the joint
  /// state and is kept as an independent marginal (exact marginalization). Seen again, it is
  /// initialized afresh from its new observations (with its true correlations to the poses) and
  /// its archived marginal is fused in by covariance intersection, which is consistent whatever
  /// the unknown correlation between the two. Bounds the state for a long-lived robot. 0 keeps
  /// every object forever.
  int object_archive_after_frames = 0;
  /// object_archive_mode: what archiving does with an object. "marginal" (the default) moves it
  /// out of the joint state as an independent marginal, fused back by covariance intersection
  /// when seen again; the rejoin carries that fusion to the poses as if the old marginal were
  /// independent of them given the object, which it is not, and pose NEES grows through a run.
  /// "consider" keeps it in the joint covariance as a Schmidt consider state
  /// (ObjectLandmark::archived): the robot's updates leave it as it is but keep its
  /// correlations, so it rejoins consistently. But every object stays in the covariance:
  /// updates cost O(active x all), a marginal carries every object in one joint block and a
  /// consensus step costs O(all^2) per fused object. For separate runs and small teams
  /// (docs/estimator.md, "Archiving").
  std::string object_archive_mode = "marginal";

  // --- Point features (opportunistic, MSCKF update, eq. 24-28) ---
  /// use_point_features: run the MSCKF update on point-feature tracks.
  bool use_point_features = true;
  /// feature_noise: noise of a point-feature observation (image units), a StereoNoise, in a
  /// config one number or a map as object_noise.
  StereoNoise feature_noise = StereoNoise::isotropic(1.0);
  /// feature_drift_sigma: image units a frame, 0 (the default) for none. A track's errors drift:
  /// each track gets a random slope (the same in both images, horizontal and vertical, standard
  /// deviation feature_drift_sigma), so its observation at frame k is off by s (k - k_mean)
  /// besides its white feature_noise. The track's rows are whitened with that covariance before
  /// the null-space projection. A white-noise model takes such a drift as information (in the
  /// columns the triangulated point takes it for parallax): docs/frontend.md, "Found by oracle".
  double feature_drift_sigma = 0.0;
  /// feature_min_observations: stereo observations of a track needed to use it.
  int feature_min_observations = 3;
  /// feature_max_observations: a track is used in an update once it has this many observations
  /// (or fills the window, whichever comes first), and its later observations start afresh; 0,
  /// the default, is the window size. The update takes a track's observation errors as
  /// independent; a frame-to-frame tracker's (KLT) errors are not: each frame's position
  /// inherits the previous one's error, so the error drifts along a track, and a long track then
  /// claims far more than it knows. An offset shared by a whole chunk is absorbed by the
  /// triangulated point; only the drift within a chunk misleads the update, so shorter chunks
  /// trade parallax for honesty (docs/frontend.md, "Track drift").
  int feature_max_observations = 0;
  /// feature_max_reprojection_error: largest RMS reprojection error of a triangulated track
  /// (image units); 0, the default, sets no bound. A fixed bound refuses good tracks when the
  /// window's poses drift (the reprojection error then grows with the pose uncertainty, not with
  /// the track's quality); the chi-square gate, which uses that uncertainty, decides instead.
  double feature_max_reprojection_error = 0.0;
  /// feature_min_distance / feature_max_distance: accepted depth of a triangulated track (m).
  double feature_min_distance = 0.5;
  double feature_max_distance = 60.0;
  /// feature_chi2_probability: chi-square gate on each projected track residual (95 %).
  double feature_chi2_probability = 0.95;
  /// feature_odometry_correlation: S of eq. (25), the 6x4 correlation (row-major) between the
  /// newest odometry noise and a point-feature observation noise at the newest frame, in
  /// (metres or radians) x image units. Zero by default, as the paper found best.
  std::array<double, 24> feature_odometry_correlation{};

  ConsensusOptions consensus;

  /// Every problem with the values, each naming the key and the bad value; empty when valid.
  std::vector<std::string> validate() const;

  /// Which state, if any, the options give each (robot, object) for the detector's error: an
  /// image offset (object_offset_sigma with a horizontal, vertical or disparity part), a
  /// displacement in space (object_displacement_sigma), or none. validate() refuses both.
  enum class DetectionErrorState { kNone, kImageOffset, kDisplacement };
  DetectionErrorState detection_error_state() const;
};

/// The unit vector of a body axis named "+x", "-x", "+y", "-y", "+z" or "-z"; zero for
/// anything else.
std::array<double, 3> body_axis_vector(const std::string& axis);

}  // namespace concord

#pragma once
/// \file
/// Sensor characterisation on a calibration segment: how far a robot's odometry and stereo
/// observations are from the truth over a stretch of frames where ground truth is available,
/// as the noise values of an estimator config (docs/tuning.md). The segment is the only place
/// ground truth is used for configuration; reported runs are never tuned against their own.

#include <string>

#include "concord/dataset/dataset.h"

namespace concord::calibration {

/// What to measure: robot `robot`'s frames [first_frame, first_frame + frames).
struct CalibrationOptions {
  int robot = 0;
  int first_frame = 0;
  int frames = 200;
  /// The body axis that points up when the robot stands level (level_up_axis), for the tilt.
  std::string up_axis = "+z";
  /// The detection-offset model (StereoErrorSpread::offset_sigma): a landmark unseen for more
  /// than track_gap frames starts a new track; the offset's walk is fitted over lags 1 to
  /// offset_max_lag frames, 0 (the default): to the span of the tracks, the median over the
  /// observations of the frames from their track's first observation to its last (at least 2).
  /// The filter holds what an object's whole track told it, so the walk must match the drift
  /// over a track's span: a detector error that drifts smoothly as the view turns (its mean
  /// square difference growing faster than the lag) fitted at shorter lags only gives a walk
  /// too small for the tracks' length.
  int track_gap = 5;
  int offset_max_lag = 0;
};

/// Robust spread of the four components of stereo observation errors (image units): the
/// common-mode position of the pair, horizontal and vertical, and the differences between the
/// two images (disparity u_left - u_right, and v_left - v_right). Robust sigma = 1.4826 x the
/// median absolute deviation; `outliers` is the fraction of observations beyond 3 robust sigmas
/// in any component.
struct StereoErrorSpread {
  int observations = 0;
  double horizontal = 0.0;
  double vertical = 0.0;
  double disparity = 0.0;
  double vertical_disparity = 0.0;
  double outliers = 0.0;
  /// Medians of the four components (a systematic offset, e.g. a disparity bias from a wrong
  /// baseline, shows here).
  Eigen::Vector4d median = Eigen::Vector4d::Zero();
  /// Time correlation within a landmark's track: sqrt(1 + 2 sum of the autocorrelations at lags
  /// 1 to 10 frames), at least 1, per component. The filter treats observations as independent;
  /// errors that persist from frame to frame (a box centre off the same way while the car is in
  /// view) carry less information than that, and a white noise of sigma times this factor is
  /// its equivalent over such a stretch (the effective sample size correction).
  Eigen::Vector4d correlation_inflation = Eigen::Vector4d::Ones();
  /// The same time correlation as a model (the estimator's object_noise_constant,
  /// object_noise_persistent, object_noise_correlation): the autocovariance of each component
  /// within tracks at lags 1 to 20 frames (clipped as above) fitted by least squares as
  /// constant^2 + persistent^2 correlation^lag, with one correlation for all four components
  /// (each component's fit weighed by its variance), and independent^2 = the variance at lag 0
  /// less both (at least 0). Standard deviations, image units; correlation 0 when no lag has
  /// enough pairs.
  Eigen::Vector4d independent = Eigen::Vector4d::Zero();
  Eigen::Vector4d constant = Eigen::Vector4d::Zero();
  Eigen::Vector4d persistent = Eigen::Vector4d::Zero();
  double persistent_correlation = 0.0;
  /// The same time correlation as the estimator's detection-offset model (object_noise,
  /// object_offset_sigma, object_offset_walk; docs/estimator.md, "Detection offsets"), in the
  /// offset's components: the left image's u, the vertical and the disparity. Along each
  /// landmark's track (a new one after a gap of more than CalibrationOptions::track_gap frames)
  /// the errors are an offset of standard deviation offset_sigma at the track's first
  /// observation that walks by offset_walk a frame, plus independent noise offset_independent:
  /// the mean squares of the differences within tracks at lags 1 to offset_lags (each lag's
  /// differences beyond 3 robust sigmas left out, at least 20 kept) fitted by least squares as
  /// 2 independent^2 + lag walk^2 (negative parts taken as 0), and offset_sigma^2 the mean
  /// square of the tracks' first errors (those beyond 3 robust sigmas left out) less
  /// independent^2: a detector's bias counts in the offset. The independent part has a floor of
  /// 10 % of the component's robust sigma (a fit to the lags says little about it); the vertical
  /// disparity is independent noise only, its robust sigma with a floor of 10 % of the vertical
  /// one. offset_tracks = 0 when some component had fewer than 2 lags to fit. offset_lags: the
  /// largest lag fitted (CalibrationOptions::offset_max_lag, or the tracks' span).
  Eigen::Vector4d offset_independent = Eigen::Vector4d::Zero();
  Eigen::Vector3d offset_sigma = Eigen::Vector3d::Zero();
  Eigen::Vector3d offset_walk = Eigen::Vector3d::Zero();
  int offset_tracks = 0;
  int offset_lags = 0;
};

/// The detection error as a displacement in space (the estimator's object_displacement_sigma,
/// object_displacement_walk; docs/estimator.md, "Detection displacements"): each object
/// observation back-projected at the depth its disparity gives, less the true object centre,
/// in the world frame. Along each track (split as for the offsets) it is a displacement of
/// standard deviation `sigma` at the track's first observation, along that camera's x (right),
/// y (down) and z (forward) axes, that walks by `walk` a frame along the newest camera's axes:
/// the mean squares of the differences within tracks at lags 1 to `lags` (in the later
/// camera's axes; each lag's beyond 3 robust sigmas left out, at least 20 kept) fitted by least
/// squares as intercept + lag walk^2, and sigma^2 the mean square of the tracks' first
/// displacements (beyond 3 robust sigmas left out) less half the intercept (the independent
/// part, which the image noise object_noise models). Metres. tracks = 0 when some axis had fewer
/// than 2 lags to fit. A box centre is a point of the object's visible side, off its centre by
/// a vector that turns with the view: in the image its error grows as the robot nears the
/// object (faster than any walk in pixels fits), in space it walks.
struct DetectionDisplacement {
  Eigen::Vector3d sigma = Eigen::Vector3d::Zero();
  Eigen::Vector3d walk = Eigen::Vector3d::Zero();
  int observations = 0;  ///< back-projected (a positive disparity)
  int tracks = 0;
  int lags = 0;
};

/// Point-feature tracks' drift (the estimator's feature_drift_sigma; docs/estimator.md,
/// "Point-feature drift"): each track's errors as white noise per stereo component plus a random
/// slope, the same in both images, horizontal and vertical, of standard deviation `sigma` (image
/// units a frame). Fitted by the method of moments on the residuals of each track against its
/// point triangulated with the true poses, the part the point absorbs accounted for exactly
/// (FeatureDriftFit in calibration.cc). `white`: the white noise's standard deviations of the
/// orthonormal components (u_left + u_right, v_left + v_right, u_left - u_right,
/// v_left - v_right, each / sqrt 2), that is, per image coordinate. Every track of at least 4
/// observations counts: the fit is of second moments, and a front-end's drift is heavy-tailed
/// (on the rendered calibration set a tenth of the tracks carry most of it), so leaving out the
/// tracks that stand out would leave out the drift. For the same reason the white part comes out
/// larger than the front-end's own estimate of its tracks' noise, which the filter keeps (its
/// chi-square gate turns away the worst tracks): docs/frontend.md, "The random slope,
/// measured". tracks = 0: fewer than 20 tracks, not fitted (sigma 0).
struct FeatureDrift {
  double sigma = 0.0;
  Eigen::Vector4d white = Eigen::Vector4d::Zero();
  int tracks = 0;
};

struct CalibrationReport {
  int frames = 0;  ///< odometry steps measured
  /// Odometry error xi = log(T_true_rel^-1 T_measured_rel) per frame: mean and RMS per axis of
  /// [rho; phi] (metres, radians), after the scale correction below.
  Eigen::Matrix<double, 6, 1> odometry_mean = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> odometry_rms = Eigen::Matrix<double, 6, 1>::Zero();
  /// Least-squares factor from measured to true translation (odometry_translation_scale).
  double translation_scale = 1.0;
  /// Object detections against the ground-truth objects projected with the true poses (needs
  /// objects_gt.csv); observations = 0 when there are none.
  StereoErrorSpread objects;
  /// The same detections' errors as a displacement in space (tracks = 0 when too few).
  DetectionDisplacement object_displacement;
  /// Point features against their tracks triangulated with the true poses (tracks of at least
  /// 3 frames); observations = 0 when there are none.
  StereoErrorSpread features;
  /// The same tracks' drift (tracks = 0 when there are none).
  FeatureDrift feature_drift;
  /// Level (a ground vehicle's level prior): the body's level axis (the nominal up axis made
  /// perpendicular to the segment's direction of travel: level_up_axis); its tilt about the
  /// segment's mean up axis, the components across it (about the tilt angles, radians): their
  /// RMS (the larger one) and the first lag (frames) at which their autocorrelation is no longer
  /// positive (the larger one: level_every_frames); the independent looks at the tilt that the
  /// segment holds (frames / that lag); and level_sigma, the spread's unbiased value from those
  /// looks, RMS sqrt(looks / (looks - 1)) (0 with a single look).
  Eigen::Vector3d level_axis = Eigen::Vector3d::UnitZ();
  double tilt_rms = 0.0;
  int tilt_decorrelation_frames = 1;
  double tilt_looks = 0.0;
  double level_sigma = 0.0;
};

/// Measures the segment. Throws std::invalid_argument when the robot or the segment is outside
/// the dataset or shorter than 10 frames.
CalibrationReport calibrate(const dataset::Dataset& dataset, const CalibrationOptions& options);

/// The report as the estimator config keys it suggests (YAML, with comments): the odometry
/// sigmas (the largest axis RMS, so that no axis is overconfident), the translation scale and the
/// object and feature noise components.
std::string to_yaml(const CalibrationReport& report, const CalibrationOptions& options);

/// Which model of the detector's error detector_model_yaml writes.
enum class DetectorModelKind {
  kDisplacement,  ///< object_noise, object_displacement_sigma, object_displacement_walk
  kImageOffset,   ///< object_noise, object_offset_sigma, object_offset_walk
};

/// The detector's error model alone, as an estimator config fragment of three keys with a
/// comment naming the segment: what `concord frontend --detector-model` reads. object_noise is
/// the independent part of the image-offset fit in both. Throws std::invalid_argument when the
/// segment had too few object tracks to fit it (offset_tracks or the displacement's tracks 0).
std::string detector_model_yaml(const CalibrationReport& report, const CalibrationOptions& options,
                                DetectorModelKind kind = DetectorModelKind::kDisplacement);

}  // namespace concord::calibration

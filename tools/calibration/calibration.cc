#include "calibration/calibration.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <map>
#include <stdexcept>

#include "concord/estimator/lie.h"
#include "concord/estimator/options.h"
#include "concord/estimator/updater_helper.h"

namespace concord::calibration {

namespace {

/// The upper median (the element at size / 2 after sorting; 0 when empty).
double upper_median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const std::size_t middle = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(middle), v.end());
  return v[middle];
}

/// 1.4826 x the median absolute deviation from the median: sigma for Gaussian data, robust to
/// outliers.
double robust_sigma(std::vector<double> values) {
  if (values.empty()) return 0.0;
  const double median = upper_median(values);
  for (double& value : values) value = std::abs(value - median);
  return 1.4826 * upper_median(std::move(values));
}

/// The values within 3 robust sigmas of their median (all of them when fewer than 5 or when the
/// spread is 0).
std::vector<double> without_outliers(std::vector<double> values) {
  if (values.size() < 5) return values;
  const double median = upper_median(values);
  const double sigma = robust_sigma(values);
  if (!(sigma > 0.0)) return values;
  values.erase(std::remove_if(values.begin(), values.end(),
                              [&](double v) { return std::abs(v - median) > 3.0 * sigma; }),
               values.end());
  return values;
}

double mean_square(const std::vector<double>& values) {
  double sum = 0.0;
  for (double value : values) sum += value * value;
  return values.empty() ? 0.0 : sum / static_cast<double>(values.size());
}

/// Observations keyed by (landmark, frame), sorted by landmark then frame.
using TrackIndex = std::map<std::pair<LandmarkId, int>, std::size_t>;
/// A track: (frame, index of the observation), in frame order.
using Track = std::vector<std::pair<int, std::size_t>>;

/// Each landmark's observations in frame order, split where it went unseen for more than `gap`
/// frames.
std::vector<Track> split_tracks(const TrackIndex& index, int gap) {
  std::vector<Track> tracks;
  LandmarkId current = 0;
  int last_frame = 0;
  for (const auto& [key, k] : index) {
    if (tracks.empty() || key.first != current || key.second - last_frame > gap) {
      tracks.emplace_back();
    }
    tracks.back().emplace_back(key.second, k);
    current = key.first;
    last_frame = key.second;
  }
  return tracks;
}

/// The largest lag to fit a walk over: `max_lag`, or when 0 the tracks' span (the median over
/// the observations of their track's first-to-last frames, at least 2); 0 without tracks.
int walk_lags(const std::vector<Track>& tracks, int max_lag) {
  if (max_lag > 0) return max_lag;
  std::vector<int> spans;
  for (const Track& track : tracks) {
    spans.insert(spans.end(), track.size(), track.back().first - track.front().first);
  }
  if (spans.empty()) return 0;
  const auto middle = spans.begin() + static_cast<std::ptrdiff_t>(spans.size() / 2);
  std::nth_element(spans.begin(), middle, spans.end());
  return std::max(2, *middle);
}

/// The differences within tracks at lag `lag` of a value per observation (later minus earlier,
/// through `difference(earlier, later)`).
template <typename Difference>
std::vector<double> lag_differences(const std::vector<Track>& tracks, int lag,
                                    const Difference& difference) {
  std::vector<double> out;
  for (const Track& track : tracks) {
    for (auto i = track.begin(); i != track.end(); ++i) {
      for (auto j = std::next(i); j != track.end() && j->first - i->first <= lag; ++j) {
        if (j->first - i->first == lag) out.push_back(difference(i->second, j->second));
      }
    }
  }
  return out;
}

/// A walk fitted to the mean squares of differences at lags 1..max_lag: least squares line
/// mean_square = intercept + slope lag over the lags with at least 20 differences (beyond 3
/// robust sigmas left out). False when fewer than 2 lags have enough.
template <typename Difference>
bool fit_walk(const std::vector<Track>& tracks, int max_lag, const Difference& difference,
              double& intercept, double& slope) {
  std::vector<double> lags, mean_squares;
  for (int lag = 1; lag <= max_lag; ++lag) {
    const std::vector<double> differences =
        without_outliers(lag_differences(tracks, lag, difference));
    if (differences.size() < 20) continue;
    lags.push_back(lag);
    mean_squares.push_back(mean_square(differences));
  }
  if (lags.size() < 2) return false;
  const auto n = static_cast<double>(lags.size());
  double mean_lag = 0.0, mean_value = 0.0;
  for (std::size_t i = 0; i < lags.size(); ++i) {
    mean_lag += lags[i] / n;
    mean_value += mean_squares[i] / n;
  }
  double sxy = 0.0, sxx = 0.0;
  for (std::size_t i = 0; i < lags.size(); ++i) {
    sxy += (lags[i] - mean_lag) * (mean_squares[i] - mean_value);
    sxx += (lags[i] - mean_lag) * (lags[i] - mean_lag);
  }
  slope = sxy / sxx;
  intercept = mean_value - slope * mean_lag;
  return true;
}

/// Accumulates stereo errors (u_left, v_left, u_right, v_right), in image units, as components,
/// with the landmark and frame of each (for the time correlation within tracks).
class StereoErrors {
 public:
  void add(LandmarkId id, int frame, const Eigen::Vector4d& error) {
    u_left_.push_back(error(0));
    horizontal_.push_back(0.5 * (error(0) + error(2)));
    vertical_.push_back(0.5 * (error(1) + error(3)));
    disparity_.push_back(error(0) - error(2));
    vertical_disparity_.push_back(error(1) - error(3));
    index_[{id, frame}] = horizontal_.size() - 1;
  }

  StereoErrorSpread spread(const CalibrationOptions& options) const {
    StereoErrorSpread out;
    out.observations = static_cast<int>(horizontal_.size());
    if (out.observations == 0) return out;
    out.horizontal = robust_sigma(horizontal_);
    out.vertical = robust_sigma(vertical_);
    out.disparity = robust_sigma(disparity_);
    out.vertical_disparity = robust_sigma(vertical_disparity_);
    out.median = {upper_median(horizontal_), upper_median(vertical_), upper_median(disparity_),
                  upper_median(vertical_disparity_)};
    int outliers = 0;
    for (std::size_t k = 0; k < horizontal_.size(); ++k) {
      const bool outlier = std::abs(horizontal_[k]) > 3.0 * out.horizontal ||
                           std::abs(vertical_[k]) > 3.0 * out.vertical ||
                           std::abs(disparity_[k]) > 3.0 * out.disparity ||
                           std::abs(vertical_disparity_[k]) > 3.0 * out.vertical_disparity;
      outliers += outlier;
    }
    out.outliers = static_cast<double>(outliers) / out.observations;
    const std::vector<double>* components[4] = {&horizontal_, &vertical_, &disparity_,
                                                &vertical_disparity_};
    const double sigmas[4] = {out.horizontal, out.vertical, out.disparity,
                              out.vertical_disparity};
    for (int c = 0; c < 4; ++c) {
      out.correlation_inflation(c) =
          inflation(*components[c], out.median(c), sigmas[c]);
    }
    fit_persistence(components, out);
    fit_offsets(options, out);
    return out;
  }

 private:
  static constexpr int kFitLags = 20;

  /// Autocovariance within tracks at lags 0..kFitLags of one component, clipped at 3 robust
  /// sigmas around the median; a lag with fewer than 10 pairs is NaN.
  std::array<double, kFitLags + 1> autocovariance(const std::vector<double>& values, double median,
                                                  double sigma) const {
    std::array<double, kFitLags + 1> out{};
    const auto clipped = [&](std::size_t k) {
      return std::clamp(values[k] - median, -3.0 * sigma, 3.0 * sigma);
    };
    for (int lag = 0; lag <= kFitLags; ++lag) {
      double products = 0.0;
      int pairs = 0;
      for (const auto& [key, k] : index_) {
        const auto later = lag == 0 ? index_.find(key) : index_.find({key.first, key.second + lag});
        if (later == index_.end()) continue;
        products += clipped(k) * clipped(later->second);
        ++pairs;
      }
      out[static_cast<std::size_t>(lag)] =
          pairs >= 10 ? products / pairs : std::numeric_limits<double>::quiet_NaN();
    }
    return out;
  }

  /// StereoErrorSpread::independent, constant, persistent, persistent_correlation.
  void fit_persistence(const std::vector<double>* const components[4],
                       StereoErrorSpread& out) const {
    const double sigmas[4] = {out.horizontal, out.vertical, out.disparity, out.vertical_disparity};
    std::array<std::array<double, kFitLags + 1>, 4> covariances{};
    for (int c = 0; c < 4; ++c) {
      covariances[c] = sigmas[c] > 0.0 ? autocovariance(*components[c], out.median(c), sigmas[c])
                                       : std::array<double, kFitLags + 1>{};
    }
    // For one correlation r, each component's constant and persistent variances by
    // non-negative least squares on the lags (two unknowns: the unconstrained solution, else the
    // better of either alone).
    struct Fit {
      double constant = 0.0, persistent = 0.0, residual = 0.0;
    };
    const auto fit_component = [&](const std::array<double, kFitLags + 1>& c, double r) {
      double s11 = 0.0, s12 = 0.0, s22 = 0.0, b1 = 0.0, b2 = 0.0, bb = 0.0;
      for (int lag = 1; lag <= kFitLags; ++lag) {
        const double y = c[static_cast<std::size_t>(lag)];
        if (!std::isfinite(y)) continue;
        const double g = std::pow(r, lag);
        s11 += 1.0;
        s12 += g;
        s22 += g * g;
        b1 += y;
        b2 += g * y;
        bb += y * y;
      }
      const auto residual = [&](double a, double b) {
        return bb - 2.0 * (a * b1 + b * b2) + a * a * s11 + 2.0 * a * b * s12 + b * b * s22;
      };
      Fit best{0.0, 0.0, bb};
      const double determinant = s11 * s22 - s12 * s12;
      if (determinant > 1e-12) {
        const double a = (s22 * b1 - s12 * b2) / determinant;
        const double b = (s11 * b2 - s12 * b1) / determinant;
        if (a >= 0.0 && b >= 0.0) return Fit{a, b, residual(a, b)};
      }
      if (s11 > 0.0 && b1 > 0.0 && residual(b1 / s11, 0.0) < best.residual) {
        best = {b1 / s11, 0.0, residual(b1 / s11, 0.0)};
      }
      if (s22 > 0.0 && b2 > 0.0 && residual(0.0, b2 / s22) < best.residual) {
        best = {0.0, b2 / s22, residual(0.0, b2 / s22)};
      }
      return best;
    };
    double best_total = std::numeric_limits<double>::infinity();
    for (int step = 0; step <= 98; ++step) {
      const double r = 0.01 * step;
      double total = 0.0;
      std::array<Fit, 4> fits{};
      for (int c = 0; c < 4; ++c) {
        const double variance = covariances[c][0];
        if (!(std::isfinite(variance) && variance > 0.0)) continue;
        fits[c] = fit_component(covariances[c], r);
        total += fits[c].residual / (variance * variance);
      }
      if (total < best_total) {
        best_total = total;
        out.persistent_correlation = r;
        for (int c = 0; c < 4; ++c) {
          const double variance = std::isfinite(covariances[c][0]) ? covariances[c][0] : 0.0;
          out.constant(c) = std::sqrt(fits[c].constant);
          out.persistent(c) = std::sqrt(fits[c].persistent);
          out.independent(c) =
              std::sqrt(std::max(0.0, variance - fits[c].constant - fits[c].persistent));
        }
      }
    }
  }

  /// StereoErrorSpread::offset_independent, offset_sigma, offset_walk, offset_tracks.
  void fit_offsets(const CalibrationOptions& options, StereoErrorSpread& out) const {
    const std::vector<Track> tracks = split_tracks(index_, options.track_gap);
    const int max_lag = walk_lags(tracks, options.offset_max_lag);
    if (max_lag == 0) {
      out.offset_tracks = 0;
      return;
    }
    out.offset_lags = max_lag;
    const std::vector<double>* components[3] = {&u_left_, &vertical_, &disparity_};
    for (int c = 0; c < 3; ++c) {
      const std::vector<double>& values = *components[c];
      double intercept = 0.0, slope = 0.0;
      if (!fit_walk(
              tracks, max_lag, [&](std::size_t i, std::size_t j) { return values[j] - values[i]; },
              intercept, slope)) {
        out.offset_tracks = 0;
        return;
      }
      std::vector<double> starts;
      for (const Track& track : tracks) starts.push_back(values[track.front().second]);
      const double start_mean_square = mean_square(without_outliers(std::move(starts)));
      const double independent =
          std::max(std::sqrt(std::max(0.5 * intercept, 0.0)), 0.1 * robust_sigma(values));
      out.offset_independent(c) = independent;
      out.offset_walk(c) = std::sqrt(std::max(slope, 0.0));
      out.offset_sigma(c) = std::sqrt(std::max(start_mean_square - independent * independent, 0.0));
    }
    out.offset_independent(3) = std::max(robust_sigma(without_outliers(vertical_disparity_)),
                                         0.1 * out.offset_independent(1));
    out.offset_tracks = static_cast<int>(tracks.size());
  }

  /// sqrt(1 + 2 sum_{lag 1..10} rho(lag)), at least 1, of one component's errors within tracks
  /// (clipped at 3 robust sigmas around the median, so that outliers do not dominate).
  double inflation(const std::vector<double>& values, double median, double sigma) const {
    if (!(sigma > 0.0)) return 1.0;
    const auto clipped = [&](std::size_t k) {
      return std::clamp(values[k] - median, -3.0 * sigma, 3.0 * sigma);
    };
    double variance = 0.0;
    for (std::size_t k = 0; k < values.size(); ++k) variance += clipped(k) * clipped(k);
    variance /= static_cast<double>(values.size());
    if (!(variance > 0.0)) return 1.0;
    double sum = 0.0;
    for (int lag = 1; lag <= 10; ++lag) {
      double products = 0.0;
      int pairs = 0;
      for (const auto& [key, k] : index_) {
        const auto later = index_.find({key.first, key.second + lag});
        if (later == index_.end()) continue;
        products += clipped(k) * clipped(later->second);
        ++pairs;
      }
      if (pairs >= 10) sum += products / pairs / variance;
    }
    return std::sqrt(std::max(1.0, 1.0 + 2.0 * sum));
  }

  std::vector<double> u_left_, horizontal_, vertical_, disparity_, vertical_disparity_;
  TrackIndex index_;
};

/// Accumulates detections' errors as displacements in space (CalibrationReport::
/// object_displacement): each in the world frame, with the rotation of its camera.
class DisplacementErrors {
 public:
  void add(LandmarkId id, int frame, const Eigen::Vector3d& error_world,
           const Eigen::Matrix3d& R_world_camera) {
    errors_.push_back(error_world);
    cameras_.push_back(R_world_camera);
    index_[{id, frame}] = errors_.size() - 1;
  }

  DetectionDisplacement fit(const CalibrationOptions& options) const {
    DetectionDisplacement out;
    out.observations = static_cast<int>(errors_.size());
    const std::vector<Track> tracks = split_tracks(index_, options.track_gap);
    out.lags = walk_lags(tracks, options.offset_max_lag);
    if (out.lags == 0) return out;
    for (int axis = 0; axis < 3; ++axis) {
      // A difference in the later camera's axes (the walk is along the newest camera's).
      const auto difference = [&](std::size_t i, std::size_t j) {
        return cameras_[j].col(axis).dot(errors_[j] - errors_[i]);
      };
      double intercept = 0.0, slope = 0.0;
      if (!fit_walk(tracks, out.lags, difference, intercept, slope)) return out;
      std::vector<double> starts;
      for (const Track& track : tracks) {
        const std::size_t first = track.front().second;
        starts.push_back(cameras_[first].col(axis).dot(errors_[first]));
      }
      const double start_mean_square = mean_square(without_outliers(std::move(starts)));
      out.walk(axis) = std::sqrt(std::max(slope, 0.0));
      out.sigma(axis) =
          std::sqrt(std::max(start_mean_square - 0.5 * std::max(intercept, 0.0), 0.0));
    }
    out.tracks = static_cast<int>(tracks.size());
    return out;
  }

 private:
  std::vector<Eigen::Vector3d> errors_;
  std::vector<Eigen::Matrix3d> cameras_;
  TrackIndex index_;
};

/// Accumulates point-feature tracks' residuals against their points triangulated with the true
/// poses, for CalibrationReport::feature_drift: white noise per stereo component plus a random
/// slope per track (feature_drift_sigma), by the method of moments. A triangulated point absorbs
/// part of any error (a slope in the columns looks like parallax), so a track's residual is
/// r = P e, with P the projection off the point's three directions, and a statistic r^T A r has
/// expectation tr(A P C P) under the errors' covariance C, linear in the unknown variances: each
/// component's sum of squares and the squared slope projections give five equations for the four
/// white variances and the slope's.
class FeatureDriftFit {
 public:
  /// One track: its observations' residuals (image units, 4 a frame: u_left, v_left, u_right,
  /// v_right), the Jacobian of their projections with respect to the point (4n x 3) and the
  /// observations' frames; its statistics are added to the sums (nothing of it is kept).
  void add(const Eigen::VectorXd& residual, const Eigen::MatrixXd& jacobian,
           const std::vector<int>& frames) {
    const Eigen::Index rows = residual.size();
    const Eigen::Index n = rows / 4;
    // Rotated, observation by observation, into the orthonormal components (common horizontal,
    // common vertical, horizontal and vertical differences, each / sqrt 2): V^T r, V^T J.
    Eigen::Matrix4d basis;
    basis << 1, 0, 1, 0,  //
        0, 1, 0, 1,       //
        1, 0, -1, 0,      //
        0, 1, 0, -1;
    basis /= std::sqrt(2.0);
    Eigen::VectorXd r(rows);  // V^T residual
    Eigen::MatrixXd J(rows, 3);
    Eigen::MatrixXd slopes = Eigen::MatrixXd::Zero(rows, 2);  // V^T [g_u g_v], unit slopes
    double mean_frame = 0.0;
    for (int frame : frames) mean_frame += frame;
    mean_frame /= static_cast<double>(n);
    for (Eigen::Index a = 0; a < n; ++a) {
      r.segment<4>(4 * a) = basis * residual.segment<4>(4 * a);
      J.middleRows<4>(4 * a) = basis * jacobian.middleRows<4>(4 * a);
      // A slope s (k - k_mean) in both images' u is sqrt 2 s (k - k_mean) in the common u.
      const double t = std::sqrt(2.0) * (frames[static_cast<std::size_t>(a)] - mean_frame);
      slopes(4 * a, 0) = t;
      slopes(4 * a + 1, 1) = t;
    }
    // P: the projection off the point's directions (onto the complement of J's columns).
    const Eigen::HouseholderQR<Eigen::MatrixXd> qr(J);
    const Eigen::MatrixXd Q = qr.householderQ() * Eigen::MatrixXd::Identity(rows, rows);
    const Eigen::MatrixXd P = Q.rightCols(rows - 3) * Q.rightCols(rows - 3).transpose();
    // The statistics and their expectations' coefficients, summed over the tracks.
    const Eigen::MatrixXd PG = P * slopes;  // rows x 2
    for (Eigen::Index a = 0; a < rows; ++a) {
      const auto i = static_cast<int>(a % 4);
      y_(i) += r(a) * r(a);
      for (Eigen::Index b = 0; b < rows; ++b) M_(i, static_cast<int>(b % 4)) += P(a, b) * P(a, b);
      M_(i, 4) += PG.row(a).squaredNorm();
      M_(4, i) += PG.row(a).squaredNorm();
    }
    y_(4) += (slopes.transpose() * r).squaredNorm();
    M_(4, 4) += (slopes.transpose() * PG).squaredNorm();
    ++tracks_;
  }

  /// The fit over every track (FeatureDrift): the moment equations solved for the four white
  /// variances and the slope's; not fitted (tracks 0) with fewer than 20 tracks or no positive
  /// white variance (a component may be exactly 0: rectified tracks' v_left = v_right). A
  /// negative slope variance: the white variances alone, the slope's 0.
  FeatureDrift fit() const {
    FeatureDrift out;
    if (tracks_ < 20) return out;
    Eigen::Matrix<double, 5, 1> variances = M_.colPivHouseholderQr().solve(y_);
    if (!(variances(4) > 0.0)) {
      variances.head<4>() = M_.topLeftCorner<4, 4>().colPivHouseholderQr().solve(y_.head<4>());
      variances(4) = 0.0;
    }
    variances = variances.cwiseMax(0.0);
    if (!variances.allFinite() || !(variances.head<4>().maxCoeff() > 0.0)) return out;
    out.white = variances.head<4>().cwiseSqrt();
    out.sigma = std::sqrt(variances(4));
    out.tracks = tracks_;
    return out;
  }

 private:
  Eigen::Matrix<double, 5, 5> M_ = Eigen::Matrix<double, 5, 5>::Zero();
  Eigen::Matrix<double, 5, 1> y_ = Eigen::Matrix<double, 5, 1>::Zero();
  int tracks_ = 0;
};

std::string number(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%.4g", value);
  return text;
}

/// The three estimator keys of the detection-offset model, uncommented.
std::string detector_model_keys(const StereoErrorSpread& spread) {
  const Eigen::Vector4d& i = spread.offset_independent;
  const Eigen::Vector3d& s = spread.offset_sigma;
  const Eigen::Vector3d& w = spread.offset_walk;
  return "object_noise: {horizontal: " + number(i(0)) + ", vertical: " + number(i(1)) +
         ", disparity: " + number(i(2)) + ", vertical_disparity: " + number(i(3)) + "}\n" +
         "object_offset_sigma: {horizontal: " + number(s(0)) + ", vertical: " + number(s(1)) +
         ", disparity: " + number(s(2)) + ", vertical_disparity: 0}\n" +
         "object_offset_walk: {horizontal: " + number(w(0)) + ", vertical: " + number(w(1)) +
         ", disparity: " + number(w(2)) + ", vertical_disparity: 0}\n";
}

/// The three estimator keys of the detection-displacement model, uncommented: the image noise
/// is the offset fit's independent part.
std::string displacement_model_keys(const StereoErrorSpread& spread,
                                    const DetectionDisplacement& displacement) {
  const Eigen::Vector4d& i = spread.offset_independent;
  const Eigen::Vector3d& s = displacement.sigma;
  const Eigen::Vector3d& w = displacement.walk;
  return "object_noise: {horizontal: " + number(i(0)) + ", vertical: " + number(i(1)) +
         ", disparity: " + number(i(2)) + ", vertical_disparity: " + number(i(3)) + "}\n" +
         "object_displacement_sigma: [" + number(s(0)) + ", " + number(s(1)) + ", " + number(s(2)) +
         "]\n" + "object_displacement_walk: [" + number(w(0)) + ", " + number(w(1)) + ", " +
         number(w(2)) + "]\n";
}

/// A flow sequence of a vector's entries, to four decimals (a config's body direction).
std::string vector_text(const Eigen::Vector3d& v) {
  char text[64];
  std::snprintf(text, sizeof(text), "[%.4f, %.4f, %.4f]", v.x(), v.y(), v.z());
  return text;
}

}  // namespace

CalibrationReport calibrate(const dataset::Dataset& dataset, const CalibrationOptions& options) {
  if (options.robot < 0 || options.robot >= static_cast<int>(dataset.robots.size())) {
    throw std::invalid_argument("calibrate: no robot " + std::to_string(options.robot) + " in " +
                                dataset.name);
  }
  const dataset::RobotData& robot = dataset.robots[options.robot];
  const int first = options.first_frame;
  const int end = first + options.frames;
  if (first < 0 || options.frames < 10 || end > robot.num_frames()) {
    throw std::invalid_argument("calibrate: frames [" + std::to_string(first) + ", " +
                                std::to_string(end) + ") are not a segment of at least 10 of robot " +
                                std::to_string(options.robot) + "'s " +
                                std::to_string(robot.num_frames()) + " frames");
  }
  if (options.track_gap < 1 || options.offset_max_lag < 0 || options.offset_max_lag == 1) {
    throw std::invalid_argument("calibrate: track gap " + std::to_string(options.track_gap) +
                                " and maximum lag " + std::to_string(options.offset_max_lag) +
                                " must be at least 1, and 0 (the tracks' span) or at least 2");
  }
  const StereoCamera& camera = dataset.camera;
  CalibrationReport report;

  // 1. Odometry: the scale of measured against true translations, measured = s * true + noise,
  //    by least squares with the (noise-free) truth as regressor, so that the noise does not bias
  //    it (regressing the other way shrinks it by |t|^2 / (|t|^2 + 3 sigma^2)); the correction
  //    is 1 / s. Then the error of each relative pose.
  double true_dot_measured = 0.0, true_squared = 0.0;
  for (int k = first; k + 1 < end; ++k) {
    const Eigen::Isometry3d truth = robot.groundtruth[k].inverse() * robot.groundtruth[k + 1];
    true_dot_measured += truth.translation().dot(robot.odometry[k].translation());
    true_squared += truth.translation().squaredNorm();
  }
  report.translation_scale = true_dot_measured > 0.0 ? true_squared / true_dot_measured : 1.0;
  Eigen::Matrix<double, 6, 1> sum = Eigen::Matrix<double, 6, 1>::Zero();
  Eigen::Matrix<double, 6, 1> squares = Eigen::Matrix<double, 6, 1>::Zero();
  for (int k = first; k + 1 < end; ++k) {
    const Eigen::Isometry3d truth = robot.groundtruth[k].inverse() * robot.groundtruth[k + 1];
    Eigen::Isometry3d measured = robot.odometry[k];
    measured.translation() *= report.translation_scale;
    const lie::Vector6d error = lie::se3_log(truth.inverse() * measured);
    sum += error;
    squares += error.cwiseAbs2();
    ++report.frames;
  }
  report.odometry_mean = sum / report.frames;
  report.odometry_rms = (squares / report.frames).cwiseSqrt();

  // 2. Objects against the projected ground truth; and, back-projected at the depth their
  //    disparity gives (one stereo pair triangulated), against the true centre in space.
  StereoErrors objects;
  DisplacementErrors displacements;
  for (int k = first; k < end; ++k) {
    const Eigen::Matrix3d R_world_camera =
        robot.groundtruth[k].linear() * camera.T_cam0_body.linear().transpose();
    for (const StereoObservation& observation : robot.objects[k]) {
      const auto truth = dataset.objects_groundtruth.find(observation.id);
      if (truth == dataset.objects_groundtruth.end()) continue;
      const auto projection =
          UpdaterHelper::project(camera, robot.groundtruth[k], truth->second);
      if (!projection) continue;
      objects.add(observation.id, k, observation.uv - camera.denormalize(projection->xy));
      const Eigen::Vector4d xy = camera.normalize(observation.uv);
      if (!(xy(0) - xy(2) > 0.0)) continue;  // no depth: at or beyond infinity
      const auto measured = UpdaterHelper::triangulate(camera, {robot.groundtruth[k]}, {xy});
      if (!measured) continue;
      displacements.add(observation.id, k, *measured - truth->second, R_world_camera);
    }
  }
  report.objects = objects.spread(options);
  report.object_displacement = displacements.fit(options);

  // 3. Point features against their tracks triangulated with the true poses; residuals of a
  //    fitted point are smaller than the noise by sqrt((4n - 3) / 4n), undone here.
  std::map<LandmarkId, std::vector<std::pair<int, Eigen::Vector4d>>> tracks;
  for (int k = first; k < end; ++k) {
    for (const StereoObservation& observation : robot.features[k]) {
      tracks[observation.id].emplace_back(k, observation.uv);
    }
  }
  StereoErrors features;
  FeatureDriftFit drift;
  // d(image) / d(normalized) of a stereo observation: the intrinsics' 2x2 part, both images.
  Eigen::Matrix4d to_image = Eigen::Matrix4d::Zero();
  to_image.topLeftCorner<2, 2>() = camera.K.topLeftCorner<2, 2>();
  to_image.bottomRightCorner<2, 2>() = camera.K.topLeftCorner<2, 2>();
  for (const auto& [id, track] : tracks) {
    if (track.size() < 3) continue;
    std::vector<Eigen::Isometry3d> poses;
    std::vector<Eigen::Vector4d> observations;
    for (const auto& [frame, uv] : track) {
      poses.push_back(robot.groundtruth[frame]);
      observations.push_back(camera.normalize(uv));
    }
    const auto point = UpdaterHelper::triangulate(camera, poses, observations);
    if (!point) continue;
    const double n = 4.0 * static_cast<double>(track.size());
    const double deflation = std::sqrt(n / (n - 3.0));
    // The residuals (image units) and their Jacobian with respect to the point, for the drift
    // fit: tracks of 4 or more observations, all in front of both cameras.
    const auto rows = static_cast<Eigen::Index>(4 * track.size());
    Eigen::VectorXd residual(rows);
    Eigen::MatrixXd jacobian(rows, 3);
    std::vector<int> frames;
    bool visible = true;
    for (std::size_t i = 0; i < track.size(); ++i) {
      const auto projection = UpdaterHelper::project(camera, poses[i], *point);
      if (!projection) {
        visible = false;
        continue;
      }
      const auto row = static_cast<Eigen::Index>(4 * i);
      residual.segment<4>(row) = track[i].second - camera.denormalize(projection->xy);
      jacobian.middleRows<4>(row) = to_image * projection->jacobian_point;
      frames.push_back(track[i].first);
      features.add(id, track[i].first, deflation * residual.segment<4>(row));
    }
    if (visible && track.size() >= 4) drift.add(residual, jacobian, frames);
  }
  report.features = features.spread(options);
  report.feature_drift = drift.fit();

  // 4. Level (a ground vehicle's level prior, docs/estimator.md):
  //    a. the level axis: the nominal up axis made perpendicular to the segment's direction of
  //       travel (the sum of the true steps in the body): a camera mounted with a small pitch
  //       travels a little off its own horizontal plane;
  //    b. the segment's up axis: the mean of the level axis seen in the world (the world frame
  //       is the start's, itself on some slope);
  //    c. the tilt: the level axis's two components across that mean, per frame; their RMS and
  //       the first lag at which their autocorrelation is no longer positive (the larger of the
  //       two each);
  //    d. level_sigma: the tilt's spread about the true level, which the filter estimates (the
  //       world up axis state): the segment's RMS about its own mean underestimates it by the
  //       one look's worth of mean it took out, so the unbiased value for its frames / lag
  //       independent looks, RMS sqrt(n / (n - 1)).
  const std::array<double, 3> axis = body_axis_vector(options.up_axis);
  const Eigen::Vector3d up(axis[0], axis[1], axis[2]);
  if (up.isZero()) {
    throw std::invalid_argument("calibrate: up axis " + options.up_axis +
                                " is not +x, -x, +y, -y, +z or -z");
  }
  Eigen::Vector3d travel = Eigen::Vector3d::Zero();
  for (int k = first; k + 1 < end; ++k) {
    travel += (robot.groundtruth[k].inverse() * robot.groundtruth[k + 1]).translation();
  }
  report.level_axis = up;
  if (travel.norm() > 1e-9) {
    const Eigen::Vector3d direction = travel.normalized();
    const Eigen::Vector3d level = up - up.dot(direction) * direction;
    if (level.norm() > 0.5) report.level_axis = level.normalized();  // else: travels "up"
  }
  Eigen::Vector3d mean_up = Eigen::Vector3d::Zero();
  for (int k = first; k < end; ++k) mean_up += robot.groundtruth[k].linear() * report.level_axis;
  mean_up.normalize();
  const Eigen::Vector3d across = mean_up.unitOrthogonal();
  const Eigen::Vector3d horizontal[2] = {across, mean_up.cross(across)};
  for (const Eigen::Vector3d& direction : horizontal) {
    std::vector<double> tilt;
    for (int k = first; k < end; ++k) {
      tilt.push_back(direction.dot(robot.groundtruth[k].linear() * report.level_axis));
    }
    const auto n = static_cast<double>(tilt.size());
    double mean = 0.0, squares = 0.0;
    for (double value : tilt) {
      mean += value / n;
      squares += value * value / n;
    }
    const double variance = squares - mean * mean;
    report.tilt_rms = std::max(report.tilt_rms, std::sqrt(std::max(variance, 0.0)));
    if (!(variance > 0.0)) continue;
    int lag = 1;
    for (; lag < static_cast<int>(tilt.size()) / 2; ++lag) {
      double covariance = 0.0;
      for (std::size_t k = 0; k + static_cast<std::size_t>(lag) < tilt.size(); ++k) {
        covariance += (tilt[k] - mean) * (tilt[k + static_cast<std::size_t>(lag)] - mean) / n;
      }
      if (covariance <= 0.0) break;
    }
    report.tilt_decorrelation_frames = std::max(report.tilt_decorrelation_frames, lag);
  }
  // d. Looks per component: n = frames / lag.
  report.tilt_looks = static_cast<double>(end - first) / report.tilt_decorrelation_frames;
  if (report.tilt_looks > 1.0) {
    report.level_sigma = report.tilt_rms * std::sqrt(report.tilt_looks / (report.tilt_looks - 1.0));
  }
  return report;
}

std::string detector_model_yaml(const CalibrationReport& report, const CalibrationOptions& options,
                                DetectorModelKind kind) {
  const bool displacement = kind == DetectorModelKind::kDisplacement;
  const std::string segment = "robot " + std::to_string(options.robot) + "'s frames " +
                              std::to_string(options.first_frame) + "-" +
                              std::to_string(options.first_frame + options.frames - 1);
  if (report.objects.offset_tracks == 0 ||
      (displacement && report.object_displacement.tracks == 0)) {
    throw std::invalid_argument("calibrate: too few object tracks on " + segment +
                                " to fit the detection-" +
                                (displacement ? "displacement" : "offset") +
                                " model (each component needs 2 lags with 20 pairs)");
  }
  const std::string head = "# The detector's error model, measured by concord calibrate on " +
                           segment + " (" + std::to_string(report.objects.offset_tracks) +
                           " object tracks, " + std::to_string(report.objects.observations) +
                           " observations): ";
  // The point-feature tracks' drift on the same segment: the front-end's tracker is measured
  // with its detector (its white noise the front-end measures itself).
  const FeatureDrift& tracks = report.feature_drift;
  const std::string drift =
      tracks.tracks == 0
          ? "# (no point-feature tracks of 4 or more observations on the segment: no drift)\n"
          : "# The point-feature tracks' drift on the same segment (" +
                std::to_string(tracks.tracks) +
                " tracks): a random slope per track, image units a frame (docs/estimator.md, "
                "\"Point-feature drift\").\nfeature_drift_sigma: " +
                number(tracks.sigma) + "\n";
  if (displacement) {
    return head +
           "a displacement in space per (robot, object) that walks (metres, camera axes x right, "
           "y down, z forward), plus independent image noise\n# (docs/estimator.md, \"Detection "
           "displacements\"); the walk fitted over lags 1-" +
           std::to_string(report.object_displacement.lags) +
           " frames. For concord frontend --detector-model.\n" +
           displacement_model_keys(report.objects, report.object_displacement) + drift;
  }
  return head +
         "an offset per (robot, object) that walks, plus independent noise\n"
         "# (docs/estimator.md, \"Detection offsets\"); the walk fitted over lags 1-" +
         std::to_string(report.objects.offset_lags) +
         " frames. For concord frontend --detector-model.\n" + detector_model_keys(report.objects) +
         drift;
}

std::string to_yaml(const CalibrationReport& report, const CalibrationOptions& options) {
  const auto& rms = report.odometry_rms;
  const auto& mean = report.odometry_mean;
  std::string text = "# concord calibrate: robot " + std::to_string(options.robot) + ", frames " +
                     std::to_string(options.first_frame) + "-" +
                     std::to_string(options.first_frame + options.frames - 1) + " (" +
                     std::to_string(report.frames) + " odometry steps)\n";
  text += "# Odometry error per axis after the scale correction, RMS (mean):\n#   rho";
  for (int axis = 0; axis < 3; ++axis) {
    text += " " + number(rms(axis)) + " (" + number(mean(axis)) + ")";
  }
  text += " m\n#   phi";
  for (int axis = 3; axis < 6; ++axis) {
    text += " " + number(rms(axis)) + " (" + number(mean(axis)) + ")";
  }
  text += " rad\n# Sigmas: the largest axis RMS, so that no axis is overconfident.\n";
  text += "odometry_translation_sigma: " + number(rms.head<3>().maxCoeff()) + "\n";
  text += "odometry_rotation_sigma: " + number(rms.tail<3>().maxCoeff()) + "\n";
  text += "odometry_translation_scale: " + number(report.translation_scale) + "\n";
  const auto noise = [&](const std::string& key, const StereoErrorSpread& spread) {
    if (spread.observations == 0) {
      text += "# " + key + ": nothing to measure on this segment\n";
      return;
    }
    const Eigen::Vector4d sigmas(spread.horizontal, spread.vertical, spread.disparity,
                                 spread.vertical_disparity);
    const Eigen::Vector4d& factor = spread.correlation_inflation;
    text += "# " + key + ": " + std::to_string(spread.observations) + " observations; robust sigmas " +
            number(sigmas(0)) + ", " + number(sigmas(1)) + ", " + number(sigmas(2)) + ", " +
            number(sigmas(3)) + "; medians " + number(spread.median(0)) + ", " +
            number(spread.median(1)) + ", " + number(spread.median(2)) + ", " +
            number(spread.median(3)) + "; " + number(100.0 * spread.outliers) +
            " % beyond 3 sigma in some component (left to the chi-square gates)\n";
    text += "# time correlation within tracks: sigmas x " + number(factor(0)) + ", " +
            number(factor(1)) + ", " + number(factor(2)) + ", " + number(factor(3)) +
            " for their white-noise equivalent (the values below)\n";
    // A component that does not vary at all (v_left = v_right on rectified tracks) gets a floor
    // of 1 % of the largest one: the estimator needs a positive definite noise.
    const Eigen::Vector4d equivalent = sigmas.cwiseProduct(factor);
    const double floor = 0.01 * equivalent.head<3>().maxCoeff();
    if (equivalent.minCoeff() < floor) {
      text += "# (components below 1 % of the largest are raised to that floor)\n";
    }
    text += key + ": {horizontal: " + number(std::max(equivalent(0), floor)) +
            ", vertical: " + number(std::max(equivalent(1), floor)) +
            ", disparity: " + number(std::max(equivalent(2), floor)) +
            ", vertical_disparity: " + number(std::max(equivalent(3), floor)) + "}\n";
    if (key != "object_noise") return;
    // Objects: the time correlation modelled instead of inflated (docs/tuning.md). The
    // independent part gets a floor of 10 % of the component's robust sigma (1 % of the largest
    // if that is 0): a fit to lags 1-20 says little about it, and the conditional of a new
    // observation needs some.
    const auto stereo_noise = [&](const Eigen::Vector4d& values, const Eigen::Vector4d& minimum) {
      return "{horizontal: " + number(std::max(values(0), minimum(0))) +
             ", vertical: " + number(std::max(values(1), minimum(1))) +
             ", disparity: " + number(std::max(values(2), minimum(2))) +
             ", vertical_disparity: " + number(std::max(values(3), minimum(3))) + "}";
    };
    const Eigen::Vector4d none = Eigen::Vector4d::Zero();
    const Eigen::Vector4d independent_floor =
        (0.1 * sigmas).cwiseMax(0.01 * sigmas.head<3>().maxCoeff());
    text += "# or, modelling the time correlation (a part constant along a track, a part with "
            "correlation " + number(spread.persistent_correlation) +
            " a frame) instead of inflating:\n";
    text += "# object_noise: " + stereo_noise(spread.independent, independent_floor) + "\n";
    text += "# object_noise_constant: " + stereo_noise(spread.constant, none) + "\n";
    text += "# object_noise_persistent: " + stereo_noise(spread.persistent, none) + "\n";
    text += "# object_noise_correlation: " + number(spread.persistent_correlation) + "\n";
    if (spread.offset_tracks == 0) {
      text += "# (too few object tracks on this segment for the detection-offset model)\n";
      return;
    }
    text +=
        "# or, as an offset per (robot, object) that walks (docs/estimator.md, \"Detection "
        "offsets\"; `concord calibrate --detector-model FILE --detector-model-kind offset` "
        "writes these three keys):\n";
    const auto commented = [](std::string model) {
      for (std::size_t at = 0; at < model.size(); at = model.find('\n', at) + 1)
        model.insert(at, "# ");
      return model;
    };
    text += commented(detector_model_keys(spread));
    if (report.object_displacement.tracks == 0) {
      text += "# (too few object tracks on this segment for the detection-displacement model)\n";
      return;
    }
    text +=
        "# or, as a displacement in space per (robot, object) that walks (docs/estimator.md, "
        "\"Detection displacements\"; what `concord calibrate --detector-model FILE` writes):\n";
    text += commented(displacement_model_keys(spread, report.object_displacement));
  };
  noise("object_noise", report.objects);
  noise("feature_noise", report.features);
  const FeatureDrift& drift = report.feature_drift;
  if (drift.tracks > 0) {
    text +=
        "# or, modelling the tracks' drift (docs/estimator.md, \"Point-feature drift\"; the "
        "method of moments over " +
        std::to_string(drift.tracks) +
        " tracks of 4 or more observations): white noise a coordinate " + number(drift.white(0)) +
        " (common u), " + number(drift.white(1)) + " (common v), " + number(drift.white(2)) +
        " (u difference), " + number(drift.white(3)) +
        " (v difference), plus a random slope per track (what `--detector-model` writes):\n";
    text += "# feature_drift_sigma: " + number(drift.sigma) + "\n";
  }
  text += "# Level (" + options.up_axis + " nominally up): the axis level with the direction of travel " +
          vector_text(report.level_axis) + "; its tilt about the segment's up axis: RMS " +
          number(report.tilt_rms) + " rad, correlated over " +
          std::to_string(report.tilt_decorrelation_frames) + " frames (" + number(report.tilt_looks) +
          " independent looks), the unbiased spread is level_sigma.\n";
  text += "# A ground vehicle's level prior (docs/estimator.md) would be:\n";
  text += "# level_sigma: " + number(report.level_sigma) + "\n";
  text += "# level_every_frames: " + std::to_string(report.tilt_decorrelation_frames) + "\n";
  text += "# level_up_axis: " + vector_text(report.level_axis) + "\n";
  return text;
}

}  // namespace concord::calibration

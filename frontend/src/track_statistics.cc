#include "concord/frontend/track_statistics.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "concord/frontend/stereo_odometry.h"
#include "sample_median.h"

namespace concord::frontend {

namespace {

struct Observation {
  int frame = 0;
  Eigen::Vector4d uv;
};

/// (u_left, v_left, u_right, v_right) of a point in the left camera frame, and its Jacobian.
Eigen::Vector4d project(const StereoCamera& camera, const Eigen::Vector3d& p,
                        Eigen::Matrix<double, 4, 3>& jacobian) {
  const double fx = camera.K(0, 0), fy = camera.K(1, 1), cx = camera.K(0, 2), cy = camera.K(1, 2);
  const double b = camera.baseline(), iz = 1.0 / p.z();
  jacobian << fx * iz, 0.0, -fx * p.x() * iz * iz,  //
      0.0, fy * iz, -fy * p.y() * iz * iz,          //
      fx * iz, 0.0, -fx * (p.x() - b) * iz * iz,    //
      0.0, fy * iz, -fy * p.y() * iz * iz;
  return Eigen::Vector4d(fx * p.x() * iz + cx, fy * p.y() * iz + cy, fx * (p.x() - b) * iz + cx,
                         fy * p.y() * iz + cy);
}

}  // namespace

TrackConsistency track_consistency(const StereoCamera& camera,
                                   const std::vector<Eigen::Isometry3d>& odometry,
                                   const std::vector<std::vector<StereoObservation>>& features,
                                   int min_observations) {
  // Poses of the left camera by dead reckoning: T_start_cam(k).
  std::vector<Eigen::Isometry3d> T_start_cam;
  Eigen::Isometry3d T_start_body = Eigen::Isometry3d::Identity();
  const Eigen::Isometry3d T_body_cam = camera.T_cam0_body.inverse();
  for (std::size_t frame = 0; frame < features.size(); ++frame) {
    if (frame > 0 && frame - 1 < odometry.size()) T_start_body = T_start_body * odometry[frame - 1];
    T_start_cam.push_back(T_start_body * T_body_cam);
  }
  std::unordered_map<LandmarkId, std::vector<Observation>> tracks;
  for (std::size_t frame = 0; frame < features.size(); ++frame) {
    for (const StereoObservation& observation : features[frame]) {
      tracks[observation.id].push_back({static_cast<int>(frame), observation.uv});
    }
  }
  TrackConsistency result;
  std::vector<double> magnitudes;
  long long parameters = 0;
  for (const auto& [id, observations] : tracks) {
    if (static_cast<int>(observations.size()) < min_observations) continue;
    const auto first = triangulate(camera, observations.front().uv, 0.5);
    if (!first) continue;
    Eigen::Vector3d point = T_start_cam[observations.front().frame] * *first;
    // Gauss-Newton on the point.
    bool usable = true;
    for (int iteration = 0; iteration < 5 && usable; ++iteration) {
      Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
      Eigen::Vector3d g = Eigen::Vector3d::Zero();
      for (const Observation& observation : observations) {
        const Eigen::Isometry3d T_cam_start = T_start_cam[observation.frame].inverse();
        const Eigen::Vector3d p = T_cam_start * point;
        if (p.z() <= 1e-3) {
          usable = false;
          break;
        }
        Eigen::Matrix<double, 4, 3> H;
        const Eigen::Vector4d r = observation.uv - project(camera, p, H);
        const Eigen::Matrix<double, 4, 3> J = H * T_cam_start.linear();
        A += J.transpose() * J;
        g += J.transpose() * r;
      }
      if (!usable) break;
      const Eigen::Vector3d step = A.ldlt().solve(g);
      if (!step.allFinite()) usable = false;
      point += step;
    }
    if (!usable) continue;
    std::vector<double> residuals;
    for (const Observation& observation : observations) {
      const Eigen::Vector3d p = T_start_cam[observation.frame].inverse() * point;
      if (p.z() <= 1e-3) {
        usable = false;
        break;
      }
      Eigen::Matrix<double, 4, 3> H;
      const Eigen::Vector4d r = observation.uv - project(camera, p, H);
      for (int coordinate = 0; coordinate < 4; ++coordinate)
        residuals.push_back(std::abs(r(coordinate)));
    }
    if (!usable) continue;
    ++result.tracks;
    parameters += 3;
    magnitudes.insert(magnitudes.end(), residuals.begin(), residuals.end());
  }
  result.residuals = static_cast<long long>(magnitudes.size());
  if (magnitudes.empty() || result.residuals <= parameters) return result;
  const auto middle = magnitudes.begin() + static_cast<std::ptrdiff_t>(magnitudes.size() / 2);
  std::nth_element(magnitudes.begin(), middle, magnitudes.end());
  const double correction = std::sqrt(static_cast<double>(result.residuals) /
                                      static_cast<double>(result.residuals - parameters));
  result.sigma = 1.4826 * *middle * correction;
  return result;
}

Eigen::Vector2d ObservationNoise::sigma(float left_variance, float stereo_variance) const {
  const auto measured_or = [](float variance, double typical) {
    // A variance next to zero (an alignment that fitted its patch exactly) is floored.
    return std::isfinite(variance) ? std::max<double>(variance, kFloor * typical) : typical;
  };
  const double left = scale_left * measured_or(left_variance, typical_left);
  const double stereo = scale_stereo * measured_or(stereo_variance, typical_stereo);
  return Eigen::Vector2d(std::sqrt(left), std::sqrt(left + stereo));
}

ObservationNoise fit_observation_noise(
    const std::vector<std::vector<StereoObservation>>& features,
    const std::vector<std::vector<std::array<float, 2>>>& variances, double sigma) {
  ObservationNoise noise;
  if (!(sigma > 0.0) || variances.size() != features.size()) return noise;
  for (std::size_t frame = 0; frame < features.size(); ++frame) {
    if (variances[frame].size() != features[frame].size()) return noise;
  }
  // Each kind's median over the measured variances: what an unmeasured one takes.
  for (int kind = 0; kind < 2; ++kind) {
    std::vector<double> measured;
    for (const auto& frame : variances) {
      for (const auto& pair : frame) {
        if (std::isfinite(pair[kind]) && pair[kind] > 0.0f) measured.push_back(pair[kind]);
      }
    }
    (kind == 0 ? noise.typical_left : noise.typical_stereo) = median_of(std::move(measured));
  }
  if (!(noise.typical_left > 0.0 && noise.typical_stereo > 0.0)) return ObservationNoise{};
  // With unit scales sigma() gives the variances as used; their means set the scales.
  noise.scale_left = noise.scale_stereo = 1.0;
  double left = 0.0, stereo = 0.0;
  for (const auto& frame : variances) {
    for (const auto& pair : frame) {
      const Eigen::Vector2d unit = noise.sigma(pair[0], pair[1]);
      left += unit(0) * unit(0);
      stereo += unit(1) * unit(1) - unit(0) * unit(0);
      ++noise.observations;
    }
  }
  noise.scale_left = sigma * sigma * noise.observations / left;
  noise.scale_stereo = sigma * sigma * noise.observations / stereo;
  return noise;
}

void RunningObservationNoise::apply(std::vector<StereoObservation>& features,
                                    const std::vector<std::array<float, 2>>& variances) {
  if (variances.size() != features.size() || !(sigma_ > 0.0)) return;
  for (const auto& pair : variances) {
    for (int kind = 0; kind < 2; ++kind) {
      if (std::isfinite(pair[kind]) && pair[kind] > 0.0f) {
        sums_[kind] += pair[kind];
        ++counts_[kind];
      }
    }
  }
  if (counts_[0] == 0 || counts_[1] == 0) return;
  ObservationNoise noise;
  noise.typical_left = sums_[0] / static_cast<double>(counts_[0]);
  noise.typical_stereo = sums_[1] / static_cast<double>(counts_[1]);
  noise.scale_left = sigma_ * sigma_ / noise.typical_left;
  noise.scale_stereo = sigma_ * sigma_ / noise.typical_stereo;
  for (std::size_t n = 0; n < features.size(); ++n) {
    features[n].sigma = noise.sigma(variances[n][0], variances[n][1]);
  }
}

}  // namespace concord::frontend

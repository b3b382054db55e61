#include "concord/frontend/stereo_odometry.h"

#include <algorithm>
#include <cmath>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "concord/dataset/result_io.h"
#include "concord/estimator/lie.h"
#include "concord/frontend/sequence.h"
#include "text_lines.h"

namespace concord::frontend {

namespace {

using Matrix36d = Eigen::Matrix<double, 3, 6>;

/// One track seen at k-1 and k: the point triangulated at k-1 (camera k-1) with its covariance,
/// and its measurement (u_left, v_left, u_right) at k.
struct Correspondence {
  LandmarkId id = 0;
  Eigen::Vector3d p_previous = Eigen::Vector3d::Zero();
  Eigen::Matrix3d point_covariance = Eigen::Matrix3d::Zero();
  Eigen::Vector3d measured = Eigen::Vector3d::Zero();
};

/// The rectified rig's numbers.
struct Rig {
  double fx, fy, cx, cy, baseline;
  explicit Rig(const StereoCamera& camera)
      : fx(camera.K(0, 0)),
        fy(camera.K(1, 1)),
        cx(camera.K(0, 2)),
        cy(camera.K(1, 2)),
        baseline(camera.baseline()) {}

  /// (u_left, v_left, u_right) of a point in the left camera frame, and its Jacobian.
  Eigen::Vector3d project(const Eigen::Vector3d& p, Eigen::Matrix3d* jacobian) const {
    const double inverse_z = 1.0 / p.z();
    const Eigen::Vector3d h(fx * p.x() * inverse_z + cx, fy * p.y() * inverse_z + cy,
                            fx * (p.x() - baseline) * inverse_z + cx);
    if (jacobian) {
      *jacobian << fx * inverse_z, 0.0, -fx * p.x() * inverse_z * inverse_z,  //
          0.0, fy * inverse_z, -fy * p.y() * inverse_z * inverse_z,           //
          fx * inverse_z, 0.0, -fx * (p.x() - baseline) * inverse_z * inverse_z;
    }
    return h;
  }

  /// Covariance of a triangulated point from independent pixel noise sigma on u_left, v_left,
  /// u_right (first order).
  Eigen::Matrix3d point_covariance(const Eigen::Vector4d& uv, double sigma) const {
    const double disparity = uv(0) - uv(2);
    const double z = fx * baseline / disparity;
    const double x = baseline * (uv(0) - cx) / disparity;
    const double y = baseline * fx * (uv(1) - cy) / (fy * disparity);
    Eigen::Matrix3d J;  // d(x, y, z) / d(u_left, v_left, u_right)
    J << baseline / disparity - x / disparity, 0.0, x / disparity,        //
        -y / disparity, baseline * fx / (fy * disparity), y / disparity,  //
        -z / disparity, 0.0, z / disparity;
    return sigma * sigma * J * J.transpose();
  }
};

/// Result of one weighted Gauss-Newton refinement.
struct Refinement {
  Eigen::Isometry3d T_previous_current = Eigen::Isometry3d::Identity();  // camera frames
  Matrix6d information = Matrix6d::Zero();
  double chi2 = 0.0;
  int used = 0;
};

/// Weighted squared residual of one correspondence under T_previous_current (camera frames),
/// with its 3x6 Jacobian (right perturbation) and weight when asked.
double residual_chi2(const Rig& rig, const Correspondence& c, const Eigen::Isometry3d& T,
                     double pixel_sigma, Eigen::Vector3d* residual, Matrix36d* jacobian,
                     Eigen::Matrix3d* weight) {
  // Q = T^-1 P; right perturbation T exp(xi): Q(xi) ~ Q - rho + Q x phi.
  const Eigen::Vector3d q = T.inverse() * c.p_previous;
  if (q.z() <= 1e-6) return std::numeric_limits<double>::infinity();
  Eigen::Matrix3d H;
  const Eigen::Vector3d r = c.measured - rig.project(q, &H);
  const Eigen::Matrix3d H_point = H * T.rotation().transpose();
  const Eigen::Matrix3d covariance = pixel_sigma * pixel_sigma * Eigen::Matrix3d::Identity() +
                                     H_point * c.point_covariance * H_point.transpose();
  const Eigen::Matrix3d W = covariance.inverse();
  if (residual) *residual = r;
  if (weight) *weight = W;
  if (jacobian) {
    Matrix36d dq;
    dq.leftCols<3>() = -Eigen::Matrix3d::Identity();
    dq.rightCols<3>() = lie::skew(q);
    *jacobian = H * dq;
  }
  return r.dot(W * r);
}

Refinement refine(const Rig& rig, const std::vector<Correspondence>& correspondences,
                  const std::vector<unsigned char>& use, Eigen::Isometry3d T, int iterations,
                  double pixel_sigma) {
  Refinement result;
  for (int iteration = 0; iteration <= iterations; ++iteration) {
    Matrix6d A = Matrix6d::Zero();
    Eigen::Matrix<double, 6, 1> g = Eigen::Matrix<double, 6, 1>::Zero();
    double chi2 = 0.0;
    int used = 0;
    for (std::size_t index = 0; index < correspondences.size(); ++index) {
      if (!use[index]) continue;
      Eigen::Vector3d r;
      Matrix36d J;
      Eigen::Matrix3d W;
      const double e = residual_chi2(rig, correspondences[index], T, pixel_sigma, &r, &J, &W);
      if (!std::isfinite(e)) continue;
      A += J.transpose() * W * J;
      g += J.transpose() * W * r;
      chi2 += e;
      ++used;
    }
    result = {T, A, chi2, used};
    if (iteration == iterations || used < 3) break;
    const Eigen::Matrix<double, 6, 1> step = A.ldlt().solve(g);
    if (!step.allFinite()) break;
    T = T * lie::se3_exp(step);
    if (step.norm() < 1e-10) {
      iterations = iteration + 1;  // one more pass evaluates A and chi2 at the final T
    }
  }
  return result;
}

Matrix6d diagonal_covariance(double translation_sigma, double rotation_sigma) {
  Matrix6d covariance = Matrix6d::Zero();
  covariance.diagonal() << Eigen::Vector3d::Constant(translation_sigma * translation_sigma),
      Eigen::Vector3d::Constant(rotation_sigma * rotation_sigma);
  return covariance;
}

}  // namespace

std::vector<std::string> OdometryOptions::validate() const {
  std::vector<std::string> problems;
  const auto require = [&](bool ok, const std::string& field, double value, const char* rule) {
    if (!ok) problems.push_back(text::problem(field, value, rule));
  };
  require(pixel_sigma > 0.0, "pixel_sigma", pixel_sigma, "> 0");
  require(ransac_threshold > 0.0, "ransac_threshold", ransac_threshold, "> 0");
  require(ransac_iterations >= 1, "ransac_iterations", ransac_iterations, ">= 1");
  require(ransac_confidence > 0.0 && ransac_confidence < 1.0, "ransac_confidence",
          ransac_confidence, "in (0, 1)");
  require(min_inliers >= 4, "min_inliers", min_inliers, ">= 4");
  require(min_disparity > 0.0, "min_disparity", min_disparity, "> 0");
  require(refine_iterations >= 1, "refine_iterations", refine_iterations, ">= 1");
  require(refine_chi2_gate > 0.0, "refine_chi2_gate", refine_chi2_gate, "> 0");
  require(failure_translation_sigma > 0.0, "failure_translation_sigma", failure_translation_sigma,
          "> 0");
  require(failure_rotation_sigma > 0.0, "failure_rotation_sigma", failure_rotation_sigma, "> 0");
  return problems;
}

std::optional<Eigen::Vector3d> triangulate(const StereoCamera& camera, const Eigen::Vector4d& uv,
                                           double min_disparity) {
  const double disparity = uv(0) - uv(2);
  if (!(disparity >= min_disparity)) return std::nullopt;
  const Rig rig(camera);
  const double z = rig.fx * rig.baseline / disparity;
  return Eigen::Vector3d((uv(0) - rig.cx) * z / rig.fx, (uv(1) - rig.cy) * z / rig.fy, z);
}

StereoVisualOdometry::StereoVisualOdometry(const StereoCamera& camera,
                                           const OdometryOptions& options)
    : camera_(camera), options_(options) {
  const std::vector<std::string> problems = options.validate();
  if (!problems.empty()) {
    std::string message = "invalid odometry options:";
    for (const std::string& problem : problems) message += " odometry." + problem + ";";
    throw FrontendError(message);
  }
}

MotionEstimate StereoVisualOdometry::estimate(int, std::span<const StereoObservation> previous,
                                              std::span<const StereoObservation> current) {
  const Rig rig(camera_);
  MotionEstimate estimate;
  const Eigen::Isometry3d T_body_cam = camera_.T_cam0_body.inverse();
  const auto fail = [&] {
    estimate.valid = false;
    estimate.T_previous_current = last_motion_;
    estimate.covariance =
        diagonal_covariance(options_.failure_translation_sigma, options_.failure_rotation_sigma);
    return estimate;
  };

  // 1. Correspondences: tracks in both frames (both lists are sorted by id), triangulated at k-1.
  std::vector<Correspondence> correspondences;
  auto it = current.begin();
  for (const StereoObservation& before : previous) {
    while (it != current.end() && it->id < before.id) ++it;
    if (it == current.end()) break;
    if (it->id != before.id) continue;
    const auto point = triangulate(camera_, before.uv, options_.min_disparity);
    if (!point) continue;
    Correspondence c;
    c.id = before.id;
    c.p_previous = *point;
    c.point_covariance = rig.point_covariance(before.uv, options_.pixel_sigma);
    c.measured = Eigen::Vector3d(it->uv(0), it->uv(1), it->uv(2));
    correspondences.push_back(c);
  }
  estimate.candidates = static_cast<int>(correspondences.size());
  if (estimate.candidates < options_.min_inliers) return fail();

  // 2. PnP + RANSAC: T_cam(k)_cam(k-1) from the points at k-1 and their left positions at k.
  std::vector<cv::Point3d> object_points;
  std::vector<cv::Point2d> image_points;
  for (const Correspondence& c : correspondences) {
    object_points.emplace_back(c.p_previous.x(), c.p_previous.y(), c.p_previous.z());
    image_points.emplace_back(c.measured(0), c.measured(1));
  }
  const cv::Matx33d K(rig.fx, 0.0, rig.cx, 0.0, rig.fy, rig.cy, 0.0, 0.0, 1.0);
  cv::Mat rotation_vector, translation;
  std::vector<int> ransac_inliers;
  const bool solved = cv::solvePnPRansac(
      object_points, image_points, K, cv::noArray(), rotation_vector, translation, false,
      options_.ransac_iterations, static_cast<float>(options_.ransac_threshold),
      options_.ransac_confidence, ransac_inliers, cv::SOLVEPNP_AP3P);
  estimate.ransac_inliers = static_cast<int>(ransac_inliers.size());
  if (!solved || estimate.ransac_inliers < options_.min_inliers) return fail();
  cv::Mat rotation_matrix;
  cv::Rodrigues(rotation_vector, rotation_matrix);
  Eigen::Isometry3d T_current_previous = Eigen::Isometry3d::Identity();
  for (int row = 0; row < 3; ++row) {
    for (int column = 0; column < 3; ++column) {
      T_current_previous.linear()(row, column) = rotation_matrix.at<double>(row, column);
    }
    T_current_previous.translation()(row) = translation.at<double>(row);
  }
  Eigen::Isometry3d T = lie::orthonormalized(T_current_previous.inverse());

  // 3. Weighted Gauss-Newton on the RANSAC inliers, then on every point inside the gate.
  std::vector<unsigned char> use(correspondences.size(), 0);
  for (const int index : ransac_inliers) use[index] = 1;
  Refinement refined =
      refine(rig, correspondences, use, T, options_.refine_iterations, options_.pixel_sigma);
  for (std::size_t index = 0; index < correspondences.size(); ++index) {
    use[index] =
        residual_chi2(rig, correspondences[index], refined.T_previous_current, options_.pixel_sigma,
                      nullptr, nullptr, nullptr) <= options_.refine_chi2_gate;
  }
  refined = refine(rig, correspondences, use, refined.T_previous_current,
                   options_.refine_iterations, options_.pixel_sigma);
  for (std::size_t index = 0; index < correspondences.size(); ++index) {
    const double chi2 = residual_chi2(rig, correspondences[index], refined.T_previous_current,
                                      options_.pixel_sigma, nullptr, nullptr, nullptr);
    if (!(chi2 <= options_.refine_chi2_gate))
      estimate.outliers.push_back(correspondences[index].id);
  }
  estimate.inliers = refined.used;
  if (estimate.inliers < options_.min_inliers) return fail();

  // 4. Covariance: inverse normal matrix, inflated by the residuals when they exceed the model;
  //    then into the body frame: T_body = A T_cam A^-1 (A = T_body_cam), xi_body = Ad(A) xi_cam.
  const int degrees_of_freedom = 3 * refined.used - 6;
  estimate.chi2_per_dof = refined.chi2 / std::max(degrees_of_freedom, 1);
  const Matrix6d camera_covariance =
      refined.information.ldlt().solve(Matrix6d::Identity()) * std::max(1.0, estimate.chi2_per_dof);
  if (!camera_covariance.allFinite()) return fail();
  const Matrix6d adjoint = lie::adjoint(T_body_cam);
  estimate.valid = true;
  estimate.T_previous_current =
      lie::orthonormalized(T_body_cam * refined.T_previous_current * camera_.T_cam0_body);
  estimate.covariance = adjoint * camera_covariance * adjoint.transpose();
  estimate.covariance = 0.5 * (estimate.covariance + estimate.covariance.transpose()).eval();
  last_motion_ = estimate.T_previous_current;
  return estimate;
}

FileOdometry::FileOdometry(std::vector<Eigen::Isometry3d> motions, const Matrix6d& covariance)
    : motions_(std::move(motions)), covariance_(covariance) {}

FileOdometry FileOdometry::read(const std::filesystem::path& file, double translation_sigma,
                                double rotation_sigma) {
  if (!(translation_sigma > 0.0 && rotation_sigma > 0.0)) {
    throw FrontendError(file.string() + ": odometry standard deviations must be > 0");
  }
  try {
    return FileOdometry(dataset::read_trajectory_kitti(file),
                        diagonal_covariance(translation_sigma, rotation_sigma));
  } catch (const std::runtime_error& error) {
    throw FrontendError(error.what());
  }
}

MotionEstimate FileOdometry::estimate(int frame, std::span<const StereoObservation>,
                                      std::span<const StereoObservation>) {
  if (frame < 1 || frame > size()) {
    throw FrontendError("odometry file: no motion for frame " + std::to_string(frame) +
                        " (it has " + std::to_string(size()) + " motions, for frames 1 to " +
                        std::to_string(size()) + ")");
  }
  MotionEstimate estimate;
  estimate.valid = true;
  estimate.T_previous_current = motions_[frame - 1];
  estimate.covariance = covariance_;
  return estimate;
}

}  // namespace concord::frontend

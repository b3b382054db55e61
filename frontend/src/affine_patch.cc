#include "affine_patch.h"

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <vector>

namespace concord::frontend {

namespace {

constexpr int kParameters = 6;
using DescentMatrix = Eigen::Matrix<float, Eigen::Dynamic, kParameters>;

/// Bilinear sample of an 8-bit image at (x, y); the caller keeps (x, y) inside [0, cols - 1) x
/// [0, rows - 1).
inline float sample(const cv::Mat& image, float x, float y) {
  const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  const float fx = x - static_cast<float>(x0), fy = y - static_cast<float>(y0);
  const unsigned char* row0 = image.ptr<unsigned char>(y0) + x0;
  const unsigned char* row1 = row0 + image.step[0];
  const float top = static_cast<float>(row0[0]) + fx * static_cast<float>(row0[1] - row0[0]);
  const float bottom = static_cast<float>(row1[0]) + fx * static_cast<float>(row1[1] - row1[0]);
  return top + fy * (bottom - top);
}

}  // namespace

bool AffineTemplate::prepare(const cv::Mat& image, const cv::Point2f& centre, WarpModel model,
                             int side) {
  valid_ = false;
  side_ = side;
  const int half = side / 2, count = side * side;
  // The template with a one-pixel rim for its gradients (bilinear at a sub-pixel centre).
  thread_local cv::Mat patch;
  cv::getRectSubPix(image, cv::Size(side + 2, side + 2), centre, patch, CV_32F);

  // Steepest-descent images of the parameters (dA11, dA12, dA21, dA22, dtx, dty), with the
  // brightness's gain and offset projected out: each is made orthogonal to the constant image
  // and to the (zero-mean) template, so the fit ignores a change of brightness.
  values_.resize(static_cast<std::size_t>(count));
  descent_.resize(static_cast<std::size_t>(count) * kParameters);
  Eigen::Map<DescentMatrix> descent(descent_.data(), count, kParameters);
  Eigen::Map<Eigen::VectorXf> values(values_.data(), count);
  for (int row = 0; row < side; ++row) {
    const float* above = patch.ptr<float>(row);
    const float* here = patch.ptr<float>(row + 1);
    const float* below = patch.ptr<float>(row + 2);
    const float y = static_cast<float>(row - half);
    for (int column = 0; column < side; ++column) {
      const float gx = 0.5f * (here[column + 2] - here[column]);
      const float gy = 0.5f * (below[column + 1] - above[column + 1]);
      const float x = static_cast<float>(column - half);
      const int index = row * side + column;
      descent.row(index) << gx * x, gx * y, gy * x, gy * y, gx, gy;
      values[index] = here[column + 1];
    }
  }
  values.array() -= values.mean();
  const float norm = values.squaredNorm();
  if (!(norm > 0.0f)) return false;
  template_norm_ = norm;
  const Eigen::Matrix<float, 1, kParameters> along_mean = descent.colwise().mean();
  const Eigen::Matrix<float, 1, kParameters> along_template =
      (values.transpose() * descent) / norm;
  descent -= Eigen::VectorXf::Ones(count) * along_mean + values * along_template;
  // The parameters fitted: a rectified pair's rows stay rows of the same height (dA21 = dA22 = 0).
  if (model == WarpModel::kRectifiedStereo) descent.middleCols<2>(2).setZero();

  const Eigen::Matrix<float, kParameters, kParameters> product = descent.transpose() * descent;
  cv::Matx<double, 6, 6> hessian;
  for (int p = 0; p < kParameters; ++p) {
    for (int q = 0; q < kParameters; ++q) hessian(p, q) = product(p, q);
  }
  if (model == WarpModel::kRectifiedStereo) {  // a parameter left out: its step is 0
    hessian(2, 2) = 1.0;
    hessian(3, 3) = 1.0;
  }
  if (cv::invert(hessian, inverse_, cv::DECOMP_CHOLESKY) == 0.0) return false;
  // A translation the patch cannot pin down (an edge, a flat patch) makes the fit meaningless.
  const double trace = hessian(4, 4) + hessian(5, 5);
  const double determinant = hessian(4, 4) * hessian(5, 5) - hessian(4, 5) * hessian(5, 4);
  if (determinant <= 1e-6 * trace * trace) return false;
  valid_ = true;
  return true;
}

bool AffineTemplate::align(const cv::Mat& image, AffineWarp& warp, int max_iterations,
                           double epsilon) const {
  if (!valid_) return false;
  const int side = side_, half = side / 2, count = side * side;
  const Eigen::Map<const DescentMatrix> descent(descent_.data(), count, kParameters);
  thread_local Floats errors;
  errors.resize(static_cast<std::size_t>(count));
  const Eigen::Map<const Eigen::VectorXf> error_vector(errors.data(), count);

  const float limit_x = static_cast<float>(image.cols - 1) - 1e-3f;
  const float limit_y = static_cast<float>(image.rows - 1) - 1e-3f;
  const float corner = static_cast<float>(half);
  double previous_moved = std::numeric_limits<double>::infinity();
  int growing = 0;
  for (int iteration = 0; iteration < max_iterations; ++iteration) {
    for (int row = 0; row < side; ++row) {
      const float y = static_cast<float>(row - half);
      const float x0 = static_cast<float>(-half);
      // Along a row of the patch the warped position moves by the first column of A.
      float u = warp.A(0, 0) * x0 + warp.A(0, 1) * y + warp.t.x;
      float v = warp.A(1, 0) * x0 + warp.A(1, 1) * y + warp.t.y;
      const float du = warp.A(0, 0), dv = warp.A(1, 0);
      const float u_end = u + du * static_cast<float>(side - 1);
      const float v_end = v + dv * static_cast<float>(side - 1);
      if (!(std::min(u, u_end) >= 0.0f && std::min(v, v_end) >= 0.0f &&
            std::max(u, u_end) < limit_x && std::max(v, v_end) < limit_y)) {
        return false;
      }
      // The template's own mean and gain are projected out of the descent images, so the
      // error needs no normalization.
      float* error = errors.data() + static_cast<std::ptrdiff_t>(row) * side;
      const float* value = values_.data() + static_cast<std::ptrdiff_t>(row) * side;
      for (int column = 0; column < side; ++column, u += du, v += dv) {
        error[column] = sample(image, u, v) - value[column];
      }
    }
    const Eigen::Matrix<float, kParameters, 1> b = descent.transpose() * error_vector;
    cv::Vec<double, 6> step;
    for (int p = 0; p < kParameters; ++p) {
      double sum = 0.0;
      for (int q = 0; q < kParameters; ++q) sum += inverse_(p, q) * b[q];
      step[p] = sum;
    }
    // Inverse composition: W <- W o dW^-1, dW(x) = (I + dA) x + dt.
    const cv::Matx22f increment(1.0f + static_cast<float>(step[0]), static_cast<float>(step[1]),
                                static_cast<float>(step[2]), 1.0f + static_cast<float>(step[3]));
    const float increment_determinant = cv::determinant(increment);
    if (!(std::abs(increment_determinant) > 1e-6f)) return false;
    const cv::Matx22f inverse_increment = increment.inv();
    const cv::Vec2f dt(static_cast<float>(step[4]), static_cast<float>(step[5]));
    warp.A = warp.A * inverse_increment;
    const cv::Vec2f shift = warp.A * dt;
    warp.t -= cv::Point2f(shift[0], shift[1]);
    if (!std::isfinite(warp.t.x) || !std::isfinite(warp.t.y)) return false;
    // How far the step moved the patch's corners (the largest of the affine and shift parts).
    const double moved = std::abs(step[4]) + std::abs(step[5]) +
                         corner * (std::abs(step[0]) + std::abs(step[1]) + std::abs(step[2]) +
                                   std::abs(step[3]));
    if (moved < epsilon) {
      // The residual's variance with the brightness's offset (the mean) and gain (along the
      // zero-mean template) projected out, over the degrees of freedom the fit leaves.
      const Eigen::Map<const Eigen::VectorXf> template_values(values_.data(), count);
      const double sum = error_vector.sum();
      const double along = error_vector.dot(template_values);
      const double residual = static_cast<double>(error_vector.squaredNorm()) - sum * sum / count -
                              along * along / template_norm_;
      const double variance = std::max(residual, 0.0) / (count - kParameters - 2);
      warp.position_variance =
          static_cast<float>(variance * 0.5 * (inverse_(4, 4) + inverse_(5, 5)));
      return true;
    }
    // A fit whose steps stop shrinking is not converging (a patch across a depth edge, whose
    // two views no warp relates): give up early.
    growing = moved >= previous_moved ? growing + 1 : 0;
    if (growing >= 2) return false;
    previous_moved = moved;
  }
  return false;
}

std::size_t AffineTemplate::bytes() const {
  return (values_.capacity() + descent_.capacity()) * sizeof(float);
}

bool align_affine(const cv::Mat& templ, const cv::Point2f& centre, const cv::Mat& image,
                  AffineWarp& warp, const AffineAlignmentOptions& options) {
  thread_local AffineTemplate scratch;
  return scratch.prepare(templ, centre, options.model, options.side) &&
         scratch.align(image, warp, options.max_iterations, options.epsilon);
}

}  // namespace concord::frontend

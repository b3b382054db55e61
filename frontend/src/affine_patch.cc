#include "affine_patch.h"

#include <array>
#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <vector>

namespace concord::frontend {

namespace {

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

bool align_affine(const cv::Mat& templ, const cv::Point2f& centre, const cv::Mat& image,
                  AffineWarp& warp, const AffineAlignmentOptions& options) {
  const int side = options.side, half = side / 2, count = side * side;
  // The template with a one-pixel rim for its gradients (bilinear at a sub-pixel centre).
  thread_local cv::Mat patch;
  cv::getRectSubPix(templ, cv::Size(side + 2, side + 2), centre, patch, CV_32F);

  // Steepest-descent images of the parameters (dA11, dA12, dA21, dA22, dtx, dty), with the
  // brightness's gain and offset projected out: each is made orthogonal to the constant image
  // and to the (zero-mean) template, so the fit ignores a change of brightness.
  thread_local std::vector<std::array<float, 6>> descent;
  thread_local std::vector<float> values;
  descent.resize(static_cast<std::size_t>(count));
  values.resize(static_cast<std::size_t>(count));
  double mean = 0.0;
  for (int row = 0; row < side; ++row) {
    const float* above = patch.ptr<float>(row);
    const float* here = patch.ptr<float>(row + 1);
    const float* below = patch.ptr<float>(row + 2);
    const float y = static_cast<float>(row - half);
    for (int column = 0; column < side; ++column) {
      const float gx = 0.5f * (here[column + 2] - here[column]);
      const float gy = 0.5f * (below[column + 1] - above[column + 1]);
      const float x = static_cast<float>(column - half);
      const std::size_t index = static_cast<std::size_t>(row * side + column);
      descent[index] = {gx * x, gx * y, gy * x, gy * y, gx, gy};
      values[index] = here[column + 1];
      mean += here[column + 1];
    }
  }
  mean /= count;
  double norm = 0.0;
  for (float& value : values) {
    value -= static_cast<float>(mean);
    norm += static_cast<double>(value) * value;
  }
  if (norm <= 0.0) return false;
  std::array<double, 6> along_mean{}, along_template{};
  for (std::size_t index = 0; index < descent.size(); ++index) {
    for (int p = 0; p < 6; ++p) {
      along_mean[p] += descent[index][p];
      along_template[p] += static_cast<double>(descent[index][p]) * values[index];
    }
  }
  for (int p = 0; p < 6; ++p) {
    along_mean[p] /= count;
    along_template[p] /= norm;
  }
  // The parameters fitted: a rectified pair's rows stay rows of the same height (dA21 = dA22 = 0).
  const bool stereo = options.model == WarpModel::kRectifiedStereo;
  const std::array<bool, 6> active{true, true, !stereo, !stereo, true, true};
  cv::Matx<double, 6, 6> hessian = cv::Matx<double, 6, 6>::zeros();
  for (std::size_t index = 0; index < descent.size(); ++index) {
    std::array<float, 6>& d = descent[index];
    for (int p = 0; p < 6; ++p) {
      d[p] = active[p] ? d[p] - static_cast<float>(along_mean[p] + along_template[p] * values[index])
                       : 0.0f;
    }
    for (int p = 0; p < 6; ++p) {
      for (int q = p; q < 6; ++q) hessian(p, q) += static_cast<double>(d[p]) * d[q];
    }
  }
  for (int p = 0; p < 6; ++p) {
    if (!active[p]) hessian(p, p) = 1.0;  // a parameter left out: its step is 0
    for (int q = 0; q < p; ++q) hessian(p, q) = hessian(q, p);
  }
  cv::Matx<double, 6, 6> inverse;
  if (cv::invert(hessian, inverse, cv::DECOMP_CHOLESKY) == 0.0) return false;
  // A translation the patch cannot pin down (an edge, a flat patch) makes the fit meaningless.
  const cv::Matx22d translation_block(hessian(4, 4), hessian(4, 5), hessian(5, 4), hessian(5, 5));
  const double trace = translation_block(0, 0) + translation_block(1, 1);
  const double determinant = cv::determinant(translation_block);
  if (determinant <= 1e-6 * trace * trace) return false;

  const float limit_x = static_cast<float>(image.cols - 1) - 1e-3f;
  const float limit_y = static_cast<float>(image.rows - 1) - 1e-3f;
  const float corner = static_cast<float>(half);
  double previous_moved = std::numeric_limits<double>::infinity();
  int growing = 0;
  for (int iteration = 0; iteration < options.max_iterations; ++iteration) {
    std::array<float, 6> b{};
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
      const std::size_t first = static_cast<std::size_t>(row * side);
      for (int column = 0; column < side; ++column, u += du, v += dv) {
        const std::size_t index = first + static_cast<std::size_t>(column);
        // The template's own mean and gain are projected out of the descent images, so the
        // error needs no normalization.
        const float error = sample(image, u, v) - values[index];
        const std::array<float, 6>& d = descent[index];
        for (int p = 0; p < 6; ++p) b[p] += d[p] * error;
      }
    }
    cv::Vec<double, 6> step;
    for (int p = 0; p < 6; ++p) {
      double sum = 0.0;
      for (int q = 0; q < 6; ++q) sum += inverse(p, q) * b[q];
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
    if (moved < options.epsilon) return true;
    // A fit whose steps stop shrinking is not converging (a patch across a depth edge, whose
    // two views no warp relates): give up early.
    growing = moved >= previous_moved ? growing + 1 : 0;
    if (growing >= 2) return false;
    previous_moved = moved;
  }
  return false;
}

}  // namespace concord::frontend

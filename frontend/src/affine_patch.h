#pragma once
/// \file
/// Private to the front-end: sub-pixel alignment of an image patch under an affine warp with a
/// gain and an offset of brightness (inverse compositional Lucas-Kanade with the brightness
/// projected out; Baker and Matthews, "Lucas-Kanade 20 years on", parts 1 and 3).
///
/// cv::calcOpticalFlowPyrLK fits a translation only: a patch that grows, shrinks or shears
/// between the two images (a robot driving towards a surface; the two views of a slanted
/// surface) is then matched with a bias that depends on where the patch's texture lies, and a
/// track that follows it frame to frame adds those biases up. cv::findTransformECC fits the
/// affine warp but costs about a millisecond a patch, over a hundred milliseconds a frame for
/// the tracker's patches. Here the template's part (its descent images and the inverse of their
/// Gauss-Newton matrix) is computed once, in an AffineTemplate that a tracker may keep for as
/// long as it aligns the same patch (an anchored track, frame after frame); an iteration then
/// costs a bilinear sample and six dot products a pixel.

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <vector>

namespace concord::frontend {

/// x_image = A x_patch + t, with x_patch relative to the patch's centre: t is where the centre
/// lands.
struct AffineWarp {
  cv::Matx22f A = cv::Matx22f::eye();
  cv::Point2f t;
  /// After a converged AffineTemplate::align: the Lucas-Kanade variance of t, pixels^2 per axis
  /// (the final residual's variance, brightness gain and offset projected out of it, times the
  /// mean of the translation's two diagonal entries of the inverse Gauss-Newton matrix): how well
  /// the patch's texture pinned the match down.
  float position_variance = 0.0f;
};

/// Which warps are fitted.
enum class WarpModel {
  /// Any affine warp (six parameters): a patch followed over time.
  kAffine,
  /// The two views of a rectified stereo pair: a row maps to a row of the same height
  /// (u' = a u + b v + c, v' = v + d; four parameters). A slanted surface scales and shears its
  /// patch along the rows only.
  kRectifiedStereo,
};

struct AffineAlignmentOptions {
  WarpModel model = WarpModel::kAffine;
  /// Patch side, pixels (odd).
  int side = 15;
  int max_iterations = 15;
  /// Converged when the step moves the patch's corners by less than this many pixels.
  double epsilon = 0.02;
};

/// The template's part of the alignment: a side x side patch of an 8-bit grey image around a
/// sub-pixel centre, its brightness-free descent images for the model's parameters and the
/// inverse of their Gauss-Newton matrix. Reusable: prepare() overwrites it in place.
class AffineTemplate {
 public:
  /// Prepares the patch of `image` centred on `centre`. False (and valid() false) when the patch
  /// has too little texture to fit the model's warp, or no texture at all.
  bool prepare(const cv::Mat& image, const cv::Point2f& centre, WarpModel model, int side);

  bool valid() const { return valid_; }

  /// Aligns the patch into `image` (8-bit grey) starting from `warp`, which holds the result.
  /// False when the template is not valid, the patch leaves `image`, or the fit does not
  /// converge within max_iterations (or its steps stop shrinking).
  bool align(const cv::Mat& image, AffineWarp& warp, int max_iterations, double epsilon) const;

  /// Heap bytes held (for the memory a tracker's templates take).
  std::size_t bytes() const;

 private:
  int side_ = 0;
  bool valid_ = false;
  /// Storage aligned to Eigen's widest packet: Eigen's sums and products over a buffer start
  /// their vector loop where the address allows, so over malloc's 16-byte alignment a build with
  /// 32-byte packets (CONCORD_ARCH=x86-64-v3) summed in an order that changed from run to run.
  using Floats = std::vector<float, Eigen::aligned_allocator<float>>;
  /// The zero-mean template, side x side row by row, and its squared norm.
  Floats values_;
  double template_norm_ = 0.0;
  /// The six descent images, one after the other (a count x 6 column-major matrix).
  Floats descent_;
  /// Inverse of descent^T descent (a parameter left out by the model has a zero row and column).
  cv::Matx<double, 6, 6> inverse_;
};

/// Aligns the side x side patch of `templ` (8-bit grey) centred on `centre` into `image` (8-bit
/// grey), starting from `warp`, which holds the result. False when the patch has too little
/// texture to fit the warp, leaves `image`, or the fit does not converge. (AffineTemplate's
/// prepare and align in one call.)
bool align_affine(const cv::Mat& templ, const cv::Point2f& centre, const cv::Mat& image,
                  AffineWarp& warp, const AffineAlignmentOptions& options);

}  // namespace concord::frontend

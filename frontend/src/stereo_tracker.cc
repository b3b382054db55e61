#include "concord/frontend/stereo_tracker.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <opencv2/calib3d.hpp>
#include <opencv2/features2d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>
#include <optional>
#include <unordered_set>
#include <vector>

#include "affine_patch.h"
#include "row_search.h"
#include "concord/frontend/sequence.h"
#include "sample_median.h"
#include "text_lines.h"

namespace concord::frontend {

namespace {

/// Half side of the patch of the coarse stereo search, pixels at half resolution.
constexpr int kSearchRadius = 4;

/// 1.4826 * median absolute deviation / sqrt(2): the per-coordinate standard deviation behind a
/// sample of differences of two equally noisy coordinates.
double robust_sigma_of_differences(std::vector<double> differences) {
  if (differences.size() < 10) return 0.0;
  const double centre = median_of(differences);
  for (double& value : differences) value = std::abs(value - centre);
  return 1.4826 * median_of(differences) / std::sqrt(2.0);
}

/// Tracks whose median flow predicts the next frame's (fewer: no prediction).
constexpr std::size_t kMinFlowTracks = 16;

/// An alignment variance no alignment measured (TrackedFrame::alignment_variances).
constexpr float kUnmeasured = std::numeric_limits<float>::quiet_NaN();

class Klt {
 public:
  Klt(const TrackerOptions& options, int window)
      : window_(window, window),
        criteria_(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, options.klt_iterations,
                  options.klt_epsilon) {}

  /// Tracks `from` (in the image of `from_pyramid`) into the image of `to_pyramid`, starting at
  /// `to` (which is overwritten). status[i] is 0 where it failed.
  void track(const std::vector<cv::Mat>& from_pyramid, const std::vector<cv::Mat>& to_pyramid,
             const std::vector<cv::Point2f>& from, std::vector<cv::Point2f>& to, int levels,
             std::vector<unsigned char>& status) const {
    status.assign(from.size(), 0);
    if (from.empty()) return;
    std::vector<float> errors;
    cv::calcOpticalFlowPyrLK(from_pyramid, to_pyramid, from, to, status, errors, window_, levels,
                             criteria_, cv::OPTFLOW_USE_INITIAL_FLOW);
  }

 private:
  cv::Size window_;
  cv::TermCriteria criteria_;
};

/// Level `level` of a pyramid built by cv::buildOpticalFlowPyramid with derivatives (images and
/// gradients interleave).
const cv::Mat& pyramid_image(const std::vector<cv::Mat>& pyramid, int level) {
  return pyramid[std::min<std::size_t>(2 * static_cast<std::size_t>(level), pyramid.size() - 2)];
}

/// The scratch template of the stereo refinement (the left patch of this frame, aligned once).
AffineTemplate& stereo_patch() {
  thread_local AffineTemplate patch;
  return patch;
}

double distance(const cv::Point2f& a, const cv::Point2f& b) {
  return std::hypot(static_cast<double>(a.x - b.x), static_cast<double>(a.y - b.y));
}

}  // namespace

std::vector<std::string> TrackerOptions::validate() const {
  std::vector<std::string> problems;
  const auto require = [&](bool ok, const std::string& field, double value, const char* rule) {
    if (!ok) problems.push_back(text::problem(field, value, rule));
  };
  require(target_features >= 1, "target_features", target_features, ">= 1");
  require(grid_columns >= 1 && grid_columns <= 64, "grid_columns", grid_columns, "in [1, 64]");
  require(grid_rows >= 1 && grid_rows <= 64, "grid_rows", grid_rows, "in [1, 64]");
  require(fast_threshold >= 1 && fast_threshold <= 255, "fast_threshold", fast_threshold,
          "in [1, 255]");
  require(min_feature_distance >= 1.0, "min_feature_distance", min_feature_distance, ">= 1");
  require(border >= 0, "border", border, ">= 0");
  require(klt_window >= 5 && klt_window % 2 == 1, "klt_window", klt_window, "odd and >= 5");
  require(stereo_klt_window >= 5 && stereo_klt_window % 2 == 1, "stereo_klt_window",
          stereo_klt_window, "odd and >= 5");
  require(temporal_pyramid_levels >= 0 && temporal_pyramid_levels <= 8, "temporal_pyramid_levels",
          temporal_pyramid_levels, "in [0, 8]");
  require(stereo_pyramid_levels >= 0 && stereo_pyramid_levels <= 8, "stereo_pyramid_levels",
          stereo_pyramid_levels, "in [0, 8]");
  require(klt_iterations >= 1, "klt_iterations", klt_iterations, ">= 1");
  require(klt_epsilon > 0.0, "klt_epsilon", klt_epsilon, "> 0");
  require(epipolar_tolerance > 0.0, "epipolar_tolerance", epipolar_tolerance, "> 0");
  require(min_disparity >= 0.0, "min_disparity", min_disparity, ">= 0");
  require(max_disparity > min_disparity, "max_disparity", max_disparity, "> min_disparity");
  require(circular_tolerance > 0.0, "circular_tolerance", circular_tolerance, "> 0");
  require(ransac_threshold > 0.0, "ransac_threshold", ransac_threshold, "> 0");
  require(ransac_confidence > 0.0 && ransac_confidence < 1.0, "ransac_confidence",
          ransac_confidence, "in (0, 1)");
  require(ransac_min_parallax >= 0.0, "ransac_min_parallax", ransac_min_parallax, ">= 0");
  require(anchor_frames >= 0 && anchor_frames <= 64, "anchor_frames", anchor_frames, "in [0, 64]");
  require(affine_window >= 7 && affine_window % 2 == 1, "affine_window", affine_window,
          "odd and >= 7");
  require(affine_tolerance > 0.0, "affine_tolerance", affine_tolerance, "> 0");
  return problems;
}

void StereoTracker::Tracks::keep(const std::vector<unsigned char>& keep_mask) {
  std::size_t kept = 0;
  for (std::size_t index = 0; index < ids.size(); ++index) {
    if (!keep_mask[index]) continue;
    ids[kept] = ids[index];
    left[kept] = left[index];
    right[kept] = right[index];
    lengths[kept] = lengths[index];
    anchor_frames[kept] = anchor_frames[index];
    anchors[kept] = anchors[index];
    temporal_warps[kept] = temporal_warps[index];
    stereo_warps[kept] = stereo_warps[index];
    variances[kept] = variances[index];
    ++kept;
  }
  ids.resize(kept);
  left.resize(kept);
  right.resize(kept);
  lengths.resize(kept);
  variances.resize(kept);
  anchor_frames.resize(kept);
  anchors.resize(kept);
  temporal_warps.resize(kept);
  stereo_warps.resize(kept);
}

void StereoTracker::Tracks::sort_by_id() {
  std::vector<std::size_t> order(ids.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::stable_sort(order.begin(), order.end(),
                   [&](std::size_t a, std::size_t b) { return ids[a] < ids[b]; });
  const auto permute = [&](auto& values) {
    auto sorted = values;
    for (std::size_t index = 0; index < order.size(); ++index) sorted[index] = values[order[index]];
    values = std::move(sorted);
  };
  permute(ids);
  permute(left);
  permute(right);
  permute(lengths);
  permute(anchor_frames);
  permute(anchors);
  permute(temporal_warps);
  permute(stereo_warps);
  permute(variances);
}

StereoTracker::StereoTracker(const TrackerOptions& options) : options_(options) {
  const std::vector<std::string> problems = options.validate();
  if (!problems.empty()) {
    std::string message = "invalid tracker options:";
    for (const std::string& problem : problems) message += " tracker." + problem + ";";
    throw FrontendError(message);
  }
}

bool StereoTracker::inside(const cv::Point2f& point, const cv::Size& size) const {
  const float border = static_cast<float>(options_.border);
  return point.x >= border && point.y >= border && point.x < size.width - 1 - border &&
         point.y < size.height - 1 - border;
}

bool StereoTracker::on_row_in_range(const cv::Point2f& left, const cv::Point2f& right) const {
  const double disparity = left.x - right.x;
  return std::abs(left.y - right.y) <= options_.epipolar_tolerance &&
         disparity >= options_.min_disparity && disparity <= options_.max_disparity;
}

TrackedFrame StereoTracker::track(const cv::Mat& left, const cv::Mat& right) {
  if (left.empty() || right.empty() || left.size() != right.size() || left.type() != CV_8UC1 ||
      right.type() != CV_8UC1) {
    throw FrontendError("StereoTracker::track: expects two 8-bit grey images of one size");
  }
  const int side = std::max(options_.klt_window, options_.stereo_klt_window);
  const cv::Size window(side, side);
  const int levels = std::max(options_.temporal_pyramid_levels, options_.stereo_pyramid_levels);
  // The pyramids are built into the buffers of the frame before last (no allocation per frame).
  std::vector<cv::Mat>& left_pyramid = spare_left_pyramid_;
  std::vector<cv::Mat>& right_pyramid = spare_right_pyramid_;
  cv::buildOpticalFlowPyramid(left, left_pyramid, window, levels, true, cv::BORDER_REFLECT_101,
                              cv::BORDER_CONSTANT, false);
  cv::buildOpticalFlowPyramid(right, right_pyramid, window, levels, true, cv::BORDER_REFLECT_101,
                              cv::BORDER_CONSTANT, false);
  if (previous_left_pyramid_.empty()) {
    // The first frame also fills the buffers the second frame will be built into: their first
    // allocation (page faults on a few megabytes) is then part of the first frame, which starts
    // every track anyway, not a cost the second frame alone pays.
    cv::buildOpticalFlowPyramid(left, previous_left_pyramid_, window, levels, true,
                                cv::BORDER_REFLECT_101, cv::BORDER_CONSTANT, false);
    cv::buildOpticalFlowPyramid(right, previous_right_pyramid_, window, levels, true,
                                cv::BORDER_REFLECT_101, cv::BORDER_CONSTANT, false);
  }

  TrackedFrame out;
  out.frame = frame_;
  out.counts.previous = static_cast<int>(tracks_.size());
  if (!tracks_.ids.empty() && !previous_left_pyramid_.empty()) {
    continue_tracks(left_pyramid, right_pyramid, left.size(), out);
  }
  add_features(left, left_pyramid, right_pyramid, out);

  out.observations.reserve(tracks_.size());
  for (std::size_t index = 0; index < tracks_.size(); ++index) {
    StereoObservation observation;
    observation.id = tracks_.ids[index];
    observation.uv = Eigen::Vector4d(tracks_.left[index].x, tracks_.left[index].y,
                                     tracks_.right[index].x, tracks_.right[index].y);
    out.observations.push_back(observation);
  }
  out.track_lengths = tracks_.lengths;
  out.alignment_variances = tracks_.variances;
  std::swap(previous_left_pyramid_, spare_left_pyramid_);
  std::swap(previous_right_pyramid_, spare_right_pyramid_);
  ++frame_;
  return out;
}

void StereoTracker::continue_tracks(const std::vector<cv::Mat>& left_pyramid,
                                    const std::vector<cv::Mat>& right_pyramid, const cv::Size& size,
                                    TrackedFrame& out) {
  const Klt temporal(options_, options_.klt_window);
  const Klt stereo(options_, options_.stereo_klt_window);
  const std::size_t count = tracks_.size();
  std::vector<unsigned char> keep(count, 1), status;
  std::vector<double> row_differences;

  // 1. Temporal KLT, left k-1 -> left k, starting where the previous frame's median flow takes
  //    each track (a constant-velocity guess: in a fast turn the image moves further in a frame
  //    than the pyramid's reach from where the track was). A track the guess loses is tracked
  //    again from where it was (the motion changed).
  std::vector<cv::Point2f> left_now = tracks_.left;
  for (cv::Point2f& point : left_now) point += predicted_flow_;
  std::fill(tracks_.variances.begin(), tracks_.variances.end(),
            std::array<float, 2>{kUnmeasured, kUnmeasured});
  temporal.track(previous_left_pyramid_, left_pyramid, tracks_.left, left_now,
                 options_.temporal_pyramid_levels, status);
  if (predicted_flow_ != cv::Point2f(0.0f, 0.0f)) {
    std::vector<std::size_t> lost;
    std::vector<cv::Point2f> from, to;
    for (std::size_t index = 0; index < count; ++index) {
      if (status[index] && inside(left_now[index], size)) continue;
      lost.push_back(index);
      from.push_back(tracks_.left[index]);
    }
    if (!lost.empty()) {
      to = from;
      std::vector<unsigned char> again;
      temporal.track(previous_left_pyramid_, left_pyramid, from, to,
                     options_.temporal_pyramid_levels, again);
      for (std::size_t position = 0; position < lost.size(); ++position) {
        left_now[lost[position]] = to[position];
        status[lost[position]] = again[position];
      }
    }
  }
  if (hook_) hook_(MatchStage::kTemporal, left_now);
  for (std::size_t index = 0; index < count; ++index) {
    if (!status[index] || !inside(left_now[index], size)) {
      keep[index] = 0;
      ++out.counts.lost_temporal;
    }
  }

  // 1b. Anchored tracking: the temporal match refined by aligning the track's patch as it was
  // at its anchor (affine); a track whose anchor is too old or whose alignment fails is anchored
  // afresh below, under a new id.
  const bool anchoring = options_.anchor_frames > 0;
  std::vector<unsigned char> anchored(count, 0);
  if (anchoring) {
    for (std::size_t index = 0; index < count; ++index) {
      if (!keep[index] || !tracks_.anchors[index] ||
          frame_ - tracks_.anchor_frames[index] >= options_.anchor_frames) {
        continue;
      }
      anchored[index] = refine_affine(*tracks_.anchors[index], left_pyramid[0], left_now[index],
                                      tracks_.temporal_warps[index], tracks_.variances[index][0])
                            ? 1
                            : 0;
    }
  }

  // 2. Stereo KLT, left k -> right k, starting from the previous disparity.
  std::vector<cv::Point2f> right_now(count);
  for (std::size_t index = 0; index < count; ++index) {
    right_now[index] = left_now[index] - (tracks_.left[index] - tracks_.right[index]);
  }
  stereo.track(left_pyramid, right_pyramid, left_now, right_now, options_.stereo_pyramid_levels,
               status);
  if (hook_) hook_(MatchStage::kStereo, right_now);
  for (std::size_t index = 0; index < count; ++index) {
    if (keep[index] && (!status[index] || !inside(right_now[index], size))) {
      keep[index] = 0;
      ++out.counts.lost_stereo;
    }
  }

  // 2b. The stereo match refined by aligning the left patch into the right image with the
  // rectified pair's warp (rows to rows); where the alignment fails the KLT match stands.
  if (options_.stereo_affine) {
    AffineTemplate& patch = stereo_patch();
    for (std::size_t index = 0; index < count; ++index) {
      if (keep[index] && patch.prepare(left_pyramid[0], left_now[index],
                                       WarpModel::kRectifiedStereo, options_.affine_window)) {
        refine_affine(patch, right_pyramid[0], right_now[index], tracks_.stereo_warps[index],
                      tracks_.variances[index][1]);
      }
    }
  }

  // 3. Circular matching: right k -> right k-1 must land on the track's right position at k-1.
  std::vector<cv::Point2f> right_back = tracks_.right;
  temporal.track(right_pyramid, previous_right_pyramid_, right_now, right_back,
                 options_.temporal_pyramid_levels, status);
  for (std::size_t index = 0; index < count; ++index) {
    if (!keep[index]) continue;
    if (!status[index] ||
        distance(right_back[index], tracks_.right[index]) > options_.circular_tolerance) {
      keep[index] = 0;
      ++out.counts.rejected_circular;
      continue;
    }
    row_differences.push_back(left_now[index].y - right_now[index].y);
  }

  // 4. Epipolar check on the rectified pair: same row, disparity in range.
  for (std::size_t index = 0; index < count; ++index) {
    if (!keep[index]) continue;
    if (!on_row_in_range(left_now[index], right_now[index])) {
      keep[index] = 0;
      ++out.counts.rejected_epipolar;
    }
  }

  // 5. RANSAC on the temporal matches (left k-1 -> left k), when there is parallax to fit.
  std::vector<std::size_t> survivors;
  std::vector<cv::Point2f> before, after;
  std::vector<double> flows;
  for (std::size_t index = 0; index < count; ++index) {
    if (!keep[index]) continue;
    survivors.push_back(index);
    before.push_back(tracks_.left[index]);
    after.push_back(left_now[index]);
    flows.push_back(distance(tracks_.left[index], left_now[index]));
  }
  out.median_flow = median_of(flows);
  if (survivors.size() >= 16 && out.median_flow >= options_.ransac_min_parallax) {
    std::vector<unsigned char> inliers;
    const cv::Mat fundamental =
        cv::findFundamentalMat(before, after, cv::FM_RANSAC, options_.ransac_threshold,
                               options_.ransac_confidence, inliers);
    if (!fundamental.empty() && inliers.size() == survivors.size()) {
      for (std::size_t position = 0; position < survivors.size(); ++position) {
        if (!inliers[position]) {
          keep[survivors[position]] = 0;
          ++out.counts.rejected_ransac;
        }
      }
    }
  }

  // The flow the next frame starts from: the median, per axis, of the tracks kept.
  std::vector<double> flow_x, flow_y;
  for (std::size_t index = 0; index < count; ++index) {
    if (!keep[index]) continue;
    flow_x.push_back(left_now[index].x - tracks_.left[index].x);
    flow_y.push_back(left_now[index].y - tracks_.left[index].y);
  }
  predicted_flow_ = flow_x.size() >= kMinFlowTracks
                        ? cv::Point2f(static_cast<float>(median_of(flow_x)),
                                      static_cast<float>(median_of(flow_y)))
                        : cv::Point2f(0.0f, 0.0f);

  tracks_.left = std::move(left_now);
  tracks_.right = std::move(right_now);
  for (int& length : tracks_.lengths) ++length;
  if (anchoring) {
    for (std::size_t index = 0; index < count; ++index) {
      if (!keep[index] || anchored[index]) continue;
      // Anchored afresh where it is: a new track as far as the estimator is concerned.
      tracks_.ids[index] = next_id_++;
      tracks_.lengths[index] = 1;
      tracks_.anchor_frames[index] = frame_;
      tracks_.anchors[index] = make_anchor(left_pyramid[0], tracks_.left[index]);
      tracks_.temporal_warps[index] = cv::Matx22f::eye();
      tracks_.variances[index][0] = kUnmeasured;  // its anchor, from now on
      ++out.counts.reanchored;
    }
  }
  tracks_.keep(keep);
  // Tracks go out sorted by id (the visual odometry pairs frames by id): those anchored afresh,
  // with the newest ids, move to the end.
  if (out.counts.reanchored > 0) tracks_.sort_by_id();
  out.counts.continued = static_cast<int>(tracks_.size());
  out.row_noise_sigma = robust_sigma_of_differences(std::move(row_differences));
}

void StereoTracker::add_features(const cv::Mat& left, const std::vector<cv::Mat>& left_pyramid,
                                 const std::vector<cv::Mat>& right_pyramid, TrackedFrame& out) {
  const int missing = options_.target_features - static_cast<int>(tracks_.size());
  if (missing <= 0) return;
  const cv::Size size = left.size();
  const int columns = options_.grid_columns, rows = options_.grid_rows;
  const int cells = columns * rows;
  const int per_cell = (options_.target_features + cells - 1) / cells;
  const auto cell_of = [&](const cv::Point2f& point) {
    const int column = std::clamp(static_cast<int>(point.x * columns / size.width), 0, columns - 1);
    const int row = std::clamp(static_cast<int>(point.y * rows / size.height), 0, rows - 1);
    return row * columns + column;
  };

  // Occupancy: tracked features block a disc of min_feature_distance around them.
  free_mask_.create(size, CV_8UC1);
  free_mask_.setTo(cv::Scalar(255));
  std::vector<int> in_cell(cells, 0);
  const int radius = static_cast<int>(std::ceil(options_.min_feature_distance));
  for (const cv::Point2f& point : tracks_.left) {
    cv::circle(free_mask_, point, radius, cv::Scalar(0), cv::FILLED);
    ++in_cell[cell_of(point)];
  }

  // FAST on the cells, emptiest first, strongest corners first, up to twice a cell's share of the
  // target (corners on weak texture often fail the stereo checks below, and textureless cells
  // leave their share to others); three times the missing tracks (at least 30) are matched.
  struct Candidate {
    cv::Point2f point;
    int cell = 0;
    /// Features the cell would hold with this one: emptier cells are served first.
    int rank = 0;
  };
  const std::size_t matched = static_cast<std::size_t>(std::max(3 * missing, 30));
  // A cell may offer up to twice its share; three times when the tracker starts from nothing.
  const int cell_limit = (tracks_.ids.empty() ? 3 : 2) * per_cell;
  std::vector<int> cell_order(cells);
  std::iota(cell_order.begin(), cell_order.end(), 0);
  std::stable_sort(cell_order.begin(), cell_order.end(),
                   [&](int a, int b) { return in_cell[a] < in_cell[b]; });
  std::vector<Candidate> candidates;
  const int cell_width = (size.width + columns - 1) / columns;
  const int cell_height = (size.height + rows - 1) / rows;
  std::vector<cv::KeyPoint> keypoints;
  for (const int cell : cell_order) {
    if (candidates.size() >= matched || in_cell[cell] >= cell_limit) break;
    const int row = cell / columns, column = cell % columns;
    const cv::Rect rect =
        cv::Rect(column * cell_width, row * cell_height, cell_width, cell_height) &
        cv::Rect(0, 0, size.width, size.height);
    keypoints.clear();
    cv::FAST(left(rect), keypoints, options_.fast_threshold, true);
    std::sort(keypoints.begin(), keypoints.end(),
              [](const cv::KeyPoint& a, const cv::KeyPoint& b) { return a.response > b.response; });
    int rank = in_cell[cell];
    for (const cv::KeyPoint& keypoint : keypoints) {
      if (rank >= cell_limit) break;
      const cv::Point2f point(keypoint.pt.x + static_cast<float>(rect.x),
                              keypoint.pt.y + static_cast<float>(rect.y));
      if (!inside(point, size)) continue;
      if (!free_mask_.at<unsigned char>(cvRound(point.y), cvRound(point.x))) continue;
      cv::circle(free_mask_, point, radius, cv::Scalar(0), cv::FILLED);
      candidates.push_back({point, cell, rank++});
    }
  }
  std::stable_sort(candidates.begin(), candidates.end(),
                   [](const Candidate& a, const Candidate& b) { return a.rank < b.rank; });
  if (candidates.size() > matched) candidates.resize(matched);
  out.counts.detected = static_cast<int>(candidates.size());
  if (candidates.empty()) return;

  // Stereo match left -> right: a coarse search along the row at half resolution, refined by
  // KLT; then back right -> left, then the row and disparity checks. The candidates are matched
  // in batches in rank order, each a half more than the tracks still missing (some fail the
  // checks), and the best-ranked matches are taken until the target is reached: candidates
  // beyond the batch that reaches it are never matched (a frame after a turn, which replaces
  // many tracks, would otherwise match three times as many as it keeps). The tracks added are
  // those of matching every candidate and keeping the best-ranked (matches are independent).
  const Klt klt(options_, options_.stereo_klt_window);
  const int search_level = std::min(1, options_.stereo_pyramid_levels);
  const float search_scale = search_level == 1 ? 0.5f : 1.0f;
  std::vector<cv::Point2f> left_points, right_points, left_back;
  std::vector<unsigned char> status, back_status;
  for (std::size_t next = 0; next < candidates.size() && out.counts.added < missing;) {
    const auto needed = static_cast<std::size_t>(missing - out.counts.added);
    const std::size_t batch =
        std::min(candidates.size() - next, std::max<std::size_t>(needed + needed / 2, 16));
    left_points.clear();
    right_points.clear();
    for (std::size_t index = next; index < next + batch; ++index) {
      const cv::Point2f& point = candidates[index].point;
      const std::optional<float> disparity = search_row(
          pyramid_image(left_pyramid, search_level), pyramid_image(right_pyramid, search_level),
          point, search_scale, kSearchRadius, options_.max_disparity, -1);
      const cv::Point2f right = point - cv::Point2f(disparity.value_or(0.0f), 0.0f);
      // The coarse match searched back along the left row must come back to the candidate
      // (within a pixel at the search's resolution): about half the candidates do not (a
      // repeated texture, a point the right camera does not see), and they are dropped here,
      // before the two KLT fits that would find the same (counted as circular rejections).
      if (disparity) {
        const std::optional<float> back = search_row(
            pyramid_image(right_pyramid, search_level), pyramid_image(left_pyramid, search_level),
            right, search_scale, kSearchRadius, options_.max_disparity, +1);
        if (!back || std::abs(*back - *disparity) > 1.0f / search_scale + 0.01f) {
          ++out.counts.rejected_circular;
          continue;
        }
      }
      left_points.push_back(point);
      right_points.push_back(right);
    }
    next += batch;
    if (left_points.empty()) continue;
    klt.track(left_pyramid, right_pyramid, left_points, right_points, search_level, status);
    if (hook_) hook_(MatchStage::kNewStereo, right_points);
    left_back = left_points;
    klt.track(right_pyramid, left_pyramid, right_points, left_back, search_level, back_status);
    for (std::size_t index = 0; index < left_points.size() && out.counts.added < missing; ++index) {
      if (!status[index] || !inside(right_points[index], size)) {
        ++out.counts.lost_stereo;
        continue;
      }
      if (!back_status[index] ||
          distance(left_back[index], left_points[index]) > options_.circular_tolerance) {
        ++out.counts.rejected_circular;
        continue;
      }
      // The match that passed the circular check refined under the rectified pair's warp (only
      // the candidates that may be kept are refined). The new track's stereo warp is not kept:
      // its next frame starts again from the identity (measured better on rendered seed 2: a
      // warp fitted from the coarse first match misleads).
      float stereo_variance = kUnmeasured;
      if (options_.stereo_affine) {
        AffineTemplate& patch = stereo_patch();
        cv::Matx22f warp = cv::Matx22f::eye();
        if (patch.prepare(left_pyramid[0], left_points[index], WarpModel::kRectifiedStereo,
                          options_.affine_window)) {
          refine_affine(patch, right_pyramid[0], right_points[index], warp, stereo_variance);
        }
      }
      if (!on_row_in_range(left_points[index], right_points[index])) {
        ++out.counts.rejected_epipolar;
        continue;
      }
      tracks_.ids.push_back(next_id_++);
      tracks_.left.push_back(left_points[index]);
      tracks_.right.push_back(right_points[index]);
      tracks_.lengths.push_back(1);
      tracks_.anchor_frames.push_back(frame_);
      tracks_.anchors.push_back(make_anchor(left, left_points[index]));
      tracks_.temporal_warps.push_back(cv::Matx22f::eye());
      tracks_.stereo_warps.push_back(cv::Matx22f::eye());
      tracks_.variances.push_back({kUnmeasured, stereo_variance});
      ++out.counts.added;
    }
  }
}

std::shared_ptr<const AffineTemplate> StereoTracker::make_anchor(const cv::Mat& image,
                                                                 const cv::Point2f& point) const {
  if (options_.anchor_frames == 0) return nullptr;
  auto patch = std::make_shared<AffineTemplate>();
  if (!patch->prepare(image, point, WarpModel::kAffine, options_.affine_window)) return nullptr;
  return patch;
}

bool StereoTracker::refine_affine(const AffineTemplate& patch, const cv::Mat& image,
                                  cv::Point2f& point, cv::Matx22f& warp, float& variance) const {
  AffineWarp fit;
  fit.A = warp;
  fit.t = point;
  const AffineAlignmentOptions defaults;
  if (!patch.align(image, fit, defaults.max_iterations, defaults.epsilon) ||
      distance(fit.t, point) > options_.affine_tolerance) {
    return false;
  }
  point = fit.t;
  warp = fit.A;
  variance = fit.position_variance;
  return true;
}

void StereoTracker::drop_tracks(std::span<const LandmarkId> ids) {
  if (ids.empty()) return;
  const std::unordered_set<LandmarkId> dropped(ids.begin(), ids.end());
  std::vector<unsigned char> keep(tracks_.size());
  for (std::size_t index = 0; index < tracks_.size(); ++index) {
    keep[index] = dropped.count(tracks_.ids[index]) ? 0 : 1;
  }
  tracks_.keep(keep);
}

}  // namespace concord::frontend

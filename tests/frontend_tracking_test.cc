// The front-end on a rendered sequence with exact ground truth (concord sim --render's world):
// known motion recovered, track positions against the true projections, injected wrong matches
// removed by circular matching and RANSAC, detections turned into stereo observations of the true
// object centres; the user's own odometry through the same interface; the dataset it writes.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <fstream>
#include <map>
#include <set>

#include "concord/config/options_file.h"
#include "concord/dataset/dataset.h"
#include "concord/estimator/lie.h"
#include "concord/frontend/frontend.h"
#include "concord/frontend/frontend_run.h"
#include "concord/frontend/object_observer.h"
#include "concord/frontend/stereo_tracker.h"
#include "evaluation/frontend_metrics.h"
#include "frontend_test_support.h"

namespace concord::frontend {
namespace {

namespace fs = std::filesystem;
using testing::random_texture;
using testing::rendered_sequence;

/// The rendered sequence's left and right images of a frame.
std::pair<cv::Mat, cv::Mat> images(const StereoSequence& sequence, int frame) {
  return {cv::imread(sequence.left_images[frame].string(), cv::IMREAD_GRAYSCALE),
          cv::imread(sequence.right_images[frame].string(), cv::IMREAD_GRAYSCALE)};
}

/// Runs the whole front-end over the rendered sequence.
std::vector<FrontendFrame> run_rendered(const FrontendOptions& options = {}) {
  StereoSequence sequence = read_stereo_sequence(rendered_sequence().sequence);
  const auto detections =
      read_detections(rendered_sequence().sequence / "detections.csv", sequence.num_frames());
  StereoFrontend frontend(std::move(sequence), options, detections);
  std::vector<FrontendFrame> frames;
  while (!frontend.done()) frames.push_back(frontend.process_next());
  return frames;
}

TEST(FrontendRendered, TheKittiLayoutCarriesTheRenderedCameraAndExactPoses) {
  const auto& rendered = rendered_sequence();
  const StereoSequence sequence = read_stereo_sequence(rendered.sequence);
  EXPECT_EQ(sequence.num_frames(), rendered.simulation.frames);
  EXPECT_EQ(sequence.rig.left.width, 376);
  EXPECT_NEAR(sequence.rig.left.fx, rendered.camera.K(0, 0), 1e-9);
  EXPECT_NEAR(sequence.rig.T_cam0_cam1.translation().x(), rendered.simulation.baseline, 1e-12);
  ASSERT_TRUE(sequence.groundtruth.has_value());
  for (int frame = 0; frame < sequence.num_frames(); ++frame) {
    const Eigen::Isometry3d T_world_cam0 =
        rendered.simulated.robots[0].groundtruth[frame] * rendered.camera.T_cam0_body.inverse();
    EXPECT_TRUE((*sequence.groundtruth)[frame].isApprox(T_world_cam0, 1e-12));
  }
}

TEST(FrontendRendered, VisualOdometryRecoversTheKnownMotion) {
  const auto frames = run_rendered();
  const StereoSequence sequence = read_stereo_sequence(rendered_sequence().sequence);
  const std::vector<Eigen::Isometry3d>& truth = *sequence.groundtruth;
  std::vector<Eigen::Isometry3d> odometry;
  for (std::size_t k = 1; k < frames.size(); ++k) {
    ASSERT_TRUE(frames[k].motion.valid) << "frame " << k;
    EXPECT_GE(frames[k].motion.inliers, 30) << "frame " << k;
    const Eigen::Isometry3d true_motion = truth[k - 1].inverse() * truth[k];
    const lie::Vector6d error =
        lie::se3_log(true_motion.inverse() * *frames[k].input.T_previous_current);
    // At this small image size (focal length 268 px); the bench measures full-size images.
    EXPECT_LT(error.head<3>().norm(), 0.02) << "frame " << k;   // true motion: 0.22 m a frame
    EXPECT_LT(error.tail<3>().norm(), 0.003) << "frame " << k;  // radians
    odometry.push_back(*frames[k].input.T_previous_current);
  }
  const auto accuracy = evaluation::odometry_accuracy(truth, odometry, {});
  EXPECT_GT(accuracy.path_length, 3.0);
  EXPECT_LT(accuracy.final_error_percent, 2.0);
}

TEST(FrontendRendered, TrackPositionsMatchTheTrueProjections) {
  const auto frames = run_rendered();
  const auto& rendered = rendered_sequence();
  const StereoSequence sequence = read_stereo_sequence(rendered.sequence);
  std::vector<std::vector<StereoObservation>> features;
  std::size_t tracked = 0;
  for (const FrontendFrame& frame : frames) {
    features.push_back(frame.input.features);
    tracked += frame.input.features.size();
  }
  EXPECT_GT(tracked / frames.size(), 150u);
  StereoCamera camera = rendered.camera;
  camera.T_cam0_body = Eigen::Isometry3d::Identity();  // the KITTI layout's body is the camera
  const auto accuracy =
      evaluation::track_accuracy(rendered.world, camera, *sequence.groundtruth, features);
  EXPECT_EQ(accuracy.unanchored, 0);
  EXPECT_GT(accuracy.left.count, 1000);
  // Pixels at this small image size (the bench measures full-size images).
  EXPECT_LT(accuracy.left.median, 0.5);    // along the tracks
  EXPECT_LT(accuracy.right.median, 0.75);  // stereo matches
  // The tail is corners on occlusion boundaries (a box edge in front of a far wall), which slide
  // as the view changes: 3.7-4.6 px on this small sequence depending on the texture draw; on the
  // images rendered since the mip levels are read where they were built (2026-11-26), 4.4 px in
  // the Release build and 5.1 px in the sanitizer build (the two builds' tracks differ a
  // little). A tracker that loses its corners has tails of tens of pixels.
  EXPECT_LT(accuracy.all.p90, 6.0);
}

TEST(FrontendRendered, AnchoredAffineTracksStayCloserToTheTruthThanFrameToFrameKlt) {
  const auto& rendered = rendered_sequence();
  const StereoSequence sequence = read_stereo_sequence(rendered.sequence);
  StereoCamera camera = rendered.camera;
  camera.T_cam0_body = Eigen::Isometry3d::Identity();
  const auto accuracy_of = [&](const std::vector<FrontendFrame>& frames) {
    std::vector<std::vector<StereoObservation>> features;
    for (const FrontendFrame& frame : frames) features.push_back(frame.input.features);
    return evaluation::track_accuracy(rendered.world, camera, *sequence.groundtruth, features);
  };
  FrontendOptions plain;
  plain.tracker.anchor_frames = 0;
  plain.tracker.stereo_affine = false;
  const FrontendOptions anchored;  // the defaults
  ASSERT_GT(anchored.tracker.anchor_frames, 0);
  const auto anchored_frames = run_rendered(anchored);
  const auto with_anchors = accuracy_of(anchored_frames);
  const auto without = accuracy_of(run_rendered(plain));
  EXPECT_LT(with_anchors.left.median, 0.8 * without.left.median);
  EXPECT_LT(with_anchors.right.median, 0.8 * without.right.median);

  // A track anchored afresh goes on under a new id: no id spans more than anchor_frames frames,
  // and every frame's tracks stay sorted by id (the visual odometry pairs frames by id).
  int reanchored = 0;
  std::map<LandmarkId, int> frames_of;
  for (const FrontendFrame& frame : anchored_frames) {
    reanchored += frame.counts.reanchored;
    EXPECT_TRUE(std::is_sorted(frame.input.features.begin(), frame.input.features.end(),
                               [](const StereoObservation& a, const StereoObservation& b) {
                                 return a.id < b.id;
                               }));
    for (const StereoObservation& feature : frame.input.features) ++frames_of[feature.id];
  }
  EXPECT_GT(reanchored, 0);
  int longest = 0;
  for (const auto& [id, count] : frames_of) longest = std::max(longest, count);
  EXPECT_LE(longest, anchored.tracker.anchor_frames);
  EXPECT_EQ(longest, anchored.tracker.anchor_frames);
}

/// Tracks the first frames with a hook that corrupts every fourth match at `stage` on frame 3: by
/// `shift`, or (when `across_epipolar_line`) by 8 pixels across the match's true epipolar line
/// (from the true motion), which no fundamental matrix near the truth explains.
struct Corruption {
  std::set<LandmarkId> corrupted;
  TrackedFrame frame;
};

Corruption track_with_corruption(TrackerOptions options, MatchStage stage, cv::Point2f shift,
                                 bool across_epipolar_line = false) {
  const StereoSequence sequence = read_stereo_sequence(rendered_sequence().sequence);
  // F of the left images of frames 2 and 3: x3^T F x2 = 0.
  const Eigen::Isometry3d T_3_2 = (*sequence.groundtruth)[3].inverse() * (*sequence.groundtruth)[2];
  const Eigen::Matrix3d K_inverse = rendered_sequence().camera.K.inverse();
  const Eigen::Matrix3d fundamental =
      K_inverse.transpose() * lie::skew(T_3_2.translation()) * T_3_2.linear() * K_inverse;
  StereoTracker tracker(options);
  Corruption result;
  std::vector<LandmarkId> previous_ids;
  std::vector<cv::Point2f> previous_left;
  for (int frame = 0; frame <= 3; ++frame) {
    if (frame == 3) {
      tracker.set_match_hook([&](MatchStage at, std::vector<cv::Point2f>& points) {
        if (at != stage) return;
        for (std::size_t index = 0; index < points.size(); index += 4) {
          cv::Point2f step = shift;
          if (across_epipolar_line) {
            const Eigen::Vector3d line =
                fundamental * Eigen::Vector3d(previous_left[index].x, previous_left[index].y, 1.0);
            const Eigen::Vector2d normal = line.head<2>().normalized();
            step = cv::Point2f(static_cast<float>(8.0 * normal.x()),
                               static_cast<float>(8.0 * normal.y()));
          }
          points[index] += step;
          result.corrupted.insert(previous_ids[index]);
        }
      });
    }
    const auto [left, right] = images(sequence, frame);
    result.frame = tracker.track(left, right);
    previous_ids.clear();
    previous_left.clear();
    for (const StereoObservation& observation : result.frame.observations) {
      previous_ids.push_back(observation.id);
      previous_left.emplace_back(observation.uv(0), observation.uv(1));
    }
  }
  return result;
}

bool contains_any(const TrackedFrame& frame, const std::set<LandmarkId>& ids) {
  return std::any_of(frame.observations.begin(), frame.observations.end(),
                     [&](const StereoObservation& o) { return ids.count(o.id) > 0; });
}

TEST(FrontendRendered, CircularMatchingRemovesWrongTemporalMatches) {
  const Corruption result =
      track_with_corruption({}, MatchStage::kTemporal, cv::Point2f(9.0f, 6.0f));
  ASSERT_GT(result.corrupted.size(), 20u);
  EXPECT_FALSE(contains_any(result.frame, result.corrupted));
  EXPECT_GE(result.frame.counts.rejected_circular + result.frame.counts.rejected_ransac +
                result.frame.counts.lost_stereo,
            static_cast<int>(result.corrupted.size()));
}

TEST(FrontendRendered, RansacRemovesWrongTemporalMatchesThatCircularMatchingLetsThrough) {
  TrackerOptions options;
  options.circular_tolerance = 1000.0;  // circular matching off
  const Corruption result =
      track_with_corruption(options, MatchStage::kTemporal, cv::Point2f(), true);
  ASSERT_GT(result.corrupted.size(), 20u);
  EXPECT_FALSE(contains_any(result.frame, result.corrupted));
  const TrackingCounts& counts = result.frame.counts;
  EXPECT_GE(counts.rejected_ransac, static_cast<int>(result.corrupted.size()) -
                                        counts.rejected_circular - counts.lost_stereo -
                                        counts.rejected_epipolar);
  EXPECT_GE(counts.rejected_ransac, static_cast<int>(result.corrupted.size()) / 2);
}

TEST(FrontendRendered, CircularMatchingRemovesWrongStereoMatchesOnTheRightRow) {
  // A wrong disparity on the right row passes the epipolar check; the loop through the previous
  // right image does not close.
  const Corruption result = track_with_corruption({}, MatchStage::kStereo, cv::Point2f(4.0f, 0.0f));
  ASSERT_GT(result.corrupted.size(), 20u);
  EXPECT_FALSE(contains_any(result.frame, result.corrupted));
  EXPECT_GE(result.frame.counts.rejected_circular, static_cast<int>(result.corrupted.size()));
}

TEST(FrontendTracker, AFastTurnIsFollowedFromTheLastFramesFlowAndASuddenStopToo) {
  // A plane facing the camera, textured with a real photograph (a EuRoC frame), at a disparity of
  // 20 pixels; the view moves sideways as a turn about the vertical axis moves it: 80 pixels a
  // frame, beyond the pyramid's reach from where a track was, then no motion (a sudden stop).
  const fs::path photographs = testing::euroc_frames() / "mav0/cam0/data";
  std::vector<fs::path> files(fs::directory_iterator(photographs), fs::directory_iterator{});
  std::sort(files.begin(), files.end());
  ASSERT_FALSE(files.empty());
  const cv::Mat plane = cv::imread(files.front().string(), cv::IMREAD_GRAYSCALE);
  const int disparity = 20;
  const std::vector<int> shifts{0, 80, 160, 240, 240};
  const cv::Size size(plane.cols - disparity - shifts.back(), plane.rows);
  StereoTracker tracker(TrackerOptions{});
  std::map<LandmarkId, Eigen::Vector4d> before;
  std::vector<int> continued;
  for (std::size_t frame = 0; frame < shifts.size(); ++frame) {
    const int shift = shifts[frame];
    const TrackedFrame tracked =
        tracker.track(plane(cv::Rect(shift, 0, size.width, size.height)).clone(),
                      plane(cv::Rect(shift + disparity, 0, size.width, size.height)).clone());
    continued.push_back(tracked.counts.continued);
    const double step = frame == 0 ? 0.0 : shift - shifts[frame - 1];
    int compared = 0, moved_with_the_view = 0;
    for (const StereoObservation& observation : tracked.observations) {
      EXPECT_NEAR(observation.uv(0) - observation.uv(2), disparity, 0.5) << "frame " << frame;
      EXPECT_NEAR(observation.uv(1), observation.uv(3), 0.5) << "frame " << frame;
      const auto it = before.find(observation.id);
      if (it == before.end()) continue;
      ++compared;
      const Eigen::Vector2d expected(it->second(0) - step, it->second(1));
      moved_with_the_view += (observation.uv.head<2>() - expected).norm() <= 0.5 ? 1 : 0;
    }
    // A continued track moved with the view, but for a rare wrong match (a repeated texture that
    // circular matching cannot tell apart, caught later by the odometry's RANSAC).
    EXPECT_GE(moved_with_the_view, compared - compared / 100) << "frame " << frame;
    before.clear();
    for (const StereoObservation& observation : tracked.observations)
      before[observation.id] = observation.uv;
  }
  // The first 80-pixel step is beyond reach: most tracks are lost. From then on the last
  // frame's flow is the guess: the tracks still in view (all but the tenth or so that left it) go on,
  // and after the stop they are found again where they were.
  EXPECT_LT(continued[1], 100) << "the premise: a step beyond the tracker's reach";
  for (std::size_t frame = 2; frame < shifts.size(); ++frame)
    EXPECT_GE(continued[frame], 150) << "frame " << frame;
}

TEST(FrontendRendered, NewStereoMatchesAreCheckedBackAndOnTheRow) {
  const StereoSequence sequence = read_stereo_sequence(rendered_sequence().sequence);
  const auto [left, right] = images(sequence, 0);
  for (const cv::Point2f shift : {cv::Point2f(3.0f, 0.0f), cv::Point2f(0.0f, 3.0f)}) {
    StereoTracker tracker(TrackerOptions{});
    tracker.set_match_hook([&](MatchStage stage, std::vector<cv::Point2f>& points) {
      if (stage == MatchStage::kNewStereo) {
        for (cv::Point2f& point : points) point += shift;
      }
    });
    const TrackedFrame frame = tracker.track(left, right);
    EXPECT_GT(frame.counts.detected, 100);
    // A match along an edge parallel to the shift cannot be told from the right one (the
    // aperture problem); it is caught at the next frame by circular matching.
    EXPECT_LE(frame.counts.added, frame.counts.detected / 50) << "shift " << shift;
  }
  // Without the corruption, every new match is on the row of its left feature.
  StereoTracker tracker(TrackerOptions{});
  const TrackedFrame frame = tracker.track(left, right);
  EXPECT_GT(frame.counts.added, 150);
  for (const StereoObservation& observation : frame.observations) {
    EXPECT_LE(std::abs(observation.uv(1) - observation.uv(3)), 1.0);
    EXPECT_GT(observation.uv(0) - observation.uv(2), 0.0);
  }
}

TEST(FrontendRendered, DetectionsBecomeStereoObservationsOfTheObjectCentres) {
  const auto frames = run_rendered();
  const auto& rendered = rendered_sequence();
  const StereoSequence sequence = read_stereo_sequence(rendered.sequence);
  int detections = 0, observed = 0, refused = 0;
  std::vector<std::vector<StereoObservation>> objects;
  for (const FrontendFrame& frame : frames) {
    detections += frame.detections;
    observed += frame.objects_observed;
    objects.push_back(frame.input.objects);
    refused += frame.objects_ambiguous + frame.objects_inconsistent;
  }
  ASSERT_GT(detections, 20);
  // Most detections are matched; a few matches are refused as ambiguous or left-right
  // inconsistent.
  EXPECT_GE(observed + refused, 0.85 * detections);
  EXPECT_LE(refused, 0.1 * detections);
  StereoCamera camera = rendered.camera;
  camera.T_cam0_body = Eigen::Isometry3d::Identity();
  const auto accuracy = evaluation::object_observation_accuracy(
      camera, *sequence.groundtruth, objects, rendered.simulated.objects_groundtruth);
  // The refused matches, measured without the checks, are mostly wrong: their disparities are
  // far worse than the kept ones'.
  FrontendOptions unchecked;
  unchecked.objects.ambiguity_ratio = 1.0;
  unchecked.objects.left_right_tolerance = 1000.0;
  const auto frames_unchecked = run_rendered(unchecked);
  std::vector<std::vector<StereoObservation>> refused_objects(frames.size());
  for (std::size_t k = 0; k < frames.size(); ++k) {
    for (const StereoObservation& object : frames_unchecked[k].input.objects) {
      const bool kept = std::any_of(
          objects[k].begin(), objects[k].end(),
          [&](const StereoObservation& other) { return other.id == object.id; });
      if (!kept) refused_objects[k].push_back(object);
    }
  }
  const auto refused_accuracy = evaluation::object_observation_accuracy(
      camera, *sequence.groundtruth, refused_objects, rendered.simulated.objects_groundtruth);
  ASSERT_GT(refused_accuracy.disparity.count, 0);
  EXPECT_GT(refused_accuracy.disparity.median, 5.0 * accuracy.disparity.median);
  EXPECT_EQ(accuracy.centre.count, observed);
  // Box centres differ from the projected cube centre by perspective only.
  EXPECT_LT(accuracy.centre.median, 3.0);
  EXPECT_LT(accuracy.disparity.median, 1.0);
  EXPECT_LT(accuracy.relative_depth.median, 0.05);
  for (const auto& frame_objects : objects) {
    for (const StereoObservation& object : frame_objects) {
      EXPECT_DOUBLE_EQ(object.uv(1), object.uv(3));  // rectified: same row
    }
  }
}

TEST(FrontendRendered, UprightObjectsCentresAreCloserToTheTruthThanTheBoxesMiddle) {
  // The rendered robots are level and the cubes stand on the floor: with `upright` the
  // observations' centres come from the silhouette model, without it from the boxes' middles.
  const auto& rendered = rendered_sequence();
  const StereoSequence sequence = read_stereo_sequence(rendered.sequence);
  StereoCamera camera = rendered.camera;
  camera.T_cam0_body = Eigen::Isometry3d::Identity();
  const auto accuracy = [&](bool upright) {
    FrontendOptions options;
    options.objects.upright = upright;
    std::vector<std::vector<StereoObservation>> objects;
    for (const FrontendFrame& frame : run_rendered(options)) objects.push_back(frame.input.objects);
    return evaluation::object_observation_accuracy(camera, *sequence.groundtruth, objects,
                                                   rendered.simulated.objects_groundtruth);
  };
  const auto middle = accuracy(false);
  const auto upright = accuracy(true);
  ASSERT_GT(middle.centre.count, 20);
  EXPECT_EQ(upright.centre.count, middle.centre.count);
  EXPECT_LT(upright.centre.median, 0.75 * middle.centre.median);
  EXPECT_LE(upright.disparity.median, middle.disparity.median * 1.1);
}

TEST(FrontendObjects, TheSilhouetteOfAnUprightBoxGivesItsCentreRowAndDepth) {
  // A box as deep as wide (centre_depth_fraction 0.5), faces parallel to the camera's axes, at
  // positions on and off the optical axis: its silhouette (the bounding box of its eight
  // corners' projections) and its near face's depth give its centre's row and depth exactly.
  StereoCamera camera;
  camera.K << 500.0, 0.0, 320.0, 0.0, 500.0, 240.0, 0.0, 0.0, 1.0;
  camera.T_cam0_cam1.translation() = Eigen::Vector3d(0.5, 0.0, 0.0);
  ObjectOptions options;
  options.upright = true;
  const double half = 0.4;  // metres
  int off_axis = 0;
  for (const Eigen::Vector3d& centre :
       {Eigen::Vector3d(0.0, 0.0, 6.0), Eigen::Vector3d(2.0, 1.2, 5.0),
        Eigen::Vector3d(-3.0, -1.5, 7.0), Eigen::Vector3d(0.2, 1.5, 4.0),
        Eigen::Vector3d(-2.5, 0.1, 9.0)}) {
    Detection box{0, 1, "box", 1e9, 1e9, -1e9, -1e9};
    for (int corner = 0; corner < 8; ++corner) {
      const Eigen::Vector3d p =
          centre + half * Eigen::Vector3d(corner & 1 ? 1 : -1, corner & 2 ? 1 : -1, corner & 4 ? 1 : -1);
      const Eigen::Vector3d image = camera.K * p / p.z();
      box.x_min = std::min(box.x_min, image.x());
      box.x_max = std::max(box.x_max, image.x());
      box.y_min = std::min(box.y_min, image.y());
      box.y_max = std::max(box.y_max, image.y());
    }
    const double true_row = camera.K(1, 1) * centre.y() / centre.z() + camera.K(1, 2);
    const ObjectCentre found = object_centre(box, centre.z() - half, camera, options);
    EXPECT_NEAR(found.depth, centre.z(), 1e-9) << centre.transpose();
    EXPECT_NEAR(found.v, true_row, 1e-9) << centre.transpose();
    EXPECT_DOUBLE_EQ(found.u, box.centre_x());  // the middle column: the yaw is unknown
    // The box's middle row is off by perspective wherever the box is off the axis vertically.
    if (std::abs(box.centre_y() - true_row) > 0.5) ++off_axis;
    // Without `upright`, the middle row; the depth is the same.
    ObjectOptions level = options;
    level.upright = false;
    const ObjectCentre middle = object_centre(box, centre.z() - half, camera, level);
    EXPECT_DOUBLE_EQ(middle.v, box.centre_y());
    EXPECT_NEAR(middle.depth, centre.z(), 1e-9);
  }
  EXPECT_GE(off_axis, 3);
}

TEST(FrontendRendered, ObjectsAtTheBorderOrWithoutAMatchAreSkipped) {
  const StereoSequence sequence = read_stereo_sequence(rendered_sequence().sequence);
  const auto [left, right] = images(sequence, 0);
  const StereoCamera& camera = rendered_sequence().camera;
  Detection box{0, 1, "cube", 0.0, 10.0, 40.0, 50.0};
  EXPECT_EQ(observe_object(box, left, right, camera, {}).skipped, ObjectSkip::kAtBorder);
  box = {0, 1, "cube", 100.0, 100.0, 104.0, 104.0};
  EXPECT_EQ(observe_object(box, left, right, camera, {}).skipped, ObjectSkip::kTooSmall);
  const cv::Mat flat(left.size(), CV_8UC1, cv::Scalar(128));
  box = {0, 1, "cube", 100.0, 100.0, 160.0, 160.0};
  EXPECT_EQ(observe_object(box, left, flat, camera, {}).skipped, ObjectSkip::kNoMatch);
}

TEST(FrontendObjects, AnAmbiguousOrLeftRightInconsistentMatchGivesNoObservation) {
  const StereoCamera& camera = rendered_sequence().camera;
  const cv::Size size(376, 240);
  // The box's central region (the half measured) is 30 x 30 px at x = 215, y = 115.
  const Detection box{0, 1, "cube", 200.0, 100.0, 260.0, 160.0};
  const cv::Rect region(215, 115, 30, 30);
  const auto at_x = [&](int x) { return cv::Rect(x, region.y, region.width, region.height); };
  const cv::Mat left = random_texture(size, 1);
  const cv::Mat patch = left(region).clone();

  // The region 40 px to the left in the right image, on unrelated texture: observed.
  cv::Mat right = random_texture(size, 2);
  patch.copyTo(right(at_x(region.x - 40)));
  const ObjectMeasurement plain = observe_object(box, left, right, camera, {});
  ASSERT_TRUE(plain.observation.has_value()) << static_cast<int>(plain.skipped);
  EXPECT_NEAR(plain.surface_disparity, 40.0, 0.5);
  // A search range beyond the image (any configured value) is the image width.
  ObjectOptions wide;
  wide.max_disparity = 1e12;
  const ObjectMeasurement wide_search = observe_object(box, left, right, camera, wide);
  ASSERT_TRUE(wide_search.observation.has_value());
  EXPECT_NEAR(wide_search.surface_disparity, 40.0, 0.5);

  // The same texture again further along the row (a repeated pattern): ambiguous.
  patch.copyTo(right(at_x(region.x - 120)));
  EXPECT_EQ(observe_object(box, left, right, camera, {}).skipped, ObjectSkip::kAmbiguous);

  // A weaker copy (NCC about 0.8) is the best match in the right image, but it matches back to
  // an exact copy of itself elsewhere in the left image (the region is another surface's there):
  // left-right inconsistent; observed only when the check allows a 100 px difference.
  cv::Mat weak;
  cv::addWeighted(patch, 0.6, random_texture(region.size(), 3), 0.4, 0.0, weak);
  right = random_texture(size, 2);
  weak.copyTo(right(at_x(region.x - 40)));
  cv::Mat left_with_copy = left.clone();
  weak.copyTo(left_with_copy(at_x(region.x + 85)));
  const ObjectMeasurement inconsistent = observe_object(box, left_with_copy, right, camera, {});
  EXPECT_EQ(inconsistent.skipped, ObjectSkip::kInconsistent);
  EXPECT_GT(inconsistent.score, 0.7);
  ObjectOptions lenient;
  lenient.left_right_tolerance = 100.0;
  const ObjectMeasurement accepted = observe_object(box, left_with_copy, right, camera, lenient);
  ASSERT_TRUE(accepted.observation.has_value());
  EXPECT_NEAR(accepted.surface_disparity, 40.0, 0.5);
  // Without the copy in the left image the weaker match is the consistent one.
  EXPECT_TRUE(observe_object(box, left, right, camera, {}).observation.has_value());

  ObjectOptions invalid;
  invalid.ambiguity_ratio = 0.0;
  invalid.left_right_tolerance = -1.0;
  EXPECT_EQ(invalid.validate().size(), 2u);
}

TEST(FrontendRendered, TheUsersOwnOdometryGoesThroughTheSameInterface) {
  StereoSequence sequence = read_stereo_sequence(rendered_sequence().sequence);
  std::vector<Eigen::Isometry3d> motions;
  for (int k = 1; k < sequence.num_frames(); ++k) {
    motions.push_back((*sequence.groundtruth)[k - 1].inverse() * (*sequence.groundtruth)[k]);
  }
  Matrix6d covariance = Matrix6d::Identity() * 1e-4;
  StereoFrontend frontend(std::move(sequence), {}, {},
                          std::make_unique<FileOdometry>(motions, covariance));
  (void)frontend.process_next();  // frame 0: no motion
  for (int k = 1; k < 4; ++k) {
    const FrontendFrame frame = frontend.process_next();
    ASSERT_TRUE(frame.input.T_previous_current.has_value());
    EXPECT_TRUE(frame.input.T_previous_current->isApprox(motions[k - 1], 1e-15));
    EXPECT_TRUE(frame.motion.covariance.isApprox(covariance));
    EXPECT_GT(frame.input.features.size(), 100u);
  }
  FileOdometry short_file({}, covariance);
  EXPECT_THROW((void)short_file.estimate(1, {}, {}), FrontendError);
}

TEST(FrontendRendered, RunWritesADatasetThatReadsBack) {
  const fs::path out = testing::temporary_folder("frontend_run");
  FrontendRunOptions options;
  options.max_frames = 6;
  options.name = "rendered-test";
  const FrontendRunSummary summary = run_frontend(rendered_sequence().team, out, options);
  ASSERT_EQ(summary.robots.size(), 1u);
  EXPECT_EQ(summary.robots[0].frames, 6);
  EXPECT_GT(summary.robots[0].tracks_per_frame, 150.0);
  EXPECT_GT(summary.robots[0].feature_track_sigma, 0.0);
  EXPECT_LT(summary.robots[0].feature_track_sigma, 1.0);
  const dataset::Dataset data = dataset::read_dataset(out);
  EXPECT_EQ(data.name, "rendered-test");
  ASSERT_EQ(data.robots.size(), 1u);
  EXPECT_EQ(data.robots[0].num_frames(), 6);
  EXPECT_TRUE(data.robots[0].has_features);
  EXPECT_EQ(data.camera.K, rendered_sequence().camera.K);
  EXPECT_FALSE(data.objects_groundtruth.empty());  // copied from the team folder
  // Every motion's covariance is read back with the dataset (and the estimator uses it).
  const auto& covariances = data.robots[0].odometry_covariance;
  ASSERT_EQ(covariances.size(), 5u);
  for (const auto& covariance : covariances) {
    ASSERT_TRUE(covariance);
    EXPECT_GT(covariance->llt().matrixL().determinant(), 0.0);
  }
  ASSERT_TRUE(data.robots[0].frame_input(3).odometry_covariance);
  EXPECT_EQ(*data.robots[0].frame_input(3).odometry_covariance, *covariances[2]);
  EXPECT_TRUE(fs::exists(out / "frontend.json"));
  // Detections and odometry files belong to a single sequence, not to a team.
  options.detections = rendered_sequence().sequence / "detections.csv";
  EXPECT_THROW((void)run_frontend(rendered_sequence().team, out, options), FrontendError);
}

TEST(FrontendRendered, TheTrackerReportsEachMatchsAlignmentVariance) {
  // A track's first left observation is its anchor (no alignment measured it); later ones and
  // the stereo matches carry the alignment's variance, which differs from match to match.
  StereoSequence sequence = read_stereo_sequence(rendered_sequence().sequence);
  StereoTracker tracker(FrontendOptions{}.tracker);
  std::map<LandmarkId, int> seen;
  int anchors = 0, measured_left = 0, measured_stereo = 0, observations = 0;
  float smallest = std::numeric_limits<float>::infinity(), largest = 0.0f;
  for (int frame = 0; frame < 8; ++frame) {
    const auto [left, right] = images(sequence, frame);
    const TrackedFrame tracked = tracker.track(left, right);
    ASSERT_EQ(tracked.alignment_variances.size(), tracked.observations.size());
    for (std::size_t n = 0; n < tracked.observations.size(); ++n) {
      const auto [v_left, v_stereo] = tracked.alignment_variances[n];
      ++observations;
      if (seen[tracked.observations[n].id]++ == 0) {
        EXPECT_TRUE(std::isnan(v_left));  // the anchor
        ++anchors;
      } else if (std::isfinite(v_left)) {
        EXPECT_GE(v_left, 0.0f);
        ++measured_left;
      }
      if (std::isfinite(v_stereo)) {
        EXPECT_GE(v_stereo, 0.0f);
        ++measured_stereo;
        smallest = std::min(smallest, v_stereo);
        largest = std::max(largest, v_stereo);
      }
    }
  }
  EXPECT_GT(anchors, 150);
  EXPECT_GT(measured_left, (observations - anchors) * 8 / 10);
  EXPECT_GT(measured_stereo, observations / 2);
  EXPECT_GT(largest, 5.0f * smallest);
}

TEST(FrontendRun, EachTrackObservationGetsItsOwnNoiseAtTheTracksLevel) {
  // features.csv carries each observation's sigma_left and sigma_right from the alignments'
  // variances, scaled so that their mean level is the tracks' own noise; with
  // observation_noise off it carries none.
  const fs::path out = testing::temporary_folder("frontend_observation_noise");
  FrontendRunOptions options;
  options.max_frames = 10;
  const FrontendRunSummary summary = run_frontend(rendered_sequence().team, out, options);
  const ObservationNoise& noise = summary.robots.at(0).observation_noise;
  ASSERT_TRUE(noise.valid());
  const double level = std::max(summary.robots[0].feature_track_sigma, 0.05);
  const dataset::RobotData robot = dataset::read_dataset(out).robots.at(0);
  double left = 0.0, stereo = 0.0, smallest = 1e9, largest = 0.0;
  long long count = 0;
  for (const auto& frame : robot.features) {
    for (const StereoObservation& observation : frame) {
      const Eigen::Vector2d& sigma = observation.sigma;
      ASSERT_GT(sigma(0), 0.0);
      ASSERT_GE(sigma(1), sigma(0));  // the right image's match adds the stereo alignment's
      left += sigma(0) * sigma(0);
      stereo += sigma(1) * sigma(1) - sigma(0) * sigma(0);
      smallest = std::min(smallest, sigma(0));
      largest = std::max(largest, sigma(0));
      ++count;
    }
  }
  ASSERT_EQ(count, noise.observations);
  EXPECT_NEAR(left / count, level * level, 1e-6 * level * level);
  EXPECT_NEAR(stereo / count, level * level, 1e-6 * level * level);
  EXPECT_GT(largest, 3.0 * smallest);  // the alignments tell good matches from poor ones

  options.observation_noise = false;
  const fs::path constant = testing::temporary_folder("frontend_constant_noise");
  EXPECT_FALSE(run_frontend(rendered_sequence().team, constant, options)
                   .robots.at(0)
                   .observation_noise.valid());
  const dataset::Dataset without = dataset::read_dataset(constant);
  for (const auto& frame : without.robots.at(0).features) {
    for (const StereoObservation& observation : frame) {
      EXPECT_EQ(observation.sigma, Eigen::Vector2d::Zero());
    }
  }
}

TEST(FrontendRun, ALiveSourceScalesItsVariancesByTheirRunningMeans) {
  // The daemon's image source: sigma_left^2 = sigma^2 v_left / mean(v_left so far), and the
  // stereo part likewise; an unmeasured variance takes the running mean; nothing until both
  // kinds were measured.
  const float unmeasured = std::numeric_limits<float>::quiet_NaN();
  RunningObservationNoise noise(0.2);
  std::vector<StereoObservation> features(2);
  noise.apply(features, {{0.002f, unmeasured}, {0.004f, unmeasured}});
  for (const StereoObservation& feature : features)
    EXPECT_EQ(feature.sigma, Eigen::Vector2d::Zero());
  features.assign(3, {});
  noise.apply(features, {{unmeasured, 0.001f}, {0.006f, 0.003f}, {0.004f, unmeasured}});
  const double mean_left = (0.002 + 0.004 + 0.006 + 0.004) / 4, mean_stereo = 0.002;
  const auto expected = [&](double v_left, double v_stereo) {
    const double left = 0.04 * v_left / mean_left;
    return Eigen::Vector2d(std::sqrt(left), std::sqrt(left + 0.04 * v_stereo / mean_stereo));
  };
  EXPECT_TRUE(features[0].sigma.isApprox(expected(mean_left, 0.001), 1e-6));
  EXPECT_TRUE(features[1].sigma.isApprox(expected(0.006, 0.003), 1e-6));
  EXPECT_TRUE(features[2].sigma.isApprox(expected(0.004, mean_stereo), 1e-6));
}

TEST(FrontendRun, AnUpAxisAlongTheCamerasVerticalMakesObjectsUpright) {
  // The rendered body is the left camera looking forward on a level robot: up is -y, the
  // camera's vertical; +z (forward) is not. The objects' rows follow (ObjectOptions::upright),
  // and frontend.json reports the options used.
  const auto run = [](const std::string& up_axis) {
    const fs::path out = testing::temporary_folder("frontend_up_" + up_axis.substr(1));
    FrontendRunOptions options;
    options.max_frames = 4;
    options.up_axis = up_axis;
    (void)run_frontend(rendered_sequence().team, out, options);
    std::ifstream file(out / "frontend.json");
    const auto document = nlohmann::json::parse(file);
    return std::pair{document.at("options").at("objects").at("upright").get<bool>(),
                     dataset::read_dataset(out).robots.at(0)};
  };
  const auto [upright, level] = run("-y");
  const auto [not_upright, forward] = run("+z");
  EXPECT_TRUE(upright);
  EXPECT_FALSE(not_upright);
  int moved = 0, observations = 0;
  for (int frame = 0; frame < 4; ++frame) {
    const auto a = level.frame_input(frame).objects;
    const auto b = forward.frame_input(frame).objects;
    ASSERT_EQ(a.size(), b.size());
    for (std::size_t i = 0; i < a.size(); ++i) {
      ++observations;
      EXPECT_DOUBLE_EQ(a[i].uv(0), b[i].uv(0));  // the same column
      if (std::abs(a[i].uv(1) - b[i].uv(1)) > 1e-6) ++moved;
    }
  }
  EXPECT_GT(observations, 0);
  EXPECT_EQ(moved, observations);
}

TEST(FrontendRun, ADetectorModelReplacesTheStatedObjectNoiseInEstimatorYaml) {
  // The detector's error model (what concord calibrate --detector-model writes) goes into the
  // estimator.yaml the front-end writes, in place of objects.detection_sigma; the front-end's
  // own odometry and feature noise stay.
  const fs::path model = testing::temporary_folder("frontend_detector_model") / "model.yaml";
  const auto write = [&](const std::string& text) { std::ofstream(model) << text; };
  write(
      "object_noise: {horizontal: 0.1, vertical: 0.04, disparity: 0.03, vertical_disparity: "
      "0.004}\nobject_offset_sigma: {horizontal: 0.7, vertical: 0.3, disparity: 0.2}\n"
      "object_offset_walk: {horizontal: 0.4, vertical: 0.15, disparity: 0.1}\n"
      "feature_drift_sigma: 0.03\n");
  FrontendRunOptions options;
  options.max_frames = 3;
  const fs::path stated = testing::temporary_folder("frontend_model_stated");
  (void)run_frontend(rendered_sequence().team, stated, options);
  options.detector_model = model;
  const fs::path modelled = testing::temporary_folder("frontend_model_modelled");
  (void)run_frontend(rendered_sequence().team, modelled, options);
  const EstimatorOptions a = config::load_estimator_options(stated / "estimator.yaml");
  const EstimatorOptions b = config::load_estimator_options(modelled / "estimator.yaml");
  EXPECT_DOUBLE_EQ(a.object_noise.horizontal,
                   StereoNoise::isotropic(options.frontend.objects.detection_sigma).horizontal);
  EXPECT_DOUBLE_EQ(a.object_offset_sigma.horizontal, 0.0);
  EXPECT_DOUBLE_EQ(b.object_noise.horizontal, 0.1);
  EXPECT_DOUBLE_EQ(b.object_noise.vertical_disparity, 0.004);
  EXPECT_DOUBLE_EQ(b.object_offset_sigma.vertical, 0.3);
  EXPECT_DOUBLE_EQ(b.object_offset_walk.disparity, 0.1);
  EXPECT_DOUBLE_EQ(a.feature_drift_sigma, 0.0);
  EXPECT_DOUBLE_EQ(b.feature_drift_sigma, 0.03);  // the tracks' drift, measured with the detector
  EXPECT_DOUBLE_EQ(b.feature_noise.horizontal, a.feature_noise.horizontal);
  EXPECT_DOUBLE_EQ(b.odometry_translation_sigma, a.odometry_translation_sigma);
  EXPECT_DOUBLE_EQ(b.object_init_max_reprojection_error, a.object_init_max_reprojection_error);
  std::ifstream file(modelled / "frontend.json");
  EXPECT_EQ(nlohmann::json::parse(file).at("detector_model"), model.string());

  // Refused, before any image is read, with the reason: a key that is not the detector's (the
  // front-end measures the odometry itself), two models of one error, a file that is not a map
  // or not there.
  const auto refusal = [&](const std::string& text) {
    write(text);
    const fs::path out = testing::temporary_folder("frontend_model_refused");
    try {
      (void)run_frontend(rendered_sequence().team, out, options);
    } catch (const FrontendError& error) {
      EXPECT_FALSE(fs::exists(out / "estimator.yaml"));
      return std::string(error.what());
    }
    return std::string("accepted");
  };
  EXPECT_THAT(refusal("object_noise: 0.1\nodometry_translation_sigma: 0.05\n"),
              ::testing::HasSubstr("not a detector's key: odometry_translation_sigma"));
  EXPECT_THAT(refusal("object_offset_sigma: 0.5\nobject_noise_persistent: 0.5\n"),
              ::testing::HasSubstr("object_offset_sigma"));
  EXPECT_THAT(refusal("feature_drift_sigma: -0.01\n"), ::testing::HasSubstr("feature_drift_sigma"));
  EXPECT_THAT(refusal("- 0.5\n"), ::testing::HasSubstr("a map of estimator object noise keys"));
  EXPECT_THAT(refusal("object_noise: [1, 2\n"), ::testing::HasSubstr(model.string()));
  EXPECT_THAT(refusal(""), ::testing::HasSubstr("a map of estimator object noise keys"));
  options.detector_model = model.parent_path() / "missing.yaml";
  EXPECT_THROW((void)run_frontend(rendered_sequence().team, stated, options), FrontendError);
}

/// A team folder of `robots` copies of the rendered sequence (robot_NN), each with its
/// detections' classes replaced by `classes[robot]` (cycled over the detections), and the
/// rendered team's dataset.json when `declared`.
fs::path team_of_copies(int robots, const std::vector<std::vector<std::string>>& classes,
                        bool declared) {
  const fs::path team = testing::temporary_folder("frontend_team");
  for (int robot = 0; robot < robots; ++robot) {
    const fs::path folder = team / dataset::robot_folder_name(robot);
    fs::copy(rendered_sequence().sequence, folder, fs::copy_options::recursive);
    auto detections = read_detections(folder / "detections.csv", 16);
    std::size_t next = 0;
    for (auto& frame : detections) {
      for (Detection& detection : frame) {
        detection.class_name = classes[robot][next++ % classes[robot].size()];
      }
    }
    std::ofstream(folder / "detections.csv") << format_detections(detections);
  }
  if (declared) fs::copy_file(rendered_sequence().team / "dataset.json", team / "dataset.json");
  return team;
}

TEST(FrontendRun, ATeamsDetectorIdsArePrivateAndItsStartsUnknownUnlessDeclared) {
  FrontendRunOptions options;
  options.max_frames = 3;
  const std::vector<std::vector<std::string>> cubes = {{"cube"}, {"cube"}};
  {
    // Two robots' own detectors and no word on how their ids or frames relate.
    const fs::path out = testing::temporary_folder("frontend_team_out");
    const FrontendRunSummary summary = run_frontend(team_of_copies(2, cubes, false), out, options);
    EXPECT_EQ(summary.object_ids, dataset::ObjectIds::kPrivate);
    EXPECT_EQ(summary.start_poses, dataset::StartPoses::kUnknown);
    const dataset::Dataset data = dataset::read_dataset(out);
    EXPECT_EQ(data.object_ids, dataset::ObjectIds::kPrivate);
    EXPECT_EQ(data.start_poses, dataset::StartPoses::kUnknown);
  }
  {
    // The rendered team's dataset.json says its ids are global and its starts known.
    const fs::path out = testing::temporary_folder("frontend_team_out");
    const FrontendRunSummary summary = run_frontend(team_of_copies(2, cubes, true), out, options);
    const dataset::Dataset data = dataset::read_dataset(out);
    EXPECT_EQ(data.object_ids, dataset::ObjectIds::kGlobal);
    EXPECT_EQ(data.start_poses, dataset::StartPoses::kKnown);
    EXPECT_EQ(summary.object_ids, dataset::ObjectIds::kGlobal);
  }
  {
    // What the user says wins.
    const fs::path out = testing::temporary_folder("frontend_team_out");
    options.object_ids = dataset::ObjectIds::kGlobal;
    options.start_poses = dataset::StartPoses::kKnown;
    (void)run_frontend(team_of_copies(2, cubes, false), out, options);
    const dataset::Dataset data = dataset::read_dataset(out);
    EXPECT_EQ(data.object_ids, dataset::ObjectIds::kGlobal);
    EXPECT_EQ(data.start_poses, dataset::StartPoses::kKnown);
  }
  {
    // The robots' up axis goes to estimator.yaml for the negotiation's tilt check.
    const fs::path out = testing::temporary_folder("frontend_team_out");
    FrontendRunOptions level = options;
    level.up_axis = "-y";
    (void)run_frontend(team_of_copies(2, cubes, false), out, level);
    EXPECT_EQ(config::load_negotiation_options(out / "estimator.yaml").association.start_up_axis,
              "-y");
    EXPECT_NO_THROW((void)config::load_estimator_options(out / "estimator.yaml"));
    level.up_axis = "up";
    EXPECT_THROW((void)run_frontend(team_of_copies(2, cubes, false), out, level), FrontendError);
    // Unknown (the default) writes no association section: the in-class default, unknown.
    (void)run_frontend(team_of_copies(2, cubes, false), out, options);
    EXPECT_EQ(config::load_negotiation_options(out / "estimator.yaml").association.start_up_axis,
              "unknown");
  }
  // One sequence has no one to associate with: global and known.
  options = FrontendRunOptions{};
  options.max_frames = 3;
  const fs::path out = testing::temporary_folder("frontend_team_out");
  (void)run_frontend(rendered_sequence().sequence, out, options);
  const dataset::Dataset data = dataset::read_dataset(out);
  EXPECT_EQ(data.object_ids, dataset::ObjectIds::kGlobal);
  EXPECT_EQ(data.start_poses, dataset::StartPoses::kKnown);
}

/// The class of every object observation of a dataset, in order.
std::vector<int> all_classes(const dataset::Dataset& data, int robot) {
  std::vector<int> out;
  for (const auto& frame : data.robots[robot].object_classes) out.insert(out.end(), frame.begin(), frame.end());
  return out;
}

TEST(FrontendRun, TheDetectorsClassesAreNumberedAlikeForEveryRobot) {
  FrontendRunOptions options;
  options.max_frames = 3;
  {
    // Names: numbered in sorted order over the team (bike 0, car 1, person 2), whichever robot
    // saw which.
    const fs::path out = testing::temporary_folder("frontend_team_out");
    const FrontendRunSummary summary =
        run_frontend(team_of_copies(2, {{"car", "person"}, {"bike", "car"}}, false), out, options);
    EXPECT_EQ(summary.classes, (std::vector<std::string>{"bike", "car", "person"}));
    const dataset::Dataset data = dataset::read_dataset(out);
    ASSERT_TRUE(data.robots[0].has_object_classes);
    ASSERT_TRUE(data.robots[1].has_object_classes);
    const std::vector<int> first = all_classes(data, 0), second = all_classes(data, 1);
    ASSERT_FALSE(first.empty());
    ASSERT_FALSE(second.empty());
    for (const int c : first) EXPECT_TRUE(c == 1 || c == 2);
    for (const int c : second) EXPECT_TRUE(c == 0 || c == 1);
    EXPECT_NE(std::find(first.begin(), first.end(), 2), first.end());
    EXPECT_NE(std::find(second.begin(), second.end(), 0), second.end());
  }
  {
    // Numbers are kept as they are.
    const fs::path out = testing::temporary_folder("frontend_team_out");
    const FrontendRunSummary summary =
        run_frontend(team_of_copies(2, {{"3", "17"}, {"17"}}, false), out, options);
    EXPECT_TRUE(summary.classes.empty());
    const dataset::Dataset data = dataset::read_dataset(out);
    for (const int c : all_classes(data, 0)) EXPECT_TRUE(c == 3 || c == 17);
    for (const int c : all_classes(data, 1)) EXPECT_EQ(c, 17);
    EXPECT_FALSE(all_classes(data, 1).empty());
  }
  {
    // The team's list (as the daemons get it): a robot processed alone that sees only cars numbers
    // them as the team does (bike 0, car 1, person 2), and a class outside the list is an error.
    const fs::path out = testing::temporary_folder("frontend_team_out");
    options.classes = {"person", "car", "bike"};
    const FrontendRunSummary summary =
        run_frontend(team_of_copies(2, {{"car"}, {"car"}}, false), out, options);
    EXPECT_EQ(summary.classes, (std::vector<std::string>{"bike", "car", "person"}));
    const dataset::Dataset data = dataset::read_dataset(out);
    ASSERT_FALSE(all_classes(data, 0).empty());
    for (const int c : all_classes(data, 0)) EXPECT_EQ(c, 1);
    options.classes = {"person", "bike"};
    EXPECT_THROW((void)run_frontend(team_of_copies(2, {{"car"}, {"car"}}, false), out, options),
                 FrontendError);
  }
}

}  // namespace
}  // namespace concord::frontend

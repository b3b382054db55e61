#pragma once
/// \file
/// A top view of a team run (world x-y plane, x to the right, y up) written as a PNG: per robot
/// the ground truth, the odometry dead reckoning and the estimate, with true and estimated objects.

#include <Eigen/Core>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "evaluation/line_plot.h"
#include "evaluation/metrics.h"

namespace concord::evaluation {

/// Width of the image write_top_view_png writes, in pixels.
inline constexpr int kTopViewWidth = 1400;
/// Height of the image write_top_view_png writes, in pixels.
inline constexpr int kTopViewHeight = 1100;

/// Draws the world x-y plane at equal scale on both axes, with a metre scale bar, a legend and the
/// title. Per robot, in its own colour: ground truth thin and solid in a grey tint of the colour,
/// odometry dead reckoning (from the first ground-truth pose) thin and dashed, the estimate thick,
/// estimated objects as filled dots; true objects are black crosses. results[i] and truths[i] are
/// robot i (throws std::invalid_argument when their counts differ); a trajectory may be empty.
/// The view covers the ground truth and true objects, widened to take in estimates that stray by
/// up to half that extent on each side; anything beyond is clipped at the border.
/// Throws std::runtime_error naming the file when it cannot be written.
void write_top_view_png(const std::filesystem::path& file, const std::vector<RobotTruth>& truths,
                        const std::vector<RobotResult>& results,
                        const std::map<LandmarkId, Eigen::Vector3d>& objects_groundtruth,
                        const std::string& title);

/// Pose NEES over time for a NEES-over-time chart: per frame, the median over the robots that
/// have a pose NEES at that frame, averaged over windows of `window` frames (x: the window's
/// middle frame); plus the expected value (6) and the 95 % bound of chi2(6) as dashed lines.
/// nullopt when no robot has pose covariances.
std::optional<LinePlot> pose_nees_plot(const std::vector<RobotTruth>& truths,
                                       const std::vector<RobotResult>& results, int window,
                                       const std::string& title);

}  // namespace concord::evaluation

// concordd's image source: a stereo sequence through the front-end on the source thread into the
// estimator queue (source.kind: images).
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>

#include "concord/config/options_file.h"
#include "concord/daemon/config.h"
#include "concord/daemon/daemon.h"
#include "concord/dataset/result_io.h"
#include "concord/frontend/detections.h"
#include "concord/frontend/frontend.h"
#include "concord/frontend/sequence.h"
#include "frontend_test_support.h"

namespace concord::daemon {
namespace {

namespace fs = std::filesystem;

TEST(DaemonImageSource, ConfigReadsTheSequenceDetectionsAndFrontEndOptions) {
  const DaemonConfig config = parse_daemon_config(
      "consensus: {mode: off}\n"
      "source: {kind: images, images: seq, detections: seq/boxes.csv, frontend: fe.yaml, "
      "rate_hz: 20}\n",
      "robot.yaml", "/base");
  EXPECT_EQ(config.source.kind, SourceKind::kImages);
  EXPECT_EQ(config.source.images, fs::path("/base/seq"));
  EXPECT_EQ(config.source.detections, fs::path("/base/seq/boxes.csv"));
  EXPECT_EQ(config.source.frontend, fs::path("/base/fe.yaml"));
  EXPECT_DOUBLE_EQ(config.source.rate_hz, 20.0);
  EXPECT_TRUE(config.source.observation_noise);  // each point observation's own noise
  EXPECT_FALSE(parse_daemon_config("consensus: {mode: off}\nsource: {kind: images, images: seq, "
                                   "observation_noise: false}\n",
                                   "robot.yaml", "/")
                   .source.observation_noise);
  try {
    (void)parse_daemon_config("consensus: {mode: off}\nsource: {kind: images}\n", "robot.yaml",
                              "/");
    FAIL() << "expected a ConfigError";
  } catch (const config::ConfigError& error) {
    EXPECT_NE(std::string(error.what()).find("source.images: required for images"),
              std::string::npos);
  }
}

TEST(DaemonImageSource, TheDaemonRunsTheFrontEndIntoTheEstimator) {
  const auto& rendered = testing::rendered_sequence();
  const fs::path out = testing::temporary_folder("daemon_images");
  const DaemonConfig config = parse_daemon_config(
      "source: {kind: images, images: " + rendered.sequence.string() +
          "}\n"
          "consensus: {mode: off}\n"
          "http: {enabled: false}\n"
          "output: {directory: " +
          out.string() +
          ", write_interval_ms: 0}\n"
          "estimator: {odometry_translation_sigma: 0.01, odometry_rotation_sigma: 0.002, "
          "feature_noise: 0.5, object_noise: 2.0, "
          "object_init_max_reprojection_error: 6.0, object_min_distance: 1.0}\n",
      "robot.yaml", "/");
  Daemon daemon(config);
  ASSERT_EQ(daemon.run(), 0);
  const auto trajectory = dataset::read_trajectory_kitti(out / "trajectory.kitti");
  const auto& truth = rendered.simulated.robots[0].groundtruth;
  ASSERT_EQ(trajectory.size(), truth.size());
  // The KITTI layout's body is the left camera, at the simulated body's position.
  for (std::size_t frame = 0; frame < truth.size(); ++frame) {
    EXPECT_LT((trajectory[frame].translation() - truth[frame].translation()).norm(), 0.1)
        << "frame " << frame;
  }
  const auto stats = nlohmann::json::parse(std::ifstream(out / "stats.json"));
  EXPECT_EQ(stats["frames"], truth.size());
  EXPECT_EQ(stats["frames_rejected"], 0);
  // The front-end's counts are those of the same front-end run outside the daemon.
  frontend::StereoSequence sequence = frontend::read_stereo_sequence(rendered.sequence);
  const int frames = sequence.num_frames();
  frontend::StereoFrontend direct(
      std::move(sequence), {},
      frontend::read_detections(rendered.sequence / "detections.csv", frames));
  long long detections = 0, observed = 0, refused = 0;
  while (!direct.done()) {
    const frontend::FrontendFrame frame = direct.process_next();
    detections += frame.detections;
    observed += frame.objects_observed;
    refused += frame.objects_ambiguous + frame.objects_inconsistent;
  }
  ASSERT_GT(observed, 0);
  EXPECT_EQ(stats["frontend"]["detections"], detections);
  EXPECT_EQ(stats["frontend"]["objects_observed"], observed);
  EXPECT_EQ(stats["frontend"]["objects_refused"], refused);
  EXPECT_EQ(stats["frontend"]["odometry_failures"], 0);
}

TEST(DaemonImageSource, AnUnreadableSequenceStopsTheDaemonWithStatusTwo) {
  const fs::path out = testing::temporary_folder("daemon_images_missing");
  const DaemonConfig config = parse_daemon_config(
      "source: {kind: images, images: " + (out / "nothing").string() +
          "}\nconsensus: {mode: off}\nhttp: {enabled: false}\noutput: {directory: " + out.string() +
          "}\n",
      "robot.yaml", "/");
  Daemon daemon(config);
  EXPECT_EQ(daemon.run(), 2);
}

TEST(DaemonImageSource, ADetectedClassOutsideTheTeamsListStopsTheDaemonWithStatusTwo) {
  const auto& rendered = testing::rendered_sequence();
  const fs::path out = testing::temporary_folder("daemon_images_classes");
  // The rendered detections are all of class "cube".
  const std::string head =
      "source: {kind: images, images: " + rendered.sequence.string() + ", classes: [";
  const std::string tail = "]}\nconsensus: {mode: off}\nhttp: {enabled: false}\n"
                           "output: {directory: " + out.string() + "}\n";
  {
    Daemon daemon(parse_daemon_config(head + "ball, box" + tail, "robot.yaml", "/"));
    EXPECT_EQ(daemon.run(), kExitCannotStart);
  }
  try {
    (void)parse_daemon_config(head + "cube, ''" + tail, "robot.yaml", "/");
    FAIL() << "expected a ConfigError";
  } catch (const config::ConfigError& error) {
    EXPECT_NE(std::string(error.what()).find("source.classes: an empty class name"),
              std::string::npos)
        << error.what();
  }
  const DaemonConfig listed = parse_daemon_config(head + "cube, ball" + tail, "robot.yaml", "/");
  EXPECT_EQ(listed.source.classes, (std::vector<std::string>{"cube", "ball"}));
}

}  // namespace
}  // namespace concord::daemon

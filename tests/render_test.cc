// concord sim --render's world: deterministic images, ray casting, visible object boxes and the
// world.csv geometry that evaluations read back.
#include "sim/render.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <map>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>
#include <optional>

#include "frontend_test_support.h"
#include "sim/simulator.h"

namespace concord::sim {
namespace {

using concord::testing::rendered_sequence;

TEST(Render, SameWorldAndSeedGiveTheSameImage) {
  const auto& rendered = rendered_sequence();
  const Eigen::Isometry3d pose =
      rendered.simulated.robots[0].groundtruth[5] * rendered.camera.T_cam0_body.inverse();
  const auto first = rendered.world.render(rendered.camera.K, pose, 120, 80, 1.0, 42);
  EXPECT_EQ(first, rendered.world.render(rendered.camera.K, pose, 120, 80, 1.0, 42));
  EXPECT_NE(first, rendered.world.render(rendered.camera.K, pose, 120, 80, 1.0, 43));
  // Without noise, two seeds agree.
  EXPECT_EQ(rendered.world.render(rendered.camera.K, pose, 120, 80, 0.0, 1),
            rendered.world.render(rendered.camera.K, pose, 120, 80, 0.0, 2));
}

TEST(Render, RaysMeetTheNearestSurfaceAndObjectCubesAreWhereTheObjectsAre) {
  const auto& rendered = rendered_sequence();
  ASSERT_FALSE(rendered.world.cubes().empty());
  for (const TexturedWorld::Cube& cube : rendered.world.cubes()) {
    EXPECT_EQ(rendered.simulated.objects_groundtruth.at(cube.id), cube.centre);
    // From 5 m above, straight down: the cube's top face, half a cube above the centre.
    const Eigen::Vector3d origin = cube.centre + Eigen::Vector3d(0.0, 0.0, 5.0);
    const auto hit = rendered.world.cast(origin, Eigen::Vector3d(0.0, 0.0, -1.0));
    ASSERT_TRUE(hit.has_value());
    if (rendered.world.quads()[hit->quad].object == cube.id) {
      EXPECT_NEAR(hit->distance, 5.0 - cube.half_size, 1e-9);
    }
  }
  // Nothing is outside the hall.
  EXPECT_FALSE(rendered.world.cast(Eigen::Vector3d(1e4, 0.0, 0.0), Eigen::Vector3d(1.0, 0.0, 0.0))
                   .has_value());
}

TEST(Render, VisibleBoxesContainTheObjectCentreAndAreUnoccluded) {
  const auto& rendered = rendered_sequence();
  const StereoCamera& camera = rendered.camera;
  int boxes = 0;
  for (const Eigen::Isometry3d& pose : rendered.simulated.robots[0].groundtruth) {
    for (const ObjectBox& box :
         visible_object_boxes(rendered.world, camera, pose, rendered.render.width,
                              rendered.render.height, 0.5, 10.0)) {
      ++boxes;
      const Eigen::Vector3d p =
          camera.T_cam0_body * pose.inverse() * rendered.simulated.objects_groundtruth.at(box.id);
      const double u = camera.K(0, 0) * p.x() / p.z() + camera.K(0, 2);
      const double v = camera.K(1, 1) * p.y() / p.z() + camera.K(1, 2);
      EXPECT_GT(u, box.x_min);
      EXPECT_LT(u, box.x_max);
      EXPECT_GT(v, box.y_min);
      EXPECT_LT(v, box.y_max);
      EXPECT_GE(box.x_min, 0.0);
      EXPECT_LE(box.y_max, rendered.render.height - 1.0);
    }
  }
  EXPECT_GT(boxes, 10);
}

TEST(Render, WorldGeometryReadsBack) {
  const auto& rendered = rendered_sequence();
  const TexturedWorld geometry = read_world_geometry(rendered.team / "world.csv");
  ASSERT_EQ(geometry.quads().size(), rendered.world.quads().size());
  EXPECT_EQ(geometry.texture_count(), 0);
  const Eigen::Vector3d origin = rendered.simulated.robots[0].groundtruth[0].translation();
  for (const Eigen::Vector3d& direction :
       {Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0.3, 1, 0.2), Eigen::Vector3d(0, -1, -0.4)}) {
    const auto a = rendered.world.cast(origin, direction);
    const auto b = geometry.cast(origin, direction);
    ASSERT_TRUE(a && b);
    EXPECT_EQ(a->quad, b->quad);
    EXPECT_NEAR(a->distance, b->distance, 1e-12);
  }
  EXPECT_THROW((void)geometry.render(rendered.camera.K, Eigen::Isometry3d::Identity(), 10, 10, 0, 0),
               std::logic_error);
}

TEST(Render, PointTracksAreOfSurfacePointsBothCamerasSee) {
  const auto& rendered = rendered_sequence();
  SimulationOptions options = rendered.simulation;
  options.points_per_frame = 60;
  options.point_track_loss = 0.1;
  options.pixel_noise = 0.0;  // exact observations: the points can be recovered exactly
  const SurfaceCast cast = [&world = rendered.world](const Eigen::Vector3d& origin,
                                                      const Eigen::Vector3d& direction) {
    const auto hit = world.cast(origin, direction);
    return hit ? std::optional<double>(hit->distance) : std::nullopt;
  };
  dataset::Dataset data = rendered.simulated;
  place_point_features_on_surfaces(data, options, cast);
  const dataset::RobotData& robot = data.robots[0];
  ASSERT_TRUE(robot.has_features);
  ASSERT_EQ(robot.features.size(), robot.groundtruth.size());
  const StereoCamera& camera = data.camera;
  std::map<LandmarkId, std::pair<int, Eigen::Vector3d>> tracks;  // last frame, point
  double farthest = 0.0;
  long long observations = 0;
  for (int k = 0; k < robot.num_frames(); ++k) {
    // Every frame is filled up to the target (a hall has surfaces in every direction).
    EXPECT_EQ(robot.features[k].size(), 60u) << "frame " << k;
    const Eigen::Isometry3d T_world_cam0 = robot.groundtruth[k] * camera.T_cam0_body.inverse();
    const Eigen::Isometry3d T_world_cam1 = robot.groundtruth[k] * camera.T_cam1_body().inverse();
    for (const StereoObservation& observation : robot.features[k]) {
      ++observations;
      // The stereo point (K is the identity): depth = baseline / disparity.
      const double disparity = observation.uv(0) - observation.uv(2);
      ASSERT_GT(disparity, 0.0);
      const double depth = camera.baseline() / disparity;
      farthest = std::max(farthest, depth);
      EXPECT_GE(depth, options.min_depth - 1e-9);
      EXPECT_NEAR(observation.uv(1), observation.uv(3), 1e-12);
      const Eigen::Vector3d p_world =
          T_world_cam0 * Eigen::Vector3d(observation.uv(0) * depth, observation.uv(1) * depth, depth);
      // On a surface that both cameras see first along their rays.
      const std::array<Eigen::Vector3d, 2> centres{T_world_cam0.translation(),
                                                    T_world_cam1.translation()};
      for (const Eigen::Vector3d& centre : centres) {
        const auto hit = rendered.world.cast(centre, p_world - centre);
        ASSERT_TRUE(hit.has_value());
        EXPECT_NEAR(hit->distance, 1.0, 1e-6);
      }
      // A track follows one point over consecutive frames.
      auto [it, first] = tracks.try_emplace(observation.id, k, p_world);
      if (!first) {
        EXPECT_EQ(it->second.first, k - 1) << "track " << observation.id;
        EXPECT_LT((it->second.second - p_world).norm(), 1e-6) << "track " << observation.id;
        it->second.first = k;
      }
    }
  }
  // Tracks end (point_track_loss, the view, occlusion) and new ones start.
  EXPECT_GT(tracks.size(), 60u);
  EXPECT_LT(static_cast<double>(tracks.size()), 0.8 * static_cast<double>(observations));
  // Surfaces beyond the simulated detectors' range are seen too.
  EXPECT_GT(farthest, options.max_depth);
  // Deterministic.
  dataset::Dataset again = rendered.simulated;
  place_point_features_on_surfaces(again, options, cast);
  for (int k = 0; k < robot.num_frames(); ++k) {
    ASSERT_EQ(again.robots[0].features[k].size(), robot.features[k].size());
    for (std::size_t i = 0; i < robot.features[k].size(); ++i) {
      EXPECT_EQ(again.robots[0].features[k][i].id, robot.features[k][i].id);
      EXPECT_EQ(again.robots[0].features[k][i].uv, robot.features[k][i].uv);
    }
  }
}

// A texture's content stays where its surface puts it at every level of the mip-map: a bright
// blob on a plane facing the camera, seen from distances that sample pyramid levels 0 to 3 (and
// blends between them), is imaged where the blob's surface point projects. (Sampling level L
// at x / 2^L shifted it by (2^L - 1) / 2 texels, 0.44 px in the image at level 3.)
TEST(Render, TextureContentStaysOnItsSurfaceAtEveryMipLevel) {
  const std::filesystem::path folder =
      std::filesystem::path(::testing::TempDir()) / "concord_render_mip_texture";
  std::filesystem::create_directories(folder);
  const int side = 256;
  const double blob_x = 97.3, blob_y = 141.7, blob_sigma = 8.0;  // texels (centres at i + 0.5)
  cv::Mat texture(side, side, CV_8UC1);
  for (int row = 0; row < side; ++row) {
    for (int column = 0; column < side; ++column) {
      const double dx = column + 0.5 - blob_x, dy = row + 0.5 - blob_y;
      texture.at<unsigned char>(row, column) = static_cast<unsigned char>(std::lround(
          40.0 + 200.0 * std::exp(-0.5 * (dx * dx + dy * dy) / (blob_sigma * blob_sigma))));
    }
  }
  ASSERT_TRUE(cv::imwrite((folder / "blob.png").string(), texture));
  const double focal = 200.0, texels_per_metre = 100.0;
  const int size = 160;
  Eigen::Matrix3d K;
  K << focal, 0.0, 80.0, 0.0, focal, 80.0, 0.0, 0.0, 1.0;
  for (const double level : {0.0, 1.0, 1.5, 2.0, 2.5, 3.0}) {
    // footprint = texels_per_metre * depth / focal texels a pixel (at the image centre).
    const double depth = std::pow(2.0, level) * focal / texels_per_metre;
    TexturedWorld scene(folder);
    TexturedWorld::Quad quad;
    const double width = side / texels_per_metre;
    // The blob straight ahead of the camera, on the optical axis.
    quad.corner = Eigen::Vector3d(-blob_x / texels_per_metre, -blob_y / texels_per_metre, depth);
    quad.edge_u = Eigen::Vector3d(width, 0.0, 0.0);
    quad.edge_v = Eigen::Vector3d(0.0, width, 0.0);
    quad.texels_per_metre = texels_per_metre;
    scene.add_quad(quad);
    const std::vector<std::uint8_t> image =
        scene.render(K, Eigen::Isometry3d::Identity(), size, size, 0.0, 1);
    // The blob's centroid over the background, in a window around the principal point.
    const double reach = 4.0 * blob_sigma / std::pow(2.0, level) + 4.0;
    double sum = 0.0, sum_u = 0.0, sum_v = 0.0;
    for (int row = 0; row < size; ++row) {
      for (int column = 0; column < size; ++column) {
        if (std::abs(column - 80.0) > reach || std::abs(row - 80.0) > reach) continue;
        const double weight = std::max(0.0, image[row * size + column] - 40.0);
        sum += weight;
        sum_u += weight * column;
        sum_v += weight * row;
      }
    }
    ASSERT_GT(sum, 0.0) << "level " << level;
    EXPECT_NEAR(sum_u / sum, 80.0, 0.05) << "level " << level;
    EXPECT_NEAR(sum_v / sum, 80.0, 0.05) << "level " << level;
  }
}

// A pixel averages the light over its area (supersampling): KLT follows the corners of a
// textured wall the camera approaches (1-4 % of scale a step, as in the rendered sequences) more
// faithfully than on images of one sample a pixel (measured: median 0.042 px against 0.049 px).
TEST(Render, SupersampledImagesAreTrackedMoreFaithfully) {
  TexturedWorld world(concord::testing::euroc_frames());
  const double focal = 300.0, depth = 5.0, texels_per_metre = 80.0;  // 1.3 texels a pixel
  TexturedWorld::Quad wall;
  wall.corner = Eigen::Vector3d(-4.0, -3.0, depth);
  wall.edge_u = Eigen::Vector3d(8.0, 0.0, 0.0);
  wall.edge_v = Eigen::Vector3d(0.0, 6.0, 0.0);
  wall.texels_per_metre = texels_per_metre;
  world.add_quad(wall);
  const int size = 160;
  const float centre = 79.5f;
  Eigen::Matrix3d K;
  K << focal, 0.0, centre, 0.0, focal, centre, 0.0, 0.0, 1.0;
  const auto image_of = [&](const Eigen::Isometry3d& pose, int samples) {
    std::vector<std::uint8_t> pixels = world.render(K, pose, size, size, 0.0, 1, samples);
    return cv::Mat(size, size, CV_8UC1, pixels.data()).clone();
  };
  // KLT's error against the true motion of each corner (the image scales about its centre),
  // pooled over five steps forward: the median, pixels. (Its tail is the translation-only
  // model's error under scale, alike with or without supersampling.)
  const auto tracking_errors = [&](int samples) {
    const cv::Mat before = image_of(Eigen::Isometry3d::Identity(), samples);
    std::vector<cv::Point2f> corners;
    cv::goodFeaturesToTrack(before, corners, 60, 0.01, 8.0, cv::noArray(), 5);
    std::vector<double> errors;
    for (const double forward : {0.03, 0.07, 0.11, 0.15, 0.22}) {
      Eigen::Isometry3d moved = Eigen::Isometry3d::Identity();
      moved.translation().z() = forward;
      const auto scale = static_cast<float>(depth / (depth - forward));
      std::vector<cv::Point2f> tracked;
      std::vector<unsigned char> status;
      std::vector<float> residuals;
      cv::calcOpticalFlowPyrLK(before, image_of(moved, samples), corners, tracked, status,
                               residuals, cv::Size(11, 11), 2);
      for (std::size_t i = 0; i < corners.size(); ++i) {
        if (!status[i]) continue;
        const cv::Point2f truth = (corners[i] - cv::Point2f(centre, centre)) * scale +
                                  cv::Point2f(centre, centre);
        errors.push_back(std::hypot(tracked[i].x - truth.x, tracked[i].y - truth.y));
      }
    }
    EXPECT_GE(errors.size(), 80u) << samples << " samples";
    std::nth_element(errors.begin(), errors.begin() + errors.size() / 2, errors.end());
    return errors[errors.size() / 2];
  };
  const double one = tracking_errors(1), three = tracking_errors(3);
  EXPECT_LT(three, 0.05);
  EXPECT_LT(three, 0.95 * one);
}

TEST(Render, InvalidOptionsAreNamed) {
  RenderOptions options;
  options.width = 10;
  options.object_size = -1.0;
  const auto problems = options.validate();
  ASSERT_EQ(problems.size(), 2u);
  EXPECT_NE(problems[0].find("--render-width"), std::string::npos);
  EXPECT_NE(problems[1].find("--render-object-size"), std::string::npos);
  RenderOptions unsampled;
  unsampled.supersampling = 0;
  ASSERT_EQ(unsampled.validate().size(), 1u);
  EXPECT_NE(unsampled.validate().front().find("--render-supersampling"), std::string::npos);
}

}  // namespace
}  // namespace concord::sim

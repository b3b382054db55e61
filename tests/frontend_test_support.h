#pragma once
/// Shared helpers for the front-end tests: a small rendered sequence (concord sim --render's code
/// path: simulated path and objects, textured world, KITTI layout), rendered once per build,
/// and the repository's EuRoC frames.

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <system_error>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/imgproc.hpp>

#include "concord/dataset/dataset.h"
#include "sim/render.h"
#include "sim/simulator.h"

namespace concord::testing {

/// A smooth random texture (blurred uniform noise), the same for the same seed.
inline cv::Mat random_texture(cv::Size size, int seed) {
  cv::Mat texture(size, CV_8UC1);
  cv::RNG rng(seed);
  rng.fill(texture, cv::RNG::UNIFORM, 0, 256);
  cv::GaussianBlur(texture, texture, cv::Size(0, 0), 1.5);
  return texture;
}

/// The four EuRoC V1_01 stereo pairs kept in the repository (data/README.md).
inline std::filesystem::path euroc_frames() {
  return std::filesystem::path(CONCORD_SOURCE_DIR) / "data" / "euroc-v101-static-4";
}

/// The folders temporary_folder made, removed when the test process ends.
class TemporaryFolders {
 public:
  void add(const std::filesystem::path& folder) { folders_.push_back(folder); }
  ~TemporaryFolders() {
    std::error_code ignored;
    for (const auto& folder : folders_) std::filesystem::remove_all(folder, ignored);
  }

 private:
  std::vector<std::filesystem::path> folders_;
};

inline TemporaryFolders& temporary_folders() {
  static TemporaryFolders folders;
  return folders;
}

/// A fresh temporary folder for one test (removed when the test process ends).
inline std::filesystem::path temporary_folder(const std::string& name) {
  const std::filesystem::path folder = std::filesystem::path(::testing::TempDir()) /
                                       ("concord_" + name + "_" + std::to_string(getpid()));
  std::filesystem::remove_all(folder);
  std::filesystem::create_directories(folder);
  temporary_folders().add(folder);
  return folder;
}

/// Where the rendered sequence is kept between the test processes of one build (ctest runs each
/// test in its own process; rendering is most of a front-end test's time, above all under the
/// sanitizers): build/test-out/rendered-sequence-<time of the test binary>. A rebuilt binary
/// renders afresh; the folders of earlier binaries are removed (a process renders into
/// rendered-sequence-<time>-<pid> first).
inline std::filesystem::path rendered_sequence_cache() {
  namespace fs = std::filesystem;
  std::error_code error;
  const auto built = fs::last_write_time("/proc/self/exe", error);
  const std::string name =
      "rendered-sequence-" + std::to_string(error ? 0 : built.time_since_epoch().count());
  const fs::path parent = fs::path(CONCORD_BINARY_DIR) / "test-out";
  fs::create_directories(parent, error);
  for (const auto& entry : fs::directory_iterator(parent, error)) {
    const std::string other = entry.path().filename().string();
    const bool ours = other == name || other.rfind(name + "-", 0) == 0;
    if (other.rfind("rendered-sequence-", 0) == 0 && !ours)
      fs::remove_all(entry.path(), error);
  }
  return parent / name;
}

/// One robot flying 16 frames of a Lissajous path (0.22 m a frame) through a textured hall with
/// object cubes, rendered at 376 x 240 pixels.
struct RenderedSequence {
  std::filesystem::path team;      ///< the dataset folder (robot_00 inside)
  std::filesystem::path sequence;  ///< team / robot_00, a KITTI-layout sequence
  dataset::Dataset simulated;      ///< the simulator's dataset (exact ground truth)
  StereoCamera camera;             ///< the rendered (rectified, pixel) camera
  sim::TexturedWorld world;        ///< the world, for true projections
  sim::RenderOptions render;
  sim::SimulationOptions simulation;
};

inline const RenderedSequence& rendered_sequence() {
  static const RenderedSequence sequence = [] {
    RenderedSequence made;
    made.simulation.robots = 1;
    made.simulation.frames = 16;
    made.simulation.objects = 40;
    made.simulation.points_per_frame = 0;
    made.simulation.seed = 3;
    made.render.width = 376;
    made.render.height = 240;
    made.render.textures = euroc_frames();
    // One sample a pixel: the tests' thresholds were set on such images, and it keeps them fast
    // (docs/frontend.md, "Track drift").
    made.render.supersampling = 1;
    const double half_width =
        std::tan(0.5 * made.simulation.horizontal_fov_degrees * 3.14159265358979323846 / 180.0);
    made.simulation.vertical_fov_degrees =
        2.0 * std::atan(half_width * made.render.height / made.render.width) * 180.0 /
        3.14159265358979323846;
    made.simulated = sim::simulate(made.simulation);
    std::vector<LandmarkId> removed;
    made.world = sim::build_world(made.simulated, made.render, made.simulation.seed, removed);
    sim::remove_objects(made.simulated, removed);
    made.camera = sim::render_camera(made.simulated.camera, made.simulation.horizontal_fov_degrees,
                                     made.render);
    made.team = rendered_sequence_cache();
    if (!std::filesystem::exists(made.team / "complete")) {
      // Rendered here, then moved into the cache in one rename: a concurrent test process
      // either finds the whole sequence or none of it, and keeps its own if another won.
      const std::filesystem::path rendered =
          made.team.string() + "-" + std::to_string(getpid());  // on the cache's file system
      std::filesystem::remove_all(rendered);
      temporary_folders().add(rendered);
      dataset::write_dataset(made.simulated, rendered);
      sim::write_rendered_sequences(made.simulated, made.world, made.camera, made.render,
                                    made.simulation.min_depth, made.simulation.max_depth,
                                    made.simulation.seed, rendered);
      std::ofstream(rendered / "complete") << "rendered\n";
      std::error_code moved;
      std::filesystem::rename(rendered, made.team, moved);
      if (moved) made.team = rendered;
    }
    made.sequence = made.team / "robot_00";
    return made;
  }();
  return sequence;
}

}  // namespace concord::testing

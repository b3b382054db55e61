#pragma once
/// \file
/// `concord launch`: one concordd per robot of a dataset on loopback, with generated configs, a
/// live status line per robot, and the outputs gathered in the replay layout
/// (OUT/robot_NN/{trajectory.kitti,objects.csv}) so that `concord eval` scores them.
///
///     OUT/configs/robot_NN.yaml   the generated daemon configs
///     OUT/logs/robot_NN.log       each daemon's log
///     OUT/robot_NN/               each daemon's outputs (trajectory.kitti, objects.csv, stats.json)

#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace concord::launch {

struct LaunchOptions {
  std::filesystem::path dataset;
  std::filesystem::path out;
  std::filesystem::path concordd;         ///< the daemon binary
  std::filesystem::path estimator_config; ///< estimator options file ("" = defaults)
  std::string mode = "lockstep";          ///< off, lockstep or async
  std::uint16_t base_port = 7100;         ///< robot i listens on base_port + i
  std::uint16_t http_base_port = 8100;    ///< robot i serves HTTP on http_base_port + i
  int robots = 0;                         ///< first robots of the dataset (0 = all)
  int frames = 0;                         ///< first frames (0 = all)
  double rate_hz = 0.0;                   ///< replay rate (0 = as fast as the mode allows)
  bool point_features = true;
  std::string team;                       ///< "" = the dataset folder name
  /// Longest run before the daemons are stopped (SIGTERM, then SIGKILL).
  std::chrono::seconds timeout{3600};
};

struct LaunchResult {
  std::vector<int> exit_codes;  ///< per robot
  double wall_seconds = 0.0;
  bool timed_out = false;
};

/// Writes the configs, starts the daemons, prints a status line per robot to `status` (every
/// half second; nothing if status is null), waits for them, and returns their exit codes.
/// `robots` is the number of robot folders to run. Throws std::runtime_error on setup errors.
LaunchResult launch_team(const LaunchOptions& options, int robots, std::ostream* status);

/// The YAML config of robot `robot` of a launched team (exposed for tests).
std::string daemon_config_yaml(const LaunchOptions& options, int robot, int robots);

}  // namespace concord::launch

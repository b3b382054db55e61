/// `concord`: the team replay, evaluation and dataset tools on the command line.
///   concord replay --dataset DIR --out DIR [--separate] [--config FILE] [--graph G] [--loss R]
///                  [--seed S] [--frames N] [--no-point-features]
///   concord eval --dataset DIR --result DIR
///   concord slice --dataset DIR --out DIR --frames N [--robots R]
///   concord launch --dataset DIR --out DIR [--lockstep|--async|--separate] [--base-port P]
///                  [--http-base-port P] [--config FILE] [--robots R] [--frames N] [--rate HZ]
///                  [--round-deadline-ms MS] [--failpoint ROBOT:NAME[=ARG] ...]
///   concord plot --input CHART.json --out CHART.png
///   concord keygen --out FILE      (a new team key, mode 0600; never overwrites)
///   concord sim --robots N --out DIR [--seed S] [--frames F] [--objects M] [--points-per-frame P]
///               [--odometry-translation-noise T] [--odometry-rotation-noise R] [--pixel-noise S]
///               ... (camera, path and object-placement parameters: concord sim --help)

#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>

#include "concord/config/options_file.h"
#include "concord/dataset/dataset.h"
#include "concord/dataset/result_io.h"
#include "concord/net/team_key.h"
#include "evaluation/line_plot.h"
#include "evaluation/metrics.h"
#include "evaluation/plot.h"
#include "launch/launch.h"
#include "replay/team_replay.h"
#include "sim/simulator.h"

namespace fs = std::filesystem;
using namespace concord;

namespace {

/// The checked-in config of a dataset, configs/datasets/<name>.yaml, if there is one.
std::optional<fs::path> dataset_config(const std::string& name) {
  const fs::path candidate = fs::path(CONCORD_CONFIG_DIR) / "datasets" / (name + ".yaml");
  if (fs::exists(candidate)) return candidate;
  return std::nullopt;
}

std::vector<evaluation::RobotTruth> truths_of(const dataset::Dataset& data) {
  std::vector<evaluation::RobotTruth> truths;
  for (const auto& robot : data.robots) truths.push_back({robot.groundtruth, robot.odometry});
  return truths;
}

/// Metrics, table, metrics.json and plot for a result in the replay layout.
evaluation::TeamMetrics report(const dataset::Dataset& data,
                               const std::vector<evaluation::RobotResult>& results,
                               const fs::path& out, const std::string& title,
                               nlohmann::json run_information) {
  const auto truths = truths_of(data);
  const auto metrics = evaluation::evaluate(truths, results, data.objects_groundtruth);
  std::cout << evaluation::format_table(metrics, title) << std::flush;
  nlohmann::json document = evaluation::to_json(metrics);
  document["run"] = std::move(run_information);
  dataset::write_file_atomically(out / "metrics.json", document.dump(2) + "\n");
  evaluation::write_top_view_png(out / "plot.png", truths, results, data.objects_groundtruth,
                                 title);
  std::cout << "metrics: " << (out / "metrics.json").string() << "\n"
            << "plot:    " << (out / "plot.png").string() << "\n"
            << "outputs: " << out.string() << "/robot_XX/{trajectory.kitti,objects.csv}\n";
  return metrics;
}

int run_replay(const fs::path& dataset_dir, const fs::path& out, bool separate,
               const std::string& config_file, const std::string& graph, double loss,
               std::uint64_t seed, int frames, bool no_point_features) {
  dataset::ReadOptions read_options;
  if (frames > 0) read_options.max_frames = frames;
  read_options.load_features = !no_point_features;
  const dataset::Dataset data = dataset::read_dataset(dataset_dir, read_options);

  fs::path config_path;
  EstimatorOptions options;
  if (!config_file.empty()) {
    config_path = config_file;
  } else if (auto found = dataset_config(data.name)) {
    config_path = *found;
  }
  if (!config_path.empty()) options = config::load_estimator_options(config_path);
  if (no_point_features) options.use_point_features = false;
  std::cerr << "concord replay: dataset " << data.name << " (" << data.robots.size()
            << " robots), config "
            << (config_path.empty() ? std::string("built-in defaults") : config_path.string())
            << ", " << (separate ? "separate" : "consensus") << ", graph " << graph << ", loss "
            << loss << ", seed " << seed << "\n"
            << config::to_yaml(options);

  replay::ReplayOptions replay_options;
  replay_options.consensus = !separate;
  replay_options.graph = replay::parse_graph_kind(graph);
  replay_options.link_loss = loss;
  replay_options.seed = seed;
  int last_percent = -1;
  const auto result = replay::run_team(data, options, replay_options, [&](int step, int steps) {
    const int percent = 100 * step / steps;
    if (percent / 10 != last_percent / 10 || step == steps) {
      std::cerr << "  step " << step << "/" << steps << " (" << percent << " %)\n";
      last_percent = percent;
    }
  });

  fs::create_directories(out);
  std::vector<evaluation::RobotResult> results;
  for (std::size_t i = 0; i < result.robots.size(); ++i) {
    const fs::path folder = out / dataset::robot_folder_name(static_cast<int>(i));
    fs::create_directories(folder);
    dataset::write_trajectory_kitti(folder / "trajectory.kitti", result.robots[i].trajectory);
    dataset::write_objects_csv(folder / "objects.csv", result.robots[i].objects);
    results.push_back({result.robots[i].trajectory, result.robots[i].objects});
  }
  const auto& s = result.statistics;
  nlohmann::json run = {
      {"dataset", data.name},
      {"mode", separate ? "separate" : "consensus"},
      {"graph", graph},
      {"loss", loss},
      {"seed", seed},
      {"config", config_path.string()},
      {"steps", s.steps},
      {"robot_steps", s.robot_steps},
      {"landmarks_fused", s.landmarks_fused},
      {"neighbours_skipped", s.neighbours_skipped},
      {"mean_shifts_limited", s.mean_shifts_limited},
      {"objects_initialized", s.objects_initialized},
      {"object_observations_rejected", s.object_observations_rejected},
      {"feature_tracks_used", s.feature_tracks_used},
      {"update_seconds", s.update_seconds},
      {"consensus_seconds", s.consensus_seconds},
      {"total_seconds", s.total_seconds},
      {"consensus_ms_per_robot_step",
       s.consensus_robot_steps > 0 ? 1e3 * s.consensus_seconds / s.robot_steps : 0.0},
  };
  std::cerr << "concord replay: " << s.robot_steps << " robot-steps in " << s.total_seconds
            << " s (update " << s.update_seconds << " s, consensus " << s.consensus_seconds
            << " s)\n";
  report(data, results, out,
         data.name + (separate ? " separate" : " consensus") +
             (frames > 0 ? " (" + std::to_string(frames) + " frames)" : ""),
         run);
  return 0;
}

int run_eval(const fs::path& dataset_dir, const fs::path& result_dir) {
  dataset::ReadOptions read_options;
  read_options.load_features = false;
  const dataset::Dataset data = dataset::read_dataset(dataset_dir, read_options);
  std::vector<evaluation::RobotResult> results;
  for (std::size_t i = 0; i < data.robots.size(); ++i) {
    const fs::path folder = result_dir / dataset::robot_folder_name(static_cast<int>(i));
    results.push_back({dataset::read_trajectory_kitti(folder / "trajectory.kitti"),
                       dataset::read_objects_csv(folder / "objects.csv")});
  }
  report(data, results, result_dir, data.name + " eval of " + result_dir.filename().string(),
         {{"dataset", data.name}, {"result", result_dir.string()}});
  return 0;
}

int run_slice(const fs::path& dataset_dir, const fs::path& out, int frames, int robots) {
  const dataset::Dataset data = dataset::read_dataset(dataset_dir);
  dataset::write_dataset(
      dataset::slice(data, frames, robots > 0 ? robots : static_cast<int>(data.robots.size())),
      out);
  std::cerr << "concord slice: wrote " << out.string() << "\n";
  return 0;
}

int run_sim(const sim::SimulationOptions& options, const fs::path& out) {
  if (const auto problems = options.validate(); !problems.empty()) {
    std::cerr << "concord sim: invalid parameters:\n";
    for (const auto& problem : problems) std::cerr << "  " << problem << "\n";
    return 1;
  }
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  const dataset::Dataset data = sim::simulate(options);
  const auto simulated = Clock::now();
  dataset::write_dataset(data, out);
  dataset::write_file_atomically(out / "simulation.json", sim::to_json(options));
  const auto written = Clock::now();
  const auto seconds = [](Clock::duration duration) {
    return std::chrono::duration<double>(duration).count();
  };
  const sim::SimulationSummary summary = sim::summarize(data);
  std::cout << "concord sim: " << summary.robots << " robots x " << options.frames << " frames, "
            << summary.objects << " objects, " << summary.object_observations
            << " object observations (" << summary.objects_per_frame << " a frame), "
            << summary.feature_observations << " feature observations ("
            << summary.features_per_frame << " a frame, " << summary.feature_tracks
            << " tracks, mean length " << summary.mean_track_length << "), written to "
            << out.string() << "\n";
  std::cerr << "concord sim: simulated in " << seconds(simulated - start) << " s, written in "
            << seconds(written - simulated) << " s\n";
  return 0;
}

/// Runs a team of concordd daemons on a dataset, then scores their outputs like `eval`.
int run_launch(launch::LaunchOptions options) {
  dataset::ReadOptions read_options;
  read_options.load_features = false;
  if (options.frames > 0) read_options.max_frames = options.frames;
  if (options.robots > 0) read_options.max_robots = options.robots;
  const dataset::Dataset data = dataset::read_dataset(options.dataset, read_options);
  if (options.estimator_config.empty()) {
    if (auto found = dataset_config(data.name)) options.estimator_config = *found;
  }
  const int robots = static_cast<int>(data.robots.size());
  std::cerr << "concord launch: " << robots << " concordd (" << options.mode << ") on "
            << data.name << ", peer ports " << options.base_port << "-"
            << options.base_port + robots - 1 << ", HTTP ports " << options.http_base_port << "-"
            << options.http_base_port + robots - 1 << ", logs in "
            << (options.out / "logs").string() << "\n";
  const launch::LaunchResult result = launch::launch_team(options, robots, &std::cout);
  bool all_ok = true;
  for (int robot = 0; robot < robots; ++robot) {
    if (result.exit_codes[robot] != 0) {
      all_ok = false;
      std::cerr << "concord launch: robot " << robot << " exited with "
                << result.exit_codes[robot] << " (see "
                << (options.out / "logs" / (dataset::robot_folder_name(robot) + ".log")).string() << ")\n";
    }
  }
  std::cerr << "concord launch: team finished in " << result.wall_seconds << " s\n";
  std::vector<evaluation::RobotResult> results;
  for (int robot = 0; robot < robots; ++robot) {
    const fs::path folder = options.out / dataset::robot_folder_name(robot);
    results.push_back({dataset::read_trajectory_kitti(folder / "trajectory.kitti"),
                       dataset::read_objects_csv(folder / "objects.csv")});
  }
  report(data, results, options.out, data.name + " launch (" + options.mode + ")",
         {{"dataset", data.name},
          {"mode", options.mode},
          {"daemons", robots},
          {"wall_seconds", result.wall_seconds},
          {"config", options.estimator_config.string()}});
  return all_ok ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"Concord: multi-robot object SLAM by distributed MSCKF (team replay and tools)"};
  app.require_subcommand(1);

  auto* replay_command = app.add_subcommand("replay", "Run the whole team on a dataset");
  std::string dataset_dir, out_dir, config_file, graph = "complete";
  bool separate = false, no_point_features = false;
  double loss = 0.0;
  std::uint64_t seed = 1;
  int frames = 0;
  replay_command->add_option("--dataset", dataset_dir, "Dataset folder (shared layout)")
      ->required()
      ->check(CLI::ExistingDirectory);
  replay_command->add_option("--out", out_dir, "Output folder")->required();
  replay_command->add_flag("--separate", separate, "No consensus (each robot alone)");
  replay_command
      ->add_option("--config", config_file,
                   "Estimator config (default: configs/datasets/<dataset name>.yaml)")
      ->check(CLI::ExistingFile);
  replay_command->add_option("--graph", graph, "Communication graph: complete, ring or random")
      ->check(CLI::IsMember({"complete", "ring", "random"}));
  replay_command->add_option("--loss", loss, "Per-round probability of dropping each edge")
      ->check(CLI::Range(0.0, 1.0));
  replay_command->add_option("--seed", seed, "Seed of the random graph and link loss");
  replay_command->add_option("--frames", frames, "Use only the first N frames of each robot")
      ->check(CLI::PositiveNumber);
  replay_command->add_flag("--no-point-features", no_point_features,
                           "Ignore features.csv (object-only run)");

  auto* eval_command = app.add_subcommand("eval", "Score a result folder against a dataset");
  std::string result_dir;
  eval_command->add_option("--dataset", dataset_dir, "Dataset folder")
      ->required()
      ->check(CLI::ExistingDirectory);
  eval_command->add_option("--result", result_dir, "Result folder (robot_XX/trajectory.kitti...)")
      ->required()
      ->check(CLI::ExistingDirectory);

  auto* slice_command = app.add_subcommand("slice", "Cut the first frames/robots of a dataset");
  int robots = 0;
  slice_command->add_option("--dataset", dataset_dir, "Dataset folder")
      ->required()
      ->check(CLI::ExistingDirectory);
  slice_command->add_option("--out", out_dir, "Output folder")->required();
  slice_command->add_option("--frames", frames, "Frames to keep")
      ->required()
      ->check(CLI::PositiveNumber);
  slice_command->add_option("--robots", robots, "Robots to keep (default all)")
      ->check(CLI::PositiveNumber);

  auto* sim_command = app.add_subcommand(
      "sim", "Simulate a multi-robot dataset (Lissajous paths, docs/simulator.md)");
  sim::SimulationOptions sim_options;
  sim_command->add_option("--out", out_dir, "Output folder (dataset layout)")->required();
  sim_command->add_option("--robots", sim_options.robots, "Number of robots, 1 to 1000")
      ->capture_default_str();
  sim_command->add_option("--frames", sim_options.frames, "Frames per robot")
      ->capture_default_str();
  sim_command->add_option("--objects", sim_options.objects, "Object landmarks (global ids)")
      ->capture_default_str();
  sim_command
      ->add_option("--points-per-frame", sim_options.points_per_frame,
                   "Point features visible per frame (0: no features.csv)")
      ->capture_default_str();
  sim_command
      ->add_option("--point-track-loss", sim_options.point_track_loss,
                   "Probability per frame that a visible point's track is lost, in [0, 1)")
      ->capture_default_str();
  sim_command->add_option("--seed", sim_options.seed, "Seed of every random stream")
      ->check(CLI::Validator(
          [](std::string& text) {
            return text.starts_with('-') ? std::string("must be an integer >= 0") : std::string();
          },
          ""))
      ->capture_default_str();
  sim_command
      ->add_option("--odometry-translation-noise", sim_options.odometry_translation_noise,
                   "Odometry noise per axis per frame, metres (one sigma)")
      ->capture_default_str();
  sim_command
      ->add_option("--odometry-rotation-noise", sim_options.odometry_rotation_noise,
                   "Odometry noise per axis per frame, radians (one sigma)")
      ->capture_default_str();
  sim_command
      ->add_option("--pixel-noise", sim_options.pixel_noise,
                   "Observation noise per coordinate, normalized image units (one sigma)")
      ->capture_default_str();
  sim_command->add_option("--baseline", sim_options.baseline, "Stereo baseline, metres")
      ->capture_default_str();
  sim_command
      ->add_option("--horizontal-fov", sim_options.horizontal_fov_degrees,
                   "Horizontal field of view, degrees, in (0, 180)")
      ->capture_default_str();
  sim_command
      ->add_option("--vertical-fov", sim_options.vertical_fov_degrees,
                   "Vertical field of view, degrees, in (0, 180)")
      ->capture_default_str();
  sim_command
      ->add_option("--min-depth", sim_options.min_depth,
                   "Smallest left-camera depth of an observed landmark, metres")
      ->capture_default_str();
  sim_command
      ->add_option("--max-depth", sim_options.max_depth,
                   "Largest left-camera depth of an observed landmark, metres")
      ->capture_default_str();
  sim_command->add_option("--period", sim_options.period_frames, "Frames per lap of a path")
      ->capture_default_str();
  sim_command
      ->add_option("--amplitude-x", sim_options.amplitude_x,
                   "Half-extent of a path along its x axis, metres")
      ->capture_default_str();
  sim_command
      ->add_option("--amplitude-y", sim_options.amplitude_y,
                   "Half-extent of a path along its y axis, metres")
      ->capture_default_str();
  sim_command
      ->add_option("--amplitude-z", sim_options.amplitude_z,
                   "Half-extent of a path's vertical oscillation, metres")
      ->capture_default_str();
  sim_command
      ->add_option("--frequency-x", sim_options.frequency_x,
                   "Lissajous frequency along x (integer >= 1)")
      ->capture_default_str();
  sim_command
      ->add_option("--frequency-y", sim_options.frequency_y,
                   "Lissajous frequency along y (integer >= 1; over the gcd, not both odd)")
      ->capture_default_str();
  sim_command
      ->add_option("--centre-offset", sim_options.centre_offset,
                   "Distance of each path's centre from the origin, metres")
      ->capture_default_str();
  sim_command
      ->add_option("--scale-spread", sim_options.scale_spread,
                   "Path scales are uniform in [1 - s, 1 + s], s in [0, 1)")
      ->capture_default_str();
  sim_command
      ->add_option("--object-min-depth", sim_options.object_min_depth,
                   "Smallest depth of an object in view of the pose it is placed around, metres")
      ->capture_default_str();
  sim_command
      ->add_option("--object-max-depth", sim_options.object_max_depth,
                   "Largest depth of an object in view of the pose it is placed around, metres")
      ->capture_default_str();

  auto* launch_command = app.add_subcommand(
      "launch", "Run one concordd per robot of a dataset on loopback and score the outputs");
  launch::LaunchOptions launch_options;
  launch_options.concordd = CONCORD_DAEMON_PATH;
  bool launch_lockstep = false, launch_async = false, launch_separate = false;
  std::string launch_config, concordd_path;
  launch_command->add_option("--dataset", launch_options.dataset, "Dataset folder")
      ->required()
      ->check(CLI::ExistingDirectory);
  launch_command->add_option("--out", launch_options.out, "Output folder (replay layout)")
      ->required();
  launch_command->add_flag("--lockstep", launch_lockstep,
                           "Lockstep consensus (the default: reproducible)");
  launch_command->add_flag("--async", launch_async, "Asynchronous consensus");
  launch_command->add_flag("--separate", launch_separate, "No consensus");
  launch_command->add_option("--base-port", launch_options.base_port,
                             "Robot i listens for peers on base-port + i")
      ->capture_default_str();
  launch_command->add_option("--http-base-port", launch_options.http_base_port,
                             "Robot i serves HTTP on http-base-port + i")
      ->capture_default_str();
  launch_command->add_option("--config", launch_config,
                             "Estimator options (default configs/datasets/<name>.yaml)");
  launch_command->add_option("--robots", launch_options.robots, "First robots only")
      ->check(CLI::PositiveNumber);
  launch_command->add_option("--frames", launch_options.frames, "First frames only")
      ->check(CLI::PositiveNumber);
  launch_command->add_option("--rate", launch_options.rate_hz,
                             "Replay rate in frames per second (0: as fast as possible)")
      ->check(CLI::NonNegativeNumber);
  launch_command->add_flag("--no-point-features", no_point_features,
                           "Ignore features.csv");
  launch_command->add_option("--concordd", concordd_path, "The concordd binary")
      ->check(CLI::ExistingFile);
  std::vector<std::string> launch_failpoints;
  launch_command->add_option("--failpoint", launch_failpoints,
                             "Testing aid: ROBOT:NAME[=ARG] passes --failpoint NAME[=ARG] to "
                             "robot ROBOT's concordd (repeatable)");
  launch_command
      ->add_option("--round-deadline-ms", launch_options.round_deadline_ms,
                   "consensus.round_deadline_ms of the daemons (default: theirs)")
      ->check(CLI::PositiveNumber);

  auto* plot_command =
      app.add_subcommand("plot", "Draw a line chart described in JSON as a PNG (bench charts)");
  std::string plot_input;
  plot_command->add_option("--input", plot_input, "Chart JSON (see evaluation/line_plot.h)")
      ->required()
      ->check(CLI::ExistingFile);
  plot_command->add_option("--out", out_dir, "PNG file to write")->required();

  auto* keygen_command = app.add_subcommand(
      "keygen", "Write a new team key (32 random bytes) to a file readable by its owner only");
  std::string key_file;
  keygen_command->add_option("--out", key_file, "Key file to create (never overwritten)")
      ->required();

  CLI11_PARSE(app, argc, argv);
  try {
    if (keygen_command->parsed()) {
      net::write_team_key(key_file, net::TeamKey::generate());
      std::cout << "team key: " << key_file << " (mode 0600; copy it to every robot of the team "
                << "and point team_key_file at it)\n";
      return 0;
    }
    if (plot_command->parsed()) {
      evaluation::write_line_plot_png(out_dir, evaluation::read_line_plot_json(plot_input));
      std::cout << "plot: " << out_dir << "\n";
      return 0;
    }
    if (launch_command->parsed()) {
      if (int{launch_lockstep} + int{launch_async} + int{launch_separate} > 1) {
        std::cerr << "concord launch: choose one of --lockstep, --async and --separate\n";
        return 1;
      }
      launch_options.mode = launch_async ? "async" : launch_separate ? "off" : "lockstep";
      launch_options.point_features = !no_point_features;
      if (!launch_config.empty()) launch_options.estimator_config = launch_config;
      if (!concordd_path.empty()) launch_options.concordd = concordd_path;
      for (const std::string& failpoint : launch_failpoints) {
        const std::size_t colon = failpoint.find(':');
        int robot = -1;
        try {
          robot = colon == std::string::npos ? -1 : std::stoi(failpoint.substr(0, colon));
        } catch (const std::exception&) {
        }
        if (robot < 0) {
          std::cerr << "concord launch: --failpoint: expected ROBOT:NAME[=ARG], got '" << failpoint
                    << "'\n";
          return 1;
        }
        auto& arguments = launch_options.extra_arguments[robot];
        arguments.push_back("--failpoint");
        arguments.push_back(failpoint.substr(colon + 1));
      }
      return run_launch(launch_options);
    }
    if (replay_command->parsed()) {
      return run_replay(dataset_dir, out_dir, separate, config_file, graph, loss, seed, frames,
                        no_point_features);
    }
    if (eval_command->parsed()) return run_eval(dataset_dir, result_dir);
    if (slice_command->parsed()) return run_slice(dataset_dir, out_dir, frames, robots);
    if (sim_command->parsed()) return run_sim(sim_options, out_dir);
  } catch (const std::exception& error) {
    std::cerr << "concord: error: " << error.what() << "\n";
    return 1;
  }
  return 0;
}

/// `concord`: the team replay, evaluation and dataset tools on the command line.
///   concord replay --dataset DIR --out DIR [--separate] [--config FILE] [--graph G] [--loss R]
///                  [--seed S] [--frames N] [--no-point-features]
///   concord eval --dataset DIR --result DIR
///   concord slice --dataset DIR --out DIR --frames N [--robots R]

#include <CLI/CLI.hpp>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>

#include "concord/config/options_file.h"
#include "concord/dataset/dataset.h"
#include "concord/dataset/result_io.h"
#include "evaluation/metrics.h"
#include "evaluation/plot.h"
#include "replay/team_replay.h"

namespace fs = std::filesystem;
using namespace concord;

namespace {

/// The checked-in config of a dataset, configs/datasets/<name>.yaml, if there is one.
std::optional<fs::path> dataset_config(const std::string& name) {
  const fs::path candidate = fs::path(CONCORD_CONFIG_DIR) / "datasets" / (name + ".yaml");
  if (fs::exists(candidate)) return candidate;
  return std::nullopt;
}

std::string robot_folder(int robot) {
  char name[16];
  std::snprintf(name, sizeof name, "robot_%02d", robot);
  return name;
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
    const fs::path folder = out / robot_folder(static_cast<int>(i));
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
    const fs::path folder = result_dir / robot_folder(static_cast<int>(i));
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

  CLI11_PARSE(app, argc, argv);
  try {
    if (replay_command->parsed()) {
      return run_replay(dataset_dir, out_dir, separate, config_file, graph, loss, seed, frames,
                        no_point_features);
    }
    if (eval_command->parsed()) return run_eval(dataset_dir, result_dir);
    if (slice_command->parsed()) return run_slice(dataset_dir, out_dir, frames, robots);
  } catch (const std::exception& error) {
    std::cerr << "concord: error: " << error.what() << "\n";
    return 1;
  }
  return 0;
}

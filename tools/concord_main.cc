/// `concord`: the team replay, evaluation and dataset tools on the command line.
///   concord replay --dataset DIR --out DIR [--separate] [--config FILE] [--graph G] [--loss R]
///                  [--range M] [--nearest K] [--max-degree D]
///                  [--seed S] [--frames N] [--no-point-features] [--set KEY=VALUE ...]
///                  [--association given|negotiated] [--search-log FILE] [--dump-descriptions DIR]
///                  [--unanchored-start SIGMA_M SIGMA_RAD]
///   concord eval --dataset DIR --result DIR [--first-frames-from DIR]
///   concord slice --dataset DIR --out DIR --frames N [--robots R] [--private-ids]
///   [--unknown-start] concord convert --dataset DIR --out DIR [--private-ids] [--unknown-start]
///   concord calibrate --dataset DIR [--robot R] [--first F] [--frames N] [--up-axis A]
///                     [--detector-model FILE [--detector-model-kind displacement|offset]]
///   concord launch --dataset DIR --out DIR [--lockstep|--async|--separate] [--base-port P]
///                  [--http-base-port P] [--config FILE] [--robots R] [--frames N] [--rate HZ]
///                  [--graph complete|ring] [--range M] [--nearest K] [--max-degree D]
///                  [--round-deadline-ms MS] [--failpoint ROBOT:NAME[=ARG] ...]
///   concord plot --input CHART.json --out CHART.png
///   concord frontend --input DIR --out DIR [--detections FILE] [--odometry FILE] [--frames N]
///                    [--detector-model FILE]
///   concord frontend-eval --dataset DIR [--world FILE]
///   concord keygen [--identity] --out FILE
///                                  (a new team key, or a robot's identity key, mode 0600; never
///                                  overwrites)
///   concord sim --robots N --out DIR [--seed S] [--frames F] [--objects M] [--points-per-frame P]
///               [--odometry-translation-noise T] [--odometry-rotation-noise R] [--pixel-noise S]
///               [--object-noise S]
///               ... (camera, path and object-placement parameters: concord sim --help)

#include <malloc.h>
#include <yaml-cpp/yaml.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <exception>
#include <filesystem>
#include <iostream>
#include <limits>
#include <nlohmann/json.hpp>
#include <numbers>
#include <set>

#include "calibration/calibration.h"
#include "concord/config/options_file.h"
#include "concord/dataset/dataset.h"
#include "concord/dataset/result_io.h"
#include "concord/frontend/frontend.h"
#include "concord/frontend/frontend_options_file.h"
#include "concord/frontend/frontend_run.h"
#include "concord/net/identity.h"
#include "concord/net/team_key.h"
#include "evaluation/frontend_metrics.h"
#include "evaluation/line_plot.h"
#include "evaluation/metrics.h"
#include "evaluation/plot.h"
#include "launch/launch.h"
#include "replay/team_replay.h"
#include "sim/render.h"
#include "sim/simulator.h"

namespace fs = std::filesystem;
using namespace concord;

namespace {

/// A path compiled in for the build tree or, in an installed copy (the .deb: /usr/bin/concord),
/// the same file relative to the executable (../share/concord/..., or concordd beside it).
fs::path build_or_installed(const fs::path& build_path, const fs::path& relative_to_executable) {
  if (fs::exists(build_path)) return build_path;
  std::error_code error;
  const fs::path executable = fs::read_symlink("/proc/self/exe", error);
  if (error) return build_path;
  const fs::path installed = (executable.parent_path() / relative_to_executable).lexically_normal();
  return fs::exists(installed) ? installed : build_path;
}

/// The config of a dataset: its own estimator.yaml (written by `concord frontend` from the
/// front-end's noise), else the checked-in config of the sensor that recorded it (one config per
/// sensor, not per dataset): configs/sensors/<sensor>.yaml, the sensor from dataset.json's
/// "sensor" or, for the shared sets that have none, from configs/sensors/datasets.yaml.
std::optional<fs::path> dataset_config(const dataset::Dataset& data) {
  if (fs::exists(data.root / "estimator.yaml")) return data.root / "estimator.yaml";
  const fs::path sensors =
      build_or_installed(fs::path(CONCORD_CONFIG_DIR) / "sensors", "../share/concord/sensors");
  std::string sensor = data.sensor;
  if (sensor.empty()) {
    const YAML::Node known = YAML::LoadFile((sensors / "datasets.yaml").string());
    if (known[data.name]) sensor = known[data.name].as<std::string>();
  }
  if (sensor.empty()) return std::nullopt;
  const fs::path candidate = sensors / (sensor + ".yaml");
  if (!fs::exists(candidate)) {
    throw std::runtime_error("dataset " + data.name + ": no config for sensor '" + sensor +
                             "' (" + candidate.string() + ")");
  }
  return candidate;
}

/// The frame of every trajectory pose from alignment.json's segments.
std::vector<std::optional<int>> frames_of_segments(const dataset::AlignmentRecord& record,
                                                   std::size_t poses) {
  std::vector<std::optional<int>> frames(poses, record.team_frame_robot);
  for (std::size_t s = 0; s < record.segments.size(); ++s) {
    const auto first = static_cast<std::size_t>(std::max(0, record.segments[s].first));
    const std::size_t last = s + 1 < record.segments.size()
                                 ? static_cast<std::size_t>(record.segments[s + 1].first)
                                 : poses;
    for (std::size_t k = first; k < std::min(last, poses); ++k)
      frames[k] = record.segments[s].second;
  }
  return frames;
}

/// One robot's outputs in a result folder: trajectory.kitti, objects.csv (with its team_id column
/// when present) and, when present, pose_covariance.csv (one row per trajectory pose, frames 0, 1,
/// ...) and alignment.json.
evaluation::RobotResult read_robot_result(const fs::path& folder) {
  evaluation::RobotResult result;
  result.trajectory = dataset::read_trajectory_kitti(folder / "trajectory.kitti");
  result.objects = dataset::read_objects_csv(folder / "objects.csv", &result.team_ids);
  if (fs::exists(folder / "alignment.json")) {
    const dataset::AlignmentRecord alignment =
        dataset::read_alignment_json(folder / "alignment.json");
    result.trajectory_frames = frames_of_segments(alignment, result.trajectory.size());
    result.aligned_at_frame = alignment.aligned_at_frame;
    result.moved = alignment.moved;
    result.T_team_own = alignment.T_team_own;
    result.T_team_own_covariance = alignment.covariance;
  }
  const fs::path covariance_file = folder / "pose_covariance.csv";
  if (!fs::exists(covariance_file)) return result;
  const auto covariances = dataset::read_pose_covariances_csv(covariance_file);
  for (std::size_t k = 0; k < covariances.size(); ++k) {
    if (covariances[k].frame != static_cast<int>(k)) {
      throw dataset::DatasetError(covariance_file.string() + ": row " + std::to_string(k + 1) +
                                  " holds frame " + std::to_string(covariances[k].frame) +
                                  ", expected frame " + std::to_string(k));
    }
    result.pose_covariances.push_back(covariances[k].covariance);
  }
  return result;
}

std::vector<dataset::PoseCovariance> numbered(
    const std::vector<Eigen::Matrix<double, 6, 6>>& covariances) {
  std::vector<dataset::PoseCovariance> out;
  out.reserve(covariances.size());
  for (std::size_t k = 0; k < covariances.size(); ++k) {
    out.push_back({static_cast<int>(k), covariances[k]});
  }
  return out;
}

/// The evaluation's truth: ground truth, odometry, truth ids (private ids) and how many frames each
/// robot observed each ground-truth object.
std::vector<evaluation::RobotTruth> truths_of(const dataset::Dataset& data) {
  std::vector<evaluation::RobotTruth> truths;
  for (const auto& robot : data.robots) {
    evaluation::RobotTruth truth{robot.groundtruth, robot.odometry};
    if (data.object_ids == dataset::ObjectIds::kPrivate) truth.truth_ids = robot.object_truth_ids;
    for (const auto& frame : robot.objects) {
      std::set<LandmarkId> seen;
      for (const StereoObservation& observation : frame) {
        LandmarkId truth_id = observation.id;
        if (data.object_ids == dataset::ObjectIds::kPrivate) {
          const auto it = robot.object_truth_ids.find(observation.id);
          truth_id = it == robot.object_truth_ids.end() ? dataset::kNoTruthId : it->second;
        }
        if (truth_id >= 0 && seen.insert(truth_id).second) ++truth.frames_observed[truth_id];
      }
    }
    truths.push_back(std::move(truth));
  }
  return truths;
}

/// Metrics, table, metrics.json and plot for a result in the replay layout.
evaluation::TeamMetrics report(const dataset::Dataset& data,
                               const std::vector<evaluation::RobotResult>& results,
                               const fs::path& out, const std::string& title,
                               nlohmann::json run_information,
                               const evaluation::EvaluationOptions& options = {}) {
  const auto truths = truths_of(data);
  const auto metrics = evaluation::evaluate(truths, results, data.objects_groundtruth, options);
  std::cout << evaluation::format_table(metrics, title) << std::flush;
  nlohmann::json document = evaluation::to_json(metrics);
  document["run"] = std::move(run_information);
  dataset::write_file_atomically(out / "metrics.json", document.dump(2) + "\n");
  evaluation::write_top_view_png(out / "plot.png", truths, results, data.objects_groundtruth,
                                 title);
  std::cout << "metrics: " << (out / "metrics.json").string() << "\n"
            << "plot:    " << (out / "plot.png").string() << "\n";
  if (const auto nees = evaluation::pose_nees_plot(
          truths, results, std::max<int>(1, metrics.maximum.frames / 100), title + ": pose NEES")) {
    evaluation::write_line_plot_png(out / "nees.png", *nees);
    std::cout << "NEES:    " << (out / "nees.png").string() << "\n";
  }
  std::cout
            << "outputs: " << out.string()
            << "/robot_XX/{trajectory.kitti,pose_covariance.csv,objects.csv}\n";
  return metrics;
}

/// alignment.json of a replay's robot output.
dataset::AlignmentRecord alignment_record(const replay::RobotOutput& output) {
  const auto robot_or_world = [](int frame) {
    return frame == association::kWorldFrame ? std::optional<int>() : std::optional<int>(frame);
  };
  dataset::AlignmentRecord record;
  record.team_frame_robot =
      robot_or_world(output.trajectory_frames.empty() ? association::kWorldFrame
                                                      : output.trajectory_frames.back());
  record.aligned_at_frame = output.aligned_at_frame;
  record.moved = output.moved;
  record.T_team_own = output.T_team_own;
  record.covariance = output.alignment_covariance;
  for (std::size_t k = 0; k < output.trajectory_frames.size(); ++k) {
    if (k == 0 || output.trajectory_frames[k] != output.trajectory_frames[k - 1]) {
      record.segments.emplace_back(static_cast<int>(k),
                                   robot_or_world(output.trajectory_frames[k]));
    }
  }
  return record;
}

/// Where a replay writes what its negotiators' searches saw (each empty: nothing).
struct SearchDiagnostics {
  /// One line a search: round, pair, map sizes, candidates, consistency edges, cliques, status
  /// (and, for a revisit, how far from the accepted alignment it found the maps); an aligned
  /// search adds a line with the two frames and the transform found (12 numbers, row by row).
  fs::path log;
  /// Both descriptions of every search, one file a search (r<round>_<owner>_<neighbour>.txt):
  /// one object a line, robot id observations x y z, then the local and the marginal covariance
  /// (9 numbers each, row by row).
  fs::path descriptions;
};

/// The listener that writes SearchDiagnostics (nullptr when both are empty). Throws
/// std::runtime_error when the log cannot be opened.
std::function<void(const association::SearchTrace&)> search_writer(
    const SearchDiagnostics& diagnostics) {
  if (diagnostics.log.empty() && diagnostics.descriptions.empty()) return nullptr;
  std::shared_ptr<std::FILE> log;
  if (!diagnostics.log.empty()) {
    log.reset(std::fopen(diagnostics.log.c_str(), "w"), [](std::FILE* file) {
      if (file != nullptr) std::fclose(file);
    });
    if (!log) throw std::runtime_error("cannot write the search log " + diagnostics.log.string());
  }
  if (!diagnostics.descriptions.empty()) fs::create_directories(diagnostics.descriptions);
  return [log, folder = diagnostics.descriptions](const association::SearchTrace& trace) {
    const association::PairAlignment& found = *trace.found;
    if (log && !trace.revisit) {
      std::fprintf(log.get(),
                   "round %d pair %d-%d: %zu/%zu objects, %d candidates, %lld edges, clique %d "
                   "rival %d (clique fit chi2 %.2f, largest %.2f): %s\n",
                   trace.round, trace.robot, trace.neighbour, trace.own->objects.size(),
                   trace.theirs->objects.size(), found.candidates, found.consistency_edges,
                   found.clique_size, found.rival_clique_size, found.clique_fit_chi2,
                   found.clique_fit_largest_residual, association::to_string(found.status).c_str());
      if (found.status == association::AlignmentStatus::kAligned) {
        // The transform found (own frame <- the neighbour's), so that a search can be judged
        // against the truth (bench/label_searches.py).
        std::fprintf(log.get(), "  frames %d <- %d, T_a_b:", trace.own->frame, trace.theirs->frame);
        for (int r = 0; r < 3; ++r) {
          for (int k = 0; k < 4; ++k) std::fprintf(log.get(), " %.6f", found.T_a_b.matrix()(r, k));
        }
        std::fprintf(log.get(), "\n");
      }
    } else if (log) {
      std::fprintf(log.get(),
                   "round %d pair %d-%d: revisit: %s, clique %d, %.2f deg off the accepted "
                   "alignment, chi2 %.1f; %zu matches, %zu as they stand\n",
                   trace.round, trace.robot, trace.neighbour,
                   association::to_string(found.status).c_str(), found.clique_size,
                   trace.revisit_degrees, trace.revisit_distance, found.matches.size(),
                   trace.matched_as_they_stand);
    }
    if (folder.empty() || trace.revisit) return;
    const fs::path file =
        folder / ("r" + std::to_string(trace.round) + "_" + std::to_string(trace.robot) + "_" +
                  std::to_string(trace.neighbour) + ".txt");
    std::FILE* out = std::fopen(file.c_str(), "w");
    if (out == nullptr) throw std::runtime_error("cannot write " + file.string());
    for (const association::MapDescription* map : {trace.own, trace.theirs}) {
      for (const association::ObjectDescription& o : map->objects) {
        std::fprintf(out, "%d %lld %d %.6f %.6f %.6f", map->robot, static_cast<long long>(o.id),
                     o.observations, o.position.x(), o.position.y(), o.position.z());
        for (const Eigen::Matrix3d* c : {&o.local_covariance, &o.covariance}) {
          for (int r = 0; r < 3; ++r)
            for (int k = 0; k < 3; ++k) std::fprintf(out, " %.8g", (*c)(r, k));
        }
        std::fprintf(out, "\n");
      }
    }
    std::fclose(out);
  };
}

int run_replay(const fs::path& dataset_dir, const fs::path& out, bool separate,
               const std::string& config_file, const std::string& graph, double loss,
               std::uint64_t seed, int frames, bool no_point_features,
               const std::vector<std::string>& overrides, const std::string& association_mode,
               replay::RadioLimits radio, const SearchDiagnostics& diagnostics,
               const std::vector<double>& unanchored_start) {
  dataset::ReadOptions read_options;
  if (frames > 0) read_options.max_frames = frames;
  read_options.load_features = !no_point_features;
  const dataset::Dataset data = dataset::read_dataset(dataset_dir, read_options);

  fs::path config_path;
  EstimatorOptions options;
  if (!config_file.empty()) {
    config_path = config_file;
  } else if (auto found = dataset_config(data)) {
    config_path = *found;
  }
  association::NegotiationOptions negotiation;
  if (!config_path.empty()) {
    options = config::load_estimator_options(config_path);
    negotiation = config::load_negotiation_options(config_path);
  }
  options = config::apply_overrides(options, overrides);
  negotiation = config::apply_association_overrides(negotiation, overrides);
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
  if (radio.any()) {
    // The simulated radio (who hears whom) follows the robots' true positions; the filters never
    // see them.
    radio.true_positions = replay::RadioLimits::positions_of(data);
    std::cerr << "  radio: range " << radio.range_m << " m, nearest " << radio.nearest
              << ", max degree " << radio.max_degree << " (0: no limit)\n";
  }
  replay_options.radio = radio;
  replay_options.negotiation = negotiation;
  replay_options.search_listener = search_writer(diagnostics);
  if (unanchored_start.size() == 2) {
    replay_options.unanchored_start_sigma = {unanchored_start[0], unanchored_start[1]};
    std::cerr << "  every robot but robot 0 starts with sigma " << unanchored_start[0] << " m, "
              << unanchored_start[1] << " rad (--unanchored-start)\n";
  }
  if (!association_mode.empty()) {
    replay_options.association = replay::parse_association_mode(association_mode);
  }
  std::cerr << "  object ids " << dataset::to_string(data.object_ids) << ", start poses "
            << dataset::to_string(data.start_poses) << "\n"
            << config::to_yaml(negotiation);
  int last_percent = -1;
  // The replay gets what the robots measure; the ground truth only goes to the evaluation.
  const dataset::TeamInputs inputs = dataset::sensor_inputs(data);
  const auto result = replay::run_team(inputs, options, replay_options, [&](int step, int steps) {
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
    dataset::write_objects_csv(folder / "objects.csv", result.robots[i].objects,
                               result.robots[i].team_ids);
    dataset::write_pose_covariances_csv(folder / "pose_covariance.csv",
                                        numbered(result.robots[i].pose_covariances));
    const dataset::AlignmentRecord alignment = alignment_record(result.robots[i]);
    dataset::write_alignment_json(folder / "alignment.json", alignment);
    evaluation::RobotResult robot_result{result.robots[i].trajectory, result.robots[i].objects,
                                         result.robots[i].pose_covariances};
    robot_result.trajectory_frames = frames_of_segments(alignment, robot_result.trajectory.size());
    robot_result.team_ids = result.robots[i].team_ids;
    robot_result.aligned_at_frame = alignment.aligned_at_frame;
    robot_result.moved = alignment.moved;
    robot_result.T_team_own = alignment.T_team_own;
    robot_result.T_team_own_covariance = alignment.covariance;
    results.push_back(std::move(robot_result));
  }
  const auto& s = result.statistics;
  nlohmann::json run = {
      {"dataset", data.name},
      {"mode", separate ? "separate" : "consensus"},
      {"graph", graph},
      {"radio",
       {{"range_m", radio.range_m}, {"nearest", radio.nearest}, {"max_degree", radio.max_degree}}},
      {"edges_per_round", s.steps > 0 ? static_cast<double>(s.edge_rounds) / s.steps : 0.0},
      {"loss", loss},
      {"seed", seed},
      {"unanchored_start_sigma",
       unanchored_start.size() == 2 ? nlohmann::json(unanchored_start) : nlohmann::json(nullptr)},
      {"config", config_path.string()},
      {"steps", s.steps},
      {"robot_steps", s.robot_steps},
      {"landmarks_fused", s.landmarks_fused},
      {"landmarks_settled", s.landmarks_settled},
      {"neighbours_skipped", s.neighbours_skipped},
      {"landmarks_refused", s.landmarks_refused},
      {"claims_refused", s.claims_refused},
      {"object_initializations_gated", s.object_initializations_gated},
      {"object_rejoins_refused", s.object_rejoins_refused},
      {"objects_reactivated", s.objects_reactivated},
      {"update_failures", s.update_failures},
      {"objects_initialized", s.objects_initialized},
      {"object_observations_rejected", s.object_observations_rejected},
      {"feature_tracks_used", s.feature_tracks_used},
      {"feature_tracks_rejected", s.feature_tracks_rejected},
      {"update_seconds", s.update_seconds},
      {"consensus_seconds", s.consensus_seconds},
      {"negotiation_seconds", s.negotiation_seconds},
      {"total_seconds", s.total_seconds},
      {"association", replay::to_string(result.association)},
      {"object_ids", dataset::to_string(data.object_ids)},
      {"start_poses", dataset::to_string(data.start_poses)},
      {"negotiation_robot_rounds", s.negotiation_robot_rounds},
      {"negotiation_messages", s.negotiation_messages},
      {"negotiation_bytes", s.negotiation_bytes},
      {"description_bytes", s.description_bytes},
      {"marginal_bytes", s.marginal_bytes},
      {"marginal_bytes_per_robot_round",
       [&] {
         std::vector<long long> bytes = s.marginal_bytes_per_robot_round;
         if (bytes.empty()) return nlohmann::json{{"median", 0}, {"max", 0}};
         std::sort(bytes.begin(), bytes.end());
         return nlohmann::json{{"median", bytes[bytes.size() / 2]}, {"max", bytes.back()}};
       }()},
      {"negotiation_bytes_per_robot_round",
       s.negotiation_robot_rounds > 0
           ? static_cast<double>(s.negotiation_bytes) / s.negotiation_robot_rounds
           : 0.0},
      {"searches", s.searches},
      {"in_frame_searches", s.in_frame_searches},
      {"in_frame_aligned", s.in_frame_aligned},
      {"ambiguous", s.ambiguous},
      {"tilted", s.tilted},
      {"frame_edges", s.frame_edges},
      {"revisits", s.revisits},
      {"revisits_ambiguous", s.revisits_ambiguous},
      {"records_redundant", s.records_redundant},
      {"records_not_owned", s.records_not_owned},
      {"frame_corrections", s.frame_corrections},
      {"reanchorings", s.reanchorings},
      {"links_accepted", s.links_accepted},
      {"links_split", s.links_split},
      {"link_conflicts", s.link_conflicts},
      {"team_id_conflicts", s.team_id_conflicts},
      {"consensus_ms_per_robot_step",
       s.consensus_robot_steps > 0 ? 1e3 * s.consensus_seconds / s.robot_steps : 0.0},
  };
  nlohmann::json offsets = nlohmann::json::array();
  for (std::size_t i = 0; i < result.robots.size(); ++i) {
    if (const auto& offset = result.robots[i].disparity_offset) {
      offsets.push_back({{"robot", i}, {"estimate", offset->first}, {"sigma", offset->second}});
      std::cerr << "concord replay: robot " << i << " disparity offset " << offset->first
                << " +- " << offset->second << " (image units)\n";
    }
  }
  if (!offsets.empty()) run["disparity_offset"] = offsets;
  std::cerr << "concord replay: " << s.robot_steps << " robot-steps in " << s.total_seconds
            << " s (update " << s.update_seconds << " s, consensus " << s.consensus_seconds
            << " s, negotiation " << s.negotiation_seconds << " s)\n";
  if (result.association == replay::AssociationMode::kNegotiated) {
    std::cerr << "concord replay: negotiation: " << s.searches << " searches (" << s.ambiguous
              << " ambiguous; " << s.tilted << " tilted), " << s.frame_edges << " frame edges ("
              << s.revisits << " revisits, " << s.revisits_ambiguous << " ambiguous, "
              << s.frame_corrections << " corrected), " << s.in_frame_searches
              << " searches in one frame (" << s.in_frame_aligned << " aligned), " << s.reanchorings
              << " moves, " << s.links_accepted << " links accepted, " << s.links_split
              << " split, " << s.link_conflicts << " refused as conflicts, " << s.team_id_conflicts
              << " left out by the team ids; " << s.negotiation_bytes << " bytes in "
              << s.negotiation_messages << " messages\n";
  }
  report(data, results, out,
         data.name + (separate ? " separate" : " consensus") +
             (frames > 0 ? " (" + std::to_string(frames) + " frames)" : ""),
         run);
  return 0;
}

int run_eval(const fs::path& dataset_dir, const fs::path& result_dir,
             const fs::path& first_frames_from) {
  dataset::ReadOptions read_options;
  read_options.load_features = false;
  const dataset::Dataset data = dataset::read_dataset(dataset_dir, read_options);
  std::vector<evaluation::RobotResult> results;
  for (std::size_t i = 0; i < data.robots.size(); ++i) {
    results.push_back(
        read_robot_result(result_dir / dataset::robot_folder_name(static_cast<int>(i))));
  }
  evaluation::EvaluationOptions options;
  if (!first_frames_from.empty()) {
    for (std::size_t i = 0; i < data.robots.size(); ++i) {
      options.first_frames.push_back(
          dataset::read_alignment_json(first_frames_from /
                                       dataset::robot_folder_name(static_cast<int>(i)) /
                                       "alignment.json")
              .aligned_at_frame);
    }
  }
  report(data, results, result_dir, data.name + " eval of " + result_dir.filename().string(),
         {{"dataset", data.name},
          {"result", result_dir.string()},
          {"first_frames_from", first_frames_from.string()}},
         options);
  return 0;
}

int run_calibrate(const fs::path& dataset_dir, const calibration::CalibrationOptions& options,
                  const fs::path& detector_model, calibration::DetectorModelKind kind) {
  const dataset::Dataset data = dataset::read_dataset(dataset_dir);
  const calibration::CalibrationReport report = calibration::calibrate(data, options);
  std::cout << calibration::to_yaml(report, options);
  if (!detector_model.empty()) {
    dataset::write_file_atomically(detector_model,
                                   calibration::detector_model_yaml(report, options, kind));
    std::cerr << "concord calibrate: the detector's error model written to "
              << detector_model.string() << "\n";
  }
  return 0;
}

int run_slice(const fs::path& dataset_dir, const fs::path& out, int frames, int robots,
              bool private_ids, bool unknown_start) {
  const dataset::Dataset data = dataset::read_dataset(dataset_dir);
  dataset::write_dataset(
      dataset::make_variant(
          dataset::slice(data, frames > 0 ? frames : std::numeric_limits<int>::max(),
                         robots > 0 ? robots : static_cast<int>(data.robots.size())),
          private_ids, unknown_start),
      out);
  std::cerr << "concord slice: wrote " << out.string() << "\n";
  return 0;
}

/// A dataset's private-ids and/or unknown-starts variant (the whole set).
int run_convert(const fs::path& dataset_dir, const fs::path& out, bool private_ids,
                bool unknown_start) {
  if (!private_ids && !unknown_start) {
    std::cerr << "concord convert: nothing to do: give --private-ids and/or --unknown-start\n";
    return 1;
  }
  const dataset::Dataset data = dataset::read_dataset(dataset_dir);
  const dataset::Dataset variant = dataset::make_variant(data, private_ids, unknown_start);
  dataset::write_dataset(variant, out);
  std::cerr << "concord convert: wrote " << out.string() << " (object_ids "
            << dataset::to_string(variant.object_ids) << ", start_poses "
            << dataset::to_string(variant.start_poses) << ")\n";
  return 0;
}

int run_sim(sim::SimulationOptions options, const fs::path& out,
            const std::optional<sim::RenderOptions>& render) {
  if (render) {
    // The rendered camera's vertical field of view follows from the image's aspect ratio.
    const double half_width =
        std::tan(0.5 * options.horizontal_fov_degrees * std::numbers::pi / 180.0);
    options.vertical_fov_degrees =
        2.0 * std::atan(half_width * render->height / render->width) * 180.0 / std::numbers::pi;
  }
  auto problems = options.validate();
  if (render) {
    for (const auto& problem : render->validate()) problems.push_back(problem);
  }
  if (!problems.empty()) {
    std::cerr << "concord sim: invalid parameters:\n";
    for (const auto& problem : problems) std::cerr << "  " << problem << "\n";
    return 1;
  }
  using Clock = std::chrono::steady_clock;
  const auto start = Clock::now();
  dataset::Dataset data = sim::simulate(options);
  std::optional<sim::TexturedWorld> world;
  if (render) {
    std::vector<LandmarkId> removed;
    world.emplace(sim::build_world(data, *render, options.seed, removed));
    sim::remove_objects(data, removed);
    // The exact point tracks of the rendered scene: points on its surfaces.
    sim::place_point_features_on_surfaces(
        data, options, [&world](const Eigen::Vector3d& origin, const Eigen::Vector3d& direction) {
          const auto hit = world->cast(origin, direction);
          return hit ? std::optional<double>(hit->distance) : std::nullopt;
        });
    std::cerr << "concord sim: rendered world of " << world->quads().size() << " textured quads ("
              << world->cubes().size() << " object cubes; " << removed.size()
              << " objects dropped because a path passes through them)\n";
  }
  const auto simulated = Clock::now();
  dataset::write_dataset(data, out);
  dataset::write_file_atomically(out / "simulation.json", sim::to_json(options));
  if (render) {
    const StereoCamera camera =
        sim::render_camera(data.camera, options.horizontal_fov_degrees, *render);
    sim::write_rendered_sequences(
        data, *world, camera, *render, options.min_depth, options.max_depth, options.seed, out,
        [](long long done, long long total) {
          if (done % 100 == 0 || done == total) {
            std::cerr << "  rendered " << done << "/" << total << " frames\n";
          }
        });
  }
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

/// The stereo front-end over a sequence (or a team of them), written as a dataset.
int run_frontend_command(const fs::path& input, const fs::path& out,
                         frontend::FrontendRunOptions options) {
  int last_percent = -1;
  options.progress = [&](int robot, int frame, int frames) {
    const int percent = 100 * (frame + 1) / frames;
    if (percent / 10 != last_percent / 10 || frame + 1 == frames) {
      std::cerr << "  robot " << robot << ": frame " << frame + 1 << "/" << frames << "\n";
      last_percent = percent;
    }
  };
  const frontend::FrontendRunSummary summary = frontend::run_frontend(input, out, options);
  for (std::size_t robot = 0; robot < summary.robots.size(); ++robot) {
    const frontend::SequenceSummary& s = summary.robots[robot];
    std::cout << "concord frontend: robot " << robot << ": " << s.frames << " frames, "
              << s.tracks_per_frame << " tracks a frame (min " << s.min_tracks
              << "), mean track length " << s.mean_track_length << ", " << s.objects_observed
              << " of " << s.detections << " detections observed (" << s.objects_ambiguous
              << " ambiguous, " << s.objects_inconsistent << " left-right inconsistent), "
              << s.odometry_failures
              << " odometry failures, " << s.total_ms.p50 << " ms a frame (p50), " << s.total_ms.p99
              << " ms (p99); CPU without image decoding " << s.processing_cpu_ms.p50
              << " ms (p50), " << s.processing_cpu_ms.p99 << " ms (p99)\n";
  }
  std::cout << "concord frontend: object ids " << dataset::to_string(summary.object_ids)
            << ", start poses " << dataset::to_string(summary.start_poses)
            << " (--object-ids, --start-poses; docs/frontend.md)";
  if (!summary.classes.empty()) {
    std::cout << "; classes";
    for (std::size_t index = 0; index < summary.classes.size(); ++index)
      std::cout << " " << index << "=" << summary.classes[index];
  }
  if (summary.robots.size() > 1 && options.up_axis == "unknown" &&
      (summary.object_ids == dataset::ObjectIds::kPrivate ||
       summary.start_poses == dataset::StartPoses::kUnknown)) {
    std::cout << "\nconcord frontend: the robots' up axis is unknown (--up-axis): the "
                 "negotiation cannot refuse an alignment that tilts one robot's frame against "
                 "another's";
  }
  if (options.observation_noise && options.detector_model.empty()) {
    std::cout << "\nconcord frontend: each point observation's noise is its own, but without a "
                 "detector model (--detector-model) estimator.yaml has no feature_drift_sigma: "
                 "the filter then takes the well-pinned tracks' drift for information and is "
                 "overconfident; give the model, or --constant-feature-noise (docs/frontend.md, "
                 "\"It needs the drift model\")";
  }
  std::cout << "\nconcord frontend: wrote " << out.string() << " (statistics in "
            << (out / "frontend.json").string() << ")\n";
  return 0;
}

/// Accuracy of a front-end's dataset against its ground truth (and, for rendered sequences, the
/// world's geometry): prints one line per robot and writes frontend_eval.json next to it.
int run_frontend_eval(const fs::path& dataset_dir, const fs::path& world_file) {
  const dataset::Dataset data = dataset::read_dataset(dataset_dir);
  std::optional<sim::TexturedWorld> world;
  if (!world_file.empty()) world.emplace(sim::read_world_geometry(world_file));
  const auto statistics_json = [](const evaluation::ErrorStatistics& s) {
    return nlohmann::json{
        {"count", s.count}, {"median", s.median}, {"p90", s.p90}, {"mean", s.mean}, {"max", s.max}};
  };
  nlohmann::json robots = nlohmann::json::array();
  for (const dataset::RobotData& robot : data.robots) {
    std::vector<Eigen::Matrix<double, 6, 6>> covariances;
    for (const auto& covariance : robot.odometry_covariance) {
      if (!covariance) {
        covariances.clear();  // not every motion has one: no NEES
        break;
      }
      covariances.push_back(*covariance);
    }
    const auto odometry =
        evaluation::odometry_accuracy(robot.groundtruth, robot.odometry, covariances);
    const auto objects = evaluation::object_observation_accuracy(
        data.camera, robot.groundtruth, robot.objects, data.objects_groundtruth);
    nlohmann::json entry = {{"robot", robot.index},
                            {"odometry",
                             {{"path_length", odometry.path_length},
                              {"final_error", odometry.final_error},
                              {"final_error_percent", odometry.final_error_percent},
                              {"max_error", odometry.max_error},
                              {"rmse", odometry.rmse},
                              {"translation_error_rms", odometry.translation_error_rms},
                              {"rotation_error_rms", odometry.rotation_error_rms},
                              {"nees_mean", odometry.nees_mean}}},
                            {"objects",
                             {{"centre_px", statistics_json(objects.centre)},
                              {"disparity_px", statistics_json(objects.disparity)},
                              {"relative_depth", statistics_json(objects.relative_depth)}}}};
    std::cout << "robot " << robot.index << ": odometry over " << odometry.path_length
              << " m: final error " << odometry.final_error << " m ("
              << odometry.final_error_percent << " %), RMSE " << odometry.rmse << " m, per motion "
              << odometry.translation_error_rms << " m / " << odometry.rotation_error_rms
              << " rad RMS, NEES " << odometry.nees_mean << "; objects: centre "
              << objects.centre.median << " px, disparity " << objects.disparity.median
              << " px (medians)";
    if (world) {
      const auto tracks =
          evaluation::track_accuracy(*world, data.camera, robot.groundtruth, robot.features);
      entry["tracks"] = {{"tracks", tracks.tracks},
                         {"unanchored", tracks.unanchored},
                         {"left_px", statistics_json(tracks.left)},
                         {"right_px", statistics_json(tracks.right)},
                         {"all_px", statistics_json(tracks.all)}};
      std::cout << "; tracks: " << tracks.all.median << " px median, " << tracks.all.p90
                << " px p90 reprojection error";
    }
    std::cout << "\n";
    robots.push_back(std::move(entry));
  }
  dataset::write_file_atomically(dataset_dir / "frontend_eval.json",
                                 nlohmann::json{{"robots", robots}}.dump(2) + "\n");
  std::cout << "frontend-eval: " << (dataset_dir / "frontend_eval.json").string() << "\n";
  return 0;
}

/// Runs a team of concordd daemons on a dataset, then scores their outputs like `eval`.
/// --range, --nearest, --max-degree: the simulated radio of `replay` and `launch` (the same rule,
/// concord/dataset/radio.h; in the daemons, consensus.radio).
void add_radio_options(CLI::App& command, double& range_m, int& nearest, int& max_degree) {
  command
      .add_option("--range", range_m,
                  "Simulated radio: a link only while the robots are within this many metres (the "
                  "dataset's ground truth; 0: no limit)")
      ->check(CLI::NonNegativeNumber);
  command
      .add_option("--nearest", nearest,
                  "Simulated radio: links only to each robot's K closest robots (0: no limit)")
      ->check(CLI::NonNegativeNumber);
  command
      .add_option("--max-degree", max_degree,
                  "Simulated radio: at most D links a robot, the shortest first (0: no limit)")
      ->check(CLI::NonNegativeNumber);
}

int run_launch(launch::LaunchOptions options) {
  dataset::ReadOptions read_options;
  read_options.load_features = false;
  if (options.frames > 0) read_options.max_frames = options.frames;
  if (options.robots > 0) read_options.max_robots = options.robots;
  const dataset::Dataset data = dataset::read_dataset(options.dataset, read_options);
  if (options.estimator_config.empty()) {
    if (auto found = dataset_config(data)) options.estimator_config = *found;
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
    results.push_back(read_robot_result(options.out / dataset::robot_folder_name(robot)));
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
  // As concordd (daemon/concordd_main.cc): large blocks stay on the heap (fewer page faults).
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 64 << 20);
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
                   "Estimator config (default: the dataset's estimator.yaml, else its sensor's "
                   "in configs/sensors/)")
      ->check(CLI::ExistingFile);
  replay_command->add_option("--graph", graph, "Communication graph: complete, ring or random")
      ->check(CLI::IsMember({"complete", "ring", "random"}));
  replay_command->add_option("--loss", loss, "Per-round probability of dropping each edge")
      ->check(CLI::Range(0.0, 1.0));
  replay_command->add_option("--seed", seed, "Seed of the random graph and link loss");
  replay::RadioLimits radio;
  add_radio_options(*replay_command, radio.range_m, radio.nearest, radio.max_degree);
  replay_command->add_option("--frames", frames, "Use only the first N frames of each robot")
      ->check(CLI::PositiveNumber);
  replay_command->add_flag("--no-point-features", no_point_features,
                           "Ignore features.csv (object-only run)");
  std::vector<std::string> overrides;
  std::string association_mode;
  replay_command
      ->add_option("--association", association_mode,
                   "given (the dataset's global ids, known starts) or negotiated (robots find "
                   "common objects and frames); default: given for global ids and known starts")
      ->check(CLI::IsMember({"given", "negotiated"}));
  SearchDiagnostics search_diagnostics;
  replay_command->add_option("--search-log", search_diagnostics.log,
                             "Negotiated runs: write one line per search of a pair to this file");
  replay_command->add_option("--dump-descriptions", search_diagnostics.descriptions,
                             "Negotiated runs: write both map descriptions of every search into "
                             "this folder (one file a search)");
  std::vector<double> unanchored_start;
  replay_command
      ->add_option("--unanchored-start", unanchored_start,
                   "SIGMA_M SIGMA_RAD: a diagnosis of one anchor: every robot but robot 0 starts "
                   "at its given start with this standard deviation (metres, radians)")
      ->expected(2);
  replay_command->add_option("--set", overrides,
                             "KEY=VALUE: an estimator option over the config (repeatable), e.g. "
                             "--set odometry_rotation_sigma=0.02 --set "
                             "consensus.neighbour_chi2_probability=0.99");

  auto* eval_command = app.add_subcommand("eval", "Score a result folder against a dataset");
  std::string result_dir;
  eval_command->add_option("--dataset", dataset_dir, "Dataset folder")
      ->required()
      ->check(CLI::ExistingDirectory);
  eval_command->add_option("--result", result_dir, "Result folder (robot_XX/trajectory.kitti...)")
      ->required()
      ->check(CLI::ExistingDirectory);
  std::string first_frames_from;
  eval_command
      ->add_option("--first-frames-from", first_frames_from,
                   "Result folder whose alignment.json frames start traj RMSE from alignment (to "
                   "compare a known-start run over the same frames)")
      ->check(CLI::ExistingDirectory);

  auto* calibrate_command = app.add_subcommand(
      "calibrate",
      "Measure odometry and observation noise on a calibration segment (a config's noise values)");
  calibration::CalibrationOptions calibration_options;
  calibrate_command->add_option("--dataset", dataset_dir, "Dataset folder (with ground truth)")
      ->required()
      ->check(CLI::ExistingDirectory);
  calibrate_command->add_option("--robot", calibration_options.robot, "Robot whose segment")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  calibrate_command->add_option("--first", calibration_options.first_frame, "First frame")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  calibrate_command->add_option("--frames", calibration_options.frames, "Frames in the segment")
      ->capture_default_str()
      ->check(CLI::Range(10, 1000000));
  calibrate_command
      ->add_option("--up-axis", calibration_options.up_axis,
                   "Body axis pointing up when level, for the tilt (+x, -x, +y, -y, +z, -z)")
      ->capture_default_str()
      ->check(CLI::IsMember({"+x", "-x", "+y", "-y", "+z", "-z"}));
  calibrate_command
      ->add_option("--offset-max-lag", calibration_options.offset_max_lag,
                   "Largest lag (frames) the detection offset's walk is fitted over; 0: the "
                   "tracks' span (median over the observations)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  std::string detector_model_out;
  calibrate_command->add_option(
      "--detector-model", detector_model_out,
      "Also write the detector's error model (object_noise and a displacement's or an image "
      "offset's sigma and walk) and the point-feature tracks' drift (feature_drift_sigma) to "
      "FILE, for concord frontend --detector-model");
  calibration::DetectorModelKind detector_model_kind =
      calibration::DetectorModelKind::kDisplacement;
  calibrate_command
      ->add_option("--detector-model-kind", detector_model_kind,
                   "The model --detector-model writes: displacement (in space, metres: "
                   "object_displacement_sigma/walk) or offset (in the image: "
                   "object_offset_sigma/walk); default displacement")
      ->transform(CLI::CheckedTransformer(
          std::map<std::string, calibration::DetectorModelKind>{
              {"displacement", calibration::DetectorModelKind::kDisplacement},
              {"offset", calibration::DetectorModelKind::kImageOffset}},
          CLI::ignore_case));

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
  bool variant_private_ids = false, variant_unknown_start = false;
  slice_command->add_flag("--private-ids", variant_private_ids,
                          "Also renumber each robot's objects privately (object_ids_truth.csv)");
  slice_command->add_flag("--unknown-start", variant_unknown_start,
                          "Also mark the start poses unknown");

  auto* convert_command =
      app.add_subcommand("convert", "Write a dataset's private-ids and/or unknown-starts variant");
  convert_command->add_option("--dataset", dataset_dir, "Dataset folder")
      ->required()
      ->check(CLI::ExistingDirectory);
  convert_command->add_option("--out", out_dir, "Output folder")->required();
  convert_command->add_flag("--private-ids", variant_private_ids,
                            "Renumber each robot's objects privately; robot_XX/"
                            "object_ids_truth.csv maps them to objects_gt.csv (evaluation only)");
  convert_command->add_flag("--unknown-start", variant_unknown_start,
                            "Start poses unknown: every filter starts at its own frame");

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
  sim_command->add_option("--object-noise", sim_options.object_noise,
                          "Object observations' noise per coordinate, normalized image units (one "
                          "sigma; default: --pixel-noise)");
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
  sim_command
      ->add_option("--classes", sim_options.classes,
                   "Detector classes: objects get a class in [0, K) (objects.csv class column); "
                   "0: no class column")
      ->capture_default_str();
  sim_command
      ->add_option("--false-detections", sim_options.false_detection_rate,
                   "Fraction of object detections that are false (phantom objects), in [0, 0.5]")
      ->capture_default_str();
  sim_command->add_flag("--private-ids", sim_options.private_ids,
                        "Each robot numbers its objects its own way (object_ids_truth.csv for "
                        "evaluation)");
  sim_command->add_flag("--unknown-start", sim_options.unknown_start,
                        "Start poses unknown to the robots (filters start at their own frames)");

  bool render_images = false;
  sim::RenderOptions render_options;
  render_options.textures = CONCORD_TEXTURE_DIR;
  sim_command->add_flag("--render", render_images,
                        "Also render stereo images of a textured world (KITTI layout per robot, "
                        "with detections.csv) for the front-end");
  sim_command->add_option("--render-width", render_options.width, "Rendered image width, pixels")
      ->capture_default_str();
  sim_command->add_option("--render-height", render_options.height, "Rendered image height, pixels")
      ->capture_default_str();
  sim_command
      ->add_option("--render-noise", render_options.image_noise,
                   "Pixel noise of the rendered images, grey levels (one sigma)")
      ->capture_default_str();
  sim_command
      ->add_option("--render-supersampling", render_options.supersampling,
                   "Samples a rendered pixel averages along each axis (its area, as a camera's "
                   "pixel integrates the light)")
      ->capture_default_str();
  sim_command
      ->add_option("--render-object-size", render_options.object_size,
                   "Edge of the cube drawn for each object, metres")
      ->capture_default_str();
  sim_command
      ->add_option("--render-pillars", render_options.pillar_density,
                   "Textured pillars per 100 square metres")
      ->capture_default_str();
  sim_command
      ->add_option("--render-textures", render_options.textures,
                   "Folder of PNG photographs used as textures")
      ->check(CLI::ExistingDirectory)
      ->capture_default_str();

  auto* launch_command = app.add_subcommand(
      "launch", "Run one concordd per robot of a dataset on loopback and score the outputs");
  launch::LaunchOptions launch_options;
  launch_options.concordd = build_or_installed(CONCORD_DAEMON_PATH, "concordd");
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
  launch_command
      ->add_option("--graph", launch_options.graph,
                   "Whom each daemon runs consensus with: complete or ring (members next to it)")
      ->check(CLI::IsMember({"complete", "ring"}));
  add_radio_options(*launch_command, launch_options.range_m, launch_options.nearest,
                    launch_options.max_degree);
  launch_command->add_flag("--separate", launch_separate, "No consensus");
  launch_command->add_option("--base-port", launch_options.base_port,
                             "Robot i listens for peers on base-port + i")
      ->capture_default_str();
  launch_command->add_option("--http-base-port", launch_options.http_base_port,
                             "Robot i serves HTTP on http-base-port + i")
      ->capture_default_str();
  launch_command->add_option("--config", launch_config,
                             "Estimator options (default: the sensor's, configs/sensors/)");
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
  bool launch_no_identities = false;
  launch_command->add_flag("--no-identities", launch_no_identities,
                           "The team key only: no per-robot signing keys (docs/network.md)");

  auto* plot_command =
      app.add_subcommand("plot", "Draw a line chart described in JSON as a PNG (bench charts)");
  std::string plot_input;
  plot_command->add_option("--input", plot_input, "Chart JSON (see evaluation/line_plot.h)")
      ->required()
      ->check(CLI::ExistingFile);
  plot_command->add_option("--out", out_dir, "PNG file to write")->required();

  auto* frontend_command = app.add_subcommand(
      "frontend",
      "Stereo front-end: image sequence(s) to a dataset folder (tracks, odometry, objects)");
  frontend::FrontendRunOptions frontend_options;
  std::string frontend_input;
  frontend_command
      ->add_option("--input", frontend_input,
                   "A sequence (EuRoC or KITTI layout) or a folder of robot_NN sequences")
      ->required()
      ->check(CLI::ExistingDirectory);
  frontend_command->add_option("--out", out_dir, "Output dataset folder")->required();
  frontend_command
      ->add_option("--detections", frontend_options.detections,
                   "detections.csv of a single sequence (default: <sequence>/detections.csv)")
      ->check(CLI::ExistingFile);
  frontend_command
      ->add_option("--odometry", frontend_options.odometry,
                   "The robot's own odometry (KITTI poses T_body(k-1)_body(k)) instead of "
                   "visual odometry")
      ->check(CLI::ExistingFile);
  frontend_command
      ->add_option("--odometry-translation-sigma", frontend_options.odometry_translation_sigma,
                   "Standard deviation of --odometry per axis per frame, metres")
      ->capture_default_str();
  frontend_command
      ->add_option("--odometry-rotation-sigma", frontend_options.odometry_rotation_sigma,
                   "Standard deviation of --odometry per axis per frame, radians")
      ->capture_default_str();
  frontend_command->add_option("--frames", frames, "Only the first N frames")
      ->check(CLI::PositiveNumber);
  frontend_command
      ->add_option("--features", frontend_options.frontend.tracker.target_features,
                   "Tracks kept per frame")
      ->capture_default_str();
  frontend_command->add_option("--name", frontend_options.name, "dataset.json name of the output")
      ->capture_default_str();
  std::string frontend_config;
  frontend_command
      ->add_option("--config", frontend_config,
                   "Front-end options (YAML: tracker:, odometry:, objects:; docs/frontend.md)")
      ->check(CLI::ExistingFile);
  std::string frontend_object_ids, frontend_start_poses;
  frontend_command
      ->add_option("--object-ids", frontend_object_ids,
                   "How the detections' track ids are to be read: global (one id per object for "
                   "the whole team) or private (each robot's own). Default: as the input team's "
                   "dataset.json says; else private for a team")
      ->check(CLI::IsMember({"global", "private"}));
  frontend_command
      ->add_option("--start-poses", frontend_start_poses,
                   "known (the robots' ground truth shares one world frame) or unknown. Default: "
                   "as the input team's dataset.json says; else unknown for a team")
      ->check(CLI::IsMember({"known", "unknown"}));
  frontend_command
      ->add_option("--up-axis", frontend_options.up_axis,
                   "The body axis that points up when the robots stand level (a forward-looking "
                   "camera in the KITTI layout: -y), written to estimator.yaml for the "
                   "negotiation's tilt check; unknown writes nothing")
      ->check(CLI::IsMember({"unknown", "+x", "-x", "+y", "-y", "+z", "-z"}))
      ->capture_default_str();
  frontend_command
      ->add_option("--classes", frontend_options.classes,
                   "The team's detector class names (comma-separated, any order; the list the "
                   "daemons get as source.classes): objects.csv's classes are numbered by it, "
                   "alike for robots processed in separate runs. Default: the names the "
                   "detections use")
      ->delimiter(',');
  bool constant_feature_noise = false;
  frontend_command->add_flag(
      "--constant-feature-noise", constant_feature_noise,
      "Write no noise per observation (features.csv without sigma_left, sigma_right): the "
      "estimator's feature_noise for every observation");
  frontend_command
      ->add_option("--detector-model", frontend_options.detector_model,
                   "The detector's error model (estimator object noise keys and "
                   "feature_drift_sigma, e.g. from concord calibrate --detector-model on a "
                   "calibration segment), written to estimator.yaml instead of "
                   "objects.detection_sigma")
      ->check(CLI::ExistingFile);
  int frontend_threads = 0;
  frontend_command
      ->add_option("--threads", frontend_threads,
                   "Threads OpenCV may use (1: one core; default: OpenCV's choice)")
      ->check(CLI::NonNegativeNumber);

  auto* frontend_eval_command = app.add_subcommand(
      "frontend-eval",
      "Accuracy of a front-end's dataset (odometry, tracks, objects) against truth");
  std::string world_file;
  frontend_eval_command->add_option("--dataset", dataset_dir, "Dataset written by concord frontend")
      ->required()
      ->check(CLI::ExistingDirectory);
  frontend_eval_command
      ->add_option("--world", world_file, "world.csv of rendered sequences (concord sim --render)")
      ->check(CLI::ExistingFile);
  auto* keygen_command = app.add_subcommand(
      "keygen", "Write a new team key (32 random bytes) to a file readable by its owner only");
  std::string key_file;
  keygen_command->add_option("--out", key_file, "Key file to create (never overwritten)")
      ->required();
  bool keygen_identity = false;
  keygen_command->add_flag("--identity", keygen_identity,
                           "A robot's identity (signing) key instead; prints its public key for "
                           "the members' member_keys");

  CLI11_PARSE(app, argc, argv);
  try {
    if (keygen_command->parsed() && keygen_identity) {
      const net::RobotIdentity identity = net::RobotIdentity::generate();
      net::write_identity(key_file, identity);
      std::cout << "identity key: " << key_file << " (mode 0600; keep it on this robot only and "
                << "point identity_key_file at it)\npublic key: " << identity.public_key().hex()
                << " (list it under member_keys in every robot's config)\n";
      return 0;
    }
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
      launch_options.identities = !launch_no_identities;
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
                        no_point_features, overrides, association_mode, radio, search_diagnostics,
                        unanchored_start);
    }
    if (eval_command->parsed()) return run_eval(dataset_dir, result_dir, first_frames_from);
    if (slice_command->parsed()) {
      return run_slice(dataset_dir, out_dir, frames, robots, variant_private_ids,
                       variant_unknown_start);
    }
    if (convert_command->parsed()) {
      return run_convert(dataset_dir, out_dir, variant_private_ids, variant_unknown_start);
    }
    if (calibrate_command->parsed())
      return run_calibrate(dataset_dir, calibration_options, detector_model_out,
                           detector_model_kind);
    if (sim_command->parsed()) {
      return run_sim(
          sim_options, out_dir,
          render_images ? std::optional<sim::RenderOptions>(render_options) : std::nullopt);
    }
    if (frontend_eval_command->parsed()) return run_frontend_eval(dataset_dir, world_file);
    if (frontend_command->parsed()) {
      if (frames > 0) frontend_options.max_frames = frames;
      frontend_options.observation_noise = !constant_feature_noise;
      if (!frontend_object_ids.empty()) {
        frontend_options.object_ids = frontend_object_ids == "private"
                                          ? dataset::ObjectIds::kPrivate
                                          : dataset::ObjectIds::kGlobal;
      }
      if (!frontend_start_poses.empty()) {
        frontend_options.start_poses = frontend_start_poses == "unknown"
                                           ? dataset::StartPoses::kUnknown
                                           : dataset::StartPoses::kKnown;
      }
      if (frontend_threads > 0) frontend::set_opencv_threads(frontend_threads);
      if (!frontend_config.empty()) {
        const int features = frontend_options.frontend.tracker.target_features;
        frontend_options.frontend = frontend::load_frontend_options(frontend_config);
        if (frontend_command->count("--features") > 0) {
          frontend_options.frontend.tracker.target_features = features;
        }
      }
      std::cerr << "concord frontend: options\n" << frontend::to_yaml(frontend_options.frontend);
      return run_frontend_command(frontend_input, out_dir, frontend_options);
    }
  } catch (const std::exception& error) {
    std::cerr << "concord: error: " << error.what() << "\n";
    return 1;
  }
  return 0;
}

/// concordd: one robot's Concord daemon.
///   concordd --config robot.yaml [--robot-id N] [--listen-port P] [--http-port P] [--out DIR]
///            [--mode off|lockstep|async] [--peer host:port ...] [--dataset DIR] [--robot N]
///            [--max-frames N] [--rate HZ] [--wait-for-peers N] [--log-level LEVEL]
///            [--failpoint NAME[=ARG] ...]
///   concordd --check-config robot.yaml [overrides]   validate, start nothing (exit 0 or 2)
/// Exit codes: 0 normal end (also after SIGTERM/SIGINT), 2 cannot start (command line, config,
/// key, data, output directory, port), 3 the final outputs could not be written.
/// See docs/daemon.md and configs/team-kitti00/robot_00.yaml.

#include <spdlog/fmt/ranges.h>
#include <spdlog/sinks/stdout_sinks.h>
#include <spdlog/spdlog.h>

#include <malloc.h>

#include <CLI/CLI.hpp>
#include <chrono>
#include <csignal>
#include <iostream>
#include <thread>

#include "concord/config/options_file.h"
#include "concord/daemon/config.h"
#include "concord/daemon/daemon.h"
#include "concord/daemon/log_file_sink.h"

using namespace concord;

int main(int argc, char** argv) {
  // The filter's covariance (megabytes) and the marginals are allocated and freed every frame and
  // round: with glibc's defaults each such block is mapped and unmapped (page faults, system
  // time). Keep up to 32 MB blocks on the heap and 64 MB of free heap before returning it to the
  // system: a third less CPU for a 3-robot team on kitti00-300 (docs/results-daemon.md).
  mallopt(M_MMAP_THRESHOLD, 32 << 20);
  mallopt(M_TRIM_THRESHOLD, 64 << 20);
  CLI::App app{"concordd: one robot's multi-robot object SLAM daemon (estimator, peer-to-peer "
               "consensus, HTTP state endpoint)"};
  std::string config_file;
  std::string check_file;
  auto* config_option =
      app.add_option("--config", config_file, "Daemon config (YAML)")->check(CLI::ExistingFile);
  auto* check_option = app.add_option(
      "--check-config", check_file,
      "Validate this config and the files it names (team key, data, output folder), start "
      "nothing; exit 0 if the daemon could start with it, else 2 with every problem");
  config_option->excludes(check_option);
  check_option->excludes(config_option);
  std::optional<int> robot_id, robot, max_frames, wait_for_peers;
  std::optional<int> listen_port, http_port;
  std::optional<double> rate;
  std::optional<std::string> out, mode, dataset, log_level;
  std::vector<std::string> peers;
  std::vector<std::string> failpoints;
  app.add_option("--robot-id", robot_id, "Override robot_id");
  app.add_option("--listen-port", listen_port, "Override network.listen_port")->check(CLI::Range(0, 65535));
  app.add_option("--http-port", http_port, "Override http.port")->check(CLI::Range(0, 65535));
  app.add_option("--out", out, "Override output.directory");
  app.add_option("--mode", mode, "Override consensus.mode (off, lockstep, async)");
  app.add_option("--peer", peers, "Override network.peers (repeatable host:port)");
  app.add_option("--dataset", dataset, "Override source.dataset");
  app.add_option("--robot", robot, "Override source.robot (robot_NN folder to replay)");
  app.add_option("--max-frames", max_frames, "Override source.max_frames")->check(CLI::NonNegativeNumber);
  app.add_option("--rate", rate, "Override source.rate_hz (0: as fast as possible)")->check(CLI::NonNegativeNumber);
  app.add_option("--wait-for-peers", wait_for_peers, "Override consensus.wait_for_peers");
  app.add_option("--log-level", log_level, "Override log_level");
  app.add_option("--failpoint", failpoints,
                 "Testing aid: switch on a failpoint (repeatable): marginal.silence, "
                 "marginal.garbage, estimator.hang=SECONDS, output.fail");
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& help) {
    return app.exit(help);  // 0
  } catch (const CLI::CallForAllHelp& help) {
    return app.exit(help);
  } catch (const CLI::ParseError& error) {
    (void)app.exit(error);  // prints the message
    return daemon::kExitCannotStart;
  }

  if (config_file.empty() && check_file.empty()) {
    std::cerr << "concordd: --config FILE (or --check-config FILE) is required\n" << app.help();
    return daemon::kExitCannotStart;
  }
  const bool check_only = !check_file.empty();
  if (check_only) config_file = check_file;

  auto logger = spdlog::stderr_logger_mt("concordd");
  spdlog::set_default_logger(logger);
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %l %v");

  // The config file, then the command-line overrides (also on a SIGHUP reload of the peers).
  auto load = [&] {
    daemon::DaemonConfig loaded = daemon::load_daemon_config(config_file);
    if (!peers.empty()) loaded.network.peers = peers;
    return loaded;
  };
  daemon::DaemonConfig config;
  try {
    config = load();
    if (robot_id) config.robot_id = *robot_id;
    if (listen_port) config.network.listen_port = static_cast<std::uint16_t>(*listen_port);
    if (http_port) config.http.port = static_cast<std::uint16_t>(*http_port);
    if (out) config.output.directory = *out;
    if (mode) {
      const auto parsed = daemon::parse_consensus_mode(*mode);
      if (!parsed) throw config::ConfigError("--mode: expected off, lockstep or async, got '" + *mode + "'");
      config.consensus.mode = *parsed;
    }
    if (dataset) config.source.dataset = *dataset;
    if (robot) config.source.robot = *robot;
    if (max_frames) config.source.max_frames = *max_frames;
    if (rate) config.source.rate_hz = *rate;
    if (wait_for_peers) config.consensus.wait_for_peers = *wait_for_peers;
    if (log_level) config.log_level = *log_level;
    for (const std::string& failpoint : failpoints) {
      const std::string problem = daemon::enable_failpoint(failpoint, config.failpoints);
      if (!problem.empty()) throw config::ConfigError("--failpoint: " + problem);
    }
    const auto problems = config.validate();
    if (!problems.empty()) {
      std::string message = "invalid settings:";
      for (const auto& problem : problems) message += "\n  " + problem;
      throw config::ConfigError(message);
    }
  } catch (const config::ConfigError& error) {
    std::cerr << "concordd: " << error.what() << "\n";
    return daemon::kExitCannotStart;
  }
  if (check_only) {
    const std::vector<std::string> problems = daemon::check_config_files(config);
    if (!problems.empty()) {
      std::cerr << "concordd: " << config_file << ": the daemon could not start with it:\n";
      for (const std::string& problem : problems) std::cerr << "  " << problem << "\n";
      return daemon::kExitCannotStart;
    }
    std::cout << "concordd: " << config_file << ": OK: " << daemon::describe(config) << "\n";
    return daemon::kExitOk;
  }
  const auto level = spdlog::level::from_str(config.log_level);
  if (level == spdlog::level::off && config.log_level != "off") {
    std::cerr << "concordd: log_level: unknown level '" << config.log_level << "'\n";
    return daemon::kExitCannotStart;
  }
  std::shared_ptr<daemon::LogFileSink> log_file;
  if (!config.log_file.empty()) {
    try {
      log_file = std::make_shared<daemon::LogFileSink>(config.log_file);
    } catch (const std::exception& error) {
      std::cerr << "concordd: " << error.what() << "\n";
      return daemon::kExitCannotStart;
    }
    logger->sinks() = {log_file};
  }
  spdlog::set_level(level);
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %l robot " + std::to_string(config.robot_id) + ": %v");
  spdlog::flush_on(spdlog::level::info);

  if (config.failpoints.any())
    spdlog::warn("failpoints switched on (testing aid): {}", fmt::join(failpoints, ", "));
  spdlog::info("config {}: {}", config_file, daemon::describe(config));
  daemon::DaemonHooks hooks;
  hooks.reload_peers = [&load] { return load().network.peers; };
  if (log_file) hooks.reopen_logs = [log_file] { return log_file->reopen(); };
  daemon::Daemon instance(config, hooks);
  const int exit_code = instance.run();
  // The run is over and its outputs are written: a SIGTERM from now on (a supervisor stopping a
  // daemon that is already on its way out) must not turn a clean exit into death by signal.
  std::signal(SIGINT, SIG_IGN);
  std::signal(SIGTERM, SIG_IGN);
  std::signal(SIGHUP, SIG_IGN);
  if (config.failpoints.exit_linger_seconds > 0.0) {
    spdlog::warn("failpoint exit.linger: exiting with {} in {} s", exit_code,
                 config.failpoints.exit_linger_seconds);
    std::this_thread::sleep_for(
        std::chrono::duration<double>(config.failpoints.exit_linger_seconds));
  }
  return exit_code;
}

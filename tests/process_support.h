#pragma once
/// Shared helpers of the multi-process tests (daemons started as child processes): scratch
/// folders, bounded polling, the daemons' HTTP answers and output files.

#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <thread>

#include "launch/launch.h"
#include "launch/process.h"
#include "test_paths.h"

namespace concord::testing {

/// An empty folder build/test-out/NAME-PID (removed first if a crashed run left it).
inline std::filesystem::path fresh_folder(const std::string& name) {
  const std::filesystem::path folder = std::filesystem::path(CONCORD_BINARY_DIR) / "test-out" /
                                       (name + "-" + std::to_string(getpid()));
  std::filesystem::remove_all(folder);
  std::filesystem::create_directories(folder);
  return folder;
}

/// Polls `condition` every 20 ms until it holds (true) or `timeout` passes (false): a bounded
/// wait on an observable state, not a sleep standing in for synchronisation.
template <typename Condition>
bool eventually(Condition condition, std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!condition()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  return true;
}

/// A daemon's JSON answer on 127.0.0.1:port (nullopt: no answer or not JSON).
inline std::optional<nlohmann::json> get_json(std::uint16_t port, const std::string& target) {
  const auto body = launch::http_get("127.0.0.1", port, target, std::chrono::milliseconds(1000));
  if (!body) return std::nullopt;
  nlohmann::json parsed = nlohmann::json::parse(*body, nullptr, false);
  if (parsed.is_discarded()) return std::nullopt;
  return parsed;
}

/// The program `name` in a folder of PATH (/usr/bin:/bin without one); nullopt if none.
inline std::optional<std::filesystem::path> find_program(const std::string& name) {
  const char* path = std::getenv("PATH");
  std::istringstream folders(path ? path : "/usr/bin:/bin");
  for (std::string folder; std::getline(folders, folder, ':');) {
    const std::filesystem::path candidate = std::filesystem::path(folder) / name;
    if (!folder.empty() && ::access(candidate.c_str(), X_OK) == 0) return candidate;
  }
  return std::nullopt;
}

inline std::string read_text(const std::filesystem::path& file) {
  std::ifstream stream(file);
  std::ostringstream text;
  text << stream.rdbuf();
  return text.str();
}

inline nlohmann::json read_json(const std::filesystem::path& file) {
  std::ifstream stream(file);
  return nlohmann::json::parse(stream);
}

/// Non-empty lines of a text file (the entries of trajectory.kitti and the like).
inline std::size_t line_count(const std::filesystem::path& file) {
  std::ifstream stream(file);
  std::size_t lines = 0;
  for (std::string line; std::getline(stream, line);) lines += line.empty() ? 0 : 1;
  return lines;
}

/// A team of daemons on the repository's kitti00-300 slice with configs/sensors/kitti-stereo.yaml:
/// robot i listens on base_port + i and serves HTTP on http_base_port + i; 240 s at most.
inline launch::LaunchOptions kitti_team_options(const std::filesystem::path& out,
                                                std::uint16_t base_port,
                                                std::uint16_t http_base_port) {
  using namespace std::chrono_literals;
  const std::filesystem::path source = CONCORD_SOURCE_DIR;
  launch::LaunchOptions options;
  options.dataset = source / "data/kitti00-300";
  options.out = out;
  options.concordd = CONCORD_DAEMON_PATH;
  options.estimator_config = source / "configs/sensors/kitti-stereo.yaml";
  options.base_port = base_port;
  options.http_base_port = http_base_port;
  options.timeout = 240s;
  return options;
}

}  // namespace concord::testing

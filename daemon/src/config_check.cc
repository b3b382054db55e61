// concordd --check-config: what a config names is checked without starting the daemon.
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <sstream>

#include "concord/daemon/config.h"
#include "concord/dataset/dataset.h"
#include "concord/frontend/frontend_options_file.h"
#include "concord/net/host_port.h"
#include "concord/net/identity.h"
#include "concord/net/team_key.h"

namespace concord::daemon {

namespace {

namespace fs = std::filesystem;

/// "" if this user can create files in `folder` (or create `folder` itself, then its nearest
/// existing ancestor must be a writable folder); else why not, naming the key.
std::string folder_problem(const fs::path& folder, const std::string& key) {
  std::error_code error;
  fs::path existing = fs::absolute(folder, error);
  if (error) return key + ": " + folder.string() + ": " + error.message();
  while (!fs::exists(existing, error) && existing.has_parent_path() &&
         existing != existing.parent_path())
    existing = existing.parent_path();
  if (!fs::is_directory(existing, error))
    return key + ": " + existing.string() + " is not a folder";
  if (access(existing.c_str(), W_OK | X_OK) != 0)
    return key + ": " + existing.string() + " is not writable by this user (" +
           std::strerror(errno) + ")" +
           (existing == fs::absolute(folder) ? ""
                                             : ", so " + folder.string() + " cannot be created");
  return {};
}

std::string file_problem(const fs::path& file, const std::string& key) {
  std::error_code error;
  if (!fs::is_regular_file(file, error)) return key + ": " + file.string() + " is not a file";
  if (access(file.c_str(), R_OK) != 0)
    return key + ": " + file.string() + " is not readable (" + std::strerror(errno) + ")";
  return {};
}

}  // namespace

std::vector<std::string> check_config_files(const DaemonConfig& config) {
  std::vector<std::string> problems;
  auto add = [&](std::string problem) {
    if (!problem.empty()) problems.push_back(std::move(problem));
  };
  // 1. The team key: what the daemon would refuse at start (missing, malformed, others can read).
  const bool needs_key =
      config.consensus.mode != ConsensusMode::kOff ||
      (config.source.kind == SourceKind::kIngest && config.source.ingest_authenticated);
  if (needs_key) {
    try {
      (void)net::load_team_key(config.team_key_file);
    } catch (const std::exception& error) {
      add(std::string("team_key_file: ") + error.what());
    }
  }
  // The identity key: readable by its owner only, well formed, and the one the members list for
  // this robot.
  if (config.consensus.mode != ConsensusMode::kOff && !config.member_keys.empty()) {
    try {
      const net::RobotIdentity identity = net::load_identity(config.identity_key_file);
      const auto listed = config.member_keys.find(config.robot_id);
      if (listed != config.member_keys.end() &&
          !(net::PublicKey::parse(listed->second, "member_keys") == identity.public_key()))
        add("member_keys: the key listed for robot " + std::to_string(config.robot_id) +
            " is not this robot's identity key (its public key is " + identity.public_key().hex() +
            ")");
    } catch (const std::exception& error) {
      add(std::string("identity_key_file: ") + error.what());
    }
  }
  // 2. Static peers: host:port each.
  for (const std::string& peer : config.network.peers)
    if (!net::parse_host_port(peer))
      add("network.peers: '" + peer + "' is not host:port with a port 1-65535");
  // 3. The source's data, read as the daemon reads it (the replay's first frame only).
  try {
    switch (config.source.kind) {
      case SourceKind::kReplay: {
        dataset::ReadOptions options;
        options.only_robot = config.source.robot;
        options.max_frames = 1;
        options.load_features = false;
        (void)dataset::read_dataset(config.source.dataset, options);
        break;
      }
      case SourceKind::kImages:
        if (!fs::is_directory(config.source.images))
          add("source.images: " + config.source.images.string() + " is not a folder");
        if (!config.source.detections.empty())
          add(file_problem(config.source.detections, "source.detections"));
        if (!config.source.frontend.empty())
          (void)frontend::load_frontend_options(config.source.frontend);
        break;
      case SourceKind::kIngest:
        (void)dataset::read_camera(config.source.camera);
        break;
    }
  } catch (const std::exception& error) {
    add(std::string("source: ") + error.what());
  }
  // 4. Where it writes.
  add(folder_problem(config.output.directory, "output.directory"));
  if (!config.log_file.empty()) {
    std::error_code error;
    if (fs::exists(config.log_file, error)) {
      if (access(config.log_file.c_str(), W_OK) != 0)
        add("log_file: " + config.log_file.string() + " is not writable (" + std::strerror(errno) +
            ")");
    } else {
      add(folder_problem(config.log_file.parent_path(), "log_file"));
    }
  }
  return problems;
}

std::string describe(const DaemonConfig& config) {
  std::ostringstream line;
  line << "robot " << config.robot_id << " of team '" << config.team << "'";
  if (!config.members.empty()) {
    line << " (members";
    for (const int member : config.members) line << ' ' << member;
    line << ')';
  }
  line << ", consensus " << to_string(config.consensus.mode) << ", source ";
  switch (config.source.kind) {
    case SourceKind::kReplay:
      line << "replay of " << config.source.dataset.string() << " robot " << config.source.robot;
      break;
    case SourceKind::kImages:
      line << "images of " << config.source.images.string();
      break;
    case SourceKind::kIngest:
      line << "ingest on " << config.source.ingest_address << ':' << config.source.ingest_port;
      break;
  }
  if (config.consensus.mode != ConsensusMode::kOff) {
    line << ", peers on " << config.network.listen_address << ':' << config.network.listen_port
         << ", " << config.network.peers.size() << " static peers, discovery "
         << (config.network.discovery ? "on" : "off");
  }
  if (config.http.enabled) line << ", http on " << config.http.address << ':' << config.http.port;
  line << ", outputs in " << config.output.directory.string();
  return line.str();
}

}  // namespace concord::daemon

#include "concord/daemon/config.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cctype>
#include <limits>
#include <map>
#include <set>

#include "concord/config/options_file.h"
#include "concord/config/yaml_section.h"

namespace concord::daemon {

namespace {

using config::ConfigError;

using Section = config::YamlSection;
using config::line_of;

}  // namespace

std::optional<ConsensusMode> parse_consensus_mode(const std::string& text) {
  if (text == "off") return ConsensusMode::kOff;
  if (text == "lockstep") return ConsensusMode::kLockstep;
  if (text == "async") return ConsensusMode::kAsync;
  return std::nullopt;
}

std::string to_string(ConsensusMode mode) {
  switch (mode) {
    case ConsensusMode::kOff:
      return "off";
    case ConsensusMode::kLockstep:
      return "lockstep";
    case ConsensusMode::kAsync:
      return "async";
  }
  return "unknown";
}

std::optional<ConsensusGraph> parse_consensus_graph(const std::string& text) {
  if (text == "complete") return ConsensusGraph::kComplete;
  if (text == "ring") return ConsensusGraph::kRing;
  return std::nullopt;
}

std::string to_string(ConsensusGraph graph) {
  return graph == ConsensusGraph::kRing ? "ring" : "complete";
}

std::optional<AssociationMode> parse_association_mode(const std::string& text) {
  if (text == "auto") return AssociationMode::kAuto;
  if (text == "given") return AssociationMode::kGiven;
  if (text == "negotiated") return AssociationMode::kNegotiated;
  return std::nullopt;
}

std::string to_string(AssociationMode mode) {
  switch (mode) {
    case AssociationMode::kAuto:
      return "auto";
    case AssociationMode::kGiven:
      return "given";
    case AssociationMode::kNegotiated:
      return "negotiated";
  }
  return "unknown";
}

std::vector<std::string> DaemonConfig::validate() const {
  std::vector<std::string> problems;
  if (robot_id < 0) problems.push_back("robot_id: expected >= 0, got " + std::to_string(robot_id));
  if (team.empty()) problems.push_back("team: must not be empty");
  const bool needs_key = consensus.mode != ConsensusMode::kOff ||
                         (source.kind == SourceKind::kIngest && source.ingest_authenticated);
  if (needs_key && team_key_file.empty())
    problems.push_back("team_key_file: required (create one with `concord keygen --out FILE`)");
  if (consensus.mode != ConsensusMode::kOff) {
    if (members.empty()) problems.push_back("members: required, the robot ids of the team");
    if (!members.empty() && std::find(members.begin(), members.end(), robot_id) == members.end())
      problems.push_back("members: does not contain this robot's id " + std::to_string(robot_id));
  }
  for (const int member : members)
    if (member < 0) problems.push_back("members: " + std::to_string(member) + " is negative");
  if (!member_keys.empty() && identity_key_file.empty())
    problems.push_back(
        "identity_key_file: required with member_keys (create one with `concord keygen "
        "--identity --out FILE`)");
  if (member_keys.empty() && !identity_key_file.empty())
    problems.push_back("member_keys: required with identity_key_file (every member's public key)");
  if (!member_keys.empty()) {
    for (const int member : members)
      if (member_keys.find(member) == member_keys.end())
        problems.push_back("member_keys: no key for member " + std::to_string(member));
    for (const auto& [robot, key] : member_keys) {
      const bool hex = key.size() == 64 && std::all_of(key.begin(), key.end(), [](char c) {
                         return std::isxdigit(static_cast<unsigned char>(c)) != 0;
                       });
      if (robot < 0)
        problems.push_back("member_keys: robot id " + std::to_string(robot) + " is negative");
      if (!hex)
        problems.push_back("member_keys: the key of robot " + std::to_string(robot) +
                           " is not 64 hex digits");
    }
  }
  if (source.kind == SourceKind::kIngest) {
    const std::string& address = source.ingest_address;
    const bool loopback =
        address.rfind("127.", 0) == 0 || address == "::1" || address == "localhost";
    if (!loopback && !source.ingest_authenticated)
      problems.push_back("source.ingest_address: " + address +
                         " is not a loopback address: set source.ingest_authenticated: true");
    if (!(source.max_translation_m > 0.0))
      problems.push_back("source.max_translation_m: expected > 0");
    if (!(source.max_rotation_rad > 0.0))
      problems.push_back("source.max_rotation_rad: expected > 0");
  }
  if (consensus.future_rounds < 1 || consensus.future_rounds > 1000)
    problems.push_back("consensus.future_rounds: expected 1-1000, got " +
                       std::to_string(consensus.future_rounds));
  if (!(consensus.suspicious_refusal_fraction >= 0.0 && consensus.suspicious_refusal_fraction < 1.0))
    problems.push_back("consensus.suspicious_refusal_fraction: expected a fraction in [0, 1), got " +
                       std::to_string(consensus.suspicious_refusal_fraction));
  if (consensus.quarantine_after < 1)
    problems.push_back("consensus.quarantine_after: expected >= 1, got " +
                       std::to_string(consensus.quarantine_after));
  if (consensus.quarantine_doublings < 0 || consensus.quarantine_doublings > 20)
    problems.push_back("consensus.quarantine_doublings: expected 0 to 20, got " +
                       std::to_string(consensus.quarantine_doublings));
  if (consensus.quarantine_rounds < 0)
    problems.push_back("consensus.quarantine_rounds: expected >= 0, got " +
                       std::to_string(consensus.quarantine_rounds));
  if (consensus.miss_limit < 1)
    problems.push_back("consensus.miss_limit: expected >= 1, got " +
                       std::to_string(consensus.miss_limit));
  if (!(consensus.link_budget_bytes_per_second >= 0.0 &&
        consensus.link_budget_bytes_per_second <= 1e10))
    problems.push_back("consensus.link_budget_bytes_per_second: expected 0 (unlimited) or a rate "
                       "in bytes per second, got " +
                       std::to_string(consensus.link_budget_bytes_per_second));
  else if (consensus.link_budget_bytes_per_second > 0.0 &&
           consensus.link_budget_bytes_per_second < 1000.0)
    problems.push_back("consensus.link_budget_bytes_per_second: " +
                       std::to_string(consensus.link_budget_bytes_per_second) +
                       " is below 1000 bytes per second (not even a landmark set per round)");
  const RadioConfig& radio = consensus.radio;
  if (!(radio.range_m >= 0.0 && radio.range_m <= 1e9))
    problems.push_back("consensus.radio.range_m: expected 0 (no limit) or a distance in metres, got " +
                       std::to_string(radio.range_m));
  if (radio.nearest < 0)
    problems.push_back("consensus.radio.nearest: expected >= 0, got " +
                       std::to_string(radio.nearest));
  if (radio.max_degree < 0)
    problems.push_back("consensus.radio.max_degree: expected >= 0, got " +
                       std::to_string(radio.max_degree));
  if (radio.any() && consensus.mode != ConsensusMode::kOff) {
    if (radio.truth.empty() && (source.kind != SourceKind::kReplay || source.dataset.empty()))
      problems.push_back("consensus.radio: needs consensus.radio.truth (a dataset with every "
                         "member's ground truth) unless the source replays a dataset");
  }
  if (consensus.max_marginal_landmarks < 1)
    problems.push_back("consensus.max_marginal_landmarks: expected >= 1");
  if (consensus.association == AssociationMode::kNegotiated &&
      consensus.mode == ConsensusMode::kAsync)
    problems.push_back("consensus.association: negotiated needs consensus.mode lockstep");
  if (consensus.association == AssociationMode::kAuto && consensus.mode == ConsensusMode::kAsync &&
      source.kind != SourceKind::kReplay && (source.unknown_start || source.private_ids))
    problems.push_back(
        "consensus.association: auto negotiates with source.unknown_start or "
        "source.private_ids, which needs consensus.mode lockstep");
  const NegotiationLimits& limits = consensus.negotiation_limits;
  if (limits.max_description_objects < 1 || limits.max_records < 1 ||
      limits.max_links_per_record < 1 || limits.max_frame_edges_per_record < 1)
    problems.push_back("consensus.max_description_objects, max_owner_records, max_record_links, "
                       "max_record_frame_edges: expected >= 1");
  for (const std::string& problem : negotiation.validate()) problems.push_back(problem);
  if (http.max_connections_per_client > http.max_connections)
    problems.push_back("http.max_connections_per_client: above http.max_connections");
  if (source.kind == SourceKind::kReplay) {
    if (source.dataset.empty()) problems.push_back("source.dataset: required for replay");
    if (source.robot < 0) problems.push_back("source.robot: expected >= 0");
    if (!(source.rate_hz >= 0.0 && source.rate_hz <= 10000.0))
      problems.push_back(
          "source.rate_hz: expected 0 (as fast as possible) or a rate up to 10000 "
          "frames per second, got " +
          std::to_string(source.rate_hz));
    else if (source.rate_hz > 0.0 && source.rate_hz < 1e-3)
      problems.push_back("source.rate_hz: " + std::to_string(source.rate_hz) +
                         " is below 0.001 frames per second (one frame in 17 minutes)");
    if (source.max_frames < 0) problems.push_back("source.max_frames: expected >= 0");
    if (!(source.frame_period_s > 0.0 && source.frame_period_s <= 3600.0))
      problems.push_back("source.frame_period_s: expected a period in (0, 3600] seconds");
  } else if (source.kind == SourceKind::kImages) {
    if (source.images.empty()) problems.push_back("source.images: required for images");
    if (!(source.rate_hz >= 0.0 && source.rate_hz <= 10000.0))
      problems.push_back("source.rate_hz: expected 0 (as fast as possible) or a rate up to 10000 "
                         "frames per second, got " + std::to_string(source.rate_hz));
    if (source.max_frames < 0) problems.push_back("source.max_frames: expected >= 0");
    for (const std::string& name : source.classes) {
      if (name.empty()) problems.push_back("source.classes: an empty class name");
    }
  } else {
    if (source.camera.empty()) problems.push_back("source.camera: required for ingest");
  }
  if (source.start_pose.size() != 7) problems.push_back("source.start_pose: expected 7 numbers");
  if (consensus.staleness_rounds < 0) problems.push_back("consensus.staleness_rounds: expected >= 0");
  if (consensus.wait_for_peers < 0) problems.push_back("consensus.wait_for_peers: expected >= 0");
  if (network.heartbeat_timeout <= network.heartbeat_interval) {
    problems.push_back("network.heartbeat_timeout: must be longer than heartbeat_interval");
  }
  if (output.directory.empty()) problems.push_back("output.directory: must not be empty");
  for (const std::string& problem : estimator.validate()) problems.push_back("estimator: " + problem);
  return problems;
}

DaemonConfig parse_daemon_config(const std::string& yaml_text, const std::string& source_name,
                                 const std::filesystem::path& base_directory) {
  const YAML::Node root = config::load_yaml(yaml_text, source_name);
  DaemonConfig config;
  std::vector<std::string> problems;
  if (!root.IsMap()) {
    throw ConfigError(source_name + ": expected a map of daemon settings");
  }
  Section top(root, "", problems);
  top.read("robot_id", config.robot_id);
  top.read("team", config.team);
  top.read("log_level", config.log_level);
  top.read("log_file", config.log_file, base_directory);
  top.read_size("queue_capacity", config.queue_capacity);
  top.read("team_key_file", config.team_key_file, base_directory);
  top.read_ints("members", config.members);
  top.read("identity_key_file", config.identity_key_file, base_directory);
  if (const YAML::Node keys = top.child("member_keys"); keys && !keys.IsNull()) {
    if (!keys.IsMap()) {
      top.problem(keys, "member_keys", "a map of robot id to public key");
    } else {
      for (const auto& entry : keys) {
        int robot = -1;
        std::string key;
        if (top.read_value(entry.first, "member_keys", robot, "a robot id") &&
            top.read_value(entry.second, "member_keys." + entry.first.Scalar(), key,
                           "a public key (64 hex digits)") &&
            !config.member_keys.emplace(robot, key).second)
          problems.push_back(line_of(entry.first) + "member_keys: robot " + std::to_string(robot) +
                             " given twice");
      }
    }
  }

  // estimator: a file name, or the options inline.
  const YAML::Node estimator = top.child("estimator");
  try {
    if (estimator && estimator.IsScalar()) {
      config.estimator_file = Section::resolve(estimator.Scalar(), base_directory);
      config.estimator = config::load_estimator_options(config.estimator_file);
      config.negotiation = config::load_negotiation_options(config.estimator_file);
    } else if (estimator && estimator.IsMap()) {
      YAML::Emitter emitter;
      emitter << estimator;
      config.estimator = config::parse_estimator_options(emitter.c_str(), source_name + " estimator");
      config.negotiation =
          config::parse_negotiation_options(emitter.c_str(), source_name + " estimator");
    } else if (estimator && !estimator.IsNull()) {
      problems.push_back(line_of(estimator) + "estimator: expected a file name or a map of options");
    }
  } catch (const ConfigError& error) {
    problems.push_back(error.what());
  }

  Section source(top.child("source"), "source.", problems);
  std::string kind = "replay";
  source.read("kind", kind);
  if (kind == "replay") {
    config.source.kind = SourceKind::kReplay;
  } else if (kind == "ingest") {
    config.source.kind = SourceKind::kIngest;
  } else if (kind == "images") {
    config.source.kind = SourceKind::kImages;
  } else {
    problems.push_back("source.kind: expected replay, ingest or images, got '" + kind + "'");
  }
  source.read("dataset", config.source.dataset, base_directory);
  source.read("robot", config.source.robot);
  source.read("rate_hz", config.source.rate_hz);
  source.read("max_frames", config.source.max_frames);
  source.read("point_features", config.source.point_features);
  source.read("frame_period_s", config.source.frame_period_s);
  source.read("ingest_address", config.source.ingest_address);
  source.read_port("ingest_port", config.source.ingest_port, true);
  source.read("camera", config.source.camera, base_directory);
  source.read_numbers("start_pose", config.source.start_pose, 7);
  source.read("images", config.source.images, base_directory);
  source.read("detections", config.source.detections, base_directory);
  source.read("frontend", config.source.frontend, base_directory);
  source.read("observation_noise", config.source.observation_noise);
  source.read("ingest_authenticated", config.source.ingest_authenticated);
  source.read("max_translation_m", config.source.max_translation_m);
  source.read("max_rotation_rad", config.source.max_rotation_rad);
  source.read("unknown_start", config.source.unknown_start);
  source.read("private_ids", config.source.private_ids);
  source.read_strings("classes", config.source.classes);
  source.finish();

  Section network(top.child("network"), "network.", problems);
  network.read("listen_address", config.network.listen_address);
  network.read_port("listen_port", config.network.listen_port, true);
  network.read_strings("peers", config.network.peers);
  network.read_milliseconds("heartbeat_interval_ms", config.network.heartbeat_interval, false);
  network.read_milliseconds("heartbeat_timeout_ms", config.network.heartbeat_timeout, false);
  network.read_size("max_frame_bytes", config.network.max_frame_bytes);
  network.read_size("send_queue_limit", config.network.send_queue_limit);
  network.read("discovery", config.network.discovery);
  network.read("discovery_address", config.network.discovery_address);
  network.read_port("discovery_port", config.network.discovery_port, false);
  network.read_size("max_pending_handshakes", config.network.max_pending_handshakes);
  network.read_size("receive_bytes_per_second", config.network.receive_bytes_per_second);
  network.read_size("receive_messages_per_second", config.network.receive_messages_per_second);
  network.finish();

  Section consensus(top.child("consensus"), "consensus.", problems);
  std::string mode = to_string(config.consensus.mode);
  consensus.read("mode", mode);
  if (const auto parsed = parse_consensus_mode(mode)) {
    config.consensus.mode = *parsed;
  } else {
    problems.push_back("consensus.mode: expected off, lockstep or async, got '" + mode + "'");
  }
  std::string graph = to_string(config.consensus.graph);
  if (consensus.read("graph", graph)) {
    if (const auto parsed = parse_consensus_graph(graph))
      config.consensus.graph = *parsed;
    else
      problems.push_back("consensus.graph: expected complete or ring, got '" + graph + "'");
  }
  consensus.read_milliseconds("round_deadline_ms", config.consensus.round_deadline, false);
  consensus.read("staleness_rounds", config.consensus.staleness_rounds);
  consensus.read("wait_for_peers", config.consensus.wait_for_peers);
  consensus.read_milliseconds("startup_timeout_ms", config.consensus.startup_timeout, true);
  consensus.read("future_rounds", config.consensus.future_rounds);
  consensus.read("miss_limit", config.consensus.miss_limit);
  consensus.read("suspicious_refusal_fraction", config.consensus.suspicious_refusal_fraction);
  consensus.read("quarantine_after", config.consensus.quarantine_after);
  consensus.read("quarantine_rounds", config.consensus.quarantine_rounds);
  consensus.read("quarantine_doublings", config.consensus.quarantine_doublings);
  consensus.read("max_marginal_landmarks", config.consensus.max_marginal_landmarks);
  consensus.read("link_budget_bytes_per_second", config.consensus.link_budget_bytes_per_second);
  std::string association = to_string(config.consensus.association);
  consensus.read("association", association);
  if (const auto parsed = parse_association_mode(association)) {
    config.consensus.association = *parsed;
  } else {
    problems.push_back("consensus.association: expected auto, given or negotiated, got '" +
                       association + "'");
  }
  {
    Section radio(consensus.child("radio"), "consensus.radio.", problems);
    radio.read("range_m", config.consensus.radio.range_m);
    radio.read("nearest", config.consensus.radio.nearest);
    radio.read("max_degree", config.consensus.radio.max_degree);
    radio.read("truth", config.consensus.radio.truth, base_directory);
    radio.finish();
  }
  NegotiationLimits& limits = config.consensus.negotiation_limits;
  consensus.read("max_description_objects", limits.max_description_objects);
  consensus.read("max_owner_records", limits.max_records);
  consensus.read("max_record_links", limits.max_links_per_record);
  consensus.read("max_record_frame_edges", limits.max_frame_edges_per_record);
  consensus.finish();

  Section http(top.child("http"), "http.", problems);
  http.read("enabled", config.http.enabled);
  http.read("address", config.http.address);
  http.read_port("port", config.http.port, true);
  http.read_size("max_connections", config.http.max_connections);
  http.read_size("max_connections_per_client", config.http.max_connections_per_client);
  http.finish();

  Section output(top.child("output"), "output.", problems);
  output.read("directory", config.output.directory, base_directory);
  output.read_milliseconds("write_interval_ms", config.output.write_interval, true);
  output.read_milliseconds("fsync_interval_ms", config.output.fsync_interval, true);
  output.read("checkpoint", config.output.checkpoint);
  output.finish();
  top.finish();

  if (problems.empty()) problems = config.validate();
  if (!problems.empty()) {
    std::string message = source_name + ": invalid daemon config:";
    for (const std::string& problem : problems) message += "\n  " + problem;
    throw ConfigError(message);
  }
  return config;
}

DaemonConfig load_daemon_config(const std::filesystem::path& file) {
  return parse_daemon_config(config::read_config_text(file, "config file"), file.string(),
                             file.parent_path());
}

}  // namespace concord::daemon

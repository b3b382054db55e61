// The daemon config loader: the checked-in examples load, every problem is reported with its key.
#include <gtest/gtest.h>

#include "concord/config/options_file.h"
#include "concord/daemon/config.h"
#include "test_paths.h"

namespace concord::daemon {
namespace {

using testing::kSource;

TEST(DaemonConfig, CheckedInTeamConfigsLoad) {
  for (int robot = 0; robot < 3; ++robot) {
    const auto file = kSource / "configs/team-kitti00" / ("robot_0" + std::to_string(robot) + ".yaml");
    const DaemonConfig config = load_daemon_config(file);
    EXPECT_EQ(config.robot_id, robot);
    EXPECT_EQ(config.source.robot, robot);
    EXPECT_EQ(config.network.listen_port, 7100 + robot);
    EXPECT_EQ(config.network.peers.size(), 2u);
    EXPECT_EQ(config.consensus.mode, ConsensusMode::kLockstep);
    // Relative paths resolve against the file's folder.
    EXPECT_TRUE(std::filesystem::exists(config.source.dataset / "dataset.json"));
    EXPECT_FALSE(config.estimator_file.empty());
  }
}

TEST(DaemonConfig, DefaultsNeedADatasetATeamKeyAndTheMembers) {
  const DaemonConfig config = parse_daemon_config(
      "team_key_file: team.key\nmembers: [0, 1]\nsource: {dataset: data/x}\n", "inline", "/base");
  EXPECT_EQ(config.source.dataset, std::filesystem::path("/base/data/x"));
  EXPECT_EQ(config.team_key_file, std::filesystem::path("/base/team.key"));
  EXPECT_EQ(config.members, (std::vector<int>{0, 1}));
  EXPECT_EQ(config.http.address, "127.0.0.1");
  EXPECT_FALSE(config.network.discovery);
}

TEST(DaemonConfig, InlineEstimatorOptions) {
  const DaemonConfig config = parse_daemon_config(
      "consensus: {mode: off}\nsource: {dataset: d}\n"
      "estimator: {window_size: 7, consensus: {neighbour_chi2_probability: 0.99}}\n",
      "inline", "/");
  EXPECT_EQ(config.estimator.window_size, 7);
  EXPECT_EQ(config.estimator.consensus.neighbour_chi2_probability, 0.99);
}

std::string problems_of(const std::string& yaml) {
  try {
    (void)parse_daemon_config(yaml, "robot.yaml", "/");
  } catch (const config::ConfigError& error) {
    return error.what();
  }
  return "";
}

TEST(DaemonConfig, EveryProblemIsNamed) {
  const std::string message = problems_of(
      "robot_id: -1\n"
      "sorce: {}\n"
      "source: {dataset: d, rate_hz: fast}\n"
      "network: {listen_port: 70000, peers: 5}\n"
      "consensus: {mode: sometimes}\n"
      "http: {prot: 80}\n"
      "estimator: {window_size: 0}\n");
  EXPECT_NE(message.find("robot.yaml"), std::string::npos);
  EXPECT_NE(message.find("unknown key sorce"), std::string::npos);
  EXPECT_NE(message.find("source.rate_hz"), std::string::npos);
  EXPECT_NE(message.find("network.listen_port"), std::string::npos);
  EXPECT_NE(message.find("network.peers"), std::string::npos);
  EXPECT_NE(message.find("consensus.mode"), std::string::npos);
  EXPECT_NE(message.find("unknown key http.prot"), std::string::npos);
  EXPECT_NE(message.find("window_size"), std::string::npos);
}

TEST(DaemonConfig, CrossFieldChecks) {
  EXPECT_NE(problems_of("source: {kind: replay}\n").find("source.dataset"), std::string::npos);
  EXPECT_NE(problems_of("source: {kind: ingest}\n").find("source.camera"), std::string::npos);
  EXPECT_NE(problems_of("source: {dataset: d}\nnetwork: {heartbeat_interval_ms: 500, "
                        "heartbeat_timeout_ms: 100}\n")
                .find("heartbeat_timeout"),
            std::string::npos);
  EXPECT_NE(problems_of("[1, 2]\n").find("expected a map"), std::string::npos);
  // The one YAML reader (config/yaml_section.h): a key given twice, with its line.
  EXPECT_NE(problems_of("robot_id: 1\nrobot_id: 2\n").find("line 2: key robot_id appears more than once"),
            std::string::npos);
  EXPECT_NE(problems_of("http: {port: many}\n").find("http.port = 'many': expected a port"),
            std::string::npos);
  EXPECT_NE(problems_of("consensus: {graph: star}\n")
                .find("consensus.graph: expected complete or ring, got 'star'"),
            std::string::npos);
  EXPECT_NE(problems_of("a: [\n").find("invalid YAML"), std::string::npos);
  EXPECT_THROW((void)load_daemon_config("/nonexistent/robot.yaml"), config::ConfigError);
}

TEST(DaemonConfig, TrustAndBoundsAreChecked) {
  const std::string unkeyed = problems_of("source: {dataset: d}\n");
  EXPECT_NE(unkeyed.find("team_key_file: required"), std::string::npos) << unkeyed;
  EXPECT_NE(unkeyed.find("members: required"), std::string::npos) << unkeyed;
  EXPECT_NE(problems_of("robot_id: 5\nteam_key_file: k\nmembers: [0, 1]\nsource: {dataset: d}\n")
                .find("does not contain this robot's id 5"),
            std::string::npos);
  // Consensus off: no key needed.
  EXPECT_EQ(problems_of("source: {dataset: d}\nconsensus: {mode: off}\n"), "");
  // Ingest on another address than loopback must be authenticated.
  const std::string open_ingest = problems_of(
      "consensus: {mode: off}\nsource: {kind: ingest, camera: c, ingest_address: 0.0.0.0}\n");
  EXPECT_NE(open_ingest.find("ingest_authenticated"), std::string::npos) << open_ingest;
  EXPECT_NE(problems_of("consensus: {mode: off}\nsource: {kind: ingest, camera: c, "
                        "ingest_address: 0.0.0.0, ingest_authenticated: true}\n")
                .find("team_key_file: required"),
            std::string::npos);
  for (const char* rate : {"-1", "1e-6", "20000"})
    EXPECT_NE(problems_of("consensus: {mode: off}\nsource: {dataset: d, rate_hz: " +
                          std::string(rate) + "}\n")
                  .find("source.rate_hz"),
              std::string::npos)
        << rate;
  EXPECT_NE(problems_of("consensus: {mode: off, future_rounds: 0}\nsource: {dataset: d}\n")
                .find("consensus.future_rounds"),
            std::string::npos);
  for (const char* doublings : {"-1", "21"})
    EXPECT_NE(problems_of("consensus: {mode: off, quarantine_doublings: " + std::string(doublings) +
                          "}\nsource: {dataset: d}\n")
                  .find("consensus.quarantine_doublings"),
              std::string::npos)
        << doublings;
  EXPECT_EQ(problems_of("consensus: {mode: off, quarantine_doublings: 0}\nsource: {dataset: d}\n"),
            "");
}

}  // namespace
}  // namespace concord::daemon

namespace concord::daemon {
namespace {

TEST(DaemonConfig, IdentitiesNeedTheRobotsKeyFileAndEveryMembersPublicKey) {
  const std::string key0(64, 'a'), key1(64, 'B');
  const std::string team = "team_key_file: k\nmembers: [0, 1]\nsource: {dataset: d}\n";
  const DaemonConfig config =
      parse_daemon_config(team + "identity_key_file: me.identity\nmember_keys: {0: " + key0 +
                              ", 1: \"" + key1 + "\"}\n",
                          "inline", "/base");
  EXPECT_EQ(config.identity_key_file, std::filesystem::path("/base/me.identity"));
  EXPECT_EQ(config.member_keys, (std::map<int, std::string>{{0, key0}, {1, key1}}));
  EXPECT_EQ(problems_of(team + "identity_key_file: me\nmember_keys: {0: " + key0 + ", 1: " + key1 +
                        "}\n"),
            "");
  const std::string no_file =
      problems_of(team + "member_keys: {0: " + key0 + ", 1: " + key1 + "}\n");
  EXPECT_NE(no_file.find("identity_key_file: required with member_keys"), std::string::npos)
      << no_file;
  const std::string no_keys = problems_of(team + "identity_key_file: me\n");
  EXPECT_NE(no_keys.find("member_keys: required with identity_key_file"), std::string::npos)
      << no_keys;
  const std::string missing =
      problems_of(team + "identity_key_file: me\nmember_keys: {0: " + key0 + "}\n");
  EXPECT_NE(missing.find("no key for member 1"), std::string::npos) << missing;
  const std::string short_key =
      problems_of(team + "identity_key_file: me\nmember_keys: {0: " + key0 + ", 1: abc}\n");
  EXPECT_NE(short_key.find("the key of robot 1 is not 64 hex digits"), std::string::npos)
      << short_key;
  const std::string not_a_map = problems_of(team + "identity_key_file: me\nmember_keys: [1, 2]\n");
  EXPECT_NE(not_a_map.find("member_keys"), std::string::npos) << not_a_map;
  const std::string bad_id =
      problems_of(team + "identity_key_file: me\nmember_keys: {zero: " + key0 + "}\n");
  EXPECT_NE(bad_id.find("a robot id"), std::string::npos) << bad_id;
}

TEST(DaemonConfig, ASimulatedRadioNeedsGroundTruthAndSaneLimits) {
  const DaemonConfig config = parse_daemon_config(
      "team_key_file: k\nmembers: [0, 1]\nsource: {dataset: d}\n"
      "consensus: {radio: {range_m: 12.5, nearest: 3, max_degree: 2, truth: t}}\n",
      "inline", "/base");
  EXPECT_DOUBLE_EQ(config.consensus.radio.range_m, 12.5);
  EXPECT_EQ(config.consensus.radio.nearest, 3);
  EXPECT_EQ(config.consensus.radio.max_degree, 2);
  EXPECT_EQ(config.consensus.radio.truth, std::filesystem::path("/base/t"));
  EXPECT_TRUE(config.consensus.radio.any());
  EXPECT_FALSE(parse_daemon_config("team_key_file: k\nmembers: [0]\nsource: {dataset: d}\n",
                                   "inline", "/")
                   .consensus.radio.any());

  const std::string bad = problems_of(
      "team_key_file: k\nmembers: [0]\nsource: {dataset: d}\n"
      "consensus: {radio: {range_m: -1, nearest: -2, max_degree: -3}}\n");
  EXPECT_NE(bad.find("consensus.radio.range_m"), std::string::npos) << bad;
  EXPECT_NE(bad.find("consensus.radio.nearest"), std::string::npos) << bad;
  EXPECT_NE(bad.find("consensus.radio.max_degree"), std::string::npos) << bad;
  EXPECT_NE(problems_of("team_key_file: k\nmembers: [0]\nsource: {dataset: d}\n"
                        "consensus: {radio: {power: 5}}\n")
                .find("unknown key consensus.radio.power"),
            std::string::npos);
  // Live sensors have no ground truth: the radio then needs a dataset named for it.
  const std::string no_truth = problems_of(
      "team_key_file: k\nmembers: [0]\nsource: {kind: ingest, camera: c}\n"
      "consensus: {radio: {range_m: 10}}\n");
  EXPECT_NE(no_truth.find("consensus.radio: needs consensus.radio.truth"), std::string::npos)
      << no_truth;
}

TEST(DaemonConfig, AssociationModeLimitsAndInlineAssociationOptions) {
  const DaemonConfig config = parse_daemon_config(
      "team_key_file: k\nmembers: [0, 1]\nsource: {dataset: d}\n"
      "consensus: {association: negotiated, max_description_objects: 50}\n"
      "estimator: {window_size: 7, association: {min_observations: 9}}\n",
      "inline", "/");
  EXPECT_EQ(config.consensus.association, AssociationMode::kNegotiated);
  EXPECT_EQ(config.consensus.negotiation_limits.max_description_objects, 50);
  EXPECT_EQ(config.negotiation.association.min_observations, 9);
  EXPECT_EQ(config.estimator.window_size, 7);

  std::string message;
  try {
    (void)parse_daemon_config(
        "team_key_file: k\nmembers: [0]\nsource: {dataset: d}\n"
        "consensus: {mode: async, association: negotiated, max_owner_records: 0}\n",
        "robot.yaml", "/");
  } catch (const config::ConfigError& error) {
    message = error.what();
  }
  EXPECT_NE(message.find("consensus.association: negotiated needs consensus.mode lockstep"),
            std::string::npos)
      << message;
  EXPECT_NE(message.find("max_owner_records"), std::string::npos) << message;
  // Images or ingest whose object ids are the robot's own: auto negotiates them, so lockstep.
  const DaemonConfig own_ids = parse_daemon_config(
      "team_key_file: k\nmembers: [0, 1]\nconsensus: {mode: lockstep}\n"
      "source: {kind: images, images: seq, private_ids: true}\n",
      "robot.yaml", "/");
  EXPECT_TRUE(own_ids.source.private_ids);
  EXPECT_FALSE(own_ids.source.unknown_start);
  for (const std::string source :
       {"{kind: images, images: seq, private_ids: true}",
        "{kind: ingest, camera: c.json, unknown_start: true}"}) {
    try {
      message.clear();
      (void)parse_daemon_config("team_key_file: k\nmembers: [0, 1]\nconsensus: {mode: async}\n"
                                "source: " + source + "\n",
                                "robot.yaml", "/");
    } catch (const config::ConfigError& error) {
      message = error.what();
    }
    EXPECT_NE(message.find("consensus.association: auto negotiates"), std::string::npos)
        << source << ": " << message;
  }
  // The same with ids given to the team is an ordinary async team.
  EXPECT_NO_THROW((void)parse_daemon_config(
      "team_key_file: k\nmembers: [0, 1]\nconsensus: {mode: async}\n"
      "source: {kind: images, images: seq}\n",
      "robot.yaml", "/"));
  try {
    message.clear();
    (void)parse_daemon_config("consensus: {mode: off, association: guessed}\nsource: {dataset: d}\n",
                              "robot.yaml", "/");
  } catch (const config::ConfigError& error) {
    message = error.what();
  }
  EXPECT_NE(message.find("consensus.association: expected auto, given or negotiated, got 'guessed'"),
            std::string::npos)
      << message;
}

}  // namespace
}  // namespace concord::daemon

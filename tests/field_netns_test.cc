// A team across hosts (issue 14): each concordd in its own network namespace on a bridge
// (tests/netns_lab.h), found by UDP beacon discovery with no static peers, partitioned (a link
// down) and healed, and on tc token-bucket links. Skipped with a message where namespaces cannot
// be created (not root, no iproute2, no CAP_NET_ADMIN). Every wait has a deadline; the namespaces
// are removed even when an assertion fails (RAII). A robot killed under a supervisor-like wrapper
// (restart on failure, as the systemd unit's Restart=on-failure) comes back from its checkpoint.
#include <gtest/gtest.h>
#include <signal.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <optional>
#include <regex>
#include <sstream>
#include <thread>

#include "concord/dataset/dataset.h"
#include "concord/dataset/result_io.h"
#include "launch/launch.h"
#include "launch/process.h"
#include "netns_lab.h"
#include "process_support.h"
#include "test_paths.h"

namespace concord {
namespace {

using testing::eventually;
using testing::fresh_folder;
using testing::get_json;
using testing::read_text;

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using launch::ChildProcess;
using nlohmann::json;
using testing::NetnsLab;
using Clock = std::chrono::steady_clock;

using testing::kSource;
using testing::kDaemon;
constexpr std::uint16_t kHttpPort = 8080;  // every robot has its own namespace: same ports

/// A test's scratch folder, its lab of namespaces and the team key; no lab (and `skip` says
/// why) where namespaces cannot be created.
struct Field {
  Field(const std::string& name, int robots) : out(fresh_folder(name)) {
    skip = NetnsLab::unavailable();
    if (!skip.empty()) return;
    try {
      lab.emplace(robots, out);
    } catch (const std::exception& error) {
      skip = std::string("cannot create network namespaces here: ") + error.what();
      return;
    }
    launch::LaunchOptions options;
    options.out = out;
    key = launch::ensure_team_key(options);
  }

  fs::path out;
  std::optional<NetnsLab> lab;
  fs::path key;
  std::string skip;
};

/// Robot `robot`'s config: discovery only (no static peers), async consensus.
std::string robot_config(const fs::path& out, const fs::path& key, int robot, int robots,
                         double rate_hz, const std::string& extra_network = "") {
  std::string members;
  for (int member = 0; member < robots; ++member)
    members += (member ? ", " : "") + std::to_string(member);
  return "robot_id: " + std::to_string(robot) + "\nteam: field\nteam_key_file: " + key.string() +
         "\nmembers: [" + members +
         "]\nestimator: " + (kSource / "configs/sensors/kitti-stereo.yaml").string() +
         "\nsource: {kind: replay, dataset: " + (kSource / "data/kitti00-300").string() +
         ", robot: " + std::to_string(robot % 3) + ", rate_hz: " + std::to_string(rate_hz) +
         "}\nnetwork: {listen_address: 0.0.0.0, listen_port: 7100, peers: [], discovery: true, "
         "heartbeat_interval_ms: 100, heartbeat_timeout_ms: 1000" +
         extra_network + "}\nconsensus: {mode: async}\nhttp: {address: 0.0.0.0, port: " +
         std::to_string(kHttpPort) +
         "}\noutput: {directory: " + (out / dataset::robot_folder_name(robot)).string() +
         ", write_interval_ms: 0}\n";
}

std::optional<json> get_json(const NetnsLab& lab, int robot, const std::string& target) {
  const auto body = launch::http_get(lab.address(robot), kHttpPort, target, 1000ms);
  if (!body) return std::nullopt;
  json parsed = json::parse(*body, nullptr, false);
  if (parsed.is_discarded()) return std::nullopt;
  return parsed;
}

/// Robots that `robot` has up, or -1 if it does not answer.
int live_peers(const NetnsLab& lab, int robot) {
  const auto peers = get_json(lab, robot, "/peers");
  if (!peers) return -1;
  int up = 0;
  for (const auto& peer : (*peers)["peers"]) up += peer["up"] == true ? 1 : 0;
  return up;
}

/// A counter of /metrics (robot label only), or -1.
double metric(const NetnsLab& lab, int robot, const std::string& name) {
  const auto text = launch::http_get(lab.address(robot), kHttpPort, "/metrics", 1000ms);
  if (!text) return -1;
  const std::string prefix = name + "{robot=\"" + std::to_string(robot) + "\"} ";
  const auto at = text->find(prefix);
  if (at == std::string::npos) return -1;
  return std::stod(text->substr(at + prefix.size()));
}

TEST(FieldNetns, DiscoveryAcrossNamespacesThenPartitionAndHeal) {
  Field field("field-partition", 3);
  if (!field.lab) GTEST_SKIP() << field.skip;
  const fs::path& out = field.out;
  const fs::path& key = field.key;
  auto& lab = field.lab;
  std::vector<ChildProcess> daemons;
  for (int robot = 0; robot < 3; ++robot) {
    const fs::path config = out / (dataset::robot_folder_name(robot) + ".yaml");
    dataset::write_file_atomically(config, robot_config(out, key, robot, 3, 10.0));
    daemons.push_back(lab->spawn(robot, {kDaemon, "--config", config},
                                 out / (dataset::robot_folder_name(robot) + ".log")));
  }
  auto log_of = [&](int robot) {
    return read_text(out / (dataset::robot_folder_name(robot) + ".log"));
  };

  // 1. Discovery: no static peers, each robot finds the two others by their beacons.
  for (int robot = 0; robot < 3; ++robot)
    ASSERT_TRUE(eventually([&] { return live_peers(*lab, robot) == 2; }, 20s))
        << "robot " << robot << ":\n"
        << log_of(robot);
  // Robots 0 and 1 see the same cars early in kitti00-300 (robot 2 does not): they fuse.
  EXPECT_TRUE(
      eventually([&] { return metric(*lab, 1, "concord_marginals_fused_total") > 0.0; }, 20s));

  // 2. Partition: robot 1's link goes down; both sides notice within the heartbeat timeout.
  lab->set_link(1, false);
  EXPECT_TRUE(
      eventually([&] { return live_peers(*lab, 0) == 1 && live_peers(*lab, 2) == 1; }, 15s));
  // Robot 1 is out of reach of the test too (its HTTP goes over the same link).
  EXPECT_EQ(live_peers(*lab, 1), -1);

  // 3. Heal: the link comes back; they find each other again and robot 1 fuses again.
  lab->set_link(1, true);
  ASSERT_TRUE(eventually([&] { return live_peers(*lab, 1) == 2; }, 20s)) << log_of(1);
  EXPECT_TRUE(
      eventually([&] { return live_peers(*lab, 0) == 2 && live_peers(*lab, 2) == 2; }, 20s));
  const double fused_at_heal = metric(*lab, 1, "concord_marginals_fused_total");
  EXPECT_TRUE(eventually(
      [&] { return metric(*lab, 1, "concord_marginals_fused_total") > fused_at_heal; }, 10s));

  for (auto& daemon : daemons) daemon.signal(SIGTERM);
  for (int robot = 0; robot < 3; ++robot) {
    ASSERT_TRUE(daemons[robot].wait_for(10s));
    EXPECT_EQ(daemons[robot].exit_code(), 0) << log_of(robot);
  }
}

TEST(FieldNetns, RateLimitedLinksUnderALinkBudgetTrimMarginalsAndKeepTheFrameRate) {
  Field field("field-budget", 3);
  if (!field.lab) GTEST_SKIP() << field.skip;
  const fs::path& out = field.out;
  const fs::path& key = field.key;
  auto& lab = field.lab;
  constexpr double kBudget = 8000.0;  // bytes per second for consensus, far below what it wants
  std::vector<ChildProcess> daemons;
  for (int robot = 0; robot < 3; ++robot) {
    lab->rate_limit(robot, "1mbit");  // each robot's radio: 1 Mbit/s out
    const fs::path config = out / (dataset::robot_folder_name(robot) + ".yaml");
    std::string yaml = robot_config(out, key, robot, 3, 20.0);
    yaml.replace(
        yaml.find("consensus: {mode: async}"), 24,
        "consensus: {mode: async, link_budget_bytes_per_second: " + std::to_string(kBudget) + "}");
    dataset::write_file_atomically(config, yaml);
    daemons.push_back(lab->spawn(robot, {kDaemon, "--config", config},
                                 out / (dataset::robot_folder_name(robot) + ".log")));
  }
  auto log_of = [&](int robot) {
    return read_text(out / (dataset::robot_folder_name(robot) + ".log"));
  };
  for (int robot = 0; robot < 3; ++robot)
    ASSERT_TRUE(eventually([&] { return live_peers(*lab, robot) == 2; }, 20s)) << log_of(robot);
  const auto start = Clock::now();
  const double bytes_at_start = metric(*lab, 0, "concord_consensus_bytes_sent_total");
  // Robots 0 and 1 share cars: their marginals do not fit and are trimmed, yet still fused.
  EXPECT_TRUE(eventually(
      [&] { return metric(*lab, 0, "concord_consensus_budget_marginals_trimmed_total") > 0; }, 20s))
      << log_of(0);
  EXPECT_TRUE(
      eventually([&] { return metric(*lab, 1, "concord_marginals_fused_total") > 0; }, 20s));
  EXPECT_GT(metric(*lab, 0, "concord_consensus_budget_landmarks_dropped_total"), 0);
  // The frame rate is kept: the estimator is never held up by the rate-limited links. Whether
  // it keeps 20 Hz depends on the machine (a sanitizer build on a shared core does not), so what
  // is checked is where its time goes, measured in the same run: async rounds never wait for a
  // neighbour, and the rounds (building and posting the messages, fusing) take less than ten
  // times the estimator's filter updates (measured: 0.4-0.7 of them in a Release build, up to
  // 1.05 on a core shared with a busy loop; 0.07-0.14 under AddressSanitizer). A round that
  // waited for its bytes to leave through the links would take far more (a Release round
  // delayed 40 ms: 100 times the updates).
  EXPECT_TRUE(
      eventually([&] { return metric(*lab, 0, "concord_frames_processed_total") >= 150; }, 60s));
  const double update_seconds = metric(*lab, 0, "concord_update_seconds_total");
  const double round_seconds = metric(*lab, 0, "concord_consensus_seconds_total");
  EXPECT_GT(update_seconds, 0.0);
  EXPECT_GE(round_seconds, 0.0);
  EXPECT_LT(round_seconds, 10.0 * update_seconds);
  EXPECT_EQ(metric(*lab, 0, "concord_consensus_wait_seconds_total"), 0.0);
  // Consensus stays within its budget: rate x elapsed + the one-second burst (+ a few control
  // messages that may overdraw it).
  const double bytes_now = metric(*lab, 0, "concord_consensus_bytes_sent_total");
  const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
  ASSERT_GE(bytes_at_start, 0.0);
  ASSERT_GT(bytes_now, bytes_at_start);
  EXPECT_LE(bytes_now - bytes_at_start, kBudget * (elapsed + 1.0) + 4000.0)
      << "over " << elapsed << " s";

  for (auto& daemon : daemons) daemon.signal(SIGTERM);
  for (int robot = 0; robot < 3; ++robot) {
    ASSERT_TRUE(daemons[robot].wait_for(10s));
    EXPECT_EQ(daemons[robot].exit_code(), 0) << log_of(robot);
  }
}

/// A supervisor-like wrapper (the systemd unit's Restart=on-failure): runs the command, writes
/// the running child's pid to `pid_file`, restarts it whenever it exits with a failure, and
/// exits 0 once it exits 0.
std::vector<std::string> supervised(const fs::path& pid_file, std::vector<std::string> command) {
  std::vector<std::string> argv{
      "/bin/sh", "-c",
      "pid_file=$1; shift; restarts=0\n"
      "while true; do\n"
      "  \"$@\" & child=$!; echo $child > \"$pid_file.tmp\"; mv \"$pid_file.tmp\" \"$pid_file\"\n"
      "  wait $child; code=$?\n"
      "  [ $code -eq 0 ] && exit 0\n"
      "  restarts=$((restarts + 1)); echo \"supervisor: exit $code, restart $restarts\"\n"
      "done",
      "supervisor", pid_file.string()};
  argv.insert(argv.end(), command.begin(), command.end());
  return argv;
}

/// The pid in `pid_file` if it names a live process other than `not_this` (0 if none).
pid_t supervised_pid(const fs::path& pid_file, pid_t not_this = 0) {
  std::ifstream stream(pid_file);
  long pid = 0;
  if (!(stream >> pid) || pid <= 0 || pid == not_this) return 0;
  return ::kill(static_cast<pid_t>(pid), 0) == 0 ? static_cast<pid_t>(pid) : 0;
}

TEST(FieldNetns, ARobotKilledUnderItsSupervisorComesBackFromItsCheckpoint) {
  Field field("field-restart", 3);
  if (!field.lab) GTEST_SKIP() << field.skip;
  const fs::path& out = field.out;
  const fs::path& key = field.key;
  auto& lab = field.lab;
  const fs::path pid_file = out / "robot_01.pid";
  std::vector<ChildProcess> processes;  // robot 1's is its supervisor
  for (int robot = 0; robot < 3; ++robot) {
    const fs::path config = out / (dataset::robot_folder_name(robot) + ".yaml");
    std::string yaml = robot_config(out, key, robot, 3, 10.0);
    // A checkpoint with every output write, five times a second.
    yaml.replace(yaml.find("write_interval_ms: 0"), 20, "write_interval_ms: 200");
    dataset::write_file_atomically(config, yaml);
    std::vector<std::string> command{kDaemon, "--config", config};
    if (robot == 1) command = supervised(pid_file, command);
    processes.push_back(
        lab->spawn(robot, command, out / (dataset::robot_folder_name(robot) + ".log")));
  }
  auto log_of = [&](int robot) {
    return read_text(out / (dataset::robot_folder_name(robot) + ".log"));
  };
  for (int robot = 0; robot < 3; ++robot)
    ASSERT_TRUE(eventually([&] { return live_peers(*lab, robot) == 2; }, 20s)) << log_of(robot);
  ASSERT_TRUE(eventually(
      [&] {
        const auto status = get_json(*lab, 1, "/status");
        return status && (*status)["frames_processed"].get<int>() >= 60;
      },
      30s))
      << log_of(1);

  // SIGKILL robot 1's daemon (not its supervisor): nothing is written on the way out.
  const pid_t first = supervised_pid(pid_file);
  ASSERT_GT(first, 0);
  ASSERT_EQ(::kill(first, SIGKILL), 0);

  // The supervisor starts it again; it resumes from its checkpoint (a round past the first 50
  // frames), is found again by both others and fuses again.
  pid_t second = 0;
  ASSERT_TRUE(eventually([&] { return (second = supervised_pid(pid_file, first)) > 0; }, 20s))
      << log_of(1);
  ASSERT_TRUE(eventually(
      [&] {
        const auto status = get_json(*lab, 1, "/status");
        return status && (*status)["resumed_from_round"].get<int>() >= 50 &&
               (*status)["live_peers"].size() == 2;
      },
      30s))
      << log_of(1);
  for (int robot : {0, 2}) {
    EXPECT_TRUE(eventually(
        [&] {
          const auto peers = get_json(*lab, robot, "/peers");
          if (!peers) return false;
          for (const auto& peer : (*peers)["peers"])
            if (peer["robot"] == 1) return peer["up"] == true && peer["reconnects"].get<int>() >= 1;
          return false;
        },
        20s))
        << "robot " << robot << " did not take robot 1 back";
  }
  EXPECT_TRUE(
      eventually([&] { return metric(*lab, 1, "concord_marginals_fused_total") > 0.0; }, 20s))
      << log_of(1);
  EXPECT_NE(log_of(1).find("supervisor: exit 137, restart 1"), std::string::npos) << log_of(1);

  // A clean stop ends the daemons, and the supervisor with them (exit 0: not restarted).
  ::kill(second, SIGTERM);
  processes[0].signal(SIGTERM);
  processes[2].signal(SIGTERM);
  for (int robot = 0; robot < 3; ++robot) {
    ASSERT_TRUE(processes[robot].wait_for(20s)) << log_of(robot);
    EXPECT_EQ(processes[robot].exit_code(), 0) << log_of(robot);
  }
  EXPECT_EQ(log_of(1).find("restart 2"), std::string::npos) << log_of(1);
}

}  // namespace
}  // namespace concord

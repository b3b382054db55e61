// concordd under a service manager (issue 14): readiness and the watchdog over systemd's notify
// protocol (a fake NOTIFY_SOCKET), the watchdog pings stopping while the estimator thread hangs
// (failpoint estimator.hang) and resuming after, SIGHUP re-reading the peer list and reopening
// the log file, --check-config on good and bad configs, and the unit through
// `systemd-analyze verify`. Every wait has a deadline; no test sleeps to synchronise.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/stat.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <sstream>
#include <thread>

#include "concord/dataset/result_io.h"
#include "launch/launch.h"
#include "launch/process.h"
#include "process_support.h"
#include "service_manager_fake.h"
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
using testing::FakeServiceManager;
using testing::ScopedEnvironment;
using Clock = std::chrono::steady_clock;

using testing::kSource;
using testing::kDaemon;

/// Ports of this test process (20 per process), below Linux's ephemeral range.
std::uint16_t supervision_port(int offset) {
  // Below Linux's ephemeral range (32768-60999: the source ports of outgoing connections) and
  // apart from the other process tests' ranges (11000-32150).
  return static_cast<std::uint16_t>(5000 + (getpid() % 300) * 20 + offset);
}

void write_text(const fs::path& file, const std::string& text) {
  dataset::write_file_atomically(file, text);
}

/// The port after `label` in a READY status line ("http on port 41234").
std::optional<std::uint16_t> port_in_status(const std::string& text, const std::string& label) {
  const std::regex pattern(label + " on port ([0-9]+)");
  std::smatch match;
  if (!std::regex_search(text, match, pattern)) return std::nullopt;
  return static_cast<std::uint16_t>(std::stoi(match[1]));
}

/// A one-robot replay config (consensus off unless `extra` says otherwise).
std::string replay_config(const fs::path& out, double rate_hz, const std::string& extra = "") {
  return "robot_id: 0\n"
         "estimator: " +
         (kSource / "configs/sensors/kitti-stereo.yaml").string() +
         "\n"
         "source: {kind: replay, dataset: " +
         (kSource / "data/kitti00-300").string() +
         ", robot: 0, rate_hz: " + std::to_string(rate_hz) +
         "}\n"
         "consensus: {mode: off}\n"
         "http: {address: 127.0.0.1, port: 0}\n"
         "output: {directory: " +
         (out / "robot_00").string() + "}\n" + extra;
}

TEST(DaemonSupervision, ReadyThenWatchdogPingsStopWhileTheEstimatorHangsAndResumeAfter) {
  const fs::path out = fresh_folder("supervision-watchdog");
  write_text(out / "robot.yaml", replay_config(out, 10.0));
  FakeServiceManager manager;
  constexpr auto kWatchdog = 1000ms;  // WatchdogSec=1s: a ping every 500 ms
  std::optional<ChildProcess> daemon;
  {
    ScopedEnvironment environment({{"NOTIFY_SOCKET", manager.notify_socket()},
                                   {"WATCHDOG_USEC", std::to_string(kWatchdog.count() * 1000)}});
    daemon.emplace(std::vector<std::string>{kDaemon, "--config", out / "robot.yaml", "--failpoint",
                                            "estimator.hang=4"},
                   out / "robot.log");
  }
  // 1. READY=1 once it listens, with the bound HTTP port in its status.
  const auto ready = manager.wait_for([](const auto& m) { return m.has_line("READY=1"); }, 30s);
  ASSERT_TRUE(ready) << read_text(out / "robot.log");
  const auto http = port_in_status(ready->text, "http");
  ASSERT_TRUE(http) << ready->text;
  EXPECT_TRUE(get_json(*http, "/healthz").has_value());
  // 2. Pings, then the hang (before the second frame): the estimator thread misses its check-in
  //    and the pings stop.
  const auto stalled =
      manager.wait_for([](const auto& m) { return m.contains("unresponsive"); }, 30s);
  ASSERT_TRUE(stalled) << read_text(out / "robot.log");
  // 3. The hang ends (4 s): it checks in again and the pings resume.
  const auto recovered =
      manager.wait_for([](const auto& m) { return m.contains("recovered"); }, 30s);
  ASSERT_TRUE(recovered) << read_text(out / "robot.log");
  ASSERT_TRUE(manager.wait_for([](const auto& m) { return m.has_line("WATCHDOG=1"); }, 10s));

  std::optional<Clock::time_point> last_ping_before, first_ping_after;
  bool in_stall = false;
  int pings_before = 0, pings_during = 0;
  for (const auto& message : manager.history()) {
    if (message.contains("unresponsive")) in_stall = true;
    if (message.contains("recovered")) in_stall = false;
    if (!message.has_line("WATCHDOG=1")) continue;
    if (in_stall) {
      ++pings_during;
    } else if (message.at < stalled->at) {
      ++pings_before;
      last_ping_before = message.at;
    } else if (!first_ping_after) {
      first_ping_after = message.at;
    }
  }
  EXPECT_GE(pings_before, 1);
  EXPECT_EQ(pings_during, 0);
  ASSERT_TRUE(last_ping_before && first_ping_after);
  // systemd would have killed it: no ping for longer than WatchdogSec (the hang is 4 s).
  EXPECT_GT(*first_ping_after - *last_ping_before, 2 * kWatchdog);

  const auto metrics = launch::http_get("127.0.0.1", *http, "/metrics", 1000ms);
  ASSERT_TRUE(metrics);
  EXPECT_NE(metrics->find("concord_watchdog_stalls_total{robot=\"0\"} 1"), std::string::npos)
      << *metrics;
  // 4. SIGTERM: STOPPING=1, then a normal exit.
  daemon->signal(SIGTERM);
  EXPECT_TRUE(manager.wait_for([](const auto& m) { return m.has_line("STOPPING=1"); }, 10s));
  ASSERT_TRUE(daemon->wait_for(10s));
  EXPECT_EQ(daemon->exit_code(), 0);
}

TEST(DaemonSupervision, SighupReReadsThePeerListAndReopensTheLogFile) {
  const fs::path out = fresh_folder("supervision-sighup");
  launch::LaunchOptions options;
  options.out = out;
  const fs::path key = launch::ensure_team_key(options);
  const std::uint16_t peer_port = supervision_port(0);
  // Two robots in async mode; robot 1 starts without static peers.
  auto yaml = [&](int robot, const std::string& peers) {
    return "robot_id: " + std::to_string(robot) + "\nteam: sighup\nteam_key_file: " + key.string() +
           "\nmembers: [0, 1]\nestimator: " +
           (kSource / "configs/sensors/kitti-stereo.yaml").string() +
           "\nsource: {kind: replay, dataset: " + (kSource / "data/kitti00-300").string() +
           ", robot: " + std::to_string(robot) + ", rate_hz: 5}\n" +
           "network: {listen_address: 127.0.0.1, listen_port: " +
           std::to_string(peer_port + robot) + ", peers: [" + peers + "]}\n" +
           "consensus: {mode: async}\nhttp: {address: 127.0.0.1, port: " +
           std::to_string(supervision_port(10 + robot)) +
           "}\noutput: {directory: " + (out / ("robot_0" + std::to_string(robot))).string() +
           "}\nlog_file: " + (out / ("robot_0" + std::to_string(robot) + ".log")).string() + "\n";
  };
  write_text(out / "robot_00.yaml", yaml(0, ""));
  write_text(out / "robot_01.yaml", yaml(1, ""));
  ChildProcess robot0({kDaemon, "--config", out / "robot_00.yaml"}, out / "robot_00.stderr");
  ChildProcess robot1({kDaemon, "--config", out / "robot_01.yaml"}, out / "robot_01.stderr");
  const std::uint16_t http1 = supervision_port(11);
  ASSERT_TRUE(eventually([&] { return get_json(http1, "/healthz").has_value(); }, 30s))
      << read_text(out / "robot_01.log");
  ASSERT_TRUE(eventually([&] { return get_json(supervision_port(10), "/healthz").has_value(); }, 30s));
  auto robot0_up_at_robot1 = [&] {
    const auto peers = get_json(http1, "/peers");
    if (!peers) return false;
    for (const auto& peer : (*peers)["peers"])
      if (peer["robot"] == 0 && peer["up"] == true) return true;
    return false;
  };
  EXPECT_FALSE(robot0_up_at_robot1());  // nobody dials anybody yet

  // 1. A bad config on SIGHUP changes nothing; the daemon goes on.
  write_text(out / "robot_01.yaml", yaml(1, "") + "network_typo: 1\n");
  robot1.signal(SIGHUP);
  ASSERT_TRUE(eventually(
      [&] {
        return read_text(out / "robot_01.log").find("peer list unchanged") != std::string::npos;
      },
      10s));
  EXPECT_TRUE(get_json(http1, "/healthz").has_value());

  // 2. logrotate moves the log away; the new peer list names robot 0.
  fs::rename(out / "robot_01.log", out / "robot_01.log.1");
  write_text(out / "robot_01.yaml", yaml(1, "\"127.0.0.1:" + std::to_string(peer_port) + "\""));
  robot1.signal(SIGHUP);
  EXPECT_TRUE(eventually(robot0_up_at_robot1, 20s)) << read_text(out / "robot_01.log");
  ASSERT_TRUE(eventually([&] { return fs::exists(out / "robot_01.log"); }, 10s));
  EXPECT_TRUE(eventually(
      [&] {
        return read_text(out / "robot_01.log").find("log file reopened") != std::string::npos;
      },
      10s));
  EXPECT_NE(read_text(out / "robot_01.log.1").find("peer list unchanged"), std::string::npos);
  const auto metrics = launch::http_get("127.0.0.1", http1, "/metrics", 1000ms);
  ASSERT_TRUE(metrics);
  EXPECT_NE(metrics->find("concord_reloads_total{robot=\"1\"} 2"), std::string::npos) << *metrics;

  robot0.signal(SIGTERM);
  robot1.signal(SIGTERM);
  ASSERT_TRUE(robot0.wait_for(10s));
  ASSERT_TRUE(robot1.wait_for(10s));
  EXPECT_EQ(robot0.exit_code(), 0);
  EXPECT_EQ(robot1.exit_code(), 0);
}

/// Runs `concordd --check-config FILE`; its exit code and output.
std::pair<int, std::string> check_config(const fs::path& config, const fs::path& log) {
  fs::remove(log);
  ChildProcess check({kDaemon, "--check-config", config}, log);
  EXPECT_TRUE(check.wait_for(30s));
  return {check.exit_code().value_or(-1), read_text(log)};
}

TEST(DaemonSupervision, CheckConfigAcceptsAGoodConfigAndNamesEachProblem) {
  const fs::path out = fresh_folder("supervision-check");
  const launch::LaunchOptions options =
      testing::kitti_team_options(out, supervision_port(0), supervision_port(10));
  const fs::path key = launch::ensure_team_key(options);
  const std::string good = launch::daemon_config_yaml(options, 0, 3);
  write_text(out / "good.yaml", good);
  const fs::path log = out / "check.log";

  auto [code, text] = check_config(out / "good.yaml", log);
  EXPECT_EQ(code, 0) << text;
  EXPECT_NE(text.find("OK: robot 0 of team"), std::string::npos) << text;
  EXPECT_FALSE(fs::exists(out / "robot_00")) << "--check-config must create nothing";

  // A key others can read: refused, naming the key and the file.
  fs::permissions(key, fs::perms::others_read, fs::perm_options::add);
  std::tie(code, text) = check_config(out / "good.yaml", log);
  EXPECT_EQ(code, 2);
  EXPECT_NE(text.find("team_key_file"), std::string::npos) << text;
  EXPECT_NE(text.find(key.string()), std::string::npos) << text;
  fs::permissions(key, fs::perms::others_read, fs::perm_options::remove);

  // Data that is not there, and an output folder under a file: both reported at once.
  std::string bad = good;
  const std::string dataset = (kSource / "data/kitti00-300").string();
  bad.replace(bad.find(dataset), dataset.size(), (out / "no-such-dataset").string());
  write_text(out / "blocker", "a file\n");
  const std::string output = (out / "robot_00").string();
  bad.replace(bad.find(output), output.size(), (out / "blocker" / "robot_00").string());
  write_text(out / "bad.yaml", bad);
  std::tie(code, text) = check_config(out / "bad.yaml", log);
  EXPECT_EQ(code, 2);
  EXPECT_NE(text.find("source:"), std::string::npos) << text;
  EXPECT_NE(text.find("no-such-dataset"), std::string::npos) << text;
  EXPECT_NE(text.find("output.directory"), std::string::npos) << text;
  EXPECT_NE(text.find("is not a folder"), std::string::npos) << text;

  // An unknown key: a config error naming the key and its line.
  write_text(out / "typo.yaml", good + "log_levle: debug\n");
  std::tie(code, text) = check_config(out / "typo.yaml", log);
  EXPECT_EQ(code, 2);
  EXPECT_NE(text.find("unknown key log_levle"), std::string::npos) << text;
}

TEST(DaemonSupervision, UnitPassesSystemdAnalyzeVerify) {
  const fs::path analyze = "/usr/bin/systemd-analyze";
  if (!fs::exists(analyze)) GTEST_SKIP() << "systemd-analyze is not installed: unit not verified";
  const fs::path out = fresh_folder("supervision-unit");
  // The installed unit runs /usr/bin/concordd; verify it against the built one (verify checks
  // that the executables exist), as an instance (a template is not verifiable).
  std::string unit = read_text(kSource / "configs/systemd/concordd@.service");
  for (std::size_t at = unit.find("/usr/bin/concordd"); at != std::string::npos;
       at = unit.find("/usr/bin/concordd", at))
    unit.replace(at, std::string("/usr/bin/concordd").size(), kDaemon.string());
  EXPECT_NE(unit.find("Type=notify"), std::string::npos);
  EXPECT_NE(unit.find("WatchdogSec="), std::string::npos);
  write_text(out / "concordd@robot_00.service", unit);
  ChildProcess verify({analyze, "verify", (out / "concordd@robot_00.service").string()},
                      out / "verify.log");
  ASSERT_TRUE(verify.wait_for(60s));
  EXPECT_EQ(verify.exit_code(), 0) << read_text(out / "verify.log");
  EXPECT_EQ(read_text(out / "verify.log"), "") << "systemd-analyze verify reported problems";
}

}  // namespace
}  // namespace concord

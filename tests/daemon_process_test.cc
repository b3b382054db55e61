// concordd as processes on loopback: three daemons in lockstep reproduce concord replay; the team
// survives a SIGKILLed peer and takes it back when it restarts; garbage on the peer port and
// malformed HTTP are rejected while the daemon keeps serving; SIGTERM loses no processed frame;
// live ingest of SensorFrame envelopes. Every wait has a deadline.
#include <gtest/gtest.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <thread>

#include "concord/config/options_file.h"
#include "concord/daemon/wire.h"
#include "concord/dataset/dataset.h"
#include "concord/dataset/result_io.h"
#include "concord/estimator/estimator.h"
#include "concord/net/frame_codec.h"
#include "concord/v1/concord.pb.h"
#include "launch/launch.h"
#include "launch/process.h"
#include "process_support.h"
#include "replay/team_replay.h"
#include "sim/simulator.h"
#include "test_paths.h"

namespace concord {
namespace {

using testing::eventually;
using testing::fresh_folder;
using testing::get_json;
using testing::line_count;

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using launch::ChildProcess;
using nlohmann::json;

using testing::kSource;
using testing::kDaemon;

/// Ports of this test process: distinct between test processes run in parallel, and below
/// Linux's ephemeral range (32768-60999) so that no outgoing connection holds them.
std::uint16_t process_port(int offset) {
  // A block of 160 ports per test process (the tests use offsets up to 152): with a smaller
  // block, tests started one after the other (neighbouring pids) shared ports.
  return static_cast<std::uint16_t>(11000 + (getpid() % 130) * 160 + offset);
}

launch::LaunchOptions team_options(const fs::path& out, int port_offset) {
  return testing::kitti_team_options(out, process_port(port_offset), process_port(port_offset + 10));
}

std::optional<json> peer_entry(std::uint16_t http_port, int robot) {
  const auto peers = get_json(http_port, "/peers");
  if (!peers || peers->is_discarded()) return std::nullopt;
  for (const auto& peer : (*peers)["peers"])
    if (peer["robot"] == robot) return peer;
  return std::nullopt;
}

void expect_close(double a, double b, const std::string& what) {
  EXPECT_LE(std::abs(a - b), 1e-6 * std::max(1.0, std::abs(b))) << what << ": " << a << " vs " << b;
}

TEST(DaemonProcess, ThreeDaemonsInLockstepReproduceTheReplay) {
  const fs::path out = fresh_folder("lockstep");
  const auto options = team_options(out, 0);
  const launch::LaunchResult result = launch::launch_team(options, 3, nullptr);
  ASSERT_FALSE(result.timed_out);
  for (int code : result.exit_codes) ASSERT_EQ(code, 0);

  const dataset::Dataset data = dataset::read_dataset(options.dataset);
  const auto reference = replay::run_team(
      data, config::load_estimator_options(options.estimator_config), replay::ReplayOptions{});
  int marginals_fused = 0;
  for (int robot = 0; robot < 3; ++robot) {
    const fs::path folder = out / ("robot_0" + std::to_string(robot));
    const auto trajectory = dataset::read_trajectory_kitti(folder / "trajectory.kitti");
    const auto& expected = reference.robots[robot].trajectory;
    ASSERT_EQ(trajectory.size(), expected.size());
    for (std::size_t k = 0; k < trajectory.size(); ++k) {
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c)
          expect_close(trajectory[k].matrix()(r, c), expected[k].matrix()(r, c),
                       "robot " + std::to_string(robot) + " frame " + std::to_string(k));
    }
    const auto objects = dataset::read_objects_csv(folder / "objects.csv");
    ASSERT_EQ(objects.size(), reference.robots[robot].objects.size());
    for (std::size_t o = 0; o < objects.size(); ++o) {
      EXPECT_EQ(objects[o].id, reference.robots[robot].objects[o].id);
      for (int i = 0; i < 3; ++i)
        expect_close(objects[o].p_world[i], reference.robots[robot].objects[o].p_world[i],
                     "object " + std::to_string(objects[o].id));
    }
    std::ifstream stats_file(folder / "stats.json");
    const json stats = json::parse(stats_file);
    EXPECT_EQ(stats["rounds"], 300);
    marginals_fused += stats["marginals_fused"].get<int>();
  }
  // Robots 0 and 1 share objects in these frames (robot 2 drives elsewhere).
  EXPECT_GT(marginals_fused, 200);
}

TEST(DaemonProcess, DaemonsOverASimulatedRadioReproduceTheRangeLimitedReplay) {
  // consensus.radio from the dataset's ground truth (concord launch --range): each daemon reads
  // every member's groundtruth.kitti and links only to the robots within range at each frame.
  const fs::path out = fresh_folder("radio");
  sim::SimulationOptions simulation;
  simulation.robots = 4;
  simulation.frames = 60;
  simulation.objects = simulation.objects * simulation.frames / 150;
  simulation.points_per_frame = 0;
  const dataset::Dataset data = sim::simulate(simulation);
  dataset::write_dataset(data, out / "data");
  // The median distance between two robots over the run: links come and go.
  const auto positions = replay::RadioLimits::positions_of(data);
  std::vector<double> distances;
  for (int k = 0; k < simulation.frames; ++k)
    for (int i = 0; i < 4; ++i)
      for (int j = i + 1; j < 4; ++j) distances.push_back((positions[i][k] - positions[j][k]).norm());
  std::nth_element(distances.begin(), distances.begin() + distances.size() / 2, distances.end());

  launch::LaunchOptions options = team_options(out / "team", 100);
  options.dataset = out / "data";
  options.estimator_config = kSource / "configs/sensors/sim.yaml";
  options.range_m = distances[distances.size() / 2];
  const launch::LaunchResult result = launch::launch_team(options, 4, nullptr);
  ASSERT_FALSE(result.timed_out);
  for (int code : result.exit_codes) ASSERT_EQ(code, 0);

  replay::ReplayOptions limited;
  limited.radio.range_m = options.range_m;
  const auto estimator = config::load_estimator_options(options.estimator_config);
  const auto reference = replay::run_team(dataset::read_dataset(options.dataset), estimator, limited);
  const auto complete = replay::run_team(dataset::read_dataset(options.dataset), estimator, {});
  bool differs_from_complete = false;
  for (int robot = 0; robot < 4; ++robot) {
    const fs::path folder = options.out / dataset::robot_folder_name(robot);
    const auto trajectory = dataset::read_trajectory_kitti(folder / "trajectory.kitti");
    const auto& expected = reference.robots[robot].trajectory;
    ASSERT_EQ(trajectory.size(), expected.size());
    for (std::size_t k = 0; k < trajectory.size(); ++k) {
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c)
          expect_close(trajectory[k].matrix()(r, c), expected[k].matrix()(r, c),
                       "robot " + std::to_string(robot) + " frame " + std::to_string(k));
      differs_from_complete |=
          (trajectory[k].matrix() - complete.robots[robot].trajectory[k].matrix())
              .cwiseAbs()
              .maxCoeff() > 1e-5;
    }
    std::ifstream stats_file(folder / "stats.json");
    const json stats = json::parse(stats_file);
    EXPECT_EQ(stats["consensus"]["deadline_misses"], 0) << "robot " << robot;
  }
  EXPECT_TRUE(differs_from_complete) << "the radio made no difference: the test shows nothing";
  EXPECT_LT(reference.statistics.edge_rounds, complete.statistics.edge_rounds);
}

TEST(DaemonProcess, AsyncTeamFusesWithoutWaiting) {
  const fs::path out = fresh_folder("async");
  auto options = team_options(out, 140);
  options.mode = "async";
  options.frames = 200;
  options.rate_hz = 100.0;  // live-like pacing, so that the robots overlap in time
  const launch::LaunchResult result = launch::launch_team(options, 3, nullptr);
  ASSERT_FALSE(result.timed_out);
  int marginals_fused = 0;
  for (int robot = 0; robot < 3; ++robot) {
    EXPECT_EQ(result.exit_codes[robot], 0);
    const fs::path folder = out / ("robot_0" + std::to_string(robot));
    EXPECT_EQ(line_count(folder / "trajectory.kitti"), 200u);
    std::ifstream stats_file(folder / "stats.json");
    const json stats = json::parse(stats_file);
    EXPECT_EQ(stats["mode"], "async");
    marginals_fused += stats["marginals_fused"].get<int>();
  }
  // Robots 0 and 1 share objects: they fused each other's marginals without waiting.
  EXPECT_GT(marginals_fused, 50);
}

TEST(DaemonProcess, TeamSurvivesAKilledPeerAndTakesItBack) {
  const fs::path out = fresh_folder("sigkill");
  auto options = team_options(out, 40);
  options.rate_hz = 50.0;  // 300 frames in about 6 s: time to kill and restart mid-run
  fs::create_directories(out / "configs");
  launch::ensure_team_key(options);
  std::vector<fs::path> configs;
  std::vector<ChildProcess> daemons;
  for (int robot = 0; robot < 3; ++robot) {
    configs.push_back(out / "configs" / ("robot_0" + std::to_string(robot) + ".yaml"));
    dataset::write_file_atomically(configs.back(), launch::daemon_config_yaml(options, robot, 3));
    daemons.emplace_back(std::vector<std::string>{kDaemon, "--config", configs.back()},
                         out / ("robot_0" + std::to_string(robot) + ".log"));
  }
  const std::uint16_t http0 = options.http_base_port;
  ASSERT_TRUE(eventually(
      [&] {
        const auto status = get_json(http0, "/status");
        return status && !status->is_discarded() && status->value("frames_processed", 0) >= 40;
      },
      30s));

  daemons[2].signal(SIGKILL);
  ASSERT_TRUE(daemons[2].wait_for(5s));
  ASSERT_TRUE(eventually(
      [&] {
        const auto peer = peer_entry(http0, 2);
        return peer && !(*peer)["up"].get<bool>();
      },
      10s));
  // The others keep going without it.
  const int frames_at_kill = get_json(http0, "/status")->value("frames_processed", 0);

  daemons[2] = ChildProcess({kDaemon, "--config", configs[2]}, out / "robot_02-restarted.log");
  ASSERT_TRUE(eventually(
      [&] {
        const auto peer = peer_entry(http0, 2);
        return peer && (*peer)["up"].get<bool>() && (*peer)["reconnects"].get<int>() >= 1;
      },
      10s))
      << "the restarted robot did not come back as a live peer";

  for (int robot = 0; robot < 2; ++robot) {
    ASSERT_TRUE(daemons[robot].wait_for(120s));
    EXPECT_EQ(daemons[robot].exit_code(), 0);
    const fs::path folder = out / ("robot_0" + std::to_string(robot));
    EXPECT_EQ(line_count(folder / "trajectory.kitti"), 300u);
  }
  EXPECT_GT(get_json(http0, "/status")
                .value_or(json{{"frames_processed", 300}})
                .value("frames_processed", 300),
            frames_at_kill - 1);

  // SIGTERM: the restarted robot stops cleanly with the output of every processed frame.
  daemons[2].signal(SIGTERM);
  ASSERT_TRUE(daemons[2].wait_for(20s));
  EXPECT_EQ(daemons[2].exit_code(), 0);
  std::ifstream stats_file(out / "robot_02" / "stats.json");
  const json stats = json::parse(stats_file);
  EXPECT_EQ(line_count(out / "robot_02" / "trajectory.kitti"), stats["frames"].get<std::size_t>());
}

/// Sends raw bytes to 127.0.0.1:port and returns what comes back until the peer closes (or
/// `timeout`); nullopt if the connection cannot be made or the peer does not close in time.
std::optional<std::string> exchange_raw(std::uint16_t port, const std::string& bytes,
                                        std::chrono::milliseconds timeout) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return std::nullopt;
  timeval tv{static_cast<time_t>(timeout.count() / 1000),
             static_cast<suseconds_t>((timeout.count() % 1000) * 1000)};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = htons(port);
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  std::optional<std::string> received;
  if (::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0 &&
      ::send(fd, bytes.data(), bytes.size(), MSG_NOSIGNAL) == static_cast<ssize_t>(bytes.size())) {
    std::string answer;
    char buffer[4096];
    while (true) {
      const ssize_t n = ::recv(fd, buffer, sizeof buffer, 0);
      if (n > 0) {
        answer.append(buffer, static_cast<std::size_t>(n));
        continue;
      }
      if (n == 0 || errno == ECONNRESET) received = answer;  // closed by the daemon
      break;                                                 // else: timed out, still open
    }
  }
  ::close(fd);
  return received;
}

TEST(DaemonProcess, RejectsGarbageAndMalformedHttpAndStillAnswers) {
  const fs::path out = fresh_folder("garbage");
  auto options = team_options(out, 80);
  options.rate_hz = 20.0;  // runs until we stop it
  const fs::path config = out / "robot_00.yaml";
  launch::ensure_team_key(options);
  dataset::write_file_atomically(config, launch::daemon_config_yaml(options, 0, 1));
  ChildProcess daemon({kDaemon, "--config", config}, out / "robot_00.log");
  const std::uint16_t http = options.http_base_port;
  const std::uint16_t peer_port = options.base_port;
  ASSERT_TRUE(eventually([&] { return get_json(http, "/healthz").has_value(); }, 20s));

  // Peer port: an oversized length prefix and an unparsable payload each close the connection.
  EXPECT_TRUE(exchange_raw(peer_port, std::string("\x7f\xff\xff\xff", 4) + "xxxx", 5s));
  EXPECT_TRUE(
      exchange_raw(peer_port, std::string("\x00\x00\x00\x05", 4) + "\xff\xff\xff\xff\xff", 5s));

  // HTTP: garbage, oversized, wrong method, unknown path.
  const auto garbage = exchange_raw(http, "BLAH BLAH\r\n\r\n", 5s);
  ASSERT_TRUE(garbage);
  EXPECT_EQ(garbage->rfind("HTTP/1.1 400", 0), 0u) << *garbage;
  const auto oversized = exchange_raw(
      http, "GET /status HTTP/1.1\r\nHost: x\r\nX-Big: " + std::string(20000, 'a') + "\r\n\r\n",
      5s);
  ASSERT_TRUE(oversized);
  EXPECT_TRUE(oversized->rfind("HTTP/1.1 431", 0) == 0 || oversized->rfind("HTTP/1.1 413", 0) == 0)
      << *oversized;
  const auto post = exchange_raw(
      http, "POST /status HTTP/1.1\r\nHost: x\r\nConnection: close\r\nContent-Length: 0\r\n\r\n",
      5s);
  ASSERT_TRUE(post);
  EXPECT_EQ(post->rfind("HTTP/1.1 405", 0), 0u) << *post;
  const auto missing =
      exchange_raw(http, "GET /nope HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n", 5s);
  ASSERT_TRUE(missing);
  EXPECT_EQ(missing->rfind("HTTP/1.1 404", 0), 0u);
  EXPECT_NE(missing->find("\"error\""), std::string::npos);
  EXPECT_FALSE(launch::http_get("127.0.0.1", http, "/trajectory?format=xml", 1s));

  // Still serving, and the rejections are counted.
  EXPECT_TRUE(get_json(http, "/healthz"));
  const auto metrics = launch::http_get("127.0.0.1", http, "/metrics", 1s);
  ASSERT_TRUE(metrics);
  EXPECT_NE(metrics->find("concord_network_frames_rejected_total{robot=\"0\"} 2"),
            std::string::npos)
      << *metrics;
  ASSERT_TRUE(eventually([&] { return get_json(http, "/pose").has_value(); }, 20s));
  const auto pose = get_json(http, "/pose");
  ASSERT_TRUE(pose);
  EXPECT_EQ((*pose)["covariance"].size(), 6u);
  // kitti-stereo.yaml makes the stereo disparity offset a state: its estimate is published.
  const auto later_metrics = launch::http_get("127.0.0.1", http, "/metrics", 1s);
  ASSERT_TRUE(later_metrics);
  EXPECT_NE(later_metrics->find("concord_disparity_offset{robot=\"0\"}"), std::string::npos);
  EXPECT_NE(later_metrics->find("concord_disparity_offset_sigma{robot=\"0\"}"), std::string::npos);
  // And its level prior makes the world's up axis one.
  EXPECT_NE(later_metrics->find("concord_world_up_tilt{robot=\"0\"}"), std::string::npos);
  EXPECT_NE(later_metrics->find("concord_world_up_tilt_sigma{robot=\"0\"}"), std::string::npos);
  const auto trajectory = launch::http_get("127.0.0.1", http, "/trajectory?format=tum", 1s);
  ASSERT_TRUE(trajectory);
  EXPECT_EQ(std::count(trajectory->begin(), trajectory->end(), '\n') > 0, true);

  daemon.signal(SIGTERM);
  ASSERT_TRUE(daemon.wait_for(20s));
  EXPECT_EQ(daemon.exit_code(), 0);
  std::ifstream stats_file(out / "robot_00" / "stats.json");
  const json stats = json::parse(stats_file);
  EXPECT_GT(stats["frames"].get<int>(), 0);
  EXPECT_LT(stats["frames"].get<int>(), 300);
  EXPECT_EQ(line_count(out / "robot_00" / "trajectory.kitti"), stats["frames"].get<std::size_t>());
}

TEST(DaemonProcess, IngestsSensorFramesOverTcp) {
  const fs::path out = fresh_folder("ingest");
  const std::uint16_t ingest_port = process_port(120);
  const std::uint16_t http = process_port(121);
  const fs::path config = out / "robot.yaml";
  dataset::write_file_atomically(
      config, "robot_id: 0\nteam: ingest\nestimator: " +
                  (kSource / "configs/sensors/kitti-stereo.yaml").string() +
                  "\nsource:\n  kind: ingest\n  ingest_port: " + std::to_string(ingest_port) +
                  "\n  camera: " + (kSource / "data/kitti00-300/dataset.json").string() +
                  "\nconsensus: {mode: off}\nhttp: {port: " + std::to_string(http) +
                  "}\noutput: {directory: " + (out / "robot_00").string() + "}\n");
  ChildProcess daemon({kDaemon, "--config", config}, out / "robot.log");
  ASSERT_TRUE(eventually([&] { return get_json(http, "/healthz").has_value(); }, 20s));

  dataset::ReadOptions read;
  read.only_robot = 0;
  read.max_frames = 30;
  const dataset::Dataset data = dataset::read_dataset(kSource / "data/kitti00-300", read);
  std::string stream;
  for (int k = 0; k < 30; ++k) {
    v1::Envelope envelope;
    envelope.set_protocol_version(net::kProtocolVersion);
    envelope.set_team("ingest");
    daemon::to_wire(data.robots[0].frame_input(k), 0.1 * k, *envelope.mutable_sensor_frame());
    envelope.mutable_sensor_frame()->set_last(k == 29);
    stream += net::encode_frame(envelope);
  }
  // The daemon processes the 30 frames and, after the last, finishes and exits by itself.
  exchange_raw(ingest_port, stream, 2s);
  ASSERT_TRUE(daemon.wait_for(30s));
  EXPECT_EQ(daemon.exit_code(), 0);

  // The start pose of an ingest daemon is configured (identity here): compare relative motion.
  Estimator reference(config::load_estimator_options(kSource / "configs/sensors/kitti-stereo.yaml"),
                      data.camera, Eigen::Isometry3d::Identity(), 0);
  for (int k = 0; k < 30; ++k) {
    FrameInput input = data.robots[0].frame_input(k);
    reference.process(input);
  }
  const auto trajectory = dataset::read_trajectory_kitti(out / "robot_00" / "trajectory.kitti");
  ASSERT_EQ(trajectory.size(), 30u);
  EXPECT_TRUE(trajectory.back().isApprox(reference.current_pose(), 1e-6));
}

}  // namespace
}  // namespace concord

namespace concord {
namespace {

TEST(LaunchStatus, ReadsStatusBodiesAndRefusesGarbage) {
  const launch::RobotStatus robot =
      launch::parse_status(R"({"phase": "running", "frame": 12, "live_peers": [1, 2]})");
  EXPECT_TRUE(robot.reachable);
  EXPECT_EQ(robot.phase, "running");
  EXPECT_EQ(robot.frame, 12);
  EXPECT_EQ(robot.peers, 2);
  EXPECT_FALSE(launch::parse_status(std::nullopt).reachable);
  EXPECT_FALSE(launch::parse_status("{not json").reachable);
  const launch::RobotStatus starting =
      launch::parse_status(R"({"phase": "waiting", "frame": null})");
  EXPECT_TRUE(starting.reachable);
  EXPECT_FALSE(starting.frame);
}

TEST(LaunchStatus, SmallTeamsGetAFieldPerRobotLargeTeamsOneSummary) {
  std::vector<launch::RobotStatus> team(3);
  for (int robot = 0; robot < 3; ++robot) {
    team[robot].reachable = true;
    team[robot].phase = "running";
    team[robot].frame = 10 + robot;
    team[robot].peers = 2;
  }
  team[2].exited = true;
  team[2].exit_code = 1;
  EXPECT_EQ(launch::team_status_line(team, 4),
            "[4 s] r0:running f10 p2 r1:running f11 p2 r2:exit 1");
  // 50 robots: frames 0..46 with 0..46 % 5 peers, one silent, two exited (one failed).
  std::vector<launch::RobotStatus> large(50);
  for (int robot = 0; robot < 47; ++robot) {
    large[robot].reachable = true;
    large[robot].phase = "running";
    large[robot].frame = robot;
    large[robot].peers = robot % 5;
  }
  large[48].exited = true;
  large[49].exited = true;
  large[49].exit_code = 3;
  const std::string line = launch::team_status_line(large, 9);
  EXPECT_EQ(line,
            "[9 s] 50 robots: 47 running, 1 not answering, 2 exited (1 failed); frame "
            "min/median/max 0/23/46, peers 0/2/4");
}

}  // namespace
}  // namespace concord

// Latency, jitter, loss and dropping links between daemons (issue 14), from the fault-injecting
// relay of tests/fault_relay.h (netem is not available on these machines): the relay itself is
// checked first; then a lockstep team whose every link is delayed, jittered and lossy gives the
// same online estimates as the replay; then an async team whose links are cut again and again
// reconnects and keeps fusing. Every wait has a deadline.
#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <boost/asio/connect.hpp>
#include <boost/asio/read.hpp>
#include <nlohmann/json.hpp>
#include <random>
#include <thread>

#include "concord/config/options_file.h"
#include "concord/dataset/dataset.h"
#include "concord/dataset/result_io.h"
#include "fault_relay.h"
#include "launch/launch.h"
#include "process_support.h"
#include "replay/team_replay.h"

namespace concord {
namespace {

using testing::FaultProfile;
using testing::FaultRelay;
using testing::fresh_folder;
using testing::kSanitized;
using testing::read_json;

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;


/// Ports of this test process: a block of 20 per process (the tests use offsets up to 17), in
/// 1100-3899: below Linux's ephemeral range and clear of the other process tests' blocks
/// (4000-10999 supervision and package, 11000-31999 the other daemon tests).
std::uint16_t link_fault_port(int offset) {
  return static_cast<std::uint16_t>(1100 + (getpid() % 140) * 20 + offset);
}

/// A TCP server on 127.0.0.1 that echoes what it reads (on its own thread, until destroyed).
class EchoServer {
 public:
  EchoServer() {
    namespace ip = boost::asio::ip;
    acceptor_.open(ip::tcp::v4());
    acceptor_.bind({ip::make_address_v4("127.0.0.1"), 0});
    acceptor_.listen();
    accept();
    thread_ = std::thread([this] { io_.run(); });
  }
  ~EchoServer() {
    io_.stop();
    thread_.join();
  }
  std::uint16_t port() const { return acceptor_.local_endpoint().port(); }

 private:
  struct Session {
    explicit Session(boost::asio::io_context& io) : socket(io) {}
    boost::asio::ip::tcp::socket socket;
    std::array<char, 4096> buffer{};
  };
  void accept() {
    auto session = std::make_shared<Session>(io_);
    acceptor_.async_accept(session->socket, [this, session](const boost::system::error_code& e) {
      if (e) return;
      echo(session);
      accept();
    });
  }
  void echo(const std::shared_ptr<Session>& session) {
    session->socket.async_read_some(
        boost::asio::buffer(session->buffer),
        [this, session](const boost::system::error_code& e, std::size_t n) {
          if (e) return;
          boost::asio::async_write(session->socket, boost::asio::buffer(session->buffer, n),
                                   [this, session](const boost::system::error_code& we,
                                                   std::size_t) {
                                     if (!we) echo(session);
                                   });
        });
  }
  boost::asio::io_context io_;
  boost::asio::ip::tcp::acceptor acceptor_{io_};
  std::thread thread_;
};

TEST(FaultRelay, DelaysEveryChunkInOrderAndCutsWhenAsked) {
  EchoServer echo;
  FaultProfile profile;
  profile.latency = 40ms;
  profile.jitter = 20ms;
  profile.loss = 0.3;
  profile.retransmit_delay = 100ms;
  FaultRelay relay(echo.port(), profile);

  boost::asio::io_context io;
  boost::asio::ip::tcp::socket socket(io);
  socket.connect({boost::asio::ip::make_address_v4("127.0.0.1"), relay.port()});
  // 20 messages of varied sizes, sent one after the other: every byte comes back, in order, and
  // each round trip takes at least twice the smallest one-way delay (latency - jitter).
  std::mt19937 random(7);
  std::uniform_int_distribution<int> size(1, 3000), byte(0, 255);
  for (int message = 0; message < 20; ++message) {
    std::string sent(static_cast<std::size_t>(size(random)), '\0');
    for (char& c : sent) c = static_cast<char>(byte(random));
    const auto start = Clock::now();
    boost::asio::write(socket, boost::asio::buffer(sent));
    std::string received(sent.size(), '\0');
    boost::asio::read(socket, boost::asio::buffer(received));
    EXPECT_EQ(received, sent) << "message " << message;
    EXPECT_GE(Clock::now() - start, 2 * (profile.latency - profile.jitter)) << "message " << message;
  }
  EXPECT_EQ(relay.connections(), 1u);
  EXPECT_GE(relay.chunks(), 40u);
  EXPECT_GT(relay.losses(), 0u);  // 30 % of at least 40 chunks
  EXPECT_EQ(relay.cuts(), 0u);

  // A relay that cuts every chunk: the first message ends the connection.
  FaultProfile cutting;
  cutting.cut = 1.0;
  FaultRelay cutter(echo.port(), cutting);
  boost::asio::ip::tcp::socket cut_socket(io);
  cut_socket.connect({boost::asio::ip::make_address_v4("127.0.0.1"), cutter.port()});
  boost::asio::write(cut_socket, boost::asio::buffer(std::string("hello")));
  char one = 0;
  boost::system::error_code error;
  boost::asio::read(cut_socket, boost::asio::buffer(&one, 1), error);
  EXPECT_TRUE(error == boost::asio::error::eof || error == boost::asio::error::connection_reset)
      << error.message();
  EXPECT_EQ(cutter.cuts(), 1u);
}

/// A team of three on kitti00-300 whose every link (robot r dials each robot below it) goes
/// through its own relay with `profile`; relays[r][other] is the one robot r dials `other` by.
struct RelayedTeam {
  launch::LaunchOptions options;
  std::vector<std::vector<std::unique_ptr<FaultRelay>>> relays;
};

RelayedTeam relayed_team(const fs::path& out, int port_offset, const FaultProfile& profile) {
  RelayedTeam team;
  team.options =
      testing::kitti_team_options(out, link_fault_port(port_offset), link_fault_port(port_offset + 5));
  auto& options = team.options;
  team.relays.resize(3);
  for (int robot = 0; robot < 3; ++robot) {
    std::vector<std::string> arguments;
    for (int other = 0; other < robot; ++other) {
      FaultProfile link = profile;
      link.seed = static_cast<unsigned>(10 * robot + other + 1);
      team.relays[robot].push_back(std::make_unique<FaultRelay>(
          static_cast<std::uint16_t>(options.base_port + other), link));
      arguments.insert(arguments.end(),
                       {"--peer", "127.0.0.1:" + std::to_string(team.relays[robot].back()->port())});
    }
    options.extra_arguments[robot] = arguments;
  }
  return team;
}

TEST(DaemonLinkFaults, LockstepOverDelayedJitteredLossyLinksGivesTheReplaysEstimates) {
  const fs::path out = fresh_folder("link-faults-lockstep");
  FaultProfile profile;
  profile.latency = 20ms;
  profile.jitter = 15ms;
  profile.loss = 0.05;
  profile.retransmit_delay = 200ms;
  RelayedTeam team = relayed_team(out, 0, profile);
  // The rounds wait on the delayed links: 60 under the sanitizers, 100 in Release.
  const int frames = kSanitized ? 60 : 100;
  team.options.frames = frames;
  const launch::LaunchResult result = launch::launch_team(team.options, 3, nullptr);
  ASSERT_FALSE(result.timed_out);
  for (int code : result.exit_codes) ASSERT_EQ(code, 0);

  // The online estimate of every frame (never revised later) is the replay's, bit for bit up to
  // the text format's precision: delays reorder nothing in lockstep.
  const dataset::Dataset data = dataset::read_dataset(team.options.dataset);
  const auto reference = replay::run_team(
      dataset::slice(data, frames, 3),
      config::load_estimator_options(team.options.estimator_config), replay::ReplayOptions{});
  int marginals_fused = 0;
  long long landmarks_fused = 0, landmarks_settled = 0;
  for (int robot = 0; robot < 3; ++robot) {
    const fs::path folder = out / dataset::robot_folder_name(robot);
    const auto trajectory = dataset::read_trajectory_kitti(folder / "trajectory.kitti");
    ASSERT_EQ(trajectory.size(), static_cast<std::size_t>(frames));
    const auto& expected = reference.robots[robot].trajectory;
    for (std::size_t k = 0; k < trajectory.size(); ++k) {
      const double difference = (trajectory[k].matrix() - expected[k].matrix()).cwiseAbs().maxCoeff();
      ASSERT_LE(difference, 1e-6) << "robot " << robot << " frame " << k;
    }
    const auto stats = read_json(folder / "stats.json");
    EXPECT_EQ(stats["rounds"], frames);
    marginals_fused += stats["marginals_fused"].get<int>();
    landmarks_fused += stats["landmarks_fused"].get<long long>();
    landmarks_settled += stats["landmarks_settled"].get<long long>();
  }
  EXPECT_GT(marginals_fused, frames / 2);
  // The same averages as the replay's, landmark for landmark.
  EXPECT_EQ(landmarks_fused, reference.statistics.landmarks_fused);
  EXPECT_EQ(landmarks_settled, reference.statistics.landmarks_settled);
  std::uint64_t chunks = 0, losses = 0;
  for (const auto& dialled : team.relays)
    for (const auto& relay : dialled) {
      chunks += relay->chunks();
      losses += relay->losses();
    }
  EXPECT_GT(chunks, 300u) << "the links did not go through the relays";
  EXPECT_GT(losses, 0u);
}

TEST(DaemonLinkFaults, AsyncTeamOnLinksThatKeepDroppingReconnectsAndKeepsFusing) {
  const fs::path out = fresh_folder("link-faults-cuts");
  FaultProfile profile;
  profile.latency = 10ms;
  profile.jitter = 5ms;
  profile.cut = 0.01;  // about one chunk in a hundred ends its connection
  RelayedTeam team = relayed_team(out, 10, profile);
  team.options.mode = "async";
  team.options.rate_hz = 20.0;
  team.options.frames = 200;
  const launch::LaunchResult result = launch::launch_team(team.options, 3, nullptr);
  ASSERT_FALSE(result.timed_out);
  for (int code : result.exit_codes) EXPECT_EQ(code, 0);
  std::uint64_t cuts = 0, connections = 0;
  for (const auto& dialled : team.relays)
    for (const auto& relay : dialled) {
      cuts += relay->cuts();
      connections += relay->connections();
    }
  EXPECT_GT(cuts, 2u);
  EXPECT_GE(connections, 3u) << "the links did not go through the relays";
  // After a cut either side may restore the link: the dialler through its relay, or the acceptor
  // straight to the address the dialler announced. Both count as a reconnection of that peer.
  std::uint64_t reconnects = 0;
  for (int robot = 0; robot < 3; ++robot) {
    const auto stats = read_json(out / dataset::robot_folder_name(robot) / "stats.json");
    EXPECT_EQ(stats["frames"], 200) << "robot " << robot;
    reconnects += stats["network"]["reconnects"].get<std::uint64_t>();
  }
  EXPECT_GT(reconnects, 0u) << "no link came up again after a cut";
  // Robots 0 and 1 share cars: they fused each other's marginals between the cuts.
  EXPECT_GT(read_json(out / dataset::robot_folder_name(1) / "stats.json")["marginals_fused"].get<int>(),
            0);
}

}  // namespace
}  // namespace concord

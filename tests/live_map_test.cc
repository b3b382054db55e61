// The live map page at / of a running 3-robot team, drawn by headless Chromium (Debian's
// `chromium`, installed by scripts/install-deps.sh): robot 0's page follows /peers to its
// neighbours' HTTP endpoints (announced in the handshake) and the screenshot shows the three
// robots' paths, each in its colour. Every wait has a deadline.
#include <gtest/gtest.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>

#include "concord/dataset/result_io.h"
#include "launch/launch.h"
#include "launch/process.h"
#include "process_support.h"
#include "test_paths.h"

namespace concord {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using launch::ChildProcess;
using nlohmann::json;
using testing::eventually;
using testing::get_json;

/// Ports 32100-32767: used by no other test (they stay below 32000) and below Linux's ephemeral
/// range, so that no outgoing connection holds them.
std::uint16_t live_map_port(int offset) {
  return static_cast<std::uint16_t>(32100 + (getpid() % 33) * 20 + offset);
}

/// Pixels of `image` (BGR) within `tolerance` of `rgb` in every channel: their count and the
/// larger side of their bounding box.
struct ColourPixels {
  int count = 0;
  int extent = 0;
};
ColourPixels pixels_of(const cv::Mat& image, std::array<int, 3> rgb, int tolerance) {
  int x0 = image.cols, x1 = -1, y0 = image.rows, y1 = -1, count = 0;
  for (int y = 0; y < image.rows; ++y) {
    for (int x = 0; x < image.cols; ++x) {
      const cv::Vec3b& bgr = image.at<cv::Vec3b>(y, x);
      if (std::abs(bgr[2] - rgb[0]) > tolerance || std::abs(bgr[1] - rgb[1]) > tolerance ||
          std::abs(bgr[0] - rgb[2]) > tolerance)
        continue;
      ++count;
      x0 = std::min(x0, x);
      x1 = std::max(x1, x);
      y0 = std::min(y0, y);
      y1 = std::max(y1, y);
    }
  }
  return {count, count ? std::max(x1 - x0, y1 - y0) + 1 : 0};
}

TEST(LiveMap, HeadlessChromiumDrawsEveryRobotsPathFromOneRobotsPage) {
  const auto chromium = testing::find_program("chromium");
  if (!chromium) GTEST_SKIP() << "chromium is not installed (scripts/install-deps.sh)";

  const fs::path out = testing::fresh_folder("live-map");
  auto options = testing::kitti_team_options(out, live_map_port(0), live_map_port(10));
  // Half the camera rate: 60 s of data, the page taken after about 20. The team must outlive
  // the wait for frame 100 and the screenshot; at the camera rate (30 s of data) a CI run on a
  // loaded machine saw the wait end at 29 s and the daemons gone before Chromium loaded the page.
  options.rate_hz = 5.0;
  fs::create_directories(out / "configs");
  launch::ensure_team_key(options);
  std::vector<ChildProcess> daemons;
  for (int robot = 0; robot < 3; ++robot) {
    const fs::path config = out / "configs" / ("robot_0" + std::to_string(robot) + ".yaml");
    dataset::write_file_atomically(config, launch::daemon_config_yaml(options, robot, 3));
    daemons.emplace_back(std::vector<std::string>{testing::kDaemon, "--config", config},
                         out / ("robot_0" + std::to_string(robot) + ".log"));
  }
  const auto http = [&](int robot) {
    return static_cast<std::uint16_t>(options.http_base_port + robot);
  };

  // Every robot has a path of 100 frames, and robot 0 knows both neighbours' HTTP endpoints.
  ASSERT_TRUE(eventually(
      [&] {
        for (int robot = 0; robot < 3; ++robot) {
          const auto status = get_json(http(robot), "/status");
          if (!status || status->value("frames_processed", 0) < 100) return false;
        }
        const auto peers = get_json(http(0), "/peers");
        if (!peers) return false;
        int announced = 0;
        for (const json& peer : (*peers)["peers"]) {
          const int robot = peer["robot"].get<int>();
          announced += peer["http"] == "127.0.0.1:" + std::to_string(http(robot));
        }
        return announced == 2;
      },
      60s))
      << "the team did not reach frame 100 with robot 0 knowing its neighbours' endpoints";

  // The page itself: built into the daemon, self-contained.
  const auto page = launch::http_get("127.0.0.1", http(0), "/", 1s);
  ASSERT_TRUE(page);
  EXPECT_NE(page->find("<canvas"), std::string::npos);
  EXPECT_EQ(page->find("src=\"http"), std::string::npos) << "the page loads nothing from outside";

  // The page reads a trajectory once, then only the frames after the last it has.
  const auto all = get_json(http(1), "/trajectory");
  ASSERT_TRUE(all);
  ASSERT_GE((*all)["poses"].size(), 100u);
  const int cut = (*all)["poses"][50]["frame"].get<int>();
  const auto later = get_json(http(1), "/trajectory?since=" + std::to_string(cut));
  ASSERT_TRUE(later);
  ASSERT_GE((*later)["poses"].size(), (*all)["poses"].size() - 51);
  EXPECT_EQ((*later)["poses"][0]["frame"].get<int>(), cut + 1);
  for (const json& pose : (*later)["poses"]) EXPECT_GT(pose["frame"].get<int>(), cut);
  for (const char* bad : {"/trajectory?since=x", "/trajectory?since=-2", "/trajectory?since=3x",
                          "/trajectory?format=kitti&since=3"}) {
    EXPECT_FALSE(launch::http_get("127.0.0.1", http(1), bad, 1s)) << bad;
  }

  const fs::path shot = out / "live-map.png";
  ChildProcess browser(
      {chromium->string(), "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
       "--hide-scrollbars", "--no-first-run", "--user-data-dir=" + (out / "chromium").string(),
       "--window-size=1000,700", "--virtual-time-budget=5000", "--screenshot=" + shot.string(),
       "http://127.0.0.1:" + std::to_string(http(0)) + "/"},
      out / "chromium.log");
  ASSERT_TRUE(browser.wait_for(90s)) << "chromium did not finish (log: " << out / "chromium.log"
                                     << ")";
  EXPECT_EQ(browser.exit_code(), 0);
  // Robot 0's neighbours were still running when the page asked them.
  for (int robot = 0; robot < 3; ++robot) EXPECT_FALSE(daemons[robot].exited()) << robot;

  const cv::Mat image = cv::imread(shot.string(), cv::IMREAD_COLOR);
  ASSERT_FALSE(image.empty()) << "no screenshot at " << shot;
  ASSERT_GT(image.cols, 300);
  // The map is the canvas left of the 300-pixel side panel (whose colour swatches are left out).
  const cv::Mat map = image(cv::Rect(0, 0, image.cols - 300, image.rows));
  // The page's colours of robots 0, 1 and 2; a path is 2.5 pixels wide, drawn opaque.
  const std::array<std::array<int, 3>, 3> colours{{{214, 39, 40}, {44, 160, 44}, {31, 119, 180}}};
  for (int robot = 0; robot < 3; ++robot) {
    const ColourPixels pixels = pixels_of(map, colours[robot], 12);
    EXPECT_GE(pixels.count, 150) << "robot " << robot << "'s path is missing from the map";
    EXPECT_GE(pixels.extent, 40) << "robot " << robot << "'s path is not drawn as a path";
  }

  for (auto& daemon : daemons) daemon.signal(SIGTERM);
  for (int robot = 0; robot < 3; ++robot) {
    ASSERT_TRUE(daemons[robot].wait_for(30s));
    EXPECT_EQ(daemons[robot].exit_code(), 0);
  }
}

}  // namespace
}  // namespace concord

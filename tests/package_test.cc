// The Debian package (issue 14): built with CPack from this build, its contents checked with
// `dpkg-deb -c`, its maintainer scripts present and valid shell, then unpacked into a scratch
// root (`dpkg -x`) where the installed concordd validates and runs its installed example config
// (paths relocated into the scratch root) up to READY=1 on a fake NOTIFY_SOCKET, answers HTTP and
// stops on SIGTERM. Skipped where cpack or dpkg-deb are missing, and in sanitizer builds (the
// package is the Release build's).
#include <gtest/gtest.h>
#include <signal.h>

#include <fstream>
#include <regex>
#include <sstream>

#include "concord/dataset/result_io.h"
#include "launch/launch.h"
#include "launch/process.h"
#include "process_support.h"
#include "service_manager_fake.h"

namespace concord {
namespace {

using testing::find_program;
using testing::read_text;

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using launch::ChildProcess;
using testing::FakeServiceManager;
using testing::ScopedEnvironment;

using testing::kSanitized;

/// Runs a command to completion (2 min at most); its exit code and output.
std::pair<int, std::string> run(const std::vector<std::string>& argv, const fs::path& log) {
  fs::remove(log);
  ChildProcess child(argv, log);
  if (!child.wait_for(120s)) return {-1, "timed out: " + argv.front()};
  return {child.exit_code().value_or(-1), read_text(log)};
}

void replace_all(std::string& text, const std::string& from, const std::string& to) {
  for (std::size_t at = text.find(from); at != std::string::npos;
       at = text.find(from, at + to.size()))
    text.replace(at, from.size(), to);
}

TEST(Package, DebHoldsTheDaemonAndItsInstalledConfigStartsToReadiness) {
  if (kSanitized) GTEST_SKIP() << "the package is built and tested in the Release build";
  const fs::path cpack = CONCORD_CPACK_PATH;
  const auto dpkg_deb = find_program("dpkg-deb");
  if (!fs::exists(cpack) || !dpkg_deb)
    GTEST_SKIP() << "cpack or dpkg-deb not installed: the .deb is not built";
  const fs::path out =
      fs::path(CONCORD_BINARY_DIR) / "test-out" / ("package-" + std::to_string(getpid()));
  fs::remove_all(out);
  fs::create_directories(out);

  // 1. Build the package from this build tree.
  auto [code, text] = run(
      {cpack.string(), "--config", (fs::path(CONCORD_BINARY_DIR) / "CPackConfig.cmake").string(),
       "-G", "DEB", "-B", (out / "package").string()},
      out / "cpack.log");
  ASSERT_EQ(code, 0) << text;
  std::optional<fs::path> deb;
  for (const auto& entry : fs::directory_iterator(out / "package"))
    if (entry.path().extension() == ".deb") deb = entry.path();
  ASSERT_TRUE(deb) << text;

  // 2. Contents.
  std::tie(code, text) = run({dpkg_deb->string(), "-c", deb->string()}, out / "contents.log");
  ASSERT_EQ(code, 0) << text;
  for (const char* path :
       {"./usr/bin/concordd", "./usr/bin/concord", "./usr/lib/systemd/system/concordd@.service",
        "./usr/share/concord/examples/robot.yaml", "./usr/share/concord/examples/camera-kitti.json",
        "./usr/share/concord/sensors/kitti-stereo.yaml", "./usr/share/doc/concord/daemon.md",
        "./usr/share/doc/concord/field.md", "./etc/concord/", "./var/lib/concord/"})
    EXPECT_NE(text.find(std::string(path) + "\n"), std::string::npos) << "missing " << path;
  // The maintainer scripts: present, valid shell, creating the system user.
  std::tie(code, text) = run({dpkg_deb->string(), "-e", deb->string(), (out / "control").string()},
                             out / "control.log");
  ASSERT_EQ(code, 0) << text;
  for (const char* script : {"postinst", "prerm", "postrm"}) {
    ASSERT_TRUE(fs::exists(out / "control" / script)) << script;
    std::tie(code, text) =
        run({"/bin/sh", "-n", (out / "control" / script).string()}, out / "sh.log");
    EXPECT_EQ(code, 0) << script << ": " << text;
  }
  EXPECT_NE(read_text(out / "control" / "postinst").find("--system"), std::string::npos);
  EXPECT_NE(read_text(out / "control" / "control").find("libsystemd0"), std::string::npos)
      << "dependencies from dpkg-shlibdeps";

  // 3. Unpack into a scratch root.
  const fs::path root = out / "root";
  std::tie(code, text) =
      run({dpkg_deb->string(), "-x", deb->string(), root.string()}, out / "x.log");
  ASSERT_EQ(code, 0) << text;
  const fs::path concordd = root / "usr/bin/concordd";
  ASSERT_TRUE(fs::exists(concordd));

  // 4. The installed example config, relocated into the scratch root (paths and ports only).
  std::string config = read_text(root / "usr/share/concord/examples/robot.yaml");
  ASSERT_FALSE(config.empty());
  replace_all(config, "/etc/concord", (root / "etc/concord").string());
  replace_all(config, "/usr/share/concord", (root / "usr/share/concord").string());
  replace_all(config, "/var/lib/concord", (root / "var/lib/concord").string());
  replace_all(config, "ingest_port: 7600", "ingest_port: 0");
  // Below the ephemeral range and the other process tests' ports.
  const auto discovery_port = std::to_string(4000 + getpid() % 1000);
  replace_all(config, "discovery_port: 47600", "discovery_port: " + discovery_port);
  const fs::path installed_config = root / "etc/concord/robot_00.yaml";
  dataset::write_file_atomically(installed_config, config);
  std::tie(code, text) = run({(root / "usr/bin/concord").string(), "keygen", "--out",
                              (root / "etc/concord/team.key").string()},
                             out / "keygen.log");
  ASSERT_EQ(code, 0) << text;
  // Per-robot identities as docs/field.md sets them up: an identity key per robot (robots 1 and
  // 2's made here too, for their public keys), the printed public keys under member_keys.
  std::vector<std::string> public_keys;
  for (int robot = 0; robot < 3; ++robot) {
    const fs::path key = robot == 0 ? root / "etc/concord/robot.identity"
                                    : out / ("robot_" + std::to_string(robot) + ".identity");
    std::tie(code, text) =
        run({(root / "usr/bin/concord").string(), "keygen", "--identity", "--out", key.string()},
            out / "keygen-identity.log");
    ASSERT_EQ(code, 0) << text;
    std::smatch printed;
    ASSERT_TRUE(std::regex_search(text, printed, std::regex("public key: ([0-9a-f]{64})"))) << text;
    public_keys.push_back(printed[1]);
  }
  const std::string identities =
      "identity_key_file: " + (root / "etc/concord/robot.identity").string() +
      "\nmember_keys: {0: " + public_keys[0] + ", 1: " + public_keys[1] + ", 2: " + public_keys[2] +
      "}\n";
  // Robot 1's public key listed for robot 0: refused before anything starts.
  const fs::path wrong_config = out / "wrong-identity.yaml";
  dataset::write_file_atomically(
      wrong_config, config +
                        "identity_key_file: " + (root / "etc/concord/robot.identity").string() +
                        "\nmember_keys: {0: " + public_keys[1] + ", 1: " + public_keys[1] +
                        ", 2: " + public_keys[2] + "}\n");
  std::tie(code, text) =
      run({concordd.string(), "--check-config", wrong_config.string()}, out / "check-wrong.log");
  EXPECT_EQ(code, 2) << text;
  EXPECT_NE(text.find("not this robot's identity key"), std::string::npos) << text;
  config += identities;
  dataset::write_file_atomically(installed_config, config);
  std::tie(code, text) =
      run({concordd.string(), "--check-config", installed_config.string()}, out / "check.log");
  EXPECT_EQ(code, 0) << text;
  EXPECT_NE(text.find("OK:"), std::string::npos) << text;

  // 5. The installed daemon starts from it and reports readiness.
  FakeServiceManager manager;
  std::optional<ChildProcess> daemon;
  {
    ScopedEnvironment environment({{"NOTIFY_SOCKET", manager.notify_socket()}});
    daemon.emplace(
        std::vector<std::string>{concordd.string(), "--config", installed_config.string(),
                                 "--listen-port", "0", "--http-port", "0"},
        out / "daemon.log");
  }
  const auto ready = manager.wait_for([](const auto& m) { return m.has_line("READY=1"); }, 30s);
  ASSERT_TRUE(ready) << read_text(out / "daemon.log");
  std::smatch match;
  ASSERT_TRUE(std::regex_search(ready->text, match, std::regex("http on port ([0-9]+)")))
      << ready->text;
  const auto http = static_cast<std::uint16_t>(std::stoi(match[1]));
  const auto status = launch::http_get("127.0.0.1", http, "/status", 2000ms);
  ASSERT_TRUE(status) << read_text(out / "daemon.log");
  EXPECT_NE(status->find("\"team\":\"field\""), std::string::npos) << *status;
  EXPECT_NE(read_text(out / "daemon.log").find("3 member keys"), std::string::npos)
      << read_text(out / "daemon.log");
  daemon->signal(SIGTERM);
  ASSERT_TRUE(daemon->wait_for(10s));
  EXPECT_EQ(daemon->exit_code(), 0) << read_text(out / "daemon.log");
  EXPECT_TRUE(fs::exists(root / "var/lib/concord/robot_00/stats.json"));
  fs::remove_all(out);  // the package and the scratch root: a few MB
}

}  // namespace
}  // namespace concord

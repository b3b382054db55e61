#pragma once
/// A team across hosts on one machine (docs/field.md): each robot in its own network namespace,
/// a veth pair from it to a bridge in the root namespace, addresses 10.213.S.(robot + 1)/24 with
/// S from the test's pid (the bridge has .254, so the test reaches each robot's HTTP port), a
/// multicast route for beacon discovery, `tc` token-bucket rate limits on a robot's egress, and
/// link down/up for partitions. Needs root and iproute2 (`ip`, `tc`); unavailable() says why not.
///
/// Cleanup is RAII and also covers a crashed earlier run: the destructor kills every process left
/// in the namespaces and deletes them and the bridge; the constructor first removes namespaces
/// and bridges of test processes that no longer exist. Names: cc<pid>n<robot>, ccbr<pid>.

#include <signal.h>
#include <sys/types.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <regex>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

#include "launch/process.h"

namespace concord::testing {

class NetnsLab {
 public:
  /// "" if namespaces can be tried here; else why not (for GTEST_SKIP).
  static std::string unavailable() {
    if (geteuid() != 0)
      return "network namespaces need root (this test runs as uid " + std::to_string(geteuid()) +
             ")";
    if (ip_path().empty()) return "iproute2 (`ip`) is not installed";
    if (tc_path().empty()) return "iproute2's `tc` is not installed";
    return {};
  }

  /// Creates `robots` namespaces on one bridge. Throws std::runtime_error (after removing what it
  /// made) when the kernel or the container refuses (e.g. no CAP_NET_ADMIN).
  NetnsLab(int robots, std::filesystem::path scratch)
      : robots_(robots), scratch_(std::move(scratch)), pid_(getpid()) {
    std::filesystem::create_directories(scratch_);
    remove_stale();
    subnet_ = "10.213." + std::to_string(pid_ % 250) + ".";
    try {
      run({ip_path(), "link", "add", bridge(), "type", "bridge"});
      run({ip_path(), "link", "set", bridge(), "type", "bridge", "mcast_snooping", "0"});
      run({ip_path(), "addr", "add", subnet_ + "254/24", "dev", bridge()});
      run({ip_path(), "link", "set", bridge(), "up"});
      for (int robot = 0; robot < robots_; ++robot) {
        const std::string ns = namespace_name(robot);
        run({ip_path(), "netns", "add", ns});
        created_.push_back(ns);
        run({ip_path(), "link", "add", host_link(robot), "type", "veth", "peer", "name", "eth0",
             "netns", ns});
        run({ip_path(), "link", "set", host_link(robot), "master", bridge(), "up"});
        run({ip_path(), "-n", ns, "addr", "add", address(robot) + "/24", "dev", "eth0"});
        run({ip_path(), "-n", ns, "link", "set", "eth0", "up"});
        run({ip_path(), "-n", ns, "link", "set", "lo", "up"});
        run({ip_path(), "-n", ns, "route", "add", "224.0.0.0/4", "dev", "eth0"});
      }
    } catch (...) {
      cleanup();
      throw;
    }
  }
  ~NetnsLab() { cleanup(); }
  NetnsLab(const NetnsLab&) = delete;
  NetnsLab& operator=(const NetnsLab&) = delete;

  int robots() const { return robots_; }
  std::string address(int robot) const { return subnet_ + std::to_string(robot + 1); }
  std::string namespace_name(int robot) const {
    return "cc" + std::to_string(pid_) + "n" + std::to_string(robot);
  }

  /// Starts argv in a robot's namespace (ip netns exec: the same pid runs the program).
  launch::ChildProcess spawn(int robot, const std::vector<std::string>& argv,
                             const std::filesystem::path& log) const {
    std::vector<std::string> command{ip_path(), "netns", "exec", namespace_name(robot)};
    command.insert(command.end(), argv.begin(), argv.end());
    return launch::ChildProcess(command, log);
  }

  /// A partition: the robot's link to the bridge goes down (both ends lose carrier), or up again.
  void set_link(int robot, bool up) {
    run({ip_path(), "link", "set", host_link(robot), up ? "up" : "down"});
  }

  /// A token-bucket limit on what a robot sends (tc tbf on its eth0; `rate` as tc writes it,
  /// e.g. "1mbit"); a queue of at most `latency` before tbf drops.
  void rate_limit(int robot, const std::string& rate, const std::string& latency = "400ms") {
    run({ip_path(), "netns", "exec", namespace_name(robot), tc_path(), "qdisc", "replace", "dev",
         "eth0", "root", "tbf", "rate", rate, "burst", "32kb", "latency", latency});
  }

  /// Runs a command to completion (10 s at most); throws with its output on failure.
  std::string run(const std::vector<std::string>& argv) const {
    const std::filesystem::path log = scratch_ / "netns-command.log";
    std::filesystem::remove(log);
    launch::ChildProcess child(argv, log);
    const bool done = child.wait_for(std::chrono::seconds(10));
    std::ifstream stream(log);
    std::ostringstream output;
    output << stream.rdbuf();
    if (!done || child.exit_code() != 0) {
      std::string command;
      for (const auto& part : argv) command += part + " ";
      throw std::runtime_error("`" + command + "` failed: " + output.str());
    }
    return output.str();
  }

 private:
  static std::string find(const std::vector<std::string>& candidates) {
    for (const auto& candidate : candidates)
      if (std::filesystem::exists(candidate)) return candidate;
    return {};
  }
  static std::string ip_path() {
    return find({"/usr/sbin/ip", "/sbin/ip", "/usr/bin/ip", "/bin/ip"});
  }
  static std::string tc_path() { return find({"/usr/sbin/tc", "/sbin/tc", "/usr/bin/tc"}); }
  std::string bridge() const { return "ccbr" + std::to_string(pid_); }
  std::string host_link(int robot) const {
    return "cc" + std::to_string(pid_) + "h" + std::to_string(robot);
  }

  /// Kills what runs in a namespace and deletes it (errors ignored: best effort).
  void remove_namespace(const std::string& ns) const {
    try {
      std::istringstream pids(run({ip_path(), "netns", "pids", ns}));
      for (pid_t pid = 0; pids >> pid;) kill(pid, SIGKILL);
    } catch (const std::exception&) {
    }
    try {
      run({ip_path(), "netns", "del", ns});
    } catch (const std::exception&) {
    }
  }

  void cleanup() {
    for (const std::string& ns : created_) remove_namespace(ns);  // also removes the veth pairs
    created_.clear();
    try {
      run({ip_path(), "link", "del", bridge()});
    } catch (const std::exception&) {
    }
  }

  /// Namespaces and bridges of earlier test processes that died without cleaning up.
  void remove_stale() const {
    const std::regex netns_name("^cc([0-9]+)n[0-9]+");
    const std::regex bridge_name("ccbr([0-9]+)");
    auto dead = [](const std::string& pid) {
      return kill(static_cast<pid_t>(std::stol(pid)), 0) != 0 && errno == ESRCH;
    };
    try {
      std::istringstream lines(run({ip_path(), "netns", "list"}));
      for (std::string line; std::getline(lines, line);) {
        std::smatch match;
        if (std::regex_search(line, match, netns_name) && dead(match[1]))
          remove_namespace(match[0]);
      }
      std::istringstream links(run({ip_path(), "-o", "link", "show", "type", "bridge"}));
      for (std::string line; std::getline(links, line);) {
        std::smatch match;
        if (std::regex_search(line, match, bridge_name) && dead(match[1])) {
          try {
            run({ip_path(), "link", "del", match[0]});
          } catch (const std::exception&) {
          }
        }
      }
    } catch (const std::exception&) {
    }
  }

  int robots_;
  std::filesystem::path scratch_;
  pid_t pid_;
  std::string subnet_;
  std::vector<std::string> created_;
};

}  // namespace concord::testing

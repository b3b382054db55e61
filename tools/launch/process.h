#pragma once
/// \file
/// Child processes for `concord launch` and the multi-process tests: spawn with stdout and stderr
/// to a log file, poll, signal, and wait with a deadline.

#include <sys/types.h>

#include <chrono>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace concord::launch {

class ChildProcess {
 public:
  ChildProcess() = default;
  /// Starts argv[0] (a path) with the arguments; stdout and stderr append to `log` (if not
  /// empty). Throws std::runtime_error if the program cannot be started.
  ChildProcess(const std::vector<std::string>& argv, const std::filesystem::path& log);
  ChildProcess(ChildProcess&& other) noexcept;
  ChildProcess& operator=(ChildProcess&& other) noexcept;
  /// Kills (SIGKILL) and reaps a child still running: no orphans, even on exceptions.
  ~ChildProcess();

  pid_t pid() const { return pid_; }
  /// Whether it has exited (reaps it if so).
  bool exited();
  /// Exit code (128 + signal if killed by a signal), once exited.
  std::optional<int> exit_code() const { return exit_code_; }
  /// Waits until it exits or the timeout passes; returns whether it exited.
  bool wait_for(std::chrono::milliseconds timeout);
  /// Sends a signal if it is still running.
  void signal(int signal_number);

 private:
  void reap(int status);

  pid_t pid_ = -1;
  std::optional<int> exit_code_;
};

/// GET http://host:port/target with a deadline; the body on a 2xx answer, std::nullopt on any
/// failure (connection refused, timeout, other status).
std::optional<std::string> http_get(const std::string& host, std::uint16_t port,
                                    const std::string& target,
                                    std::chrono::milliseconds timeout);

}  // namespace concord::launch

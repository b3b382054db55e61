#pragma once
/// A fake systemd for the supervision tests: the unix datagram socket of the notify protocol
/// (NOTIFY_SOCKET, in the abstract namespace: no file to clean up), the messages received with
/// their arrival times, and a scoped environment for the child daemons (WATCHDOG_USEC).

#include <poll.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <sys/un.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <chrono>
#include <cstddef>
#include <cstring>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace concord::testing {

class FakeServiceManager {
 public:
  using Clock = std::chrono::steady_clock;
  struct Message {
    Clock::time_point at;
    std::string text;  ///< "KEY=VALUE" lines
    bool has_line(const std::string& line) const {
      std::size_t start = 0;
      while (start <= text.size()) {
        const std::size_t end = std::min(text.find('\n', start), text.size());
        if (text.compare(start, end - start, line) == 0) return true;
        start = end + 1;
      }
      return false;
    }
    bool contains(const std::string& part) const { return text.find(part) != std::string::npos; }
  };

  FakeServiceManager() {
    static std::atomic<int> counter{0};
    name_ = "concord-test-notify-" + std::to_string(getpid()) + "-" + std::to_string(counter++);
    socket_ = socket(AF_UNIX, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    if (socket_ < 0) throw std::runtime_error("socket(AF_UNIX) failed");
    sockaddr_un address{};
    address.sun_family = AF_UNIX;
    std::memcpy(address.sun_path + 1, name_.data(), name_.size());  // abstract: leading NUL
    const auto length = static_cast<socklen_t>(offsetof(sockaddr_un, sun_path) + 1 + name_.size());
    if (bind(socket_, reinterpret_cast<const sockaddr*>(&address), length) != 0)
      throw std::runtime_error("bind of the notify socket failed");
  }
  ~FakeServiceManager() { close(socket_); }
  FakeServiceManager(const FakeServiceManager&) = delete;
  FakeServiceManager& operator=(const FakeServiceManager&) = delete;

  /// The value of NOTIFY_SOCKET for a child.
  std::string notify_socket() const { return "@" + name_; }

  /// The next message, waiting at most `timeout`; kept in history().
  std::optional<Message> receive(std::chrono::milliseconds timeout) {
    pollfd ready{socket_, POLLIN, 0};
    if (poll(&ready, 1, static_cast<int>(timeout.count())) <= 0) return std::nullopt;
    std::array<char, 4096> buffer{};
    const ssize_t bytes = recv(socket_, buffer.data(), buffer.size(), 0);
    if (bytes < 0) return std::nullopt;
    history_.push_back({Clock::now(), std::string(buffer.data(), static_cast<std::size_t>(bytes))});
    return history_.back();
  }

  /// Reads messages until one satisfies `matches` or `timeout` passes.
  template <typename Predicate>
  std::optional<Message> wait_for(Predicate matches, std::chrono::milliseconds timeout) {
    const auto deadline = Clock::now() + timeout;
    while (Clock::now() < deadline) {
      const auto left =
          std::chrono::duration_cast<std::chrono::milliseconds>(deadline - Clock::now());
      const auto message = receive(std::max(left, std::chrono::milliseconds(1)));
      if (message && matches(*message)) return message;
    }
    return std::nullopt;
  }

  const std::vector<Message>& history() const { return history_; }

 private:
  std::string name_;
  int socket_ = -1;
  std::vector<Message> history_;
};

/// Sets environment variables for the children started in its scope (posix_spawn passes
/// environ), and unsets them after.
class ScopedEnvironment {
 public:
  explicit ScopedEnvironment(std::vector<std::pair<std::string, std::string>> variables)
      : variables_(std::move(variables)) {
    for (const auto& variable : variables_)
      setenv(variable.first.c_str(), variable.second.c_str(), 1);
  }
  ~ScopedEnvironment() {
    for (const auto& variable : variables_) unsetenv(variable.first.c_str());
  }
  ScopedEnvironment(const ScopedEnvironment&) = delete;
  ScopedEnvironment& operator=(const ScopedEnvironment&) = delete;

 private:
  std::vector<std::pair<std::string, std::string>> variables_;
};

}  // namespace concord::testing

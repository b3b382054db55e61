#pragma once
/// \file
/// Supervision by the service manager (systemd's notify protocol, through libsystemd's
/// sd_notify): readiness once the daemon listens, a status line, stopping, and the watchdog.
///
/// The watchdog is fed by the estimator thread's check-ins, not by a timer alone: the estimator
/// thread calls check_in(budget) before each step, promising to check in again within the
/// watchdog interval plus that step's own bound (a consensus round's deadlines, the wait for
/// peers). A timer on the network thread sends WATCHDOG=1 every half interval while the promise
/// holds. A hung estimator thread (a deadlock, an endless loop, the `estimator.hang` failpoint)
/// breaks its promise: the pings stop, the daemon says so in its status and its log, and systemd
/// (WatchdogSec) kills and restarts it. A stall that ends resumes the pings.
///
/// Without NOTIFY_SOCKET (not started by systemd) every message is a no-op; without WATCHDOG_USEC
/// (no WatchdogSec) there is no timer.

#include <atomic>
#include <boost/asio/io_context.hpp>
#include <boost/asio/steady_timer.hpp>
#include <chrono>
#include <cstdint>
#include <string>

namespace concord::daemon {

class ServiceNotifier {
 public:
  using Clock = std::chrono::steady_clock;

  /// Reads the watchdog interval from the environment (sd_watchdog_enabled); the timer runs on
  /// `io` once start_watchdog() is called.
  explicit ServiceNotifier(boost::asio::io_context& io);

  /// READY=1 with a status line (the daemon listens: peers, ingest and HTTP are bound).
  void ready(const std::string& status);
  /// STATUS=... (shown by systemctl status).
  void status(const std::string& status);
  /// RELOADING=1 ... READY=1 around a SIGHUP reload.
  void reloading();
  void reloaded(const std::string& status);
  /// STOPPING=1: the daemon is finishing (writing its outputs).
  void stopping();

  /// Estimator thread: "I will check in again within the watchdog interval plus `budget`".
  void check_in(Clock::duration budget = Clock::duration::zero());

  /// Starts the ping timer on the io_context (no-op without a watchdog). Call once.
  void start_watchdog();
  /// Cancels the ping timer. Any thread.
  void stop_watchdog();

  bool watchdog_enabled() const { return watchdog_interval_ > Clock::duration::zero(); }
  Clock::duration watchdog_interval() const { return watchdog_interval_; }
  /// WATCHDOG=1 messages sent, and times the estimator thread broke its promise.
  std::uint64_t pings_sent() const { return pings_sent_.load(); }
  std::uint64_t stalls() const { return stalls_.load(); }
  /// Whether the estimator thread is past its promise now.
  bool stalled() const { return stalled_.load(); }

 private:
  void arm();
  void tick();
  static void notify(const std::string& message);

  boost::asio::io_context& io_;
  boost::asio::steady_timer timer_;
  Clock::duration watchdog_interval_{};
  /// Clock ticks (time_since_epoch) by which the estimator thread promised to check in.
  std::atomic<Clock::rep> promised_by_;
  std::atomic<bool> stalled_{false};
  std::atomic<bool> stopped_{false};
  std::atomic<std::uint64_t> pings_sent_{0};
  std::atomic<std::uint64_t> stalls_{0};
  Clock::time_point stall_started_{};  ///< timer thread only
};

}  // namespace concord::daemon

#include "service_notifier.h"

#include <spdlog/spdlog.h>
#include <systemd/sd-daemon.h>

#include <boost/asio/post.hpp>

namespace concord::daemon {

ServiceNotifier::ServiceNotifier(boost::asio::io_context& io)
    : io_(io), timer_(io), promised_by_(Clock::now().time_since_epoch().count()) {
  std::uint64_t microseconds = 0;
  // > 0 when systemd set WATCHDOG_USEC for this process (WatchdogSec=); the variables are kept.
  if (sd_watchdog_enabled(0, &microseconds) > 0 && microseconds > 0)
    watchdog_interval_ = std::chrono::microseconds(microseconds);
  check_in();
}

void ServiceNotifier::notify(const std::string& message) {
  // Returns 0 without NOTIFY_SOCKET; a failure to reach the manager is not the daemon's problem.
  if (sd_notify(0, message.c_str()) < 0) spdlog::debug("sd_notify failed: {}", message);
}

void ServiceNotifier::ready(const std::string& status) {
  notify("READY=1\nSTATUS=" + status);
  if (watchdog_enabled())
    spdlog::info("watchdog: the service manager expects a ping every {} ms",
                 std::chrono::duration_cast<std::chrono::milliseconds>(watchdog_interval_).count());
}

void ServiceNotifier::status(const std::string& status) { notify("STATUS=" + status); }

void ServiceNotifier::reloading() { notify("RELOADING=1"); }

void ServiceNotifier::reloaded(const std::string& status) { notify("READY=1\nSTATUS=" + status); }

void ServiceNotifier::stopping() { notify("STOPPING=1\nSTATUS=stopping: writing the outputs"); }

void ServiceNotifier::check_in(Clock::duration budget) {
  promised_by_.store((Clock::now() + watchdog_interval_ + budget).time_since_epoch().count());
}

void ServiceNotifier::start_watchdog() {
  if (!watchdog_enabled()) return;
  boost::asio::post(io_, [this] { tick(); });
}

void ServiceNotifier::stop_watchdog() {
  stopped_ = true;
  boost::asio::post(io_, [this] { timer_.cancel(); });
}

void ServiceNotifier::arm() {
  if (stopped_) return;
  // Half the interval, as sd_watchdog_enabled(3) recommends.
  timer_.expires_after(watchdog_interval_ / 2);
  timer_.async_wait([this](const boost::system::error_code& error) {
    if (!error) tick();
  });
}

void ServiceNotifier::tick() {
  if (stopped_) return;
  const auto now = Clock::now();
  const Clock::time_point promised_by{Clock::duration(promised_by_.load())};
  if (now <= promised_by) {
    if (stalled_.exchange(false)) {
      spdlog::warn("watchdog: the estimator thread checked in again after {:.1f} s; pings resumed",
                   std::chrono::duration<double>(now - stall_started_).count());
      notify("STATUS=running (the estimator thread recovered from a stall)");
    }
    notify("WATCHDOG=1");
    ++pings_sent_;
  } else if (!stalled_.exchange(true)) {
    stall_started_ = promised_by;
    ++stalls_;
    spdlog::error(
        "watchdog: the estimator thread has not checked in when it promised; pings stopped, so the "
        "service manager restarts the daemon unless it recovers");
    notify("STATUS=estimator thread unresponsive: watchdog pings stopped");
  }
  arm();
}

}  // namespace concord::daemon

#pragma once
// Durations on the daemon's monotonic clock, in seconds (metrics, deadlines, logs).

#include <chrono>

namespace concord::daemon {

/// Seconds from `a` to `b` (negative when b is earlier).
inline double seconds_between(std::chrono::steady_clock::time_point a,
                              std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

}  // namespace concord::daemon

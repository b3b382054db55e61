#pragma once
// Durations on the daemon's monotonic clock, in seconds (metrics, deadlines, logs), and the
// calling thread's CPU time.

#include <time.h>

#include <chrono>

namespace concord::daemon {

/// Seconds from `a` to `b` (negative when b is earlier).
inline double seconds_between(std::chrono::steady_clock::time_point a,
                              std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

/// CPU seconds the calling thread has used (CLOCK_THREAD_CPUTIME_ID): what a piece of work costs
/// on a busy machine, where its wall-clock time also counts the other processes' turns.
inline double thread_cpu_seconds() {
  timespec now{};
  if (clock_gettime(CLOCK_THREAD_CPUTIME_ID, &now) != 0) return 0.0;
  return static_cast<double>(now.tv_sec) + 1e-9 * static_cast<double>(now.tv_nsec);
}

}  // namespace concord::daemon

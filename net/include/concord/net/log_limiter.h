#pragma once
/// \file
/// Rate limit for log lines caused by others (a peer, a client, a sensor): per key (e.g.
/// "robot 3 malformed-marginal" or "127.0.0.1 bad-frame") a burst of lines, then at most one line
/// per period; lines over the limit are counted, not written, and the next line written says how
/// many were suppressed. The log then grows with time, not with attack traffic. Thread-safe;
/// memory bounded (a fixed number of keys; further keys share one overflow bucket).

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <map>
#include <mutex>
#include <string>

namespace concord::net {

class LogLimiter {
 public:
  using Clock = std::chrono::steady_clock;

  struct Options {
    int burst = 5;                            ///< lines allowed at once per key
    std::chrono::milliseconds period{10000};  ///< then one more line per period per key
    std::size_t max_keys = 512;               ///< keys tracked; the rest share one bucket
  };

  LogLimiter();
  explicit LogLimiter(Options options);

  /// Whether a line for `key` may be written now. When it may, `suppressed` is set to the
  /// number of lines of this key held back since the last one written (to append to the line).
  [[nodiscard]] bool allow(const std::string& key, std::uint64_t& suppressed);

  /// Lines held back since construction (all keys): exposed as a metric.
  std::uint64_t suppressed_total() const;

 private:
  struct Bucket {
    double tokens = 0.0;
    Clock::time_point refilled{};
    std::uint64_t held_back = 0;
  };
  Options options_;
  mutable std::mutex mutex_;
  std::map<std::string, Bucket> buckets_;
  std::uint64_t suppressed_total_ = 0;
};

/// " (N similar lines suppressed)" when N > 0, else "".
std::string suppressed_note(std::uint64_t suppressed);

}  // namespace concord::net

#pragma once
/// \file
/// Exponential reconnect backoff with jitter: delays initial, 2 initial, 4 initial, ... capped at
/// max, each multiplied by a uniform factor in [1 - jitter, 1 + jitter] so that robots which lost
/// each other at the same moment do not redial in lockstep.

#include <chrono>
#include <cstdint>
#include <random>

namespace concord::net {

struct ReconnectBackoffOptions {
  std::chrono::milliseconds initial{100};  ///< first delay after a drop or a failed dial
  std::chrono::milliseconds max{5000};     ///< cap of the un-jittered delay
  double multiplier = 2.0;                 ///< growth per failed attempt
  double jitter = 0.2;                     ///< relative spread, in [0, 1)
};

class ReconnectBackoff {
 public:
  ReconnectBackoff(ReconnectBackoffOptions options, std::uint64_t seed);

  /// The delay before the next attempt; grows the following one.
  std::chrono::milliseconds next();

  /// Back to the initial delay (after a successful handshake).
  void reset();

  /// Un-jittered delay the next call to next() is based on.
  std::chrono::milliseconds current() const { return current_; }

 private:
  ReconnectBackoffOptions options_;
  std::chrono::milliseconds current_;
  std::mt19937_64 random_;
};

}  // namespace concord::net

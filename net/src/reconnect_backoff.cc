#include "concord/net/reconnect_backoff.h"

#include <algorithm>
#include <cmath>

namespace concord::net {

ReconnectBackoff::ReconnectBackoff(ReconnectBackoffOptions options, std::uint64_t seed)
    : options_(options), current_(options.initial), random_(seed) {}

std::chrono::milliseconds ReconnectBackoff::next() {
  std::uniform_real_distribution<double> factor(1.0 - options_.jitter, 1.0 + options_.jitter);
  const double jittered = static_cast<double>(current_.count()) * factor(random_);
  const auto delay = std::chrono::milliseconds(std::max<long long>(1, std::llround(jittered)));
  const double grown = static_cast<double>(current_.count()) * options_.multiplier;
  current_ = std::min(options_.max, std::chrono::milliseconds(std::llround(grown)));
  return delay;
}

void ReconnectBackoff::reset() { current_ = options_.initial; }

}  // namespace concord::net

#include "concord/net/log_limiter.h"

#include <algorithm>

namespace concord::net {

LogLimiter::LogLimiter() : LogLimiter(Options{}) {}

LogLimiter::LogLimiter(Options options) : options_(options) {}

bool LogLimiter::allow(const std::string& key, std::uint64_t& suppressed) {
  const auto now = Clock::now();
  std::lock_guard lock(mutex_);
  auto it = buckets_.find(key);
  if (it == buckets_.end()) {
    const std::string bucket_key = buckets_.size() < options_.max_keys ? key : std::string("*");
    it = buckets_.try_emplace(bucket_key).first;
    if (it->second.refilled == Clock::time_point{}) {
      it->second.tokens = options_.burst;
      it->second.refilled = now;
    }
  }
  Bucket& bucket = it->second;
  const double period = std::chrono::duration<double>(options_.period).count();
  const double elapsed = std::chrono::duration<double>(now - bucket.refilled).count();
  bucket.tokens = std::min<double>(options_.burst, bucket.tokens + elapsed / period);
  bucket.refilled = now;
  if (bucket.tokens < 1.0) {
    ++bucket.held_back;
    ++suppressed_total_;
    return false;
  }
  bucket.tokens -= 1.0;
  suppressed = bucket.held_back;
  bucket.held_back = 0;
  return true;
}

std::uint64_t LogLimiter::suppressed_total() const {
  std::lock_guard lock(mutex_);
  return suppressed_total_;
}

std::string suppressed_note(std::uint64_t suppressed) {
  if (suppressed == 0) return {};
  return " (" + std::to_string(suppressed) + " similar lines suppressed)";
}

}  // namespace concord::net

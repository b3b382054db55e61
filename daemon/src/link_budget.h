#pragma once
/// \file
/// Consensus under a link budget (consensus.link_budget_bytes_per_second, docs/field.md): what a
/// robot's consensus may send per second over all its links together, and what a marginal keeps
/// when the budget cannot carry all of it. Pure (time is passed in), so it is tested alone.
///
/// The budget is a token bucket (burst: one second's worth). Each round, a neighbour's marginal
/// may use an equal share of the tokens left. A marginal that does not fit is trimmed on purpose:
/// the landmarks least valuable to that neighbour go first. Least valuable = archived landmarks
/// (out of the window: they change least) before landmarks of the joint state, and within each,
/// the ones this neighbour received most recently (never sent = most valuable), so every landmark
/// gets through in turn. A marginal with no landmark left is still sent, empty: it is the
/// neighbour's answer for the round (lockstep does not wait for it) and nothing is fused.

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <map>
#include <vector>

#include "concord/estimator/types.h"

namespace concord::daemon {

class LinkBudget {
 public:
  using Clock = std::chrono::steady_clock;

  /// `bytes_per_second` <= 0: unlimited.
  explicit LinkBudget(double bytes_per_second, Clock::time_point now = Clock::now())
      : rate_(bytes_per_second), tokens_(bytes_per_second), refilled_(now) {}

  bool unlimited() const { return !(rate_ > 0.0); }
  double rate() const { return rate_; }

  /// Adds the tokens earned since the last refill (at most one second's worth in the bucket).
  void refill(Clock::time_point now) {
    if (unlimited()) return;
    const double elapsed = std::chrono::duration<double>(now - refilled_).count();
    if (elapsed > 0.0) tokens_ = std::min(rate_, tokens_ + elapsed * rate_);
    refilled_ = now;
  }
  /// Bytes one of `links` remaining links may use now (0 when the bucket is empty).
  double share(int links) const {
    if (unlimited()) return 1e18;
    return links > 0 ? std::max(0.0, tokens_) / links : 0.0;
  }
  /// Bytes sent (control messages too: the bucket may go below zero, and then it refills first).
  void spend(std::size_t bytes) {
    if (!unlimited()) tokens_ -= static_cast<double>(bytes);
  }
  double tokens() const { return tokens_; }

 private:
  double rate_;
  double tokens_;
  Clock::time_point refilled_;
};

/// Estimated encoded size (bytes on the wire: envelope, encryption and framing included) of a
/// marginal with `in_state` landmarks in one dense block and `archived` 3x3 blocks.
std::size_t estimated_marginal_bytes(std::size_t in_state, std::size_t archived);

/// Which of `candidates` (ascending ids, each with whether it is in the joint state) a marginal to
/// one neighbour keeps within `allowance` bytes, in ascending id order. `last_sent` holds the
/// round each id was last sent to that neighbour (absent: never).
std::vector<LandmarkId> choose_within_budget(
    const std::vector<std::pair<LandmarkId, bool>>& candidates,
    const std::map<LandmarkId, std::uint64_t>& last_sent, double allowance);

}  // namespace concord::daemon

#include "link_budget.h"

#include <algorithm>
#include <limits>

namespace concord::daemon {

std::size_t estimated_marginal_bytes(std::size_t in_state, std::size_t archived) {
  // Envelope header, round, degree; encryption (secretstream, 17 bytes) and the length prefix.
  constexpr std::size_t kOverhead = 80;
  const std::size_t landmarks = in_state + archived;
  std::size_t bytes = kOverhead + 5 * landmarks + 8 * 3 * landmarks;  // ids (varints), means
  bytes += 12;  // the headers of the flat block fields (block_landmarks, packed_upper)
  const std::size_t dense = 3 * in_state;
  if (in_state > 0) {  // its size (a varint), its packed upper triangle
    bytes += (in_state < 128 ? 1 : 3) + 8 * dense * (dense + 1) / 2;
  }
  bytes += archived * (1 + 8 * 6);                             // 3x3 blocks
  return bytes;
}

std::vector<LandmarkId> choose_within_budget(
    const std::vector<std::pair<LandmarkId, bool>>& candidates,
    const std::map<LandmarkId, std::uint64_t>& last_sent, double allowance) {
  // 1. Most valuable first: in the joint state before archived; never sent before sent long ago.
  struct Ranked {
    LandmarkId id;
    bool in_state;
    std::uint64_t sent;  // round last sent + 1; 0 = never
  };
  std::vector<Ranked> ranked;
  ranked.reserve(candidates.size());
  for (const auto& [id, in_state] : candidates) {
    const auto found = last_sent.find(id);
    ranked.push_back({id, in_state, found == last_sent.end() ? 0 : found->second + 1});
  }
  std::stable_sort(ranked.begin(), ranked.end(), [](const Ranked& a, const Ranked& b) {
    if (a.in_state != b.in_state) return a.in_state;
    return a.sent < b.sent;
  });
  // 2. In that order, every landmark that still fits (the size grows with every one added).
  std::size_t in_state = 0, archived = 0;
  std::vector<LandmarkId> chosen;
  for (const Ranked& landmark : ranked) {
    const std::size_t next = landmark.in_state ? estimated_marginal_bytes(in_state + 1, archived)
                                               : estimated_marginal_bytes(in_state, archived + 1);
    if (static_cast<double>(next) > allowance) continue;  // a smaller one may still fit
    (landmark.in_state ? in_state : archived) += 1;
    chosen.push_back(landmark.id);
  }
  std::sort(chosen.begin(), chosen.end());
  return chosen;
}

}  // namespace concord::daemon

#include "concord/association/relabelling.h"

#include <algorithm>
#include <cassert>
#include <utility>

namespace concord::association {

namespace {

bool first_less(const std::pair<LandmarkId, LandmarkId>& x,
                const std::pair<LandmarkId, LandmarkId>& y) {
  return x.first < y.first;
}

/// The entry of an ascending, first-unique list whose first is `key`, or nullptr.
const LandmarkId* find_second(const Labels& labels, LandmarkId key) {
  const auto it = std::lower_bound(labels.begin(), labels.end(), std::pair{key, LandmarkId{}},
                                   first_less);
  return it != labels.end() && it->first == key ? &it->second : nullptr;
}

}  // namespace

Labels receiver_view(const std::vector<std::pair<LandmarkId, LandmarkId>>& received) {
  Labels view;
  view.reserve(received.size());
  for (const auto& [own, theirs] : received) view.emplace_back(theirs, own);
  std::stable_sort(view.begin(), view.end(), first_less);
  // Keep the last of each run of equal sender ids (unique keeps the first: run it backwards).
  view.erase(view.begin(),
             std::unique(view.rbegin(), view.rend(), [](const auto& x, const auto& y) {
               return x.first == y.first;
             }).base());
  return view;
}

Labels agreed_labels(const std::vector<std::pair<LandmarkId, LandmarkId>>& sent,
                     const std::vector<std::pair<LandmarkId, LandmarkId>>& received) {
  const Labels view = receiver_view(received);
  Labels labels;
  labels.reserve(sent.size());
  for (const auto& [own, theirs] : sent) {
    const LandmarkId* receiver = find_second(view, own);
    if (receiver != nullptr && *receiver == theirs) labels.emplace_back(own, theirs);
  }
  // A sender id agrees with one receiver id at most, so equal firsts are equal entries.
  std::sort(labels.begin(), labels.end(), first_less);
  labels.erase(std::unique(labels.begin(), labels.end()), labels.end());
  return labels;
}

namespace {

/// The landmarks of `marginal` at `kept` (ascending positions) under `ids` (parallel to kept):
/// means and covariance entries copied exactly, blocks left empty dropped.
Marginal cut_relabelled(const Marginal& marginal, const std::vector<Eigen::Index>& kept,
                        std::vector<LandmarkId> ids) {
  Marginal out;
  out.ids = std::move(ids);
  out.mean.resize(3 * static_cast<Eigen::Index>(kept.size()));
  for (std::size_t n = 0; n < kept.size(); ++n)
    out.mean.segment<3>(3 * static_cast<Eigen::Index>(n)) = marginal.mean.segment<3>(3 * kept[n]);
  // Blocks cover consecutive landmarks: keep each block's rows and columns of kept landmarks
  // (the whole block when every one of its landmarks is kept).
  Eigen::Index first = 0;  // first landmark of the current block
  std::size_t next = 0;    // next entry of `kept`
  std::vector<Eigen::Index> rows;
  for (const Eigen::MatrixXd& block : marginal.blocks) {
    const Eigen::Index landmarks = block.rows() / 3;
    const std::size_t begin = next;
    while (next < kept.size() && kept[next] < first + landmarks) ++next;
    const auto count = static_cast<Eigen::Index>(next - begin);
    if (count == landmarks && landmarks > 0) {
      out.blocks.push_back(block);
    } else if (count > 0) {
      rows.clear();
      for (std::size_t n = begin; n < next; ++n)
        for (int k = 0; k < 3; ++k) rows.push_back(3 * (kept[n] - first) + k);
      out.blocks.push_back(block(rows, rows));
    }
    first += landmarks;
  }
  return out;
}

/// Looks up keys in a list of (key, value) pairs ascending by key: the value of the first entry
/// whose key equals the one asked, or nullptr. Keys asked in ascending order cost a step of a
/// cursor each; a key below the previous one a binary search (the ids of a marginal ascend
/// within its blocks).
class AscendingLookup {
 public:
  explicit AscendingLookup(const Labels& sorted) : sorted_(sorted), cursor_(sorted.begin()) {}

  const LandmarkId* find(LandmarkId key) {
    if (!started_ || key < previous_) {
      cursor_ = std::lower_bound(sorted_.begin(), sorted_.end(), std::pair{key, LandmarkId{}},
                                 first_less);
    } else {
      while (cursor_ != sorted_.end() && cursor_->first < key) ++cursor_;
    }
    started_ = true;
    previous_ = key;
    return cursor_ != sorted_.end() && cursor_->first == key ? &cursor_->second : nullptr;
  }

 private:
  const Labels& sorted_;
  Labels::const_iterator cursor_;
  bool started_ = false;
  LandmarkId previous_ = 0;
};

/// `marginal` with `ids` (one a landmark) in place of its own: nothing copied.
Marginal renamed(Marginal&& marginal, std::vector<LandmarkId> ids) {
  marginal.ids = std::move(ids);
  std::erase_if(marginal.blocks, [](const Eigen::MatrixXd& block) { return block.rows() == 0; });
  return std::move(marginal);
}

}  // namespace

Marginal relabel_marginal(const Marginal& marginal, const Labels& labels) {
  std::vector<Eigen::Index> kept;  // landmark positions in `marginal`
  std::vector<LandmarkId> ids;
  kept.reserve(marginal.ids.size());
  ids.reserve(marginal.ids.size());
  for (std::size_t i = 0; i < marginal.ids.size(); ++i) {
    const LandmarkId* label = find_second(labels, marginal.ids[i]);
    if (label == nullptr) continue;
    ids.push_back(*label);
    kept.push_back(static_cast<Eigen::Index>(i));
  }
  return cut_relabelled(marginal, kept, std::move(ids));
}

SharedCut shared_cut(const std::vector<std::pair<LandmarkId, LandmarkId>>& shared,
                     const std::vector<LandmarkId>& held_ids) {
  SharedCut cut;
  cut.ids.reserve(shared.size());
  for (const auto& [own, other] : shared) cut.ids.push_back(own);
  cut.receiver_ids.reserve(shared.size());
  AscendingLookup lookup(shared);
  for (const LandmarkId id : held_ids) {
    if (const LandmarkId* receiver = lookup.find(id)) cut.receiver_ids.push_back(*receiver);
  }
  return cut;
}

Marginal relabel_agreed(Marginal&& marginal, const std::vector<LandmarkId>& receiver_ids,
                        const Labels& view) {
  assert(receiver_ids.size() == marginal.ids.size());
  AscendingLookup lookup(view);
  std::vector<LandmarkId> ids;
  std::vector<Eigen::Index> kept;
  ids.reserve(marginal.ids.size());
  kept.reserve(marginal.ids.size());
  for (std::size_t i = 0; i < marginal.ids.size(); ++i) {
    const LandmarkId* receiver = lookup.find(marginal.ids[i]);
    if (receiver == nullptr || *receiver != receiver_ids[i]) continue;
    ids.push_back(*receiver);
    kept.push_back(static_cast<Eigen::Index>(i));
  }
  if (kept.size() == marginal.ids.size()) return renamed(std::move(marginal), std::move(ids));
  return cut_relabelled(marginal, kept, std::move(ids));
}

}  // namespace concord::association

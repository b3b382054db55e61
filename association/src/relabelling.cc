#include "concord/association/relabelling.h"

#include <algorithm>
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

Labels agreed_labels_in_view(const std::vector<std::pair<LandmarkId, LandmarkId>>& sent,
                             const Labels& view) {
  Labels labels;
  labels.reserve(sent.size());
  for (const auto& [own, theirs] : sent) {
    const LandmarkId* receiver = find_second(view, own);
    if (receiver != nullptr && *receiver == theirs) labels.emplace_back(own, theirs);
  }
  // A sender id agrees with one receiver id at most, so equal firsts are equal entries.
  if (!std::is_sorted(labels.begin(), labels.end(), first_less))
    std::sort(labels.begin(), labels.end(), first_less);
  labels.erase(std::unique(labels.begin(), labels.end()), labels.end());
  return labels;
}

Labels agreed_labels(const std::vector<std::pair<LandmarkId, LandmarkId>>& sent,
                     const std::vector<std::pair<LandmarkId, LandmarkId>>& received) {
  return agreed_labels_in_view(sent, receiver_view(received));
}

Marginal relabel_marginal(const Marginal& marginal, const Labels& labels) {
  Marginal out;
  std::vector<Eigen::Index> kept;  // landmark positions in `marginal`
  kept.reserve(marginal.ids.size());
  out.ids.reserve(marginal.ids.size());
  for (std::size_t i = 0; i < marginal.ids.size(); ++i) {
    const LandmarkId* label = find_second(labels, marginal.ids[i]);
    if (label == nullptr) continue;
    out.ids.push_back(*label);
    kept.push_back(static_cast<Eigen::Index>(i));
  }
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

Marginal relabel_marginal(Marginal&& marginal, const Labels& labels) {
  std::vector<LandmarkId> ids;
  ids.reserve(marginal.ids.size());
  for (const LandmarkId id : marginal.ids) {
    const LandmarkId* label = find_second(labels, id);
    if (label == nullptr) return relabel_marginal(std::as_const(marginal), labels);
    ids.push_back(*label);
  }
  marginal.ids = std::move(ids);
  std::erase_if(marginal.blocks, [](const Eigen::MatrixXd& block) { return block.rows() == 0; });
  return std::move(marginal);
}

}  // namespace concord::association

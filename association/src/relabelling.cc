#include "concord/association/relabelling.h"

namespace concord::association {

std::map<LandmarkId, LandmarkId> agreed_labels(
    const std::vector<std::pair<LandmarkId, LandmarkId>>& sent,
    const std::vector<std::pair<LandmarkId, LandmarkId>>& received) {
  std::map<LandmarkId, LandmarkId> receiver_view;  // sender id -> receiver id
  for (const auto& [own, theirs] : received) receiver_view[theirs] = own;
  std::map<LandmarkId, LandmarkId> labels;
  for (const auto& [own, theirs] : sent) {
    const auto it = receiver_view.find(own);
    if (it != receiver_view.end() && it->second == theirs) labels[own] = theirs;
  }
  return labels;
}

Marginal relabel_marginal(const Marginal& marginal,
                          const std::map<LandmarkId, LandmarkId>& labels) {
  Marginal out;
  std::vector<Eigen::Index> kept;  // landmark positions in `marginal`
  for (std::size_t i = 0; i < marginal.ids.size(); ++i) {
    const auto it = labels.find(marginal.ids[i]);
    if (it == labels.end()) continue;
    out.ids.push_back(it->second);
    kept.push_back(static_cast<Eigen::Index>(i));
  }
  out.mean.resize(3 * static_cast<Eigen::Index>(kept.size()));
  for (std::size_t n = 0; n < kept.size(); ++n)
    out.mean.segment<3>(3 * static_cast<Eigen::Index>(n)) = marginal.mean.segment<3>(3 * kept[n]);
  // Blocks cover consecutive landmarks: keep each block's rows and columns of kept landmarks.
  Eigen::Index first = 0;  // first landmark of the current block
  std::size_t next = 0;    // next entry of `kept`
  for (const Eigen::MatrixXd& block : marginal.blocks) {
    const Eigen::Index landmarks = block.rows() / 3;
    std::vector<Eigen::Index> rows;
    for (; next < kept.size() && kept[next] < first + landmarks; ++next)
      for (int k = 0; k < 3; ++k) rows.push_back(3 * (kept[next] - first) + k);
    if (!rows.empty()) out.blocks.push_back(block(rows, rows));
    first += landmarks;
  }
  return out;
}

}  // namespace concord::association

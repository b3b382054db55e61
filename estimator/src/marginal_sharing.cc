#include "concord/estimator/marginal_sharing.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>

namespace concord {

namespace {

/// (block, row offset in it) of every landmark of a marginal, in ids order.
std::vector<std::pair<std::size_t, Eigen::Index>> landmark_positions(const Marginal& marginal) {
  std::vector<std::pair<std::size_t, Eigen::Index>> positions;
  positions.reserve(marginal.ids.size());
  for (std::size_t b = 0; b < marginal.blocks.size(); ++b) {
    for (Eigen::Index offset = 0; offset < marginal.blocks[b].rows(); offset += 3) {
      positions.emplace_back(b, offset);
    }
  }
  return positions;
}

ObjectEstimate estimate_at(const Marginal& marginal,
                           const std::vector<std::pair<std::size_t, Eigen::Index>>& positions,
                           std::size_t k) {
  const auto [block, offset] = positions.at(k);
  return {marginal.ids[k], marginal.mean.segment<3>(3 * static_cast<Eigen::Index>(k)),
          marginal.blocks[block].block<3, 3>(offset, offset)};
}

}  // namespace

double kl_divergence(const ObjectEstimate& p, const ObjectEstimate& q) {
  const Eigen::LLT<Eigen::Matrix3d> q_llt(q.covariance);
  const Eigen::LLT<Eigen::Matrix3d> p_llt(p.covariance);
  if (q_llt.info() != Eigen::Success || p_llt.info() != Eigen::Success) {
    return std::numeric_limits<double>::infinity();
  }
  const Eigen::Vector3d difference = q.p_world - p.p_world;
  const double trace = q_llt.solve(p.covariance).trace();
  const double mahalanobis = difference.dot(q_llt.solve(difference));
  // ln det = 2 sum ln diag(L).
  const double log_det_q = 2.0 * q_llt.matrixL().toDenseMatrix().diagonal().array().log().sum();
  const double log_det_p = 2.0 * p_llt.matrixL().toDenseMatrix().diagonal().array().log().sum();
  return 0.5 * (trace + mahalanobis - 3.0 + log_det_q - log_det_p);
}

ObjectEstimate landmark_estimate(const Marginal& marginal, std::size_t k) {
  return estimate_at(marginal, landmark_positions(marginal), k);
}

Marginal sub_marginal(const Marginal& marginal, const std::vector<bool>& keep) {
  Marginal out;
  sub_marginal(marginal, keep, out);
  return out;
}

void CutLayout::assign(const Marginal& marginal, const std::vector<bool>& keep) {
  kept.clear();
  blocks.clear();
  Eigen::Index position = 0;
  for (const Eigen::MatrixXd& block : marginal.blocks) {
    Block& layout = blocks.emplace_back();
    layout.first = position;
    layout.begin = kept.size();
    for (const Eigen::Index end = position + block.rows() / 3; position < end; ++position) {
      if (keep[static_cast<std::size_t>(position)]) kept.push_back(position);
    }
    layout.end = kept.size();
  }
}

void sub_marginal(const Marginal& marginal, const std::vector<bool>& keep, Marginal& out) {
  thread_local CutLayout layout;
  layout.assign(marginal, keep);
  const auto count = static_cast<Eigen::Index>(layout.kept.size());
  out.ids.clear();
  if (out.mean.size() != 3 * count) out.mean.resize(3 * count);
  for (Eigen::Index k = 0; k < count; ++k) {
    const Eigen::Index position = layout.kept[static_cast<std::size_t>(k)];
    out.ids.push_back(marginal.ids[static_cast<std::size_t>(position)]);
    out.mean.segment<3>(3 * k) = marginal.mean.segment<3>(3 * position);
  }
  const auto blocks = static_cast<std::size_t>(std::count_if(
      layout.blocks.begin(), layout.blocks.end(), [](const auto& b) { return b.size() > 0; }));
  out.blocks.resize(blocks);  // kept blocks keep their storage
  std::size_t block = 0;
  for (std::size_t b = 0; b < layout.blocks.size(); ++b) {
    const CutLayout::Block& cut = layout.blocks[b];
    const Eigen::MatrixXd& source = marginal.blocks[b];
    const Eigen::Index n = cut.size();
    if (n == 0) continue;
    Eigen::MatrixXd& target = out.blocks[block++];
    if (target.rows() != 3 * n || target.cols() != 3 * n) target.resize(3 * n, 3 * n);
    if (3 * n == source.rows()) {
      target = source;  // the whole block (an archived object's 3x3, most often)
      continue;
    }
    for (Eigen::Index c = 0; c < n; ++c) {
      const Eigen::Index sc = layout.source_row(cut, 3 * c);
      for (Eigen::Index r = 0; r < n; ++r) {
        target.block<3, 3>(3 * r, 3 * c) = source.block<3, 3>(layout.source_row(cut, 3 * r), sc);
      }
    }
  }
}

long long CompactMarginal::bytes() const {
  if (ids.empty()) return 0;  // nothing goes in the message (the daemons write no fields)
  long long total = 8 * static_cast<long long>(ids.size()) + 24 +
                    4 * static_cast<long long>(mean_offsets.size());
  for (const Block& block : blocks) {
    total += 4 * static_cast<long long>(block.cholesky_lower.size()) +
             8 * static_cast<long long>(block.packed_upper.size());
  }
  return total;
}

CompactMarginal compact(const Marginal& marginal) {
  CompactMarginal out;
  out.ids = marginal.ids;
  if (marginal.mean.size() >= 3) out.origin = marginal.mean.head<3>();
  out.mean_offsets.reserve(static_cast<std::size_t>(marginal.mean.size()));
  for (Eigen::Index i = 0; i < marginal.mean.size(); ++i) {
    out.mean_offsets.push_back(static_cast<float>(marginal.mean(i) - out.origin(i % 3)));
  }
  for (const Eigen::MatrixXd& covariance : marginal.blocks) {
    CompactMarginal::Block block;
    block.landmarks = static_cast<int>(covariance.rows() / 3);
    const Eigen::Index n = covariance.rows();
    const Eigen::LLT<Eigen::MatrixXd> llt(covariance);
    bool factored = llt.info() == Eigen::Success;
    if (factored) {
      const Eigen::MatrixXd L = llt.matrixL();
      block.cholesky_lower.reserve(static_cast<std::size_t>(n * (n + 1) / 2));
      for (Eigen::Index r = 0; r < n && factored; ++r) {
        for (Eigen::Index c = 0; c <= r; ++c) {
          const auto value = static_cast<float>(L(r, c));
          // The factor's diagonal must stay positive (and everything finite) in float.
          if (!std::isfinite(value) || (r == c && !(value > 0.0F))) {
            factored = false;
            break;
          }
          block.cholesky_lower.push_back(value);
        }
      }
    }
    if (!factored) {
      block.cholesky_lower.clear();
      block.packed_upper.reserve(static_cast<std::size_t>(n * (n + 1) / 2));
      for (Eigen::Index r = 0; r < n; ++r) {
        for (Eigen::Index c = r; c < n; ++c) block.packed_upper.push_back(covariance(r, c));
      }
    }
    out.blocks.push_back(std::move(block));
  }
  return out;
}

Marginal expand(const CompactMarginal& compact) {
  const auto size = static_cast<Eigen::Index>(3 * compact.ids.size());
  if (static_cast<Eigen::Index>(compact.mean_offsets.size()) != size) return {};
  Marginal out;
  out.ids = compact.ids;
  out.mean.resize(size);
  for (Eigen::Index i = 0; i < size; ++i) {
    out.mean(i) = compact.origin(i % 3) + static_cast<double>(compact.mean_offsets[i]);
  }
  Eigen::Index covered = 0;
  for (const CompactMarginal::Block& block : compact.blocks) {
    const Eigen::Index n = 3 * static_cast<Eigen::Index>(block.landmarks);
    if (block.landmarks <= 0 || covered + n > size) return {};
    const auto triangle = static_cast<std::size_t>(n * (n + 1) / 2);
    const bool in_float = block.cholesky_lower.size() == triangle && block.packed_upper.empty();
    const bool in_double = block.packed_upper.size() == triangle && block.cholesky_lower.empty();
    if (!in_float && !in_double) return {};  // checked before anything is allocated
    Eigen::MatrixXd covariance(n, n);
    if (in_float) {
      Eigen::MatrixXd L = Eigen::MatrixXd::Zero(n, n);
      std::size_t next = 0;
      for (Eigen::Index r = 0; r < n; ++r) {
        for (Eigen::Index c = 0; c <= r; ++c) L(r, c) = static_cast<double>(block.cholesky_lower[next++]);
      }
      covariance = L * L.transpose();
    } else {
      std::size_t next = 0;
      for (Eigen::Index r = 0; r < n; ++r) {
        for (Eigen::Index c = r; c < n; ++c) {
          covariance(r, c) = covariance(c, r) = block.packed_upper[next++];
        }
      }
    }
    out.blocks.push_back(std::move(covariance));
    covered += n;
  }
  if (covered != size || !out.well_formed()) return {};
  return out;
}

Marginal quantized(const Marginal& marginal) { return expand(compact(marginal)); }

Marginal split_blocks(const Marginal& marginal, int max_block_landmarks) {
  if (max_block_landmarks <= 0) return marginal;
  const Eigen::Index run = 3 * static_cast<Eigen::Index>(max_block_landmarks);
  Marginal out;
  out.ids = marginal.ids;
  out.mean = marginal.mean;
  for (const Eigen::MatrixXd& block : marginal.blocks) {
    for (Eigen::Index k = 0; k < block.rows(); k += run) {
      const Eigen::Index n = std::min(run, block.rows() - k);
      out.blocks.emplace_back(block.block(k, k, n, n));
    }
  }
  return out;
}

int link_landmark_cap(int robot_cap, int links) {
  if (robot_cap <= 0) return 0;
  return std::max(1, robot_cap / std::max(links, 1));
}

Marginal MarginalSender::select(const Marginal& full, double kl_threshold,
                                int max_landmarks) const {
  const std::size_t n = full.ids.size();
  const bool capped = max_landmarks > 0 && n > static_cast<std::size_t>(max_landmarks);
  if (kl_threshold <= 0.0 && !capped) return full;
  // Priority of each landmark: infinity if never sent on this link, else its KL since.
  std::vector<double> priority(n, std::numeric_limits<double>::infinity());
  const auto positions = landmark_positions(full);
  for (std::size_t k = 0; k < n; ++k) {
    const auto it = last_sent_.find(full.ids[k]);
    if (it == last_sent_.end()) continue;
    const double kl = kl_divergence(estimate_at(full, positions, k), it->second);
    if (kl >= 0.0) priority[k] = kl;  // NaN (a broken marginal): sent, as if never sent
  }
  std::vector<std::size_t> candidates;
  for (std::size_t k = 0; k < n; ++k) {
    if (kl_threshold <= 0.0 || priority[k] > kl_threshold) candidates.push_back(k);
  }
  if (max_landmarks > 0 && candidates.size() > static_cast<std::size_t>(max_landmarks)) {
    std::stable_sort(candidates.begin(), candidates.end(),
                     [&](std::size_t a, std::size_t b) { return priority[a] > priority[b]; });
    candidates.resize(static_cast<std::size_t>(max_landmarks));
  }
  std::vector<bool> keep(n, false);
  for (std::size_t k : candidates) keep[k] = true;
  return sub_marginal(full, keep);
}

void MarginalSender::delivered(const Marginal& sent) {
  const auto positions = landmark_positions(sent);
  for (std::size_t k = 0; k < sent.ids.size(); ++k) {
    last_sent_[sent.ids[k]] = estimate_at(sent, positions, k);
  }
}

void MarginalReceiver::ingest(const Marginal& received) {
  const auto positions = landmark_positions(received);
  for (std::size_t k = 0; k < received.ids.size() && k < positions.size(); ++k) {
    const auto it = last_received_.find(received.ids[k]);
    if (it != last_received_.end()) {
      it->second = estimate_at(received, positions, k);
    } else if (last_received_.size() < max_landmarks_) {
      last_received_.emplace(received.ids[k], estimate_at(received, positions, k));
    }
  }
}

Marginal MarginalReceiver::build(const Marginal& received, const std::vector<LandmarkId>& common) {
  for (auto it = last_received_.begin(); it != last_received_.end();) {
    it = std::binary_search(common.begin(), common.end(), it->first) ? std::next(it)
                                                                      : last_received_.erase(it);
  }
  Marginal out = received;
  std::vector<LandmarkId> sorted_received = received.ids;
  std::sort(sorted_received.begin(), sorted_received.end());
  std::vector<double> extra_mean;
  for (const auto& [id, estimate] : last_received_) {
    if (std::binary_search(sorted_received.begin(), sorted_received.end(), id)) continue;
    out.ids.push_back(id);
    for (int i = 0; i < 3; ++i) extra_mean.push_back(estimate.p_world(i));
    out.blocks.emplace_back(estimate.covariance);
  }
  if (!extra_mean.empty()) {
    const Eigen::Index before = out.mean.size();
    out.mean.conservativeResize(before + static_cast<Eigen::Index>(extra_mean.size()));
    for (std::size_t i = 0; i < extra_mean.size(); ++i) {
      out.mean(before + static_cast<Eigen::Index>(i)) = extra_mean[i];
    }
  }
  return out;
}

}  // namespace concord

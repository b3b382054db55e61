#include "concord/estimator/consensus.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <map>
#include <optional>
#include <set>

#include "concord/estimator/state_helper.h"

namespace concord {

namespace {

/// Where a landmark sits in a block-diagonal marginal.
struct Location {
  int position = 0;  ///< index in ids
  int block = 0;     ///< index in blocks
  int offset = 0;    ///< row of its first coordinate in that block
};

/// A neighbour's marginal checked once: its weight and where each id sits in it.
struct CheckedNeighbour {
  double weight = 0.0;
  const Marginal* marginal = nullptr;
  /// (id, location) sorted by id: binary search over contiguous memory.
  std::vector<std::pair<LandmarkId, Location>> locations;

  const Location* find(LandmarkId id) const {
    const auto it = std::lower_bound(
        locations.begin(), locations.end(), id,
        [](const std::pair<LandmarkId, Location>& entry, LandmarkId key) { return entry.first < key; });
    return it != locations.end() && it->first == id ? &it->second : nullptr;
  }

  Eigen::Matrix3d covariance(const Location& at) const {
    return marginal->blocks[at.block].block<3, 3>(at.offset, at.offset);
  }
};

/// Cholesky factor of a covariance if it is positive definite and its (1-norm) condition
/// number, estimated from the factor, is below max_condition_number.
template <typename Matrix>
std::optional<Eigen::LLT<Matrix>> checked_cholesky(const Matrix& covariance,
                                                   double max_condition_number) {
  Eigen::LLT<Matrix> llt(covariance);
  if (llt.info() != Eigen::Success) return std::nullopt;
  const double reciprocal_condition = llt.rcond();
  if (!(reciprocal_condition * max_condition_number >= 1.0)) return std::nullopt;
  return llt;
}

/// Mean and covariance of the given landmarks of a block-diagonal marginal (zero covariance
/// between landmarks of different blocks).
void sub_marginal(const CheckedNeighbour& neighbour, const std::vector<Location>& at,
                  Eigen::VectorXd& mean, Eigen::MatrixXd& covariance) {
  const auto k = static_cast<Eigen::Index>(at.size());
  mean.resize(3 * k);
  covariance = Eigen::MatrixXd::Zero(3 * k, 3 * k);
  for (Eigen::Index a = 0; a < k; ++a) {
    mean.segment<3>(3 * a) = neighbour.marginal->mean.segment<3>(3 * at[a].position);
    const Eigen::MatrixXd& block = neighbour.marginal->blocks[at[a].block];
    for (Eigen::Index b = 0; b < k; ++b) {
      if (at[b].block != at[a].block) continue;
      covariance.block<3, 3>(3 * a, 3 * b) = block.block<3, 3>(at[a].offset, at[b].offset);
    }
  }
}

/// Proposition 2 on the covariance P of a Gaussian: replaces the marginal of the coordinates
/// `indices` (currently own_mean, P_yy) by N(target_mean, target_covariance) and keeps the
/// conditional of the other coordinates. With B = P[:, y] and L = B P_yy^-1 (eq. 14):
///   P <- P + L (Sigma_bar - P_yy) L^T = P + B M B^T,  M = P_yy^-1 (Sigma_bar - P_yy) P_yy^-1,
/// and the mean correction is L (mu_bar - mu_y). Forming M (k^3) instead of L (k^2 n) and updating
/// only the lower triangle makes it k^3 + k^2 n + n^2 k / 2. Returns the correction, or
/// std::nullopt (P unchanged) if P_yy is not positive definite.
std::optional<Eigen::VectorXd> proposition_two(Eigen::MatrixXd& P, const std::vector<int>& indices,
                                               const Eigen::VectorXd& own_mean,
                                               const Eigen::VectorXd& target_mean,
                                               const Eigen::MatrixXd& target_covariance) {
  const Eigen::MatrixXd own_covariance = P(indices, indices);
  const Eigen::LLT<Eigen::MatrixXd> llt(own_covariance);
  if (llt.info() != Eigen::Success) return std::nullopt;
  const Eigen::MatrixXd B = P(Eigen::all, indices);
  Eigen::VectorXd correction = B * llt.solve(target_mean - own_mean);
  const Eigen::MatrixXd half = llt.solve(target_covariance - own_covariance);  // P_yy^-1 D
  Eigen::MatrixXd M = llt.solve(half.transpose());                            // P_yy^-1 D P_yy^-1
  M = 0.5 * (M + M.transpose()).eval();
  const Eigen::MatrixXd BM = B * M;
  P.triangularView<Eigen::Lower>() += BM * B.transpose();
  P.triangularView<Eigen::StrictlyUpper>() = P.transpose();
  return correction;
}

/// Proposition 2 on a Gaussian N(mean, covariance) (see proposition_two).
bool replace_gaussian_marginal(Eigen::VectorXd& mean, Eigen::MatrixXd& covariance,
                               const std::vector<int>& indices,
                               const Eigen::VectorXd& target_mean,
                               const Eigen::MatrixXd& target_covariance) {
  const Eigen::VectorXd own_mean = mean(indices);
  const auto correction =
      proposition_two(covariance, indices, own_mean, target_mean, target_covariance);
  if (!correction) return false;
  mean += *correction;
  return true;
}

/// Information-form weighted average (eq. 19) of the robot's own marginal and its neighbours'.
/// A neighbour whose covariance is not positive definite or is ill-conditioned is left out (its
/// weight goes to the robot) and counted. Returns false if no neighbour is usable or the robot's
/// own marginal is not positive definite (nothing to average).
bool information_average(double own_weight, const Eigen::VectorXd& own_mean,
                         const Eigen::MatrixXd& own_covariance, std::vector<double> weights,
                         const std::vector<Eigen::VectorXd>& means,
                         const std::vector<Eigen::MatrixXd>& covariances,
                         double max_condition_number, Eigen::VectorXd& mean,
                         Eigen::MatrixXd& covariance, ConsensusReport& report) {
  const Eigen::Index d = own_mean.size();
  Eigen::MatrixXd information = Eigen::MatrixXd::Zero(d, d);
  Eigen::VectorXd information_vector = Eigen::VectorXd::Zero(d);
  const Eigen::MatrixXd identity = Eigen::MatrixXd::Identity(d, d);
  int used = 0;
  for (std::size_t j = 0; j < weights.size(); ++j) {
    const auto llt = checked_cholesky(covariances[j], max_condition_number);
    if (!llt) {
      ++report.neighbours_skipped;
      own_weight += weights[j];
      continue;
    }
    information += weights[j] * llt->solve(identity);
    information_vector += weights[j] * llt->solve(means[j]);
    ++used;
  }
  if (used == 0) return false;
  const Eigen::LLT<Eigen::MatrixXd> own(own_covariance);
  if (own.info() != Eigen::Success) return false;
  information += own_weight * own.solve(identity);
  information_vector += own_weight * own.solve(own_mean);
  information = 0.5 * (information + information.transpose()).eval();
  const Eigen::LLT<Eigen::MatrixXd> llt(information);
  if (llt.info() != Eigen::Success) return false;
  covariance = llt.solve(identity);
  covariance = 0.5 * (covariance + covariance.transpose()).eval();
  mean = covariance * information_vector;
  return true;
}

/// Shortens each landmark's mean shift to at most max_shift metres.
void limit_mean_shift(const Eigen::VectorXd& own_mean, Eigen::VectorXd& mean, double max_shift,
                      ConsensusReport& report) {
  for (Eigen::Index i = 0; i < own_mean.size(); i += 3) {
    Eigen::Vector3d shift = mean.segment<3>(i) - own_mean.segment<3>(i);
    const double length = shift.norm();
    if (max_shift > 0.0 && length > max_shift) {
      shift *= max_shift / length;
      mean.segment<3>(i) = own_mean.segment<3>(i) + shift;
      ++report.mean_shifts_limited;
    }
    report.largest_mean_shift = std::max(report.largest_mean_shift, shift.norm());
  }
}

/// The information average (eq. 19) of one archived object with its holders' 3x3 marginals,
/// written into `estimate`; the same rules as information_average, without heap allocations.
bool average_archived(ObjectEstimate& estimate, double own_weight,
                      const std::vector<CheckedNeighbour>& checked, const std::vector<int>& holders,
                      LandmarkId id, const ConsensusOptions& options, ConsensusReport& report) {
  Eigen::Matrix3d information = Eigen::Matrix3d::Zero();
  Eigen::Vector3d information_vector = Eigen::Vector3d::Zero();
  int used = 0;
  for (int j : holders) {
    const Location& at = *checked[j].find(id);
    const auto llt = checked_cholesky<Eigen::Matrix3d>(checked[j].covariance(at),
                                                       options.max_condition_number);
    if (!llt) {
      ++report.neighbours_skipped;
      own_weight += checked[j].weight;
      continue;
    }
    information += checked[j].weight * llt->solve(Eigen::Matrix3d::Identity());
    information_vector +=
        checked[j].weight * llt->solve(checked[j].marginal->mean.segment<3>(3 * at.position));
    ++used;
  }
  if (used == 0) return false;
  const Eigen::LLT<Eigen::Matrix3d> own(estimate.covariance);
  if (own.info() != Eigen::Success) return false;
  information += own_weight * own.solve(Eigen::Matrix3d::Identity());
  information_vector += own_weight * own.solve(estimate.p_world);
  information = 0.5 * (information + information.transpose()).eval();
  const Eigen::LLT<Eigen::Matrix3d> llt(information);
  if (llt.info() != Eigen::Success) return false;
  Eigen::Matrix3d covariance = llt.solve(Eigen::Matrix3d::Identity());
  covariance = 0.5 * (covariance + covariance.transpose()).eval();
  Eigen::VectorXd mean = covariance * information_vector;
  const Eigen::VectorXd own_mean = estimate.p_world;
  limit_mean_shift(own_mean, mean, options.max_mean_shift, report);
  estimate.p_world = mean;
  estimate.covariance = covariance;
  return true;
}

}  // namespace

Marginal Consensus::marginal(const State& state, const std::vector<LandmarkId>& ids) {
  Marginal out;
  std::vector<int> slots;
  std::vector<const ObjectEstimate*> archived;
  for (LandmarkId id : ids) {
    const int slot = state.landmark_slot(id);
    if (slot >= 0) {
      slots.push_back(slot);
    } else if (auto it = state.archived.find(id); it != state.archived.end()) {
      archived.push_back(&it->second);
    }
  }
  out = StateHelper::landmark_marginal(state, slots);
  const Eigen::Index joint = out.mean.size();
  out.mean.conservativeResize(joint + 3 * static_cast<Eigen::Index>(archived.size()));
  for (std::size_t i = 0; i < archived.size(); ++i) {
    out.ids.push_back(archived[i]->id);
    out.mean.segment<3>(joint + 3 * static_cast<Eigen::Index>(i)) = archived[i]->p_world;
    out.blocks.emplace_back(archived[i]->covariance);
  }
  return out;
}

bool Consensus::replace_marginal(State& state, const std::vector<int>& slots,
                                 const Eigen::VectorXd& mean, const Eigen::MatrixXd& covariance) {
  std::vector<int> indices;
  indices.reserve(3 * slots.size());
  Eigen::VectorXd own_mean(3 * slots.size());
  for (std::size_t i = 0; i < slots.size(); ++i) {
    own_mean.segment<3>(3 * static_cast<Eigen::Index>(i)) = state.landmarks[slots[i]].p_world;
    for (int k = 0; k < 3; ++k) indices.push_back(state.landmark_index(slots[i]) + k);
  }
  const auto correction = proposition_two(state.covariance, indices, own_mean, mean, covariance);
  if (!correction) return false;
  // eq. (21): poses T <- T exp(mu_x_bar^); landmarks shift additively.
  StateHelper::apply_correction(state, *correction);
  return true;
}

ConsensusReport Consensus::fuse(State& state, const std::vector<WeightedMarginal>& neighbours,
                                const ConsensusOptions& options) {
  ConsensusReport report;

  // 1. Check every neighbour's marginal once.
  std::vector<CheckedNeighbour> checked;
  for (const WeightedMarginal& neighbour : neighbours) {
    const Marginal& m = neighbour.marginal;
    if (m.ids.empty()) continue;
    // Positive definiteness and conditioning are checked per averaged group, below.
    if (!m.well_formed() || !(neighbour.weight > 0.0 && neighbour.weight < 1.0)) {
      ++report.neighbours_skipped;
      continue;
    }
    CheckedNeighbour entry{neighbour.weight, &m, {}};
    int position = 0;
    for (std::size_t b = 0; b < m.blocks.size(); ++b) {
      for (Eigen::Index offset = 0; offset < m.blocks[b].rows(); offset += 3) {
        entry.locations.push_back(
            {m.ids[position], {position, static_cast<int>(b), static_cast<int>(offset)}});
        ++position;
      }
    }
    std::sort(entry.locations.begin(), entry.locations.end(),
              [](const auto& a, const auto& b) { return a.first < b.first; });
    // Repeated ids make a marginal malformed.
    if (std::adjacent_find(entry.locations.begin(), entry.locations.end(), [](const auto& a, const auto& b) {
          return a.first == b.first;
        }) != entry.locations.end()) {
      ++report.neighbours_skipped;
      continue;
    }
    checked.push_back(std::move(entry));
  }
  if (checked.empty()) return report;

  // 2. For every landmark the robot holds, the neighbours that hold it (after the gate).
  auto own_estimate = [&](LandmarkId id, Eigen::Vector3d& mean, Eigen::Matrix3d& covariance) {
    const int slot = state.landmark_slot(id);
    if (slot >= 0) {
      const int index = state.landmark_index(slot);
      mean = state.landmarks[slot].p_world;
      covariance = state.covariance.block<3, 3>(index, index);
    } else {
      const ObjectEstimate& estimate = state.archived.at(id);
      mean = estimate.p_world;
      covariance = estimate.covariance;
    }
  };
  // Groups keyed by (in joint state?, holder neighbours), landmarks in id order.
  std::map<std::pair<bool, std::vector<int>>, std::vector<LandmarkId>> groups;
  for (LandmarkId id : state.object_ids()) {
    std::vector<int> holders;
    for (std::size_t j = 0; j < checked.size(); ++j) {
      const Location* found = checked[j].find(id);
      if (found == nullptr) continue;
      if (options.disagreement_gate > 0.0) {
        Eigen::Vector3d own_mean;
        Eigen::Matrix3d own_covariance;
        own_estimate(id, own_mean, own_covariance);
        const Location& at = *found;
        const Eigen::Vector3d difference =
            checked[j].marginal->mean.segment<3>(3 * at.position) - own_mean;
        const Eigen::Matrix3d sum = own_covariance + checked[j].covariance(at);
        if (difference.dot(sum.ldlt().solve(difference)) >
            options.disagreement_gate * options.disagreement_gate) {
          ++report.landmarks_gated;
          continue;
        }
      }
      holders.push_back(static_cast<int>(j));
    }
    if (holders.empty()) continue;
    groups[{state.landmark_slot(id) >= 0, holders}].push_back(id);
  }

  // 3. In-state groups are averaged one after another on the joint marginal of all in-state
  //    landmarks being fused (U): replacing a group's marginal keeps the conditional of the rest
  //    given it, so p(rest of the state | U) never changes and the sequence of replacements
  //    equals one replacement of U's marginal at the end (Proposition 2 once, not per group).
  std::vector<int> union_slots;
  std::map<LandmarkId, int> union_position;
  for (const auto& [key, ids] : groups) {
    if (!key.first) continue;
    for (LandmarkId id : ids) {
      union_position[id] = static_cast<int>(union_slots.size());
      union_slots.push_back(state.landmark_slot(id));
    }
  }
  Eigen::VectorXd union_mean;
  Eigen::MatrixXd union_covariance;
  if (!union_slots.empty()) {
    Marginal own = StateHelper::landmark_marginal(state, union_slots);
    union_mean = std::move(own.mean);
    union_covariance = std::move(own.blocks.front());
  }
  int union_fused = 0;
  int union_groups = 0;

  for (const auto& [key, ids] : groups) {
    const auto& [in_joint_state, holders] = key;
    double own_weight = 1.0;
    for (int j : holders) own_weight -= checked[j].weight;
    if (!in_joint_state) {
      // Archived objects are independent: average them one by one (fixed-size 3x3 algebra).
      for (LandmarkId id : ids) {
        ObjectEstimate& estimate = state.archived.at(id);
        if (average_archived(estimate, own_weight, checked, holders, id, options, report)) {
          ++report.landmarks_fused;
          ++report.groups;
        }
      }
      continue;
    }
    // In-state group: averaged jointly on U.
    std::vector<int> indices;  // coordinates of the group in U
    for (LandmarkId id : ids) {
      for (int k = 0; k < 3; ++k) indices.push_back(3 * union_position.at(id) + k);
    }
    const Eigen::VectorXd own_mean = union_mean(indices);
    const Eigen::MatrixXd own_covariance = union_covariance(indices, indices);
    std::vector<double> weights;
    std::vector<Eigen::VectorXd> means;
    std::vector<Eigen::MatrixXd> covariances;
    for (int j : holders) {
      std::vector<Location> at;
      for (LandmarkId id : ids) at.push_back(*checked[j].find(id));
      Eigen::VectorXd m;
      Eigen::MatrixXd c;
      sub_marginal(checked[j], at, m, c);
      weights.push_back(checked[j].weight);
      means.push_back(std::move(m));
      covariances.push_back(std::move(c));
    }
    Eigen::VectorXd mean;
    Eigen::MatrixXd covariance;
    if (!information_average(own_weight, own_mean, own_covariance, weights, means, covariances,
                             options.max_condition_number, mean, covariance, report)) {
      continue;
    }
    limit_mean_shift(own_mean, mean, options.max_mean_shift, report);
    if (!replace_gaussian_marginal(union_mean, union_covariance, indices, mean, covariance)) {
      continue;
    }
    union_fused += static_cast<int>(ids.size());
    ++union_groups;
  }
  if (union_groups > 0 && replace_marginal(state, union_slots, union_mean, union_covariance)) {
    report.landmarks_fused += union_fused;
    report.groups += union_groups;
  }
  return report;
}

double Consensus::metropolis_weight(int degree_i, int degree_j) {
  return 1.0 / (1.0 + static_cast<double>(std::max(degree_i, degree_j)));
}

}  // namespace concord

#include "concord/estimator/consensus.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <optional>
#include <span>

#include "concord/estimator/marginal_sharing.h"
#include "concord/estimator/state_helper.h"
#include "concord/estimator/updater_helper.h"

namespace concord {

namespace {

/// Where a landmark sits in a block-diagonal marginal.
struct Location {
  int position = 0;  ///< index in ids
  int block = 0;     ///< index in blocks
  int offset = 0;    ///< row of its first coordinate in that block
};

/// (id, location) of every landmark of a block-diagonal Gaussian, sorted by id; nullopt when an
/// id repeats.
std::optional<std::vector<std::pair<LandmarkId, Location>>> locate(
    const std::vector<LandmarkId>& ids, const std::vector<Eigen::MatrixXd>& blocks) {
  std::vector<std::pair<LandmarkId, Location>> locations;
  locations.reserve(ids.size());
  int position = 0;
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    for (Eigen::Index offset = 0; offset < blocks[b].rows(); offset += 3) {
      locations.push_back({ids[position], {position, static_cast<int>(b), static_cast<int>(offset)}});
      ++position;
    }
  }
  std::sort(locations.begin(), locations.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  const auto repeated = std::adjacent_find(
      locations.begin(), locations.end(), [](const auto& a, const auto& b) { return a.first == b.first; });
  if (repeated != locations.end()) return std::nullopt;
  return locations;
}

const Location* find_location(const std::vector<std::pair<LandmarkId, Location>>& locations,
                              LandmarkId id) {
  const auto it = std::lower_bound(
      locations.begin(), locations.end(), id,
      [](const std::pair<LandmarkId, Location>& entry, LandmarkId key) { return entry.first < key; });
  return it != locations.end() && it->first == id ? &it->second : nullptr;
}

/// A member of an average: the robot itself or a neighbour, its marginal checked once, with
/// its weight and where each id sits in it.
struct Member {
  int index = -1;  ///< position in the neighbours given to fuse(), -1 for the robot itself
  double weight = 0.0;
  const Marginal* marginal = nullptr;
  std::vector<std::pair<LandmarkId, Location>> locations;

  const Location* find(LandmarkId id) const { return find_location(locations, id); }
  Eigen::Vector3d mean(const Location& at) const {
    return marginal->mean.segment<3>(3 * at.position);
  }
  Eigen::Matrix3d covariance(const Location& at) const {
    return marginal->blocks[at.block].block<3, 3>(at.offset, at.offset);
  }
};

/// Checks a marginal (shapes, finite values, no repeated id); nullopt when malformed.
std::optional<Member> check(const Marginal& marginal, int index, double weight) {
  if (!marginal.well_formed()) return std::nullopt;
  auto locations = locate(marginal.ids, marginal.blocks);
  if (!locations) return std::nullopt;
  return Member{index, weight, &marginal, std::move(*locations)};
}

/// The inverse (symmetrised) of a covariance if it is positive definite and its 1-norm condition
/// number ||P||_1 ||P^-1||_1, exact from the inverse, is at most max_condition_number.
template <typename Matrix>
std::optional<Matrix> checked_inverse(const Matrix& covariance, double max_condition_number) {
  const Eigen::LLT<Matrix> llt(covariance);
  if (llt.info() != Eigen::Success) return std::nullopt;
  Matrix inverse = llt.solve(Matrix::Identity(covariance.rows(), covariance.cols()));
  inverse = 0.5 * (inverse + inverse.transpose()).eval();
  const double condition = covariance.cwiseAbs().colwise().sum().maxCoeff() *
                           inverse.cwiseAbs().colwise().sum().maxCoeff();
  if (!(condition <= max_condition_number)) return std::nullopt;
  return inverse;
}

/// checked_inverse for one landmark's 3x3 covariance, in closed form: positive definite when its
/// leading principal minors are positive (Sylvester), the inverse from the cofactors. Like the
/// Cholesky factorization, it reads the lower triangle only (the matrix is taken as symmetric).
std::optional<Eigen::Matrix3d> checked_inverse3(const Eigen::Matrix3d& covariance,
                                                double max_condition_number) {
  const Eigen::Matrix3d P = covariance.selfadjointView<Eigen::Lower>();
  const double minor2 = P(0, 0) * P(1, 1) - P(0, 1) * P(1, 0);
  const double determinant = P.determinant();
  if (!(P(0, 0) > 0.0 && minor2 > 0.0 && determinant > 0.0)) return std::nullopt;
  Eigen::Matrix3d inverse = P.inverse();
  inverse = 0.5 * (inverse + inverse.transpose()).eval();
  const double condition = P.cwiseAbs().colwise().sum().maxCoeff() *
                           inverse.cwiseAbs().colwise().sum().maxCoeff();
  if (!(condition <= max_condition_number)) return std::nullopt;
  return inverse;
}

/// Mean and covariance of the landmarks at `at` (all in one block) of a block-diagonal Gaussian.
void sub_gaussian(const Eigen::VectorXd& full_mean, const std::vector<Eigen::MatrixXd>& blocks,
                  const std::vector<Location>& at, Eigen::VectorXd& mean,
                  Eigen::MatrixXd& covariance) {
  const auto k = static_cast<Eigen::Index>(at.size());
  mean.resize(3 * k);
  covariance.resize(3 * k, 3 * k);
  for (Eigen::Index a = 0; a < k; ++a) {
    mean.segment<3>(3 * a) = full_mean.segment<3>(3 * at[a].position);
    const Eigen::MatrixXd& block = blocks[at[a].block];
    for (Eigen::Index b = 0; b < k; ++b) {
      covariance.block<3, 3>(3 * a, 3 * b) = block.block<3, 3>(at[a].offset, at[b].offset);
    }
  }
}

/// A run of consecutive coordinates [start, start + length) of a matrix, found at `position`
/// in an index list.
struct Run {
  Eigen::Index start = 0;
  Eigen::Index length = 0;
  Eigen::Index position = 0;
};

/// The runs of consecutive values of an ascending index list (a landmark's three coordinates
/// are one run at least; the poses one long one).
std::vector<Run> runs_of(const std::vector<int>& indices) {
  std::vector<Run> runs;
  for (std::size_t i = 0; i < indices.size(); ++i) {
    if (!runs.empty() && runs.back().start + runs.back().length == indices[i]) {
      ++runs.back().length;
    } else {
      runs.push_back({indices[i], 1, static_cast<Eigen::Index>(i)});
    }
  }
  return runs;
}

/// P(rows, columns) for index lists given as runs, copied block by block.
Eigen::MatrixXd gather(const Eigen::MatrixXd& P, const std::vector<Run>& rows,
                       const std::vector<Run>& columns, Eigen::Index row_count,
                       Eigen::Index column_count) {
  Eigen::MatrixXd out(row_count, column_count);
  for (const Run& column : columns) {
    for (const Run& row : rows) {
      out.block(row.position, column.position, row.length, column.length) =
          P.block(row.start, column.start, row.length, column.length);
    }
  }
  return out;
}

/// Proposition 2 on the covariance P of a Gaussian: replaces the marginal of the coordinates
/// `indices` (y; currently own_mean, P_yy) by N(target_mean, target_covariance) and keeps the
/// conditional of the other coordinates (x). With L = P_xy P_yy^-1 (eq. 14) and
/// D = Sigma_bar - P_yy:
///   P_yy <- Sigma_bar,  P_xy <- P_xy + L D,  P_xx <- P_xx + L D L^T,
/// and the mean moves by mu_bar - mu_y on y and by L (mu_bar - mu_y) on x. This is
/// P + B M B^T with B = P[:, y] and M = P_yy^-1 D P_yy^-1, written out by blocks: the y rows of B
/// are P_yy itself, so they need no product. With m = |x| and k = |y| it costs
/// k^3 / 6 + 2 m k^2 + m^2 k / 2 multiply-adds (the product over all of B:
/// k^3 / 6 + k^3 + n k^2 + n^2 k / 2, n = m + k); a consensus round fuses most in-state
/// landmarks, so k is a good part of n. Returns the correction, or std::nullopt (P unchanged) if
/// P_yy is not positive definite.
std::optional<Eigen::VectorXd> proposition_two(Eigen::MatrixXd& P, const std::vector<int>& indices,
                                               const Eigen::VectorXd& own_mean,
                                               const Eigen::VectorXd& target_mean,
                                               const Eigen::MatrixXd& target_covariance) {
  const Eigen::Index n = P.rows();
  const auto k = static_cast<Eigen::Index>(indices.size());
  const std::vector<Run> y_runs = runs_of(indices);
  const Eigen::MatrixXd own_covariance = gather(P, y_runs, y_runs, k, k);
  const Eigen::LLT<Eigen::MatrixXd> llt(own_covariance);
  if (llt.info() != Eigen::Success) return std::nullopt;
  std::vector<unsigned char> in_y(static_cast<std::size_t>(n), 0);
  for (int i : indices) in_y[static_cast<std::size_t>(i)] = 1;
  std::vector<int> others;  // x, ascending
  others.reserve(static_cast<std::size_t>(n - k));
  for (int i = 0; i < static_cast<int>(n); ++i) {
    if (!in_y[static_cast<std::size_t>(i)]) others.push_back(i);
  }
  const auto m = static_cast<Eigen::Index>(others.size());
  const Eigen::VectorXd step = target_mean - own_mean;
  Eigen::MatrixXd D = target_covariance - own_covariance;
  D = 0.5 * (D + D.transpose()).eval();

  Eigen::VectorXd correction(n);
  for (Eigen::Index a = 0; a < k; ++a) correction(indices[a]) = step(a);
  // x is most often the leading block of P (the poses, when every in-state landmark is fused):
  // the products then go into P's block directly, and x's rows and columns are blocks.
  const bool leading = m > 0 && others.back() == static_cast<int>(m) - 1;
  if (m > 0) {
    const std::vector<Run> x_runs = runs_of(others);
    const Eigen::MatrixXd gain_transpose = llt.solve(gather(P, y_runs, x_runs, k, m));  // L^T
    correction(others) = gain_transpose.transpose() * step;
    const Eigen::MatrixXd cross = D * gain_transpose;  // (L D)^T, k x m
    if (leading) {
      P.topLeftCorner(m, m).triangularView<Eigen::Lower>() +=
          gain_transpose.transpose() * cross;  // L D L^T
      P.topLeftCorner(m, m).triangularView<Eigen::StrictlyUpper>() =
          P.topLeftCorner(m, m).transpose();
      for (Eigen::Index a = 0; a < k; ++a) {
        P.row(indices[a]).head(m) += cross.row(a);
        P.col(indices[a]).head(m) = P.row(indices[a]).head(m).transpose();
      }
    } else {
      Eigen::MatrixXd update(m, m);
      update.triangularView<Eigen::Lower>() = gain_transpose.transpose() * cross;  // L D L^T
      for (Eigen::Index c = 0; c < m; ++c) {
        const Eigen::Index column = others[c];
        for (Eigen::Index r = c; r < m; ++r) P(others[r], column) += update(r, c);
        for (Eigen::Index a = 0; a < k; ++a) P(indices[a], column) += cross(a, c);
      }
      // The lower triangle of P_xx and every P_yx entry were written: mirror them.
      for (Eigen::Index c = 0; c < m; ++c) {
        const Eigen::Index column = others[c];
        for (Eigen::Index r = c + 1; r < m; ++r) P(column, others[r]) = P(others[r], column);
        for (Eigen::Index a = 0; a < k; ++a) P(column, indices[a]) = P(indices[a], column);
      }
    }
  }
  for (const Run& column : y_runs) {
    for (const Run& row : y_runs) {
      const auto block = target_covariance.block(row.position, column.position, row.length,
                                                 column.length);
      const auto mirrored = target_covariance.block(column.position, row.position,
                                                    column.length, row.length);
      P.block(row.start, column.start, row.length, column.length) =
          0.5 * (block + mirrored.transpose());
    }
  }
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

/// Buffers of proposition_two_single, kept across the landmarks of one consensus step (no
/// allocation per landmark).
struct SingleScratch {
  Eigen::Matrix<double, Eigen::Dynamic, 3> B;
  Eigen::Matrix<double, Eigen::Dynamic, 3> BM;
  Eigen::VectorXd correction;
};

/// Proposition 2 (see proposition_two) for one landmark, coordinates [c, c + 3) of P, with
/// fixed-size algebra. Reads and updates only the lower triangle of P (a sequence of these
/// mirrors P once at its end: see mirror_lower). The mean's correction is left in
/// scratch.correction; false (P unchanged) if the landmark's block is not positive definite.
bool proposition_two_single(Eigen::MatrixXd& P, Eigen::Index c, const Eigen::Vector3d& own_mean,
                            const Eigen::Vector3d& target_mean,
                            const Eigen::Matrix3d& target_covariance, SingleScratch& scratch) {
  const Eigen::Index n = P.rows();
  const Eigen::Matrix3d own_covariance = P.block<3, 3>(c, c).selfadjointView<Eigen::Lower>();
  const Eigen::LLT<Eigen::Matrix3d> llt(own_covariance);
  if (llt.info() != Eigen::Success) return false;
  // B = P[:, c:c+3]: rows above c from the lower triangle's rows c..c+2.
  Eigen::Matrix<double, Eigen::Dynamic, 3>& B = scratch.B;
  B.resize(n, 3);
  B.topRows(c) = P.block(c, 0, 3, c).transpose();
  B.middleRows<3>(c) = own_covariance;
  B.bottomRows(n - c - 3) = P.block(c + 3, c, n - c - 3, 3);
  scratch.correction.resize(n);
  scratch.correction.noalias() = B * llt.solve(target_mean - own_mean);
  const Eigen::Matrix3d half = llt.solve(target_covariance - own_covariance);
  Eigen::Matrix3d M = llt.solve(half.transpose());
  M = 0.5 * (M + M.transpose()).eval();
  scratch.BM.resize(n, 3);
  scratch.BM.noalias() = B * M;
  P.triangularView<Eigen::Lower>() += scratch.BM * B.transpose();
  return true;
}

/// Copies the lower triangle of a square matrix onto its upper one.
void mirror_lower(Eigen::MatrixXd& P) {
  P.triangularView<Eigen::StrictlyUpper>() = P.transpose();
}

/// A landmark's holders: (position among the neighbour members, where it sits in that one's
/// marginal).
using Holder = std::pair<int, const Location*>;
using Holders = std::span<const Holder>;

/// The neighbours' part of one landmark's average (eq. 19) from their 3x3 marginals:
/// sum_j w_j I_j and sum_j w_j I_j m_j, and the weight they take from the robot. A holder whose
/// covariance is not positive definite or ill-conditioned is left out (its weight stays with
/// the robot) and counted.
struct NeighbourShare {
  Eigen::Matrix3d matrix = Eigen::Matrix3d::Zero();
  Eigen::Vector3d vector = Eigen::Vector3d::Zero();
  double weight = 0.0;
  int used = 0;
  int skipped = 0;
};

NeighbourShare neighbour_share(const std::vector<Member>& members, const Holders& holders,
                               double max_condition_number) {
  NeighbourShare share;
  for (const auto& [j, location] : holders) {
    const Member& neighbour = members[j];
    const auto information =
        checked_inverse3(neighbour.covariance(*location), max_condition_number);
    if (!information) {
      ++share.skipped;
      continue;
    }
    share.weight += neighbour.weight;
    share.matrix += neighbour.weight * *information;
    share.vector += neighbour.weight * (*information * neighbour.mean(*location));
    ++share.used;
  }
  return share;
}

/// A Gaussian over a group of landmarks in information form (matrix, vector = matrix * mean).
struct Information {
  Eigen::MatrixXd matrix;
  Eigen::VectorXd vector;
};

/// A member's marginal of `ids` (all in one block of it) in information form; nullopt when its
/// covariance is not positive definite or ill-conditioned.
std::optional<Information> information_of(const Member& member, const std::vector<LandmarkId>& ids,
                                          double max_condition_number) {
  if (ids.size() == 1) {  // most groups: one landmark, with fixed-size (allocation-free) algebra
    const Location& at = *member.find(ids.front());
    const auto matrix = checked_inverse3(member.covariance(at), max_condition_number);
    if (!matrix) return std::nullopt;
    return Information{*matrix, *matrix * member.mean(at)};
  }
  std::vector<Location> at;
  at.reserve(ids.size());
  for (LandmarkId id : ids) at.push_back(*member.find(id));
  Eigen::VectorXd mean;
  Eigen::MatrixXd covariance;
  sub_gaussian(member.marginal->mean, member.marginal->blocks, at, mean, covariance);
  auto matrix = checked_inverse(covariance, max_condition_number);
  if (!matrix) return std::nullopt;
  Information out;
  out.vector = *matrix * mean;
  out.matrix = std::move(*matrix);
  return out;
}

/// The weighted average of eq. (19) in information form (a geometric mean of Gaussians:
/// consistent whatever the correlation between the members, if each is). Returns false when the
/// result is not positive definite.
bool information_average(const std::vector<std::pair<double, Information>>& members,
                         Eigen::VectorXd& mean, Eigen::MatrixXd& covariance) {
  const Eigen::Index d = members.front().second.vector.size();
  double total_weight = 0.0;
  for (const auto& [weight, information] : members) {
    if (information.matrix.diagonal().maxCoeff() > 0.0) total_weight += weight;
  }
  if (!(total_weight > 0.0)) return false;
  Eigen::MatrixXd matrix = Eigen::MatrixXd::Zero(d, d);
  Eigen::VectorXd vector = Eigen::VectorXd::Zero(d);
  for (const auto& [weight, information] : members) {
    if (!(information.matrix.diagonal().maxCoeff() > 0.0)) continue;
    matrix += (weight / total_weight) * information.matrix;
    vector += (weight / total_weight) * information.vector;
  }
  matrix = 0.5 * (matrix + matrix.transpose()).eval();
  const Eigen::LLT<Eigen::MatrixXd> llt(matrix);
  if (llt.info() != Eigen::Success) return false;
  covariance = llt.solve(Eigen::MatrixXd::Identity(d, d));
  covariance = 0.5 * (covariance + covariance.transpose()).eval();
  mean = covariance * vector;
  return mean.allFinite() && covariance.allFinite();
}

/// Records the longest landmark step of an average.
void note_mean_shift(const Eigen::Ref<const Eigen::VectorXd>& own_mean,
                     const Eigen::Ref<const Eigen::VectorXd>& mean, ConsensusReport& report) {
  for (Eigen::Index i = 0; i < own_mean.size(); i += 3) {
    report.largest_mean_shift = std::max(report.largest_mean_shift,
                                         (mean.segment<3>(i) - own_mean.segment<3>(i)).norm());
  }
}

/// A group of landmarks averaged jointly (see Consensus::fuse, step 3).
struct Group {
  bool in_joint_state = false;
  std::span<const std::pair<int, int>> members;  ///< (member, block); the robot is member -1
  std::span<const int> positions;                ///< in `accepted`, ascending
};

}  // namespace

Marginal Consensus::marginal(const State& state, const std::vector<LandmarkId>& ids) {
  Marginal out;
  std::vector<int> slots;
  std::vector<const ObjectEstimate*> archived;
  slots.reserve(ids.size());
  archived.reserve(ids.size());
  for (LandmarkId id : ids) {
    // In-state objects, archived consider states among them, go in one joint block: averaging
    // correlated objects one by one and carrying each average into the state (Proposition 2)
    // was measured to cost accuracy (docs/estimator.md, "Archiving").
    const int slot = state.landmark_slot(id);
    if (slot >= 0) {
      slots.push_back(slot);
    } else if (auto it = state.archived.find(id); it != state.archived.end()) {
      archived.push_back(&it->second);
    }
  }
  out = StateHelper::landmark_marginal(state, slots);
  out.ids.reserve(out.ids.size() + archived.size());
  out.blocks.reserve(out.blocks.size() + archived.size());
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
  // eq. (21): poses move by the correction (left perturbation, see State); landmarks additively.
  StateHelper::apply_correction(state, *correction);
  return true;
}

ConsensusReport Consensus::fuse(State& state, const std::vector<WeightedMarginal>& neighbours,
                                const ConsensusOptions& options) {
  ConsensusReport report;
  report.refused_per_neighbour.assign(neighbours.size(), 0);
  report.tested_per_neighbour.assign(neighbours.size(), 0);

  // 1. The robot's own marginal of everything it holds, and every neighbour's marginal checked
  //    once.
  const Marginal own_marginal = marginal(state, state.object_ids());
  std::vector<Member> neighbour_members;
  for (std::size_t j = 0; j < neighbours.size(); ++j) {
    const Marginal& m = neighbours[j].marginal;
    if (m.ids.empty()) continue;
    // Positive definiteness and conditioning are checked per averaged group, below.
    std::optional<Member> member;
    if (neighbours[j].weight > 0.0 && neighbours[j].weight < 1.0) {
      member = check(m, static_cast<int>(j), neighbours[j].weight);
    }
    if (!member) {
      ++report.neighbours_skipped;
      continue;
    }
    neighbour_members.push_back(std::move(*member));
  }
  double neighbour_weight = 0.0;
  for (const Member& member : neighbour_members) neighbour_weight += member.weight;
  const std::optional<Member> own = check(own_marginal, -1, 1.0 - neighbour_weight);
  if (neighbour_members.empty() || own_marginal.ids.empty() || !own) return report;
  const double refusal_bound =
      options.neighbour_chi2_probability > 0.0
          ? UpdaterHelper::chi2_quantile(options.neighbour_chi2_probability, 3)
          : std::numeric_limits<double>::infinity();

  // 2. For every landmark the robot holds, the neighbours that hold it and agree with the robot
  //    (a neighbour's mean beyond the chi-square bound under the sum of both covariances is
  //    refused: an outlier, a wrong association or a lie; not averaged in, counted).
  // (id, its holders: neighbour position and where the landmark sits in its marginal), by id.
  // Every accepted landmark's holders lie in one buffer (no allocation per landmark).
  std::vector<Holder> holder_buffer;
  std::vector<std::pair<LandmarkId, std::pair<std::size_t, std::size_t>>> accepted_ranges;
  accepted_ranges.reserve(own->locations.size());
  for (const auto& [id, own_at] : own->locations) {  // sorted by id
    const std::size_t first = holder_buffer.size();
    for (std::size_t j = 0; j < neighbour_members.size(); ++j) {
      const Member& neighbour = neighbour_members[j];
      const Location* found = neighbour.find(id);
      if (found == nullptr) continue;
      ++report.tested_per_neighbour[neighbour.index];
      if (options.neighbour_chi2_probability > 0.0) {
        const Eigen::Vector3d difference = neighbour.mean(*found) - own->mean(own_at);
        const Eigen::LLT<Eigen::Matrix3d> sum(own->covariance(own_at) +
                                              neighbour.covariance(*found));
        if (sum.info() != Eigen::Success ||
            !(difference.dot(sum.solve(difference)) <= refusal_bound)) {
          ++report.landmarks_refused;
          ++report.refused_per_neighbour[neighbour.index];
          continue;
        }
      }
      holder_buffer.emplace_back(static_cast<int>(j), found);
    }
    if (holder_buffer.size() > first) accepted_ranges.push_back({id, {first, holder_buffer.size()}});
  }
  std::vector<std::pair<LandmarkId, Holders>> accepted;
  accepted.reserve(accepted_ranges.size());
  for (const auto& [id, range] : accepted_ranges) {
    accepted.emplace_back(
        id, Holders(holder_buffer.data() + range.first, range.second - range.first));
  }

  // 2b. Event-triggered fusion (consensus.fuse_kl_threshold): a landmark whose average, from
  //     the 3x3 marginals, is within the threshold of the robot's own is left out of the round.
  if (options.fuse_kl_threshold > 0.0) {
    const auto settled = [&](const std::pair<LandmarkId, Holders>& entry) {
      const auto& [id, offered] = entry;
      const Location& own_at = *own->find(id);
      ObjectEstimate current{id, own->mean(own_at), own->covariance(own_at)};
      const auto own_information =
          checked_inverse3(current.covariance, options.max_condition_number);
      if (!own_information) return false;  // fused (or refused) as usual below
      NeighbourShare share =
          neighbour_share(neighbour_members, offered, options.max_condition_number);
      const double own_weight = 1.0 - share.weight;
      share.matrix += own_weight * *own_information;
      share.vector += own_weight * (*own_information * current.p_world);
      const Eigen::LLT<Eigen::Matrix3d> average(share.matrix);
      if (average.info() != Eigen::Success) return false;
      ObjectEstimate step{id, average.solve(share.vector),
                          average.solve(Eigen::Matrix3d::Identity())};
      return kl_divergence(step, current) <= options.fuse_kl_threshold;
    };
    const auto kept = std::remove_if(accepted.begin(), accepted.end(), settled);
    report.landmarks_settled = static_cast<int>(accepted.end() - kept);
    accepted.erase(kept, accepted.end());
  }

  // 3. The weighted average (eq. 19) of landmarks grouped by (in joint state?, and for the
  //    robot and each holder the block of its marginal that holds the landmark). A marginal claims nothing about
  //    the correlation of landmarks in different blocks (archived objects lost theirs), so only
  //    landmarks that share a block in every member's contribution are averaged jointly;
  //    averaging them jointly as if independent would credit the member with information it
  //    does not have (e.g. on their common offset) and make the robot overconfident. In-state
  //    groups are replaced one after another on the joint marginal of all in-state landmarks
  //    being fused (U): replacing a group's marginal keeps the conditional of the rest given it,
  //    so p(rest of the state | U) never changes and the sequence of replacements equals one
  //    replacement of U's marginal at the end (Proposition 2 once, not per group).
  //    A landmark's key: (in the joint state?, (member, block) of each holder and of the robot);
  //    the groups are the runs of equal keys, in the keys' lexicographic order, each run's
  //    landmarks in the order of `accepted` (a stable sort of flat keys: no allocation per
  //    landmark).
  std::vector<std::pair<int, int>> key_members;  // every landmark's (member, block), flat
  std::vector<std::size_t> key_start(accepted.size() + 1, 0);
  std::vector<unsigned char> key_joint(accepted.size(), 0);
  key_members.reserve(holder_buffer.size() + accepted.size());
  for (std::size_t a = 0; a < accepted.size(); ++a) {
    const auto& [id, holders] = accepted[a];
    key_start[a] = key_members.size();
    for (const auto& [j, at] : holders) key_members.emplace_back(j, at->block);
    key_members.emplace_back(-1, own->find(id)->block);
    key_joint[a] = state.landmark_slot(id) >= 0 ? 1 : 0;
  }
  key_start[accepted.size()] = key_members.size();
  const auto key_of = [&](int a) {
    return std::span<const std::pair<int, int>>(key_members.data() + key_start[a],
                                                key_start[a + 1] - key_start[a]);
  };
  const auto key_less = [&](int a, int b) {
    if (key_joint[a] != key_joint[b]) return key_joint[a] < key_joint[b];
    const auto x = key_of(a), y = key_of(b);
    return std::lexicographical_compare(x.begin(), x.end(), y.begin(), y.end());
  };
  std::vector<int> order(accepted.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), key_less);
  std::vector<Group> groups;
  for (std::size_t begin = 0; begin < order.size();) {
    std::size_t end = begin + 1;
    while (end < order.size() && !key_less(order[begin], order[end])) ++end;
    groups.push_back({key_joint[order[begin]] != 0, key_of(order[begin]),
                      std::span<const int>(order.data() + begin, end - begin)});
    begin = end;
  }
  std::vector<int> union_slots;
  std::vector<int> union_position(accepted.size(), -1);  // by position in accepted
  for (const Group& group : groups) {
    if (!group.in_joint_state) continue;
    for (int a : group.positions) {
      union_position[a] = static_cast<int>(union_slots.size());
      union_slots.push_back(state.landmark_slot(accepted[a].first));
    }
  }
  Eigen::VectorXd union_mean;
  Eigen::MatrixXd union_covariance;
  if (!union_slots.empty()) {
    Marginal own_union = StateHelper::landmark_marginal(state, union_slots);
    union_mean = std::move(own_union.mean);
    union_covariance = std::move(own_union.blocks.front());
  }
  int union_fused = 0;
  int union_groups = 0;
  // Single-landmark replacements update only U's lower triangle; it is mirrored before anything
  // reads U whole.
  bool union_lower_only = false;
  SingleScratch scratch;
  for (const Group& group : groups) {
    const bool in_joint_state = group.in_joint_state;
    const std::span<const std::pair<int, int>> members = group.members;
    const std::span<const int> positions = group.positions;
    if (positions.size() == 1) {
      // Most groups: one landmark. The same average and replacement as below, with fixed-size
      // algebra and no allocation.
      const auto& [id, holders] = accepted[positions.front()];
      const NeighbourShare share =
          neighbour_share(neighbour_members, holders, options.max_condition_number);
      report.neighbours_skipped += share.skipped;  // their weight stays with the robot
      if (share.used == 0) continue;
      Eigen::Matrix3d matrix = share.matrix;
      Eigen::Vector3d vector = share.vector;
      const double own_weight = 1.0 - share.weight;
      const Eigen::Index c = in_joint_state ? 3 * union_position[positions.front()] : 0;
      ObjectEstimate* archived = in_joint_state ? nullptr : &state.archived.at(id);
      const Eigen::Vector3d own_mean =
          in_joint_state ? Eigen::Vector3d(union_mean.segment<3>(c)) : archived->p_world;
      const Eigen::Matrix3d own_covariance =
          in_joint_state
              ? Eigen::Matrix3d(union_covariance.block<3, 3>(c, c).selfadjointView<Eigen::Lower>())
              : archived->covariance;
      const Eigen::LLT<Eigen::Matrix3d> own_llt(own_covariance);
      if (own_llt.info() != Eigen::Success) continue;
      Eigen::Matrix3d own_information = own_llt.solve(Eigen::Matrix3d::Identity());
      own_information = 0.5 * (own_information + own_information.transpose()).eval();
      matrix += own_weight * own_information;
      vector += own_weight * (own_information * own_mean);
      matrix = 0.5 * (matrix + matrix.transpose()).eval();
      const Eigen::LLT<Eigen::Matrix3d> average(matrix);
      if (average.info() != Eigen::Success) continue;
      Eigen::Matrix3d covariance = average.solve(Eigen::Matrix3d::Identity());
      covariance = 0.5 * (covariance + covariance.transpose()).eval();
      const Eigen::Vector3d mean = covariance * vector;
      if (!mean.allFinite() || !covariance.allFinite()) continue;
      note_mean_shift(own_mean, mean, report);
      if (!in_joint_state) {
        archived->p_world = mean;
        archived->covariance = covariance;
        ++report.landmarks_fused;
        ++report.groups;
        continue;
      }
      if (!proposition_two_single(union_covariance, c, own_mean, mean, covariance, scratch)) {
        continue;
      }
      union_lower_only = true;
      union_mean += scratch.correction;
      ++union_fused;
      ++union_groups;
      continue;
    }
    std::vector<LandmarkId> ids;
    ids.reserve(positions.size());
    for (int a : positions) ids.push_back(accepted[a].first);
    std::vector<std::pair<double, Information>> shares;
    double own_weight = 1.0;
    for (const auto& [j, block] : members) {
      if (j < 0) continue;
      const Member& neighbour = neighbour_members[j];
      if (auto information = information_of(neighbour, ids, options.max_condition_number)) {
        own_weight -= neighbour.weight;
        shares.emplace_back(neighbour.weight, std::move(*information));
      } else {
        ++report.neighbours_skipped;  // its weight stays with the robot
      }
    }
    if (shares.empty()) continue;  // no usable neighbour: nothing to average
    // The robot's own marginal as it is now: after the groups replaced before this one (the
    // replacements are sequential Bayesian steps; see above).
    std::vector<int> indices;  // coordinates of an in-state group in U
    Eigen::VectorXd own_mean;
    Eigen::MatrixXd own_covariance;
    if (in_joint_state) {
      if (union_lower_only) {
        mirror_lower(union_covariance);
        union_lower_only = false;
      }
      for (int a : positions) {
        for (int k = 0; k < 3; ++k) indices.push_back(3 * union_position[a] + k);
      }
      own_mean = union_mean(indices);
      own_covariance = union_covariance(indices, indices);
    } else {
      const ObjectEstimate& estimate = state.archived.at(ids.front());
      own_mean = estimate.p_world;
      own_covariance = estimate.covariance;
    }
    const Eigen::LLT<Eigen::MatrixXd> own_llt(own_covariance);
    if (own_llt.info() != Eigen::Success) continue;
    Information own_information;
    own_information.matrix =
        own_llt.solve(Eigen::MatrixXd::Identity(own_covariance.rows(), own_covariance.rows()));
    own_information.matrix =
        0.5 * (own_information.matrix + own_information.matrix.transpose()).eval();
    own_information.vector = own_information.matrix * own_mean;
    shares.emplace_back(own_weight, std::move(own_information));
    Eigen::VectorXd mean;
    Eigen::MatrixXd covariance;
    if (!information_average(shares, mean, covariance)) continue;

    if (!in_joint_state) {
      // An archived object (each is its own group): independent of the state, set directly.
      ObjectEstimate& estimate = state.archived.at(ids.front());
      note_mean_shift(estimate.p_world, mean, report);
      estimate.p_world = mean;
      estimate.covariance = covariance;
      ++report.landmarks_fused;
      ++report.groups;
      continue;
    }
    note_mean_shift(own_mean, mean, report);
    if (!replace_gaussian_marginal(union_mean, union_covariance, indices, mean, covariance)) {
      continue;
    }
    union_fused += static_cast<int>(ids.size());
    ++union_groups;
  }
  if (union_lower_only) mirror_lower(union_covariance);
  if (union_groups > 0 && replace_marginal(state, union_slots, union_mean, union_covariance)) {
    report.landmarks_fused += union_fused;
    report.groups += union_groups;
  }

  return report;
}

std::optional<ObjectEstimate> Consensus::covariance_intersection(const ObjectEstimate& a,
                                                               const ObjectEstimate& b) {
  const Eigen::LLT<Eigen::Matrix3d> llt_a(a.covariance);
  const Eigen::LLT<Eigen::Matrix3d> llt_b(b.covariance);
  if (llt_a.info() != Eigen::Success || llt_b.info() != Eigen::Success ||
      !a.p_world.allFinite() || !b.p_world.allFinite()) {
    return std::nullopt;
  }
  const Eigen::Matrix3d information_a = llt_a.solve(Eigen::Matrix3d::Identity());
  const Eigen::Matrix3d information_b = llt_b.solve(Eigen::Matrix3d::Identity());
  // The fused covariance's determinant is 1 / det(w I_a + (1 - w) I_b), and log det of that
  // information is concave in w: golden-section search for its maximum.
  const auto log_information = [&](double w) {
    return std::log((w * information_a + (1.0 - w) * information_b).determinant());
  };
  const double golden = 0.5 * (std::sqrt(5.0) - 1.0);
  double low = 0.0, high = 1.0;
  double left = high - golden * (high - low), right = low + golden * (high - low);
  double value_left = log_information(left), value_right = log_information(right);
  for (int iteration = 0; iteration < 40; ++iteration) {
    if (value_left < value_right) {
      low = left;
      left = right;
      value_left = value_right;
      right = low + golden * (high - low);
      value_right = log_information(right);
    } else {
      high = right;
      right = left;
      value_right = value_left;
      left = high - golden * (high - low);
      value_left = log_information(left);
    }
  }
  double w = 0.5 * (low + high);
  // The ends are candidates too (one estimate may be better in every direction).
  for (double end : {0.0, 1.0}) {
    if (log_information(end) > log_information(w)) w = end;
  }
  const Eigen::Matrix3d information = w * information_a + (1.0 - w) * information_b;
  const Eigen::LLT<Eigen::Matrix3d> llt(information);
  if (llt.info() != Eigen::Success) return std::nullopt;
  ObjectEstimate fused;
  fused.id = a.id;
  fused.covariance = llt.solve(Eigen::Matrix3d::Identity());
  fused.covariance = 0.5 * (fused.covariance + fused.covariance.transpose()).eval();
  fused.p_world = fused.covariance * (w * information_a * a.p_world + (1.0 - w) * information_b * b.p_world);
  return fused;
}

double Consensus::metropolis_weight(int degree_i, int degree_j) {
  return 1.0 / (1.0 + static_cast<double>(std::max(degree_i, degree_j)));
}

}  // namespace concord

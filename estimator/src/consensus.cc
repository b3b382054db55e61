#include "concord/estimator/consensus.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cassert>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <optional>
#include <span>
#include <vector>

#include "concord/estimator/marginal_sharing.h"
#include "concord/estimator/state_helper.h"
#include "concord/estimator/symmetric3.h"
#include "concord/estimator/updater_helper.h"

namespace concord {

// Helpers of this file. A named namespace, not an anonymous one: ConsensusWorkspace::Buffers
// (declared in the header) holds them.
namespace consensus_internal {

using symmetric3::inverse_quadratic;
using symmetric3::Lower;
using symmetric3::lower_of;
using symmetric3::positive_definite_inverse;

using MatrixMap = Eigen::Map<Eigen::MatrixXd>;
using VectorMap = Eigen::Map<Eigen::VectorXd>;

/// Storage for a dynamic-size matrix or vector that grows to the largest size asked for and is
/// then reused: once the sizes of a round have been seen, its views allocate nothing (issue 13:
/// no heap churn a consensus round). A view is valid until the next call on the same scratch.
class Scratch {
 public:
  template <typename Matrix = Eigen::MatrixXd>
  Eigen::Map<Matrix> matrix(Eigen::Index rows, Eigen::Index cols) {
    reserve(rows * cols);
    return {storage_.data(), rows, cols};
  }
  VectorMap vector(Eigen::Index size) {
    reserve(size);
    return {storage_.data(), size};
  }

 private:
  void reserve(Eigen::Index size) {
    // std::vector grows geometrically: a run that grows its map reallocates O(log) times.
    if (storage_.size() < static_cast<std::size_t>(size)) {
      storage_.resize(static_cast<std::size_t>(size));
    }
  }
  /// Aligned to Eigen's widest packet: a product or sum over a view starts its vector loop where
  /// the address allows, so with malloc's 16-byte alignment and 32-byte packets (a build for
  /// x86-64-v3) the rounding would hang on where the heap put the buffer.
  std::vector<double, Eigen::aligned_allocator<double>> storage_;
};

/// Makes a square matrix symmetric in place, 0.5 (A + A^T), element pair by element pair.
void symmetrize(Eigen::Ref<Eigen::MatrixXd> A) {
  for (Eigen::Index c = 0; c < A.cols(); ++c) {
    for (Eigen::Index r = c + 1; r < A.rows(); ++r) {
      const double mean = 0.5 * (A(r, c) + A(c, r));
      A(r, c) = mean;
      A(c, r) = mean;
    }
  }
}

/// Where a landmark sits in a block-diagonal marginal (or, for the robot itself, in its state).
struct Location {
  int position = 0;  ///< index in ids (the robot: slot in the state, or index among archived)
  int block = 0;     ///< index in blocks (the robot: 0 for the joint state, 1 + i archived)
  int offset = 0;    ///< row of its first coordinate in that block (the robot: in the state)
};

using Locations = std::vector<std::pair<LandmarkId, Location>>;

/// Sorts locations by id. They most often come as two ascending runs (a marginal's joint block,
/// then its archived objects; the robot's: the state, then the archive): those are merged
/// through `spare` in linear time, anything else is sorted.
void sort_by_id(Locations& locations, Locations& spare) {
  const auto by_id = [](const auto& a, const auto& b) { return a.first < b.first; };
  const auto middle = std::is_sorted_until(locations.begin(), locations.end(), by_id);
  if (middle == locations.end()) return;
  if (!std::is_sorted(middle, locations.end(), by_id)) {
    std::sort(locations.begin(), locations.end(), by_id);
    return;
  }
  spare.resize(locations.size());
  std::merge(locations.begin(), middle, middle, locations.end(), spare.begin(), by_id);
  std::copy(spare.begin(), spare.end(), locations.begin());
}

/// Fills `locations` with (id, location) of every landmark of a block-diagonal Gaussian, sorted
/// by id; false when an id repeats.
bool locate(const std::vector<LandmarkId>& ids, const std::vector<Eigen::MatrixXd>& blocks,
            Locations& locations, Locations& spare) {
  locations.clear();
  int position = 0;
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    for (Eigen::Index offset = 0; offset < blocks[b].rows(); offset += 3) {
      locations.push_back({ids[position], {position, static_cast<int>(b), static_cast<int>(offset)}});
      ++position;
    }
  }
  sort_by_id(locations, spare);
  const auto repeated = std::adjacent_find(
      locations.begin(), locations.end(), [](const auto& a, const auto& b) { return a.first == b.first; });
  return repeated == locations.end();
}

const Location* find_location(const Locations& locations, LandmarkId id) {
  const auto it = std::lower_bound(
      locations.begin(), locations.end(), id,
      [](const std::pair<LandmarkId, Location>& entry, LandmarkId key) { return entry.first < key; });
  return it != locations.end() && it->first == id ? &it->second : nullptr;
}

/// A member of an average: a neighbour (its marginal checked once) or the robot itself (read
/// from its state: the in-state objects one joint block, each archived object a block of its
/// own, as Consensus::marginal would give them), with its weight and where each id sits.
struct Member {
  int index = -1;  ///< position in the neighbours given to fuse(), -1 for the robot itself
  int sender = -1;  ///< a neighbour's robot id (WeightedMarginal::sender), -1 if not given
  double weight = 0.0;
  const Marginal* marginal = nullptr;  ///< a neighbour's
  const State* state = nullptr;        ///< the robot's
  const std::vector<const ObjectEstimate*>* archived = nullptr;  ///< the robot's, by position
  Locations owned;                    ///< where each id sits, unless shared
  const Locations* shared = nullptr;  ///< a shared marginal's, indexed once

  const Locations& locations() const { return shared != nullptr ? *shared : owned; }
  const Location* find(LandmarkId id) const { return find_location(locations(), id); }
  Eigen::Vector3d mean(const Location& at) const {
    if (marginal != nullptr) return marginal->mean.segment<3>(3 * at.position);
    return at.block == 0 ? state->landmarks[at.position].p_world : (*archived)[at.position]->p_world;
  }
  Eigen::Matrix3d covariance(const Location& at) const {
    if (marginal != nullptr) return marginal->blocks[at.block].block<3, 3>(at.offset, at.offset);
    return at.block == 0 ? Eigen::Matrix3d(state->covariance.block<3, 3>(at.offset, at.offset))
                         : (*archived)[at.position]->covariance;
  }
};

/// Checks a neighbour's marginal (shapes, finite values, no repeated id) into `member`; false
/// when malformed.
bool check(const Marginal& marginal, int index, double weight, Member& member, Locations& spare) {
  if (!marginal.well_formed()) return false;
  if (!locate(marginal.ids, marginal.blocks, member.owned, spare)) return false;
  member.shared = nullptr;
  member.index = index;
  member.sender = -1;
  member.weight = weight;
  member.marginal = &marginal;
  member.state = nullptr;
  member.archived = nullptr;
  return true;
}

/// The robot itself as a member: every object it holds, in its state or archived.
void own_member(const State& state, double weight, std::vector<const ObjectEstimate*>& archived,
                Member& member, Locations& spare) {
  member.index = -1;
  member.sender = -1;
  member.weight = weight;
  member.marginal = nullptr;
  member.state = &state;
  member.archived = &archived;
  member.shared = nullptr;
  member.owned.clear();
  archived.clear();
  for (int slot = 0; slot < state.num_landmarks(); ++slot) {
    if (state.landmarks[slot].detection_offset) continue;  // the robot's own, not an object
    member.owned.push_back({state.landmarks[slot].id, {slot, 0, state.landmark_index(slot)}});
  }
  for (const auto& [id, estimate] : state.archived) {
    const auto position = static_cast<int>(archived.size());
    member.owned.push_back({id, {position, 1 + position, 0}});
    archived.push_back(&estimate);
  }
  sort_by_id(member.owned, spare);
}

/// The inverse of a covariance, into `inverse` (symmetrised), if the covariance is positive
/// definite and its 1-norm condition number ||P||_1 ||P^-1||_1, exact from the inverse, is at
/// most max_condition_number. `factor` is a buffer of the covariance's size.
bool checked_inverse(const Eigen::Ref<const Eigen::MatrixXd>& covariance,
                     double max_condition_number, Eigen::Ref<Eigen::MatrixXd> factor,
                     Eigen::Ref<Eigen::MatrixXd> inverse) {
  factor = covariance;
  const Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(factor);  // in place
  if (llt.info() != Eigen::Success) return false;
  inverse.setIdentity();
  llt.solveInPlace(inverse);
  symmetrize(inverse);
  const double condition = covariance.cwiseAbs().colwise().sum().maxCoeff() *
                           inverse.cwiseAbs().colwise().sum().maxCoeff();
  return condition <= max_condition_number;
}

/// The largest absolute column sum of a 3x3 matrix (its 1-norm).
double norm1(const Eigen::Matrix3d& A) { return A.cwiseAbs().colwise().sum().maxCoeff(); }

/// checked_inverse for one landmark's 3x3 covariance (read as symmetric, from its lower
/// triangle), in closed form (positive_definite_inverse).
std::optional<Eigen::Matrix3d> checked_inverse3(const Eigen::Matrix3d& covariance,
                                                double max_condition_number) {
  auto inverse = positive_definite_inverse(covariance);
  if (!inverse) return std::nullopt;
  const double condition = norm1(covariance.selfadjointView<Eigen::Lower>()) * norm1(*inverse);
  if (!(condition <= max_condition_number)) return std::nullopt;
  return inverse;
}

/// What each neighbour claimed about each landmark in recent rounds
/// (ConsensusOptions::claim_history_rounds). For one landmark and neighbour the claims kept are
/// a ladder: each at least twice as certain (covariance trace at most half) as the one kept
/// before it, none older than the window. Two consistent estimates a, b of one static
/// landmark, whatever their correlation, differ by an error of covariance at most
/// 2 (P_a + P_b) (since (a - b)(a - b)^T <= 2 a a^T + 2 b b^T): a new claim is tested against
/// every claim kept under that bound. A claim more certain than it is shows once its mean
/// moves by more than its covariance allows. Entries not claimed for a window are dropped, so
/// the history holds at most (neighbours) x (landmarks claimed in a window) entries.
class ClaimHistory {
 public:
  /// Starts a round (fuse call) with the given window; forgets what is older.
  void begin_round(int window) {
    ++round_;
    if (window != window_) {
      window_ = window;
      keys_.clear();
      entries_.clear();
      fresh_.clear();
    }
    const bool sweep = round_ % static_cast<std::uint64_t>(window_) == 0;
    // New keys wait in a tree until they are an eighth of the rest (each entry then moves a
    // bounded number of times on average); all at once before a sweep.
    if (sweep || fresh_.size() > std::max<std::size_t>(64, keys_.size() / 8)) merge(sweep);
    cursor_ = 0;
  }

  /// Tests a claim of `sender` about landmark `id` against the sender's earlier ones and, if it
  /// is consistent with them, keeps it. False: inconsistent (the claim is not kept).
  bool consistent(int sender, LandmarkId id, const Eigen::Vector3d& mean,
                  const Eigen::Matrix3d& covariance, double bound) {
    Entry& entry = find({id, sender});
    // Not claimed within the window: forgotten (the neighbour may have lost and found it again).
    if (expired(entry.last)) entry.count = 0;
    entry.last = round_;
    const Lower claimed = lower_of(covariance);
    for (int k = 0; k < entry.count; ++k) {
      const Claim& earlier = entry.claims[k];
      Lower sum;  // 2 (P_earlier + P): the factor 2 is exact in floating point
      for (std::size_t e = 0; e < sum.size(); ++e) {
        sum[e] = 2.0 * earlier.covariance[e] + 2.0 * claimed[e];
      }
      const Eigen::Vector3d difference(mean(0) - earlier.mean[0], mean(1) - earlier.mean[1],
                                       mean(2) - earlier.mean[2]);
      const auto distance = inverse_quadratic(sum, difference);
      if (!distance || !(*distance <= bound)) return false;
    }
    // Consistent: claims older than the window give way (only now, so that a neighbour that
    // keeps making an inconsistent claim is tested against the last consistent ones for as
    // long as it does; the ladder is in the order kept, oldest first).
    int first = 0;
    while (first < entry.count && expired(entry.claims[first].round)) ++first;
    if (first > 0) {
      std::move(entry.claims.begin() + first, entry.claims.begin() + entry.count,
                entry.claims.begin());
      entry.count -= first;
    }
    const double trace = claimed[0] + claimed[3] + claimed[5];
    if (entry.count == 0 || trace <= 0.5 * entry.claims[entry.count - 1].trace()) {
      if (entry.count == kLadder) {  // the oldest, least certain claim gives way
        std::move(entry.claims.begin() + 1, entry.claims.end(), entry.claims.begin());
        --entry.count;
      }
      entry.claims[entry.count++] = {{mean(0), mean(1), mean(2)}, claimed, round_};
    }
    return true;
  }

 private:
  static constexpr int kLadder = 8;
  struct Claim {
    std::array<double, 3> mean{};
    Lower covariance{};
    std::uint64_t round = 0;
    double trace() const { return covariance[0] + covariance[3] + covariance[5]; }
  };
  struct Entry {
    std::uint64_t last = 0;
    int count = 0;
    std::array<Claim, kLadder> claims;
  };
  using Key = std::pair<LandmarkId, int>;  // (landmark, sender)

  bool expired(std::uint64_t round) const {
    return round_ - round > static_cast<std::uint64_t>(window_);
  }

  /// The entry of (landmark, sender). A round asks in ascending landmark order (the fuse walks
  /// the robot's landmarks by id, each landmark's neighbours in turn), and the entries are
  /// sorted the same way, so a cursor finds each reading the history once, front to back: the
  /// history is larger than the caches, and a sequential read is what keeps it cheap. New keys
  /// wait in `fresh_` until the next merge.
  Entry& find(const Key& key) {
    if (cursor_ > 0 && keys_[cursor_ - 1].first > key.first) cursor_ = 0;  // out of order
    while (cursor_ < keys_.size() && keys_[cursor_].first < key.first) ++cursor_;
    for (std::size_t k = cursor_; k < keys_.size() && keys_[k].first == key.first; ++k) {
      if (keys_[k].second == key.second) return entries_[k];
    }
    return fresh_[key];
  }

  /// Merges the waiting keys in, from the back (few entries move where the new keys are the
  /// highest); with `sweep`, drops the entries not claimed within the window.
  void merge(bool sweep) {
    std::size_t old = keys_.size();
    keys_.resize(old + fresh_.size());
    entries_.resize(old + fresh_.size());
    auto next = fresh_.rbegin();
    for (std::size_t to = keys_.size(); next != fresh_.rend();) {
      --to;
      if (old > 0 && keys_[old - 1] > next->first) {
        --old;
        keys_[to] = keys_[old];
        entries_[to] = entries_[old];
      } else {
        keys_[to] = next->first;
        entries_[to] = next->second;
        ++next;
      }
    }
    fresh_.clear();
    if (!sweep) return;
    std::size_t kept = 0;
    for (std::size_t k = 0; k < keys_.size(); ++k) {
      if (expired(entries_[k].last)) continue;
      if (kept != k) {
        keys_[kept] = keys_[k];
        entries_[kept] = entries_[k];
      }
      ++kept;
    }
    keys_.resize(kept);
    entries_.resize(kept);
  }

  std::uint64_t round_ = 0;
  int window_ = 0;
  std::vector<Key> keys_;       // sorted
  std::vector<Entry> entries_;  // entries_[k] is keys_[k]'s
  std::map<Key, Entry> fresh_;  // new keys, not merged yet
  std::size_t cursor_ = 0;
};

/// Mean and covariance of the landmarks at `at` (all in one block) of a neighbour's
/// block-diagonal marginal, into buffers of size 3k and 3k x 3k.
void sub_gaussian(const Marginal& marginal, const std::vector<Location>& at,
                  Eigen::Ref<Eigen::VectorXd> mean, Eigen::Ref<Eigen::MatrixXd> covariance) {
  const auto k = static_cast<Eigen::Index>(at.size());
  for (Eigen::Index a = 0; a < k; ++a) {
    mean.segment<3>(3 * a) = marginal.mean.segment<3>(3 * at[a].position);
    const Eigen::MatrixXd& block = marginal.blocks[at[a].block];
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
/// are one run at least; the poses one long one), into `runs`.
void runs_of(const std::vector<int>& indices, std::vector<Run>& runs) {
  runs.clear();
  for (std::size_t i = 0; i < indices.size(); ++i) {
    if (!runs.empty() && runs.back().start + runs.back().length == indices[i]) {
      ++runs.back().length;
    } else {
      runs.push_back({indices[i], 1, static_cast<Eigen::Index>(i)});
    }
  }
}

/// P(rows, columns) for index lists given as runs, copied block by block into `out`.
void gather(const Eigen::Ref<const Eigen::MatrixXd>& P, const std::vector<Run>& rows,
            const std::vector<Run>& columns, Eigen::Ref<Eigen::MatrixXd> out) {
  for (const Run& column : columns) {
    for (const Run& row : rows) {
      out.block(row.position, column.position, row.length, column.length) =
          P.block(row.start, column.start, row.length, column.length);
    }
  }
}

/// Copies the lower triangle of a square matrix onto its upper one, in 8x8 tiles, so that
/// neither the reads nor the writes stride a whole column apart element after element.
void mirror_lower(Eigen::Ref<Eigen::MatrixXd> P) {
  constexpr Eigen::Index tile = 8;
  const Eigen::Index n = P.rows();
  for (Eigen::Index c = 0; c < n; c += tile) {
    const Eigen::Index width = std::min(tile, n - c);
    P.block(c, c, width, width).triangularView<Eigen::StrictlyUpper>() =
        P.block(c, c, width, width).transpose();
    for (Eigen::Index r = c + width; r < n; r += tile) {
      const Eigen::Index height = std::min(tile, n - r);
      P.block(c, r, width, height) = P.block(r, c, height, width).transpose();
    }
  }
}

/// Buffers of proposition_two, kept across calls.
struct PropositionTwoScratch {
  std::vector<Run> y_runs;
  std::vector<Run> x_runs;
  std::vector<unsigned char> in_y;
  std::vector<int> others;
  Scratch own_covariance, factor, step, difference, correction, gain, cross, update, x_correction;
};

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
/// landmarks, so k is a good part of n. Returns false (P unchanged) if P_yy is not positive
/// definite; otherwise the mean's correction is scratch.correction.vector(n).
bool proposition_two(Eigen::Ref<Eigen::MatrixXd> P, const std::vector<int>& indices,
                     const Eigen::Ref<const Eigen::VectorXd>& own_mean,
                     const Eigen::Ref<const Eigen::VectorXd>& target_mean,
                     const Eigen::Ref<const Eigen::MatrixXd>& target_covariance,
                     PropositionTwoScratch& scratch) {
  const Eigen::Index n = P.rows();
  const auto k = static_cast<Eigen::Index>(indices.size());
  std::vector<Run>& y_runs = scratch.y_runs;
  runs_of(indices, y_runs);
  MatrixMap own_covariance = scratch.own_covariance.matrix(k, k);
  gather(P, y_runs, y_runs, own_covariance);
  MatrixMap factor = scratch.factor.matrix(k, k);
  factor = own_covariance;
  const Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(factor);  // in place
  if (llt.info() != Eigen::Success) return false;
  scratch.in_y.assign(static_cast<std::size_t>(n), 0);
  for (int i : indices) scratch.in_y[static_cast<std::size_t>(i)] = 1;
  std::vector<int>& others = scratch.others;  // x, ascending
  others.clear();
  for (int i = 0; i < static_cast<int>(n); ++i) {
    if (!scratch.in_y[static_cast<std::size_t>(i)]) others.push_back(i);
  }
  const auto m = static_cast<Eigen::Index>(others.size());
  VectorMap step = scratch.step.vector(k);
  step = target_mean - own_mean;
  MatrixMap D = scratch.difference.matrix(k, k);
  D = target_covariance - own_covariance;
  symmetrize(D);

  VectorMap correction = scratch.correction.vector(n);
  for (Eigen::Index a = 0; a < k; ++a) correction(indices[a]) = step(a);
  // x is most often the leading block of P (the poses, when every in-state landmark is fused):
  // the products then go into P's block directly, and x's rows and columns are blocks.
  const bool leading = m > 0 && others.back() == static_cast<int>(m) - 1;
  if (m > 0) {
    runs_of(others, scratch.x_runs);
    // L = P_xy P_yy^-1, solved from the right (the trsm kernel is faster with the many
    // right-hand sides as rows than as columns).
    MatrixMap gain = scratch.gain.matrix(m, k);
    gather(P, scratch.x_runs, y_runs, gain);
    llt.matrixU().solveInPlace<Eigen::OnTheRight>(gain);
    llt.matrixL().solveInPlace<Eigen::OnTheRight>(gain);
    VectorMap x_correction = scratch.x_correction.vector(m);
    x_correction.noalias() = gain * step;
    for (Eigen::Index c = 0; c < m; ++c) correction(others[c]) = x_correction(c);
    MatrixMap cross = scratch.cross.matrix(m, k);  // L D
    cross.noalias() = gain * D;
    if (leading) {
      P.topLeftCorner(m, m).triangularView<Eigen::Lower>() += cross * gain.transpose();  // L D L^T
      mirror_lower(P.topLeftCorner(m, m));
      for (const Run& run : y_runs) {
        P.block(0, run.start, m, run.length) += cross.middleCols(run.position, run.length);
        P.block(run.start, 0, run.length, m) = P.block(0, run.start, m, run.length).transpose();
      }
    } else {
      MatrixMap update = scratch.update.matrix(m, m);
      update.triangularView<Eigen::Lower>() = cross * gain.transpose();  // L D L^T
      for (Eigen::Index c = 0; c < m; ++c) {
        const Eigen::Index column = others[c];
        for (Eigen::Index r = c; r < m; ++r) P(others[r], column) += update(r, c);
      }
      for (Eigen::Index a = 0; a < k; ++a) {
        const Eigen::Index column = indices[a];
        for (Eigen::Index r = 0; r < m; ++r) P(others[r], column) += cross(r, a);
      }
      // The lower triangle of P_xx and every P_xy entry were written: mirror them.
      for (Eigen::Index c = 0; c < m; ++c) {
        const Eigen::Index column = others[c];
        for (Eigen::Index r = c + 1; r < m; ++r) P(column, others[r]) = P(others[r], column);
      }
      for (Eigen::Index a = 0; a < k; ++a) {
        const Eigen::Index column = indices[a];
        for (Eigen::Index r = 0; r < m; ++r) P(column, others[r]) = P(others[r], column);
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
  return true;
}

/// Buffers of proposition_two_single, kept across the landmarks of one consensus step and
/// across steps.
struct SingleScratch {
  Scratch B;
  Scratch BM;
  Scratch correction;
};

/// Proposition 2 (see proposition_two) for one landmark, coordinates [c, c + 3) of P, with
/// fixed-size algebra. Reads and updates only the lower triangle of P (a sequence of these
/// mirrors P once at its end: see mirror_lower). The mean's correction is left in
/// scratch.correction.vector(n); false (P unchanged) if the landmark's block is not positive
/// definite.
bool proposition_two_single(Eigen::Ref<Eigen::MatrixXd> P, Eigen::Index c,
                            const Eigen::Vector3d& own_mean, const Eigen::Vector3d& target_mean,
                            const Eigen::Matrix3d& target_covariance, SingleScratch& scratch) {
  using Columns3 = Eigen::Matrix<double, Eigen::Dynamic, 3>;
  const Eigen::Index n = P.rows();
  const Eigen::Matrix3d own_covariance = P.block<3, 3>(c, c).selfadjointView<Eigen::Lower>();
  const Eigen::LLT<Eigen::Matrix3d> llt(own_covariance);
  if (llt.info() != Eigen::Success) return false;
  // B = P[:, c:c+3]: rows above c from the lower triangle's rows c..c+2.
  Eigen::Map<Columns3> B = scratch.B.matrix<Columns3>(n, 3);
  B.topRows(c) = P.block(c, 0, 3, c).transpose();
  B.middleRows<3>(c) = own_covariance;
  B.bottomRows(n - c - 3) = P.block(c + 3, c, n - c - 3, 3);
  VectorMap correction = scratch.correction.vector(n);
  correction.noalias() = B * llt.solve(target_mean - own_mean);
  const Eigen::Matrix3d half = llt.solve(target_covariance - own_covariance);
  Eigen::Matrix3d M = llt.solve(half.transpose());
  M = 0.5 * (M + M.transpose()).eval();
  Eigen::Map<Columns3> BM = scratch.BM.matrix<Columns3>(n, 3);
  BM.noalias() = B * M;
  // P's lower triangle += BM B^T, column by column (three axpys each: faster than the blocked
  // triangular product for a rank of 3).
  for (Eigen::Index j = 0; j < n; ++j) {
    const Eigen::Index rows = n - j;
    P.col(j).tail(rows) += BM.col(0).tail(rows) * B(j, 0) + BM.col(1).tail(rows) * B(j, 1) +
                           BM.col(2).tail(rows) * B(j, 2);
  }
  return true;
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

  /// Adds a holder's 3x3 marginal (mean, covariance) with its weight.
  void add(double holder_weight, const Eigen::Vector3d& mean, const Eigen::Matrix3d& covariance,
           double max_condition_number) {
    const auto information = checked_inverse3(covariance, max_condition_number);
    if (!information) {
      ++skipped;
      return;
    }
    weight += holder_weight;
    matrix += holder_weight * *information;
    vector += holder_weight * (*information * mean);
    ++used;
  }

  /// The average (eq. 19) of this share and the robot's own marginal (mean, information), the
  /// robot weighing what the holders leave; nullopt when not positive definite. Every
  /// information here is exactly symmetric (positive_definite_inverse), and so are their sums.
  std::optional<ObjectEstimate> average_with(LandmarkId id, const Eigen::Vector3d& own_mean,
                                             const Eigen::Matrix3d& own_information) const {
    const double own_weight = 1.0 - weight;
    const Eigen::Matrix3d information = matrix + own_weight * own_information;
    const Eigen::Vector3d information_vector = vector + own_weight * (own_information * own_mean);
    const auto covariance = positive_definite_inverse(information);
    if (!covariance) return std::nullopt;
    return ObjectEstimate{id, *covariance * information_vector, *covariance};
  }
};

/// A landmark accepted for averaging: its holders and their share (in the holders' order).
struct Accepted {
  LandmarkId id = 0;
  const Location* own = nullptr;  ///< where the robot holds it (block 0: in the joint state)
  std::size_t first = 0;  ///< the holders' position and number in the buffer that holds them
  std::size_t count = 0;
  Holders holders;  ///< set once that buffer stops growing
  NeighbourShare share;
};

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

/// The members' marginals of a group of d coordinates in information form, stacked: share s is
/// matrices columns [s d, (s + 1) d) and vectors rows [s d, (s + 1) d), with its weight.
struct GroupShares {
  std::vector<double> weights;
  Scratch matrices;
  Scratch vectors;
  double* matrix_data = nullptr;
  double* vector_data = nullptr;
  Eigen::Index d = 0;

  /// Room for `count` shares of d coordinates (the views of earlier shares stay valid).
  void prepare(std::size_t count, Eigen::Index dimension) {
    d = dimension;
    const auto n = static_cast<Eigen::Index>(count);
    matrix_data = matrices.matrix(d, d * n).data();
    vector_data = vectors.vector(d * n).data();
    weights.clear();
  }
  MatrixMap matrix(std::size_t s) const {
    return {matrix_data + d * d * static_cast<Eigen::Index>(s), d, d};
  }
  VectorMap vector(std::size_t s) const {
    return {vector_data + d * static_cast<Eigen::Index>(s), d};
  }
};

}  // namespace consensus_internal

using namespace consensus_internal;

/// Everything Consensus::fuse needs besides its inputs, kept from one round to the next.
struct ConsensusWorkspace::Buffers {
  ConsensusReport report;
  ClaimHistory claims;  // kept from round to round (the workspace's only state)
  // The members.
  std::vector<const ObjectEstimate*> own_archived;
  Locations spare_locations;  // sort_by_id's
  Member own;
  std::vector<Member> neighbour_members;  // the first neighbour_count hold this round's
  std::size_t neighbour_count = 0;
  // The landmarks accepted for averaging and their holders.
  std::vector<Holder> holder_buffer;
  std::vector<std::size_t> cursors;  // a neighbour's position in its locations, by id
  std::vector<Accepted> accepted;    // holders as offsets into holder_buffer until it is whole
  // Groups.
  std::vector<std::pair<int, int>> key_members;
  std::vector<std::size_t> key_start;
  std::vector<int> order;
  std::vector<Group> groups;
  // U, the joint marginal of the in-state landmarks fused.
  std::vector<int> union_slots;
  std::vector<int> union_position;
  Scratch union_mean;
  Scratch union_covariance;
  SingleScratch single;
  // Groups of several landmarks.
  std::vector<LandmarkId> ids;
  std::vector<Location> at;
  std::vector<int> indices;
  GroupShares shares;
  Scratch member_mean, member_covariance, factor, own_mean, own_covariance, average,
      average_vector, mean, covariance;
  // Proposition 2 on U and on the state.
  PropositionTwoScratch proposition;
  std::vector<int> state_indices;
  Scratch state_own_mean;
};

ConsensusWorkspace::ConsensusWorkspace() : buffers_(std::make_unique<Buffers>()) {}
ConsensusWorkspace::~ConsensusWorkspace() = default;
ConsensusWorkspace::ConsensusWorkspace(const ConsensusWorkspace&)
    : buffers_(std::make_unique<Buffers>()) {}
ConsensusWorkspace& ConsensusWorkspace::operator=(const ConsensusWorkspace&) { return *this; }
ConsensusWorkspace::ConsensusWorkspace(ConsensusWorkspace&&) noexcept = default;
ConsensusWorkspace& ConsensusWorkspace::operator=(ConsensusWorkspace&&) noexcept = default;

namespace {

/// Consensus::replace_marginal with the workspace's buffers.
bool replace_state_marginal(State& state, const std::vector<int>& slots,
                            const Eigen::Ref<const Eigen::VectorXd>& mean,
                            const Eigen::Ref<const Eigen::MatrixXd>& covariance,
                            ConsensusWorkspace::Buffers& buffers) {
  std::vector<int>& indices = buffers.state_indices;
  indices.clear();
  VectorMap own_mean =
      buffers.state_own_mean.vector(3 * static_cast<Eigen::Index>(slots.size()));
  for (std::size_t i = 0; i < slots.size(); ++i) {
    own_mean.segment<3>(3 * static_cast<Eigen::Index>(i)) = state.landmarks[slots[i]].p_world;
    for (int k = 0; k < 3; ++k) indices.push_back(state.landmark_index(slots[i]) + k);
  }
  if (!proposition_two(state.covariance, indices, own_mean, mean, covariance,
                       buffers.proposition)) {
    return false;
  }
  // eq. (21): poses move by the correction (left perturbation, see State); landmarks additively.
  StateHelper::apply_correction(state,
                                buffers.proposition.correction.vector(state.covariance.rows()));
  return true;
}

}  // namespace

Marginal Consensus::marginal(const State& state, const std::vector<LandmarkId>& ids) {
  Marginal out;
  marginal(state, ids, out);
  return out;
}

void Consensus::marginal(const State& state, const std::vector<LandmarkId>& ids, Marginal& out) {
  // In-state objects, archived consider states among them, go in one joint block: averaging
  // correlated objects one by one and carrying each average into the state (Proposition 2)
  // was measured to cost accuracy (docs/estimator.md, "Archiving"). Each archived object is a
  // 3x3 block of its own, after the joint block.
  // One look-up an id; the lists are kept between calls (no allocation once they are large
  // enough).
  thread_local std::vector<std::pair<int, Eigen::Index>> in_state;  // slot, index in the state
  thread_local std::vector<std::pair<LandmarkId, const ObjectEstimate*>> archived;
  thread_local std::vector<std::pair<LandmarkId, int>> slots;  // the in-state objects by id
  in_state.clear();
  archived.clear();
  out.ids.clear();
  if (std::is_sorted(ids.begin(), ids.end())) {
    // Ascending ids (as a neighbour's common list comes) are merged with the in-state objects
    // sorted by id and with the archive (ordered by id) instead of looked up one by one in two
    // trees: with tens of archived objects a marginal, the look-ups' pointer chasing was a third
    // of the time here. The archive's iterator walks a few entries, then searches.
    slots.clear();
    for (int slot = 0; slot < state.num_landmarks(); ++slot) {
      if (!state.landmarks[slot].detection_offset)
        slots.emplace_back(state.landmarks[slot].id, slot);
    }
    std::sort(slots.begin(), slots.end());
    auto next_slot = slots.begin();
    auto next_archived = state.archived.begin();
    for (LandmarkId id : ids) {
      while (next_slot != slots.end() && next_slot->first < id) ++next_slot;
      if (next_slot != slots.end() && next_slot->first == id) {
        out.ids.push_back(id);
        in_state.emplace_back(next_slot->second, state.landmark_index(next_slot->second));
        continue;
      }
      constexpr int kWalk = 4;
      for (int step = 0;
           step < kWalk && next_archived != state.archived.end() && next_archived->first < id;
           ++step) {
        ++next_archived;
      }
      if (next_archived != state.archived.end() && next_archived->first < id) {
        next_archived = state.archived.lower_bound(id);
      }
      if (next_archived != state.archived.end() && next_archived->first == id) {
        archived.emplace_back(id, &next_archived->second);
      }
    }
  } else {
    for (LandmarkId id : ids) {
      if (const int slot = state.landmark_slot(id); slot >= 0) {
        out.ids.push_back(id);
        in_state.emplace_back(slot, state.landmark_index(slot));
      } else if (const auto it = state.archived.find(id); it != state.archived.end()) {
        archived.emplace_back(id, &it->second);
      }
    }
  }
  const auto joint = static_cast<Eigen::Index>(out.ids.size());
  for (const auto& [id, estimate] : archived) out.ids.push_back(id);
  const auto count = static_cast<Eigen::Index>(out.ids.size());
  if (out.mean.size() != 3 * count) out.mean.resize(3 * count);
  const std::size_t blocks = (joint > 0 ? 1 : 0) + static_cast<std::size_t>(count - joint);
  out.blocks.resize(blocks);  // kept blocks keep their storage
  if (joint > 0) {
    Eigen::MatrixXd& covariance = out.blocks.front();
    if (covariance.rows() != 3 * joint || covariance.cols() != 3 * joint)
      covariance.resize(3 * joint, 3 * joint);
    // A landmark's three coordinates are adjacent in the state: each column of the joint
    // block is gathered three rows at a time, from a column of the state's covariance (kept
    // symmetric: both triangles are read, nothing is transposed).
    for (Eigen::Index j = 0; j < joint; ++j) {
      const auto [slot, column] = in_state[static_cast<std::size_t>(j)];
      out.mean.segment<3>(3 * j) = state.landmarks[slot].p_world;
      for (Eigen::Index c = 0; c < 3; ++c) {
        const double* source = state.covariance.col(column + c).data();
        double* target = covariance.col(3 * j + c).data();
        for (Eigen::Index i = 0; i < joint; ++i, target += 3) {
          const double* rows = source + in_state[static_cast<std::size_t>(i)].second;
          target[0] = rows[0];
          target[1] = rows[1];
          target[2] = rows[2];
        }
      }
    }
  }
  std::size_t block = joint > 0 ? 1 : 0;
  for (Eigen::Index a = joint; a < count; ++a, ++block) {
    const ObjectEstimate& estimate = *archived[static_cast<std::size_t>(a - joint)].second;
    out.mean.segment<3>(3 * a) = estimate.p_world;
    Eigen::MatrixXd& covariance = out.blocks[block];
    if (covariance.rows() != 3 || covariance.cols() != 3) covariance.resize(3, 3);
    covariance = estimate.covariance;
  }
}

void Consensus::select(const Marginal& full, const std::vector<LandmarkId>& ids, Marginal& out) {
  assert(full.well_formed());
  // The cut itself is sub_marginal's.
  thread_local std::vector<bool> keep;
  kept_by(full, ids, keep);
  sub_marginal(full, keep, out);
}

void Consensus::kept_by(const Marginal& full, const std::vector<LandmarkId>& ids,
                        std::vector<bool>& keep) {
  assert(std::is_sorted(ids.begin(), ids.end()));
  // Which of full's landmarks are in `ids`: a cursor in `ids` walks along full's ids while they
  // ascend (they do within each block of a marginal of ascending ids) and searches where they
  // do not.
  keep.assign(full.ids.size(), false);
  auto cursor = ids.begin();
  LandmarkId previous = std::numeric_limits<LandmarkId>::min();
  for (std::size_t position = 0; position < full.ids.size(); ++position) {
    const LandmarkId id = full.ids[position];
    if (id < previous) cursor = std::lower_bound(ids.begin(), ids.end(), id);
    previous = id;
    while (cursor != ids.end() && *cursor < id) ++cursor;
    keep[position] = cursor != ids.end() && *cursor == id;
  }
}

bool Consensus::replace_marginal(State& state, const std::vector<int>& slots,
                                 const Eigen::VectorXd& mean, const Eigen::MatrixXd& covariance) {
  ConsensusWorkspace workspace;
  return replace_state_marginal(state, slots, mean, covariance, *workspace.buffers_);
}

bool Consensus::replace_marginal_keeping_the_rest(State& state, int slot,
                                                  const Eigen::Vector3d& mean,
                                                  const Eigen::Matrix3d& covariance) {
  const Eigen::Index index = state.landmark_index(slot);
  const Eigen::Matrix3d own = state.covariance.block<3, 3>(index, index);
  const Eigen::LLT<Eigen::Matrix3d> llt(own);
  if (llt.info() != Eigen::Success) return false;
  // The rest's gain on the landmark, B = P_rest,landmark own^-1 (the landmark's rows zero).
  Eigen::MatrixXd gain = llt.solve(state.covariance.middleCols(index, 3).transpose()).transpose();
  gain.middleRows(index, 3).setZero();
  if (!replace_marginal(state, {slot}, mean, covariance)) return false;
  // What Proposition 2 took off the rest, B (own - new) B^T, given back where it is positive.
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(own - covariance);
  const Eigen::Vector3d shrunk = eigen.eigenvalues().cwiseMax(0.0);
  if (shrunk.maxCoeff() <= 0.0) return true;
  const Eigen::MatrixXd root =
      gain * (eigen.eigenvectors() * shrunk.cwiseSqrt().asDiagonal());  // B S^(1/2)
  state.covariance.noalias() += root * root.transpose();
  return true;
}

ConsensusReport Consensus::fuse(State& state, const std::vector<WeightedMarginal>& neighbours,
                                const ConsensusOptions& options) {
  ConsensusWorkspace workspace;
  return fuse(state, neighbours, options, workspace);
}

namespace consensus_internal {

/// The buffers of a step with `neighbours` neighbours: the report zeroed, room for a member a
/// neighbour, none taken yet.
ConsensusWorkspace::Buffers& begin_step(ConsensusWorkspace::Buffers& w, std::size_t neighbours) {
  ConsensusReport& report = w.report;
  report.landmarks_fused = 0;
  report.groups = 0;
  report.neighbours_skipped = 0;
  report.landmarks_refused = 0;
  report.claims_refused = 0;
  report.refused_per_neighbour.assign(neighbours, 0);
  report.tested_per_neighbour.assign(neighbours, 0);
  report.landmarks_settled = 0;
  report.largest_mean_shift = 0.0;
  if (w.neighbour_members.size() < neighbours) w.neighbour_members.resize(neighbours);
  w.neighbour_count = 0;
  return w;
}

/// Consensus::fuse once the neighbours' members (the first w.neighbour_count) are ready.
const ConsensusReport& fuse_members(State& state, const ConsensusOptions& options,
                                    ConsensusWorkspace::Buffers& w);

}  // namespace consensus_internal

struct SharedMarginal::Index {
  Locations locations;
  Locations spare;
  bool usable = false;
};

SharedMarginal::SharedMarginal() : index_(std::make_unique<Index>()) {}
SharedMarginal::~SharedMarginal() = default;
SharedMarginal::SharedMarginal(SharedMarginal&&) noexcept = default;
SharedMarginal& SharedMarginal::operator=(SharedMarginal&&) noexcept = default;

bool SharedMarginal::index() {
  index_->usable = marginal_.well_formed() &&
                   locate(marginal_.ids, marginal_.blocks, index_->locations, index_->spare);
  return index_->usable;
}

bool SharedMarginal::usable() const { return index_->usable; }

void SharedMarginal::count_common(const std::vector<LandmarkId>& ids,
                                  std::vector<int>& per_block) const {
  assert(usable());
  per_block.assign(marginal_.blocks.size(), 0);
  const Locations& locations = index_->locations;  // sorted by id
  std::size_t cursor = 0;
  for (LandmarkId id : ids) {
    while (cursor < locations.size() && locations[cursor].first < id) ++cursor;
    if (cursor == locations.size()) break;
    if (locations[cursor].first == id) ++per_block[locations[cursor].second.block];
  }
}

const ConsensusReport& Consensus::fuse(State& state,
                                       const std::vector<WeightedMarginal>& neighbours,
                                       const ConsensusOptions& options,
                                       ConsensusWorkspace& workspace) {
  ConsensusWorkspace::Buffers& w = begin_step(*workspace.buffers_, neighbours.size());
  // 1. Every neighbour's marginal checked once.
  for (std::size_t j = 0; j < neighbours.size(); ++j) {
    const Marginal& m = neighbours[j].marginal;
    if (m.ids.empty()) continue;
    // Positive definiteness and conditioning are checked per averaged group, below.
    const bool usable = neighbours[j].weight > 0.0 && neighbours[j].weight < 1.0 &&
                        check(m, static_cast<int>(j), neighbours[j].weight,
                              w.neighbour_members[w.neighbour_count], w.spare_locations);
    if (!usable) {
      ++w.report.neighbours_skipped;
      continue;
    }
    w.neighbour_members[w.neighbour_count].sender = neighbours[j].sender;
    ++w.neighbour_count;
  }
  return fuse_members(state, options, w);
}

int Consensus::witness(const State& state, const std::vector<WeightedMarginal>& neighbours,
                       const ConsensusOptions& options, ConsensusWorkspace& workspace) {
  if (options.claim_history_rounds <= 0 || !(options.neighbour_chi2_probability > 0.0)) return 0;
  if (state.landmarks.empty() && state.archived.empty()) return 0;
  ConsensusWorkspace::Buffers& w = *workspace.buffers_;
  // The robot's own landmarks: only claims about those are kept (as in fuse).
  own_member(state, 1.0, w.own_archived, w.own, w.spare_locations);
  const double bound = UpdaterHelper::chi2_quantile(options.neighbour_chi2_probability, 3);
  int refused = 0;
  Member member;
  Locations spare;
  for (const WeightedMarginal& neighbour : neighbours) {
    if (neighbour.sender < 0 || neighbour.marginal.ids.empty()) continue;
    if (!check(neighbour.marginal, 0, 0.0, member, spare)) continue;
    const Locations& theirs = member.locations();
    std::size_t cursor = 0;  // both sorted by id: a merge
    for (const auto& [id, own_at] : w.own.locations()) {
      while (cursor < theirs.size() && theirs[cursor].first < id) ++cursor;
      if (cursor == theirs.size()) break;
      if (theirs[cursor].first != id) continue;
      const Location& at = theirs[cursor].second;
      if (!w.claims.consistent(neighbour.sender, id, member.mean(at), member.covariance(at),
                               bound)) {
        ++refused;
      }
    }
  }
  return refused;
}

const ConsensusReport& Consensus::fuse(State& state, std::span<const WeightedShare> neighbours,
                                       const ConsensusOptions& options,
                                       ConsensusWorkspace& workspace) {
  ConsensusWorkspace::Buffers& w = begin_step(*workspace.buffers_, neighbours.size());
  // 1. Every neighbour's marginal was checked and indexed by its owner, once.
  for (std::size_t j = 0; j < neighbours.size(); ++j) {
    const WeightedShare& share = neighbours[j];
    if (share.marginal == nullptr || share.marginal->marginal().ids.empty()) continue;
    if (!(share.weight > 0.0 && share.weight < 1.0) || !share.marginal->usable()) {
      ++w.report.neighbours_skipped;
      continue;
    }
    Member& member = w.neighbour_members[w.neighbour_count++];
    member.index = static_cast<int>(j);
    member.weight = share.weight;
    member.marginal = &share.marginal->marginal();
    member.state = nullptr;
    member.archived = nullptr;
    member.shared = &share.marginal->index_->locations;
    member.sender = share.sender;
  }
  return fuse_members(state, options, w);
}

const ConsensusReport& consensus_internal::fuse_members(State& state,
                                                        const ConsensusOptions& options,
                                                        ConsensusWorkspace::Buffers& w) {
  ConsensusReport& report = w.report;
  // 1. The robot's own marginal of everything it holds (read from its state).
  const std::span<const Member> neighbour_members(w.neighbour_members.data(), w.neighbour_count);
  double neighbour_weight = 0.0;
  for (const Member& member : neighbour_members) neighbour_weight += member.weight;
  if (neighbour_members.empty() || (state.landmarks.empty() && state.archived.empty())) {
    return report;
  }
  own_member(state, 1.0 - neighbour_weight, w.own_archived, w.own, w.spare_locations);
  const Member* const own = &w.own;
  const double refusal_bound =
      options.neighbour_chi2_probability > 0.0
          ? UpdaterHelper::chi2_quantile(options.neighbour_chi2_probability, 3)
          : std::numeric_limits<double>::infinity();
  const bool check_claims =
      options.claim_history_rounds > 0 && options.neighbour_chi2_probability > 0.0;
  if (check_claims) w.claims.begin_round(options.claim_history_rounds);

  // 2. For every landmark the robot holds, the neighbours that hold it and agree with the robot
  //    (a neighbour's mean beyond the chi-square bound under the sum of both covariances is
  //    refused: an outlier, a wrong association or a lie; not averaged in, counted).
  // (id, its holders: neighbour position and where the landmark sits in its marginal), by id.
  // Every accepted landmark's holders lie in one buffer (no allocation per landmark). Each
  // holder's share of the average (its information, from its 3x3 marginal) is taken while its
  // marginal is at hand.
  std::vector<Holder>& holder_buffer = w.holder_buffer;
  holder_buffer.clear();
  std::vector<Accepted>& accepted = w.accepted;
  accepted.clear();
  NeighbourShare share;
  // Every member's locations are sorted by id: one cursor a neighbour walks them alongside the
  // robot's (a merge, not a search a landmark and neighbour).
  w.cursors.assign(neighbour_members.size(), 0);
  for (const auto& [id, own_at] : own->locations()) {  // sorted by id
    const std::size_t first = holder_buffer.size();
    const Eigen::Vector3d own_mean = own->mean(own_at);
    const Eigen::Matrix3d own_covariance = own->covariance(own_at);
    share = NeighbourShare();
    for (std::size_t j = 0; j < neighbour_members.size(); ++j) {
      const Member& neighbour = neighbour_members[j];
      const Locations& theirs = neighbour.locations();
      std::size_t& cursor = w.cursors[j];
      while (cursor < theirs.size() && theirs[cursor].first < id) ++cursor;
      if (cursor == theirs.size() || theirs[cursor].first != id) continue;
      const Location* found = &theirs[cursor].second;
      ++report.tested_per_neighbour[neighbour.index];
      const Eigen::Vector3d their_mean = neighbour.mean(*found);
      const Eigen::Matrix3d their_covariance = neighbour.covariance(*found);
      if (check_claims && neighbour.sender >= 0 &&
          !w.claims.consistent(neighbour.sender, id, their_mean, their_covariance, refusal_bound)) {
        ++report.landmarks_refused;
        ++report.claims_refused;
        ++report.refused_per_neighbour[neighbour.index];
        continue;
      }
      if (options.neighbour_chi2_probability > 0.0) {
        const auto distance =
            inverse_quadratic(own_covariance, their_covariance, their_mean - own_mean);
        if (!distance || !(*distance <= refusal_bound)) {
          ++report.landmarks_refused;
          ++report.refused_per_neighbour[neighbour.index];
          continue;
        }
      }
      holder_buffer.emplace_back(static_cast<int>(j), found);
      share.add(neighbour.weight, their_mean, their_covariance, options.max_condition_number);
    }
    if (holder_buffer.size() > first) {
      accepted.push_back({id, &own_at, first, holder_buffer.size() - first, Holders(), share});
    }
  }
  for (Accepted& entry : accepted) {
    entry.holders = Holders(holder_buffer.data() + entry.first, entry.count);
  }

  // 2b. Event-triggered fusion (consensus.fuse_kl_threshold): a landmark whose average, from
  //     the 3x3 marginals, is within the threshold of the robot's own is left out of the round.
  if (options.fuse_kl_threshold > 0.0) {
    const auto settled = [&](const Accepted& entry) {
      const LandmarkId id = entry.id;
      const Location& own_at = *entry.own;
      ObjectEstimate current{id, own->mean(own_at), own->covariance(own_at)};
      const auto own_information =
          checked_inverse3(current.covariance, options.max_condition_number);
      if (!own_information) return false;  // fused (or refused) as usual below
      const auto step = entry.share.average_with(id, current.p_world, *own_information);
      return step && kl_divergence(*step, current) <= options.fuse_kl_threshold;
    };
    const auto kept = std::remove_if(accepted.begin(), accepted.end(), settled);
    report.landmarks_settled = static_cast<int>(accepted.end() - kept);
    accepted.erase(kept, accepted.end());
  }

  // 3. The weighted average (eq. 19) of landmarks grouped by (in joint state?, and for the
  //    robot and each holder the block of its marginal that holds the landmark). A marginal
  //    claims nothing about the correlation of landmarks in different blocks (archived objects
  //    lost theirs), so only landmarks that share a block in every member's contribution are
  //    averaged jointly; averaging them jointly as if independent would credit the member with
  //    information it does not have (e.g. on their common offset) and make the robot
  //    overconfident. In-state groups are replaced one after another on the joint marginal of
  //    all in-state landmarks being fused (U): replacing a group's marginal keeps the
  //    conditional of the rest given it, so p(rest of the state | U) never changes and the
  //    sequence of replacements equals one replacement of U's marginal at the end
  //    (Proposition 2 once, not per group).
  //    A landmark's key: ((member, block) of each holder and of the robot); the groups are
  //    the runs of equal keys. The robot holds each archived object in a block of its own: an
  //    archived object is a group alone, and those come first, in the order of `accepted` (they
  //    are independent of each other and of the state). The in-state landmarks' groups follow
  //    in their keys' lexicographic order, each run's landmarks in the order of `accepted`
  //    (flat keys sorted with the position as the last criterion: the order of a stable sort,
  //    without its buffer).
  std::vector<std::pair<int, int>>& key_members = w.key_members;  // (member, block), flat
  key_members.clear();
  w.key_start.assign(accepted.size() + 1, 0);
  std::vector<int>& order = w.order;
  order.clear();
  for (std::size_t a = 0; a < accepted.size(); ++a) {
    w.key_start[a] = key_members.size();
    if (accepted[a].own->block != 0) {
      order.push_back(static_cast<int>(a));  // archived: no key needed
      continue;
    }
    for (const auto& [j, at] : accepted[a].holders) key_members.emplace_back(j, at->block);
    key_members.emplace_back(-1, 0);
  }
  w.key_start[accepted.size()] = key_members.size();
  const std::size_t archived_groups = order.size();
  for (std::size_t a = 0; a < accepted.size(); ++a) {
    if (accepted[a].own->block == 0) order.push_back(static_cast<int>(a));
  }
  const auto key_of = [&](int a) {
    return std::span<const std::pair<int, int>>(key_members.data() + w.key_start[a],
                                                w.key_start[a + 1] - w.key_start[a]);
  };
  const auto key_less = [&](int a, int b) {
    const auto x = key_of(a), y = key_of(b);
    return std::lexicographical_compare(x.begin(), x.end(), y.begin(), y.end());
  };
  const auto in_state = order.begin() + static_cast<std::ptrdiff_t>(archived_groups);
  std::sort(in_state, order.end(), [&](int a, int b) {
    if (key_less(a, b)) return true;
    if (key_less(b, a)) return false;
    return a < b;
  });
  std::vector<Group>& groups = w.groups;
  groups.clear();
  for (std::size_t g = 0; g < archived_groups; ++g) {
    groups.push_back({false, {}, std::span<const int>(order.data() + g, 1)});
  }
  for (std::size_t begin = archived_groups; begin < order.size();) {
    std::size_t end = begin + 1;
    while (end < order.size() && !key_less(order[begin], order[end])) ++end;
    groups.push_back(
        {true, key_of(order[begin]), std::span<const int>(order.data() + begin, end - begin)});
    begin = end;
  }
  std::vector<int>& union_slots = w.union_slots;
  union_slots.clear();
  w.union_position.assign(accepted.size(), -1);  // by position in accepted
  for (const Group& group : groups) {
    if (!group.in_joint_state) continue;
    for (int a : group.positions) {
      w.union_position[a] = static_cast<int>(union_slots.size());
      union_slots.push_back(accepted[a].own->position);  // the slot
    }
  }
  const auto union_size = 3 * static_cast<Eigen::Index>(union_slots.size());
  VectorMap union_mean = w.union_mean.vector(union_size);
  MatrixMap union_covariance = w.union_covariance.matrix(union_size, union_size);
  for (std::size_t j = 0; j < union_slots.size(); ++j) {  // 3x3 block by 3x3 block
    const auto column = static_cast<Eigen::Index>(j);
    const int start_j = state.landmark_index(union_slots[j]);
    union_mean.segment<3>(3 * column) = state.landmarks[union_slots[j]].p_world;
    for (std::size_t i = 0; i < union_slots.size(); ++i) {
      union_covariance.block<3, 3>(3 * static_cast<Eigen::Index>(i), 3 * column) =
          state.covariance.block<3, 3>(state.landmark_index(union_slots[i]), start_j);
    }
  }
  int union_fused = 0;
  int union_groups = 0;
  // Single-landmark replacements update only U's lower triangle; it is mirrored before anything
  // reads U whole.
  bool union_lower_only = false;
  for (const Group& group : groups) {
    const bool in_joint_state = group.in_joint_state;
    const std::span<const std::pair<int, int>> members = group.members;
    const std::span<const int> positions = group.positions;
    if (positions.size() == 1) {
      // Most groups: one landmark. The same average and replacement as below, with fixed-size
      // algebra.
      const auto& [id, own_at, first, count, holders, share] = accepted[positions.front()];
      report.neighbours_skipped += share.skipped;  // their weight stays with the robot
      if (share.used == 0) continue;
      const Eigen::Index c = in_joint_state ? 3 * w.union_position[positions.front()] : 0;
      ObjectEstimate* archived = in_joint_state ? nullptr : &state.archived.at(id);
      const Eigen::Vector3d own_mean =
          in_joint_state ? Eigen::Vector3d(union_mean.segment<3>(c)) : archived->p_world;
      const Eigen::Matrix3d own_covariance =
          in_joint_state
              ? Eigen::Matrix3d(union_covariance.block<3, 3>(c, c).selfadjointView<Eigen::Lower>())
              : archived->covariance;
      const auto own_information = positive_definite_inverse(own_covariance);
      if (!own_information) continue;
      const auto average = share.average_with(id, own_mean, *own_information);
      if (!average) continue;
      const Eigen::Matrix3d& covariance = average->covariance;
      const Eigen::Vector3d& mean = average->p_world;
      if (!mean.allFinite() || !covariance.allFinite()) continue;
      note_mean_shift(own_mean, mean, report);
      if (!in_joint_state) {
        archived->p_world = mean;
        archived->covariance = covariance;
        ++report.landmarks_fused;
        ++report.groups;
        continue;
      }
      if (!proposition_two_single(union_covariance, c, own_mean, mean, covariance, w.single)) {
        continue;
      }
      union_lower_only = true;
      union_mean += w.single.correction.vector(union_size);
      ++union_fused;
      ++union_groups;
      continue;
    }
    // Several landmarks, in the joint state (an archived object is a block of its own).
    std::vector<LandmarkId>& ids = w.ids;
    ids.clear();
    for (int a : positions) ids.push_back(accepted[a].id);
    const auto d = 3 * static_cast<Eigen::Index>(ids.size());
    // The members' information: the neighbours that hold the group (in its key), then the robot.
    GroupShares& shares = w.shares;
    shares.prepare(members.size(), d);
    double own_weight = 1.0;
    for (const auto& [j, block] : members) {
      if (j < 0) continue;
      const Member& neighbour = neighbour_members[j];
      w.at.clear();
      for (LandmarkId id : ids) w.at.push_back(*neighbour.find(id));
      VectorMap member_mean = w.member_mean.vector(d);
      MatrixMap member_covariance = w.member_covariance.matrix(d, d);
      sub_gaussian(*neighbour.marginal, w.at, member_mean, member_covariance);
      const std::size_t s = shares.weights.size();
      MatrixMap information = shares.matrix(s);
      if (!checked_inverse(member_covariance, options.max_condition_number,
                           w.factor.matrix(d, d), information)) {
        ++report.neighbours_skipped;  // its weight stays with the robot
        continue;
      }
      shares.vector(s).noalias() = information * member_mean;
      own_weight -= neighbour.weight;
      shares.weights.push_back(neighbour.weight);
    }
    if (shares.weights.empty()) continue;  // no usable neighbour: nothing to average
    // The robot's own marginal as it is now: after the groups replaced before this one (the
    // replacements are sequential Bayesian steps; see above).
    if (union_lower_only) {
      mirror_lower(union_covariance);
      union_lower_only = false;
    }
    std::vector<int>& indices = w.indices;  // coordinates of the group in U
    indices.clear();
    for (int a : positions) {
      for (int k = 0; k < 3; ++k) indices.push_back(3 * w.union_position[a] + k);
    }
    VectorMap own_mean = w.own_mean.vector(d);
    MatrixMap own_covariance = w.own_covariance.matrix(d, d);
    for (Eigen::Index c = 0; c < d; ++c) {
      own_mean(c) = union_mean(indices[c]);
      for (Eigen::Index r = 0; r < d; ++r) own_covariance(r, c) = union_covariance(indices[r], indices[c]);
    }
    {
      MatrixMap factor = w.factor.matrix(d, d);
      factor = own_covariance;
      const Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> own_llt(factor);  // in place
      if (own_llt.info() != Eigen::Success) continue;
      const std::size_t s = shares.weights.size();
      MatrixMap information = shares.matrix(s);
      information.setIdentity();
      own_llt.solveInPlace(information);
      symmetrize(information);
      shares.vector(s).noalias() = information * own_mean;
      shares.weights.push_back(own_weight);
    }
    // The weighted average of eq. (19) in information form (a geometric mean of Gaussians:
    // consistent whatever the correlation between the members, if each is).
    double total_weight = 0.0;
    for (std::size_t s = 0; s < shares.weights.size(); ++s) {
      if (shares.matrix(s).diagonal().maxCoeff() > 0.0) total_weight += shares.weights[s];
    }
    if (!(total_weight > 0.0)) continue;
    MatrixMap matrix = w.average.matrix(d, d);
    VectorMap vector = w.average_vector.vector(d);
    matrix.setZero();
    vector.setZero();
    for (std::size_t s = 0; s < shares.weights.size(); ++s) {
      if (!(shares.matrix(s).diagonal().maxCoeff() > 0.0)) continue;
      matrix += (shares.weights[s] / total_weight) * shares.matrix(s);
      vector += (shares.weights[s] / total_weight) * shares.vector(s);
    }
    symmetrize(matrix);
    const Eigen::LLT<Eigen::Ref<Eigen::MatrixXd>> llt(matrix);  // in place
    if (llt.info() != Eigen::Success) continue;
    MatrixMap covariance = w.covariance.matrix(d, d);
    covariance.setIdentity();
    llt.solveInPlace(covariance);
    symmetrize(covariance);
    VectorMap mean = w.mean.vector(d);
    mean.noalias() = covariance * vector;
    if (!mean.allFinite() || !covariance.allFinite()) continue;
    note_mean_shift(own_mean, mean, report);
    // Proposition 2 on U (own_mean is U's mean at `indices`, gathered above).
    if (!proposition_two(union_covariance, indices, own_mean, mean, covariance, w.proposition)) {
      continue;
    }
    union_mean += w.proposition.correction.vector(union_size);
    union_fused += static_cast<int>(ids.size());
    ++union_groups;
  }
  if (union_lower_only) mirror_lower(union_covariance);
  if (union_groups > 0 &&
      replace_state_marginal(state, union_slots, union_mean, union_covariance, w)) {
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

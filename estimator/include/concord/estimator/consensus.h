#pragma once
/// \file
/// The consensus step (§V-B): marginals of common landmarks out, the information-form weighted
/// average of the robot's own and its neighbours' marginals (eq. 19), reconstruction of the
/// joint by Proposition 2 and the pose correction of eq. (21).
///
/// Landmarks held by only some neighbours: a neighbour that does not hold a landmark is treated
/// as agreeing with the robot, i.e. its weight A_ij goes to the robot's own marginal for that
/// landmark. Landmarks are grouped by the set of neighbours holding them; each group is averaged
/// jointly (the full joint marginal over the group), groups one after another. Archived objects
/// (outside the joint state) are averaged one by one.

#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "concord/estimator/options.h"
#include "concord/estimator/state.h"
#include "concord/estimator/types.h"

namespace concord {

/// What one consensus step did.
struct ConsensusReport {
  int landmarks_fused = 0;  ///< landmarks whose marginal was replaced by an average
  int groups = 0;           ///< jointly averaged groups
  /// Neighbour marginals left out: malformed (whole marginal), or not positive definite or
  /// ill-conditioned (counted per averaged group).
  int neighbours_skipped = 0;
  /// (landmark, neighbour) pairs left out by the chi-square test of the neighbour's marginal
  /// against the robot's own (consensus.neighbour_chi2_probability), in total and per
  /// neighbour (in the order the neighbours were given).
  int landmarks_refused = 0;
  std::vector<int> refused_per_neighbour;
  /// Of landmarks_refused, those whose claim disagreed with the neighbour's own earlier claims
  /// about the landmark (ConsensusOptions::claim_history_rounds).
  int claims_refused = 0;
  /// Landmarks each neighbour's marginal offered that the robot holds (tested), per neighbour.
  std::vector<int> tested_per_neighbour;
  /// Landmarks held by a neighbour that were left out because their step was below
  /// consensus.fuse_kl_threshold.
  int landmarks_settled = 0;
  double largest_mean_shift = 0.0;  ///< metres, the longest step of a landmark mean
};

/// The buffers of Consensus::fuse, kept from one round to the next by the robot that fuses
/// (one per robot, used by one thread at a time). A round whose landmarks and neighbours are no
/// more than those of an earlier round allocates nothing on the heap (issue 13); a copy is a
/// fresh, empty workspace. Besides buffers it holds one piece of state: the neighbours' recent
/// claims (ConsensusOptions::claim_history_rounds), which a copy does not carry over.
class ConsensusWorkspace {
 public:
  ConsensusWorkspace();
  ~ConsensusWorkspace();
  ConsensusWorkspace(const ConsensusWorkspace&);
  ConsensusWorkspace& operator=(const ConsensusWorkspace&);
  ConsensusWorkspace(ConsensusWorkspace&&) noexcept;
  ConsensusWorkspace& operator=(ConsensusWorkspace&&) noexcept;

  struct Buffers;  ///< defined in consensus.cc

 private:
  friend class Consensus;
  std::unique_ptr<Buffers> buffers_;
};

/// A marginal that several robots fuse in one round, checked and indexed by id once. In the
/// replay every robot's marginal of all it holds is read by each of its neighbours: each fuses
/// the part it holds itself, which is what a daemon receives from that neighbour (the marginal
/// of their common objects, Consensus::select), without a copy cut for each (issue 13).
class SharedMarginal {
 public:
  SharedMarginal();
  ~SharedMarginal();
  SharedMarginal(SharedMarginal&&) noexcept;
  SharedMarginal& operator=(SharedMarginal&&) noexcept;

  /// The marginal, to be filled (its storage is reused from round to round); index() after.
  Marginal& marginal() { return marginal_; }
  const Marginal& marginal() const { return marginal_; }
  /// Checks the marginal (shapes, finite values, no repeated id) and indexes it by id. A
  /// malformed one is left out by every robot that fuses it (counted in neighbours_skipped).
  /// Returns whether it is usable.
  bool index();
  /// Whether the last index() found it well formed.
  bool usable() const;
  /// Of the landmarks `ids` (ascending), how many it holds in each of its blocks, into
  /// `per_block` (one count a block; usable() marginals only): the block sizes of
  /// Consensus::select(marginal(), ids), without the cut.
  void count_common(const std::vector<LandmarkId>& ids, std::vector<int>& per_block) const;

 private:
  friend class Consensus;
  struct Index;  ///< defined in consensus.cc
  Marginal marginal_;
  std::unique_ptr<Index> index_;
};

/// A shared marginal and the weight A_ij the robot that fuses it gives it (eq. 19).
struct WeightedShare {
  double weight = 0.0;
  const SharedMarginal* marginal = nullptr;
  int sender = -1;  ///< as WeightedMarginal::sender
};

class Consensus {
 public:
  /// Joint marginal of any subset of the objects the robot holds (in-state block of the joint
  /// covariance; archived objects independent). Unknown ids are skipped.
  static Marginal marginal(const State& state, const std::vector<LandmarkId>& ids);
  /// The same into `out`, reusing its storage: blocks of the sizes `out` already holds (an
  /// archived object's 3x3) are overwritten, not allocated again. Same result as above.
  static void marginal(const State& state, const std::vector<LandmarkId>& ids, Marginal& out);
  /// The marginal of the ids of `full` that are in `ids` (ascending; others are skipped), into
  /// `out` (its storage reused): each of full's blocks cut down to the ids it keeps, in full's
  /// order. A robot with several neighbours builds the marginal of everything it holds once a
  /// round and cuts each neighbour's out of it: for ascending ids the result equals
  /// marginal(state, ids) entry for entry when `full` is marginal(state, all) with `all`
  /// ascending, without a look-up in the state's trees per neighbour.
  static void select(const Marginal& full, const std::vector<LandmarkId>& ids, Marginal& out);
  /// Which of full's landmarks select() keeps for `ids` (ascending): one flag a landmark of
  /// full, into `keep` (for sub_marginal, or to encode the cut without making it).
  static void kept_by(const Marginal& full, const std::vector<LandmarkId>& ids,
                      std::vector<bool>& keep);

  /// Averages the robot's marginals with its neighbours' (eq. 19) and reconstructs the joint
  /// (Proposition 2, eq. 21). Each neighbour carries its weight A_ij; the robot's own weight is
  /// 1 - sum of its neighbours' weights.
  static ConsensusReport fuse(State& state, const std::vector<WeightedMarginal>& neighbours,
                              const ConsensusOptions& options);
  /// The same with the buffers of earlier rounds; the report is the workspace's, valid until
  /// its next use.
  static const ConsensusReport& fuse(State& state, const std::vector<WeightedMarginal>& neighbours,
                                     const ConsensusOptions& options,
                                     ConsensusWorkspace& workspace);

  /// The same with shared marginals (indexed; see SharedMarginal): the robot fuses the part of
  /// each that it holds. Gives what fuse() gives on Consensus::select of each marginal to the
  /// ids the robot holds, for the neighbours that hold any of them.
  static const ConsensusReport& fuse(State& state, std::span<const WeightedShare> neighbours,
                                     const ConsensusOptions& options,
                                     ConsensusWorkspace& workspace);
  /// Tests the neighbours' claims against their own earlier ones
  /// (ConsensusOptions::claim_history_rounds) without fusing anything, and keeps the consistent
  /// ones as fuse() does: for a neighbour whose marginals are not fused for a while (a daemon's
  /// quarantine), so that its history is not forgotten meanwhile and a lie it still tells is
  /// still refused when it is heard again. Returns how many claims were refused.
  static int witness(const State& state, const std::vector<WeightedMarginal>& neighbours,
                     const ConsensusOptions& options, ConsensusWorkspace& workspace);

  /// Proposition 2: replaces the marginal of in-state landmarks (slots) by N(mean, covariance),
  /// keeping the conditional of the rest of the state, and corrects poses by eq. (21).
  /// Returns false (state unchanged) if the current marginal is not positive definite.
  static bool replace_marginal(State& state, const std::vector<int>& slots,
                               const Eigen::VectorXd& mean, const Eigen::MatrixXd& covariance);

  /// Proposition 2 for one landmark whose new marginal N(mean, covariance) came from fusing in
  /// an estimate whose correlation with the rest of the state is unknown (an archived object's
  /// old marginal, by covariance intersection): the landmark takes the new marginal and the
  /// rest moves by the conditional, as replace_marginal does, but the rest's covariance never
  /// shrinks: it is replace_marginal's plus B S B^T, with B the rest's gain on the landmark and
  /// S the part of (own - new) covariance that is positive (the directions the landmark became
  /// more certain in). Where the new marginal is nowhere more certain than the own one it is
  /// replace_marginal. Returns false (state unchanged) if the own marginal is not positive
  /// definite.
  static bool replace_marginal_keeping_the_rest(State& state, int slot, const Eigen::Vector3d& mean,
                                                const Eigen::Matrix3d& covariance);

  /// Covariance intersection of two estimates of one object whose errors are correlated in an
  /// unknown way: the information-weighted average w I_a + (1 - w) I_b with the weight w in
  /// [0, 1] that minimizes the determinant of the fused covariance. Consistent whenever both
  /// inputs are. nullopt when a covariance is not positive definite.
  static std::optional<ObjectEstimate> covariance_intersection(const ObjectEstimate& a,
                                                               const ObjectEstimate& b);

  /// Metropolis-Hastings weight of edge (i, j): 1 / (1 + max(degree_i, degree_j)). Doubly
  /// stochastic on any undirected graph; 1/n on the complete graph of n robots.
  static double metropolis_weight(int degree_i, int degree_j);
};

}  // namespace concord

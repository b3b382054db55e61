#pragma once
/// \file
/// Compact, event-triggered sharing of marginals on one directed link (issue 13): what a robot
/// sends a neighbour each round and what the neighbour fuses.
///
/// - **Event-triggered.** A sender sends a neighbour only the landmarks whose 3x3 marginal moved,
///   measured in information terms, since it last sent them to that neighbour: the
///   Kullback-Leibler divergence KL(now || last sent) above `share_kl_threshold` (nats). The
///   receiver keeps the last marginal it got of every landmark and fuses it while no newer one
///   comes, as its own 3x3 block (a block structure claims nothing about correlation between
///   blocks, see Consensus::fuse). Threshold 0 sends every landmark every round.
/// - **float32.** Means as float offsets from a per-marginal origin (the first landmark's mean,
///   in double), covariance blocks as the float lower triangle of their Cholesky factor: the
///   receiver's L L^T is positive semi-definite whatever the rounding, where rounding the
///   covariance itself can make a strongly correlated block indefinite. A block that is not
///   positive definite travels in double.
///
/// Both ends of a link must agree on what the receiver holds: the sender records a landmark as
/// sent only when the link delivers (the daemons' TCP links do, or drop and reset both ends).
/// Pure and deterministic, so `concord replay` and the daemons share it bit for bit.

#include <map>
#include <vector>

#include "concord/estimator/types.h"

namespace concord {

/// KL(p || q) of two 3-D Gaussians (nats); infinity when q's covariance is not positive definite.
double kl_divergence(const ObjectEstimate& p, const ObjectEstimate& q);

/// The 3x3 marginal of landmark k of a marginal (the diagonal block of its covariance block).
ObjectEstimate landmark_estimate(const Marginal& marginal, std::size_t k);

/// Where the landmarks a cut keeps (keep[k] set) sit in a block-diagonal marginal, block by
/// block: what sub_marginal and the encoding of a cut without making it (concordd) share.
struct CutLayout {
  /// A block of the marginal: its first landmark's position, and its kept landmarks'
  /// range [begin, end) in `kept`.
  struct Block {
    Eigen::Index first = 0;
    std::size_t begin = 0, end = 0;
    Eigen::Index size() const { return static_cast<Eigen::Index>(end - begin); }
  };
  std::vector<Eigen::Index> kept;  ///< each kept landmark's position, in the marginal's order
  std::vector<Block> blocks;       ///< one a block of the marginal, kept landmarks or not

  void assign(const Marginal& marginal, const std::vector<bool>& keep);
  /// The row (or column) of the marginal's block that coordinate r of its cut is.
  Eigen::Index source_row(const Block& block, Eigen::Index r) const {
    return 3 * (kept[block.begin + static_cast<std::size_t>(r / 3)] - block.first) + r % 3;
  }
};

/// The marginal's landmarks whose positions are given, as a sub-marginal with the joint blocks
/// restricted to them (order kept).
Marginal sub_marginal(const Marginal& marginal, const std::vector<bool>& keep);
/// The same into `out`, reusing its storage (blocks of the sizes it already holds are
/// overwritten, not allocated again).
void sub_marginal(const Marginal& marginal, const std::vector<bool>& keep, Marginal& out);

/// The marginal with every block cut into consecutive runs of at most max_block_landmarks
/// landmarks (each run's diagonal block of the block it was in): the correlations between runs
/// left out (consensus.share_block_landmarks; 1: each landmark a 3x3 block of its own). The
/// marginal as it is when max_block_landmarks <= 0.
Marginal split_blocks(const Marginal& marginal, int max_block_landmarks);

/// Wire form of a marginal in float32 (see the file comment).
struct CompactMarginal {
  std::vector<LandmarkId> ids;
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  std::vector<float> mean_offsets;  ///< 3 per landmark, mean - origin
  struct Block {
    int landmarks = 0;
    /// Lower triangle of the Cholesky factor, row by row (float), or empty when the block went
    /// in double (`packed_upper`, the covariance's upper triangle row by row).
    std::vector<float> cholesky_lower;
    std::vector<double> packed_upper;
  };
  std::vector<Block> blocks;

  /// Bytes on the wire, counted as marginal_bytes counts the double form: 8 per id, 24 for the
  /// origin, 4 per float, 8 per double; 0 for an empty marginal (no fields are written).
  long long bytes() const;
};

CompactMarginal compact(const Marginal& marginal);
/// The marginal the receiver reconstructs. Returns an empty marginal when the shapes disagree.
Marginal expand(const CompactMarginal& compact);
/// expand(compact(marginal)): what a neighbour receives of `marginal` in float32.
Marginal quantized(const Marginal& marginal);

/// A link's share of a robot's landmarks a round (consensus.share_max_landmarks): robot_cap / links
/// rounded down, at least 1; 0 (no cap) when robot_cap is 0.
int link_landmark_cap(int robot_cap, int links);

/// One link's sending end.
class MarginalSender {
 public:
  /// The landmarks of `full` to send now: those never sent on this link or whose marginal moved
  /// by more than kl_threshold (nats) since (with kl_threshold 0, all of them), and at most
  /// max_landmarks of them (0: no cap): the never sent first, then by decreasing KL, ties by
  /// position in `full`. Order kept.
  Marginal select(const Marginal& full, double kl_threshold, int max_landmarks = 0) const;
  /// Records the landmarks of `sent` (as the receiver will have them) as delivered.
  void delivered(const Marginal& sent);
  /// The link dropped: everything is sent afresh.
  void reset() { last_sent_.clear(); }

 private:
  std::map<LandmarkId, ObjectEstimate> last_sent_;
};

/// One link's receiving end.
class MarginalReceiver {
 public:
  MarginalReceiver() = default;
  /// At most `max_landmarks` are kept (a peer cannot grow the store without bound).
  explicit MarginalReceiver(std::size_t max_landmarks) : max_landmarks_(max_landmarks) {}
  /// Keeps the received landmarks' marginals (every message that arrives, in order, fused or
  /// not: the sender counts it as delivered). New ids beyond max_landmarks are not kept.
  void ingest(const Marginal& received);
  /// What to fuse: `received` (this round's message, possibly empty) plus, for every id of
  /// `common` it lacks, the last marginal received of it (each its own 3x3 block). Landmarks no
  /// longer common are forgotten. `common` must be sorted.
  Marginal build(const Marginal& received, const std::vector<LandmarkId>& common);
  /// ingest, then build.
  Marginal complete(const Marginal& received, const std::vector<LandmarkId>& common) {
    ingest(received);
    return build(received, common);
  }
  void reset() { last_received_.clear(); }
  std::size_t size() const { return last_received_.size(); }

 private:
  std::size_t max_landmarks_ = 100000;
  std::map<LandmarkId, ObjectEstimate> last_received_;
};

}  // namespace concord

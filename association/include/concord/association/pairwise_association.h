#pragma once
/// \file
/// Which objects of two robots' maps are the same, and how the two frames relate.
///
/// Maps in different frames (align_maps): objects are paired by how their surroundings look
/// (distances to their nearest objects, which a rigid transform keeps), the candidate pairs form a
/// consistency graph (two candidates are consistent when the distance between their objects is
/// the same in both maps within a chi-square bound under the covariances), its maximum clique is
/// the largest set of mutually consistent pairs (CLIPPER's idea with an exact clique), the
/// transform is fitted to it, and a rival hypothesis (the largest clique of candidates the
/// transform rejects) of comparable size makes the answer ambiguous: symmetric and repetitive
/// layouts are left unmerged rather than merged wrongly. The correspondences are then every
/// pair of objects that the transform brings within a chi-square gate of each other, mutual best
/// with a margin over the second best.
///
/// Maps in one frame (match_in_frame): only that last gating.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <string>
#include <vector>

#include "concord/association/map_description.h"
#include "concord/estimator/lie.h"

namespace concord::association {

/// Every tunable of the pairwise association, with defaults in-class (YAML keys:
/// association.<name>).
struct AssociationOptions {
  /// min_observations: objects detected in fewer frames are not described (a false detection is
  /// rarely tracked long, a briefly seen object is poorly placed).
  int min_observations = 5;
  /// search_max_sigma: only objects whose position is known this well (metres, the largest
  /// standard deviation of the local covariance) take part in the search for a transform; the
  /// others can still be matched once it is known. A loosely placed object makes almost any
  /// distance consistent.
  double search_max_sigma = 0.5;
  /// descriptor_neighbours: an object's surroundings are its distances to this many nearest
  /// objects of its map.
  int descriptor_neighbours = 8;
  /// descriptor_chi2_probability: two neighbour distances agree within this chi-square quantile
  /// (1 degree of freedom) under their variances.
  double descriptor_chi2_probability = 0.95;
  /// candidates_per_object: each object keeps this many best-described partners as candidates.
  int candidates_per_object = 5;
  /// min_descriptor_matches: a candidate needs this many of its neighbour distances to agree.
  int min_descriptor_matches = 2;
  /// consistency_chi2_probability: two candidates are consistent when the difference of their
  /// objects' distances in the two maps is within this chi-square quantile (1 degree of freedom)
  /// under the covariances.
  double consistency_chi2_probability = 0.999;
  /// distance_noise: model error of a position beyond its covariance (metres, per axis), e.g.
  /// viewpoint-dependent detection centres; added to every covariance.
  double distance_noise = 0.05;
  /// min_inliers: correspondences needed to accept a transform.
  int min_inliers = 5;
  /// min_spread: the matched objects must spread at least this far (metres, the standard
  /// deviation along their second principal direction): nearly collinear points do not fix a
  /// rotation.
  double min_spread = 1.0;
  /// ambiguity_ratio: a rival clique (candidates the best transform rejects) with at least this
  /// fraction of the best clique's size (and at least 3) makes the pair ambiguous.
  double ambiguity_ratio = 0.5;
  /// match_chi2_probability: gate of a correspondence under a known transform (3 degrees of
  /// freedom).
  double match_chi2_probability = 0.999;
  /// match_margin: the second-best partner of either object must be at least this much further
  /// (squared Mahalanobis distance; 9 is a likelihood ratio of about 90) than the best.
  double match_margin = 9.0;
  /// max_hypotheses: cliques tried in turn when the largest does not fit a rigid transform.
  int max_hypotheses = 3;
  /// max_candidates: candidates kept (best descriptor scores first).
  int max_candidates = 1500;
  /// max_clique_expansions: branch-and-bound budget of one clique search.
  int max_clique_expansions = 200000;
  /// use_classes: only objects of the same class (or of unknown class) are candidates.
  bool use_classes = true;

  /// Every problem with the values, each naming the key and the bad value; empty when valid.
  std::vector<std::string> validate() const;
};

/// One correspondence: object id_a of map a is object id_b of map b.
struct Match {
  LandmarkId id_a = 0;
  LandmarkId id_b = 0;
  double mahalanobis_squared = 0.0;
};

enum class AlignmentStatus {
  kAligned,
  kTooFewObjects,     ///< a map has fewer than min_inliers objects
  kTooFewCandidates,  ///< fewer than min_inliers candidates
  kTooFewInliers,     ///< the largest consistent set is smaller than min_inliers
  kDegenerate,        ///< the consistent set does not fix a transform (collinear, too small)
  kAmbiguous,         ///< a rival hypothesis of comparable size
};

std::string to_string(AlignmentStatus status);

/// The outcome of align_maps.
struct PairAlignment {
  AlignmentStatus status = AlignmentStatus::kTooFewObjects;
  /// Maps b's frame into a's (valid when aligned).
  Eigen::Isometry3d T_a_b = Eigen::Isometry3d::Identity();
  /// Covariance of T_a_b as a left perturbation in a's frame (alignment.h).
  lie::Matrix6d covariance = lie::Matrix6d::Identity();
  /// Correspondences, sorted by id_a (valid when aligned).
  std::vector<Match> matches;
  int candidates = 0;
  long long consistency_edges = 0;
  int clique_size = 0;
  int rival_clique_size = 0;
  /// Whether both clique searches finished within their budget.
  bool cliques_exact = true;
};

/// Correspondences and transform between two maps in different frames (see the file comment).
PairAlignment align_maps(const MapDescription& a, const MapDescription& b,
                         const AssociationOptions& options);

/// Correspondences of two maps under a known transform T_a_b (identity for maps in one frame):
/// pairs within the match gate, mutual best with the margin, compatible classes; residual
/// covariance C_a + R C_b R^T + distance_noise^2 I with the marginal covariances (local: the
/// local covariances). Sorted by id_a.
std::vector<Match> match_with_transform(const MapDescription& a, const MapDescription& b,
                                        const Eigen::Isometry3d& T_a_b, bool local,
                                        const AssociationOptions& options);

/// Squared Mahalanobis distance of two descriptions of one object in one frame (marginal
/// covariances plus distance_noise).
double mahalanobis_squared(const ObjectDescription& a, const ObjectDescription& b,
                           const AssociationOptions& options);

}  // namespace concord::association

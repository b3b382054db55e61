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
#include <memory>
#include <string>
#include <vector>

#include "concord/association/alignment.h"
#include "concord/association/map_description.h"
#include "concord/association/options.h"
#include "concord/estimator/lie.h"

namespace concord::association {

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
  kTilted,            ///< the transform tilts the start frames beyond max_start_tilt
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
  /// The fit of the largest clique (alignment.h, RigidAlignment::chi2 and largest_residual), once
  /// a level one was found.
  double clique_fit_chi2 = 0.0;
  double clique_fit_largest_residual = 0.0;
  /// Whether both clique searches finished within their budget.
  bool cliques_exact = true;
};

/// Correspondences and transform between two maps in different frames (see the file comment).
PairAlignment align_maps(const MapDescription& a, const MapDescription& b,
                         const AssociationOptions& options);

/// A map made ready for align_maps: the objects a search uses (the well placed ones), the
/// distances between them and each one's descriptor, all of which depend on the map alone. A
/// robot searches its own map against several neighbours' in a round: prepared once, the same
/// results as align_maps on the maps themselves, without deriving them again for every pair.
class PreparedMap {
 public:
  /// `options` must be those the searches use (search_max_sigma, distance_noise and
  /// descriptor_neighbours shape what is prepared).
  PreparedMap(const MapDescription& map, const AssociationOptions& options);
  ~PreparedMap();
  PreparedMap(PreparedMap&&) noexcept;
  PreparedMap& operator=(PreparedMap&&) noexcept;

 private:
  friend PairAlignment align_maps(const PreparedMap& a, const PreparedMap& b,
                                  const AssociationOptions& options);
  friend PairAlignment align_in_frame(const PreparedMap& a, const PreparedMap& b,
                                      const AssociationOptions& options);
  struct Parts;
  std::unique_ptr<const Parts> parts_;
};

/// align_maps on prepared maps (the same result as on the maps they were prepared from).
PairAlignment align_maps(const PreparedMap& a, const PreparedMap& b,
                         const AssociationOptions& options);

/// The search of align_maps for two maps already in one frame: the candidates are the pairs of
/// compatible classes whose positions agree as the maps stand, within the match gate of their
/// marginal covariances (not the descriptors', which assume nothing of the transform); the
/// consistency graph, its cliques, the rival check and the final matching are align_maps'. A
/// common shift of one map against the other (the error of a move into the team frame) keeps the
/// distances within each map, so the largest consistent set finds it where matching object by
/// object would pair each object with the neighbour the shift brought closest; in a repetitive
/// layout the shifted set is a rival and the result is ambiguous.
PairAlignment align_in_frame(const PreparedMap& a, const PreparedMap& b,
                             const AssociationOptions& options);

/// Which of an object's covariances a comparison of two maps takes (ObjectDescription):
/// kMarginal, the marginal (maps compared as they stand in one frame); kTransform,
/// transform_covariance() (under a transform fitted where the robots are now); kLocal,
/// local_covariance (under the relative pose fitted to a pair's accepted correspondences,
/// which absorbs what each map shares, however old its parts).
enum class Covariances { kMarginal, kTransform, kLocal };

/// Correspondences of two maps under a known transform T_a_b (identity for maps in one frame):
/// pairs within the match gate, mutual best with the margin, compatible classes; residual
/// covariance C_a + R C_b R^T + distance_noise^2 I with the covariances `which`, plus
/// J Sigma J^T when the transform's covariance Sigma is given (a left perturbation in a's frame,
/// J = [I, -[T_a_b p_b]x]: a fitted transform's error grows with the distance from where it was
/// fitted). Sorted by id_a.
std::vector<Match> match_with_transform(const MapDescription& a, const MapDescription& b,
                                        const Eigen::Isometry3d& T_a_b, Covariances which,
                                        const AssociationOptions& options,
                                        const lie::Matrix6d* transform_covariance = nullptr);

/// The unit vector of an AssociationOptions::start_up_axis ("+x" ... "-z"); zero for "unknown"
/// or anything else.
Eigen::Vector3d start_up_vector(const std::string& axis);

/// Whether T_a_b keeps the up axis (start_up_axis) level: the angle between up and R_a_b up is
/// at most max_start_tilt plus three standard deviations of the transform's rotation about the
/// horizontal axes (`covariance`, a left perturbation in a's frame on [rho; phi]). Always true
/// when the axis is unknown.
bool keeps_level(const Eigen::Isometry3d& T_a_b, const lie::Matrix6d& covariance,
                 const AssociationOptions& options);

/// The correspondence of one object described by robot a and by robot b, as a transform's fit
/// takes it: a's position is the target, b's the source; covariances relative to each robot's
/// current pose when `local` (ObjectDescription::transform_covariance), the marginals otherwise;
/// the model error distance_noise^2 I once, on a's side.
PointPair point_pair(const ObjectDescription& a, const ObjectDescription& b, bool local,
                     double distance_noise);

/// Squared Mahalanobis distance of two descriptions of one object in one frame (marginal
/// covariances plus distance_noise).
double mahalanobis_squared(const ObjectDescription& a, const ObjectDescription& b,
                           const AssociationOptions& options);

}  // namespace concord::association

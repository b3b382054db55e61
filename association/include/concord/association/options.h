#pragma once
/// \file
/// The association's tunables (YAML keys: association.<name> in a sensor config), in a header
/// without Eigen so that configs can hold them.

#include <string>
#include <vector>

namespace concord::association {

/// Every tunable of the pairwise association, with defaults in-class (YAML keys:
/// association.<name>).
struct AssociationOptions {
  /// min_observations: objects detected in fewer frames are not described (a false detection is
  /// rarely tracked long, a briefly seen object is poorly placed).
  int min_observations = 5;
  /// min_detection_ratio: objects detected in fewer than this fraction of the frames in which
  /// they were in the robot's view are not described (ObservationTally: a false detection is not
  /// seen again where it was while the robot still looks there; a real object is, but for
  /// occlusion and the detector's misses). 0: every object is described.
  double min_detection_ratio = 0.5;
  /// search_max_sigma: only objects whose position is known this well (metres, the largest
  /// standard deviation of the local covariance) take part in the search for a transform; the
  /// others can still be matched once it is known. A loosely placed object makes almost any
  /// distance consistent.
  double search_max_sigma = 0.5;
  /// archived_local_covariance: describe an archived object by its covariance relative to the
  /// pose the robot had when it archived it (State::archived_local_covariance) instead of its
  /// marginal, in the search filter, the descriptors and the consistency graph (the map's
  /// geometry); the transform's fit keeps the marginal. Off: it lets old parts of a map take part
  /// in the search (kitti00 aligns), but a robot that aligns early with a drifted map moves its
  /// archived objects into the team frame with a transform that fits its current map
  /// (docs/association.md, "Limits").
  bool archived_local_covariance = false;
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
  /// freedom). 0.999 until 2026-11-30: true correspondences lie well inside it (their covariances
  /// are conservative: at most 0.6 % of them beyond the 95 % bound on the development seeds),
  /// while a fifth to two fifths of the wrong ones were accepted between the two bounds, where
  /// the other map had nothing closer (docs/association.md).
  double match_chi2_probability = 0.95;
  /// match_margin: the second-best partner of either object must be at least this much further
  /// (squared Mahalanobis distance; 4 is a likelihood ratio of about 7) than the best. 9 (about
  /// 90) until 2026-11-29: on the development seeds 11-13 it refused so many true matches of
  /// objects near others that alignments came late or not at all (docs/association.md).
  double match_margin = 4.0;
  /// max_hypotheses: cliques tried in turn when the largest does not fit a rigid transform.
  int max_hypotheses = 3;
  /// max_candidates: candidates kept (best descriptor scores first).
  int max_candidates = 1500;
  /// max_clique_expansions: branch-and-bound budget of one clique search.
  int max_clique_expansions = 200000;
  /// use_classes: only objects of the same class (or of unknown class) are candidates.
  bool use_classes = true;
  /// start_up_axis: the body axis that points up when the robot stands level ("+x", "-x", "+y",
  /// "-y", "+z", "-z"), the same for every robot of the team, or "unknown" (the default). When
  /// known, two robots' start frames are taken to be level to within max_start_tilt (ground
  /// robots, or start frames levelled by an IMU's gravity), and a pair whose best transform
  /// tilts one robot's up axis further from the other's (beyond max_start_tilt plus three
  /// standard deviations of the fit) is refused for that description. It only ever refuses:
  /// rivals still count, no other hypothesis is tried instead. A wrong match of two nearly
  /// flat or collinear layouts (cars along streets) can fit a rotation that turns one robot's
  /// world over as well as the right one fits.
  std::string start_up_axis = "unknown";
  /// max_start_tilt: degrees; how far two robots' start frames may be tilted relative to each
  /// other (slopes, suspension, mounting), with start_up_axis.
  double max_start_tilt = 10.0;

  /// Every problem with the values, each naming the key and the bad value; empty when valid.
  std::vector<std::string> validate() const;
};

/// Tunables of the negotiation (YAML keys: association.<name>, as AssociationOptions).
struct NegotiationOptions {
  AssociationOptions association;
  /// description_interval: a robot describes its map every this many rounds.
  int description_interval = 5;
  /// confirmations: consecutive descriptions in which a transform (across frames) or a
  /// correspondence (in one frame) must be found before it is acted on.
  int confirmations = 3;
  /// confirmation_new_matches: a transform across frames is confirmed only when the last of its
  /// confirming descriptions also matches at least this many correspondences that the first did
  /// not (0: the count of descriptions alone). A right transform keeps predicting the objects
  /// both robots go on to map; a wrong one fitted to a coincidental layout stops at it, and
  /// maps that barely change between descriptions confirm it over and over.
  int confirmation_new_matches = 1;
  /// transform_agreement_chi2_probability: two successive transforms of a pair agree when the
  /// 6-D difference is within this chi-square quantile under the sum of their covariances.
  double transform_agreement_chi2_probability = 0.999;
  /// split_chi2_probability: the objects of an accepted correspondence disagree when their
  /// squared Mahalanobis distance (marginal covariances) exceeds this quantile (3 dof).
  double split_chi2_probability = 0.9999;
  /// split_after: consecutive descriptions of disagreement that undo a correspondence.
  int split_after = 2;
  /// revisit_descriptions, revisit_interval: after accepting a transform, the owner of the pair
  /// searches the two maps (now in one frame) as if their frames still differed, on every
  /// revisit_interval-th of its next revisit_descriptions descriptions (0: never). A transform
  /// away from the identity (revisit_chi2_probability) in revisit_confirmations such revisits in
  /// a row that agree shows the accepted one wrong: the edge is corrected, the robots on its far
  /// side move, and the window starts again. A search costs as much as one across frames.
  int revisit_descriptions = 18;
  int revisit_interval = 3;
  int revisit_confirmations = 2;
  /// revisit_chi2_probability: the maps are misaligned when the 6-D transform a revisit finds is
  /// beyond this chi-square quantile from the identity under its covariance.
  double revisit_chi2_probability = 0.9999;
  /// revisit_ambiguity_ratio: the accepted alignment is a hypothesis too. A revisit whose maps,
  /// as they stand in the common frame, match at least this fraction of the correspondences the
  /// found transform matches is ambiguous (a layout that fits two ways, or one robot's map gone
  /// wrong on its own), as a rival clique makes a search: it corrects nothing. 0.5, the
  /// search's ambiguity_ratio; above 1 only a clearly better supported transform is ambiguous.
  double revisit_ambiguity_ratio = 0.5;
  /// relay_delay: rounds a robot holds another owner's record before it relays it to a neighbour
  /// that has not said it holds it (every message lists the versions its sender holds). On the
  /// complete graph every robot has a record from its owner in the round it is sent: relayed at
  /// once, each record would cross every link of the team, most of them for nothing. Two rounds
  /// let a neighbour's next message say so first (messages of a round are made before that
  /// round's are read). A record then crosses a hop in relay_delay + 1 rounds where its owner
  /// is not a neighbour; 0 relays at once.
  int relay_delay = 2;
  /// max_corrections: corrections of one frame edge at most.
  int max_corrections = 2;
  /// in_frame_fit: two robots in one frame match their maps under their relative pose fitted to
  /// the pair's accepted correspondences, on the covariances relative to each robot (as a search
  /// across frames fits and matches), once there are min_inliers of them; otherwise, and when
  /// off, as the maps stand in the common frame on their marginal covariances. The marginals
  /// carry each robot's uncertainty about the team frame (tenths of a metre to metres after a
  /// move): a gate that wide lets unrelated objects match, and a robot whose map is shifted
  /// against the other's misses its true partners. Off until 2026-11-30 (docs/association.md).
  bool in_frame_fit = true;
  /// in_frame_current_pass: after matching under the fit, the objects both robots still hold in
  /// their joint states (in view now) that it left without a partner, and that no accepted
  /// correspondence holds, are matched again where the robots are now. The fit rests on the
  /// pair's accepted links, often parts of the maps mapped long before; where the robots are
  /// now, their maps may have drifted apart since by more than the fit's gate allows, and a
  /// robot that is not linked there is not corrected there either. Where the pair has
  /// min_inliers links (accepted or just matched) between objects both hold in their states,
  /// under the maps' offset there: the mean difference of those links' positions, on the local
  /// covariances plus the offsets' spread (Negotiator::current_offset). Otherwise as the maps
  /// stand, on their marginals: an in-state object's marginal is its robot's current
  /// uncertainty in the frame (since moves carry the maps' drift, session 75), which is what the
  /// two maps' offset there is made of, but a gate that wide pairs an object with a neighbour's
  /// false detection that the offset brought closer than its true partner (session 77).
  /// Archived objects take no part: their marginals are wide enough to take in false detections
  /// (docs/association.md, Results).
  bool in_frame_current_pass = true;
  /// in_frame_search: with in_frame_fit, a pair in one frame without min_inliers accepted
  /// correspondences to fit finds its first ones by a search (align_in_frame: the candidates
  /// that agree as the maps stand on their marginals, then align_maps' consistency graph,
  /// largest clique and rival check), and matches under its transform as under the fit. Where
  /// the search finds no consistent set (too few objects, not ambiguous), objects are matched
  /// one by one as the maps stand only while no map can have been moved into the frame (no
  /// frame edge joins it: known starts). Off, always one by one. After a move into the team
  /// frame both maps carry the move's error, common to all their objects: one by one, a shift of
  /// a metre or more pairs an object whose partner the other robot does not hold with the
  /// neighbour the shift brought closest, and consensus then pulls the wrong objects together,
  /// which makes the error look consistent to every later test (docs/association.md, Results,
  /// session 76).
  bool in_frame_search = true;

  /// Every problem with the values (and with association's), naming the key; empty when valid.
  std::vector<std::string> validate() const;
};

}  // namespace concord::association

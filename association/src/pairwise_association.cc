#include "concord/association/pairwise_association.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numbers>
#include <optional>

#include "concord/association/alignment.h"
#include "concord/association/max_clique.h"
#include "concord/estimator/options.h"
#include "concord/estimator/symmetric3.h"
#include "concord/estimator/updater_helper.h"

namespace concord::association {

namespace pairwise_detail {

/// Distances and their variances between every two objects of one map (local covariances):
/// sigma^2 of |p_i - p_j| is u^T (C_i + C_j) u + 2 distance_noise^2 along the unit vector u.
class DistanceTable {
 public:
  /// A distance and its variance; the two lie together (the consistency graph reads both of
  /// two objects at once, in rows it does not walk in order).
  using Entry = std::pair<double, double>;

  DistanceTable(const MapDescription& map, double distance_noise)
      : n_(map.objects.size()), entries_(n_ * n_, Entry(0.0, 0.0)) {
    const double floor = 2.0 * distance_noise * distance_noise;
    for (std::size_t i = 0; i < n_; ++i) {
      for (std::size_t j = i + 1; j < n_; ++j) {
        const Eigen::Vector3d difference = map.objects[i].position - map.objects[j].position;
        const double distance = difference.norm();
        double variance = floor;
        if (distance > 0.0) {
          const Eigen::Vector3d u = difference / distance;
          variance +=
              u.dot((map.objects[i].local_covariance + map.objects[j].local_covariance) * u);
        } else {
          variance += (map.objects[i].local_covariance + map.objects[j].local_covariance).trace();
        }
        entries_[i * n_ + j] = entries_[j * n_ + i] = Entry(distance, variance);
      }
    }
  }

  const Entry& entry(std::size_t i, std::size_t j) const { return entries_[i * n_ + j]; }
  /// Row i: the entries of object i with every object (its own first-to-last, itself 0, 0).
  const Entry* row(std::size_t i) const { return entries_.data() + i * n_; }

  /// The k nearest other objects of object i as (distance, variance), by distance.
  std::vector<Entry> neighbours(std::size_t i, int k) const {
    std::vector<Entry> all;
    all.reserve(n_);
    for (std::size_t j = 0; j < n_; ++j) {
      if (j != i) all.push_back(entry(i, j));
    }
    const std::size_t keep = std::min<std::size_t>(all.size(), static_cast<std::size_t>(k));
    std::partial_sort(all.begin(), all.begin() + static_cast<std::ptrdiff_t>(keep), all.end());
    all.resize(keep);
    return all;
  }

 private:
  std::size_t n_;
  std::vector<Entry> entries_;
};

}  // namespace pairwise_detail

/// What a prepared map holds: the objects a search uses, their distance table and descriptors.
/// The well-placed objects at once; their distances and descriptors when a search first needs
/// them (a search in one frame needs no descriptors, and no distances when it has too few
/// candidates).
struct PreparedMap::Parts {
  MapDescription placed;
  double distance_noise = 0.0;
  int descriptor_neighbours = 0;
  mutable std::optional<pairwise_detail::DistanceTable> table_made;
  mutable std::optional<std::vector<std::vector<pairwise_detail::DistanceTable::Entry>>>
      descriptors_made;

  const pairwise_detail::DistanceTable& table() const;
  const std::vector<std::vector<pairwise_detail::DistanceTable::Entry>>& descriptors() const;
};

namespace {

using pairwise_detail::DistanceTable;

constexpr double kInfinity = std::numeric_limits<double>::infinity();

bool classes_compatible(int a, int b, const AssociationOptions& options) {
  return !options.use_classes || a == kUnknownClass || b == kUnknownClass || a == b;
}

/// How well two sorted neighbour lists agree: the number of distances that agree within the
/// bound (greedy two-pointer matching, each used once), plus, to order equal counts, the sum of
/// exp(-z^2 / 2) over those (z the normalized difference) divided by (list size + 1).
/// A count below `min_count` is returned alone (without the closeness, which only orders equal
/// counts): a candidate needs min_count matches to be kept, and any score below min_count ranks
/// below every score that is kept.
double descriptor_score(const std::vector<std::pair<double, double>>& a,
                        const std::vector<std::pair<double, double>>& b, double bound,
                        int min_count) {
  // The matching is walked once to count, and again for the closeness only when it counts.
  const auto walk = [&](auto&& on_match) {
    std::size_t i = 0, j = 0;
    while (i < a.size() && j < b.size()) {
      const double difference = a[i].first - b[j].first;
      const double squared = difference * difference / (a[i].second + b[j].second);
      if (squared <= bound) {
        on_match(squared);
        ++i;
        ++j;
      } else if (difference < 0.0) {
        ++i;
      } else {
        ++j;
      }
    }
  };
  int count = 0;
  walk([&](double) { ++count; });
  if (count < min_count) return count;
  double closeness = 0.0;
  walk([&](double squared) { closeness += std::exp(-0.5 * squared); });
  return count + closeness / static_cast<double>(std::max(a.size(), b.size()) + 1);
}

struct Candidate {
  int a = 0;  ///< index in map a
  int b = 0;  ///< index in map b
  double score = 0.0;
};

/// Candidate pairs: each object's best-described partners in the other map (both directions).
using Descriptors = std::vector<std::vector<DistanceTable::Entry>>;

/// Each object's descriptor: its descriptor_neighbours nearest other objects as (distance,
/// variance), by distance.
Descriptors descriptors_of(const MapDescription& map, const DistanceTable& table, int neighbours) {
  Descriptors descriptors;
  descriptors.reserve(map.objects.size());
  for (std::size_t i = 0; i < map.objects.size(); ++i)
    descriptors.push_back(table.neighbours(i, neighbours));
  return descriptors;
}

/// At most `max_candidates` of them, the best scored (ties in their order), in (a, b) order.
void keep_best_candidates(std::vector<Candidate>& candidates, int max_candidates) {
  if (static_cast<int>(candidates.size()) <= max_candidates) return;
  std::stable_sort(candidates.begin(), candidates.end(),
                   [](const Candidate& x, const Candidate& y) { return x.score > y.score; });
  candidates.resize(static_cast<std::size_t>(max_candidates));
  std::sort(candidates.begin(), candidates.end(), [](const Candidate& x, const Candidate& y) {
    return x.a != y.a ? x.a < y.a : x.b < y.b;
  });
}

std::vector<Candidate> find_candidates(const MapDescription& a, const MapDescription& b,
                                       const Descriptors& descriptors_a,
                                       const Descriptors& descriptors_b,
                                       const AssociationOptions& options) {
  const std::size_t na = a.objects.size(), nb = b.objects.size();
  const double bound = UpdaterHelper::chi2_quantile(options.descriptor_chi2_probability, 1);
  std::vector<double> scores(na * nb, 0.0);
  for (std::size_t i = 0; i < na; ++i) {
    for (std::size_t j = 0; j < nb; ++j) {
      if (!classes_compatible(a.objects[i].object_class, b.objects[j].object_class, options)) {
        continue;
      }
      scores[i * nb + j] = descriptor_score(descriptors_a[i], descriptors_b[j], bound,
                                            options.min_descriptor_matches);
    }
  }
  // Keep the best candidates_per_object of each row and of each column.
  std::vector<bool> kept(na * nb, false);
  const auto keep_best = [&](std::vector<std::pair<double, std::size_t>>& line) {
    std::stable_sort(line.begin(), line.end(),
                     [](const auto& x, const auto& y) { return x.first > y.first; });
    for (std::size_t n = 0;
         n < line.size() && n < static_cast<std::size_t>(options.candidates_per_object); ++n) {
      if (line[n].first >= options.min_descriptor_matches) kept[line[n].second] = true;
    }
  };
  std::vector<std::pair<double, std::size_t>> line;
  for (std::size_t i = 0; i < na; ++i) {
    line.clear();
    for (std::size_t j = 0; j < nb; ++j) line.emplace_back(scores[i * nb + j], i * nb + j);
    keep_best(line);
  }
  for (std::size_t j = 0; j < nb; ++j) {
    line.clear();
    for (std::size_t i = 0; i < na; ++i) line.emplace_back(scores[i * nb + j], i * nb + j);
    keep_best(line);
  }
  std::vector<Candidate> candidates;
  for (std::size_t cell = 0; cell < kept.size(); ++cell) {
    if (kept[cell]) {
      candidates.push_back(
          {static_cast<int>(cell / nb), static_cast<int>(cell % nb), scores[cell]});
    }
  }
  keep_best_candidates(candidates, options.max_candidates);
  return candidates;
}

/// Consistency graph: candidates u, v (different objects on both sides) are adjacent when their
/// distances agree: (d_a - d_b)^2 <= chi2_1 (sigma_a^2 + sigma_b^2).
ConsistencyGraph consistency_graph(const std::vector<Candidate>& candidates,
                                   const DistanceTable& table_a, const DistanceTable& table_b,
                                   double bound) {
  const std::size_t n = candidates.size();
  ConsistencyGraph graph(static_cast<int>(n));
  // Each candidate's edges to the later ones as a row of bits, 64 tests a word without a
  // branch, then added at once (their mirror bits too).
  std::vector<std::uint64_t> upper(graph.words(), 0);
  for (std::size_t u = 0; u < n; ++u) {
    const Candidate& x = candidates[u];
    const DistanceTable::Entry* row_a = table_a.row(static_cast<std::size_t>(x.a));
    const DistanceTable::Entry* row_b = table_b.row(static_cast<std::size_t>(x.b));
    std::fill(upper.begin(), upper.end(), 0);
    for (std::size_t w = (u + 1) / 64; w < upper.size(); ++w) {
      std::uint64_t word = 0;
      const std::size_t end = std::min(n, 64 * (w + 1));
      for (std::size_t v = std::max(u + 1, 64 * w); v < end; ++v) {
        const Candidate& y = candidates[v];
        const DistanceTable::Entry& in_a = row_a[y.a];
        const DistanceTable::Entry& in_b = row_b[y.b];
        const double difference = in_a.first - in_b.first;
        const double variance = in_a.second + in_b.second;
        const bool consistent =
            (x.a != y.a) & (x.b != y.b) & (difference * difference <= bound * variance);
        word |= static_cast<std::uint64_t>(consistent) << (v & 63);
      }
      upper[w] = word;
    }
    graph.add_edges_above(static_cast<int>(u), upper.data());
  }
  return graph;
}

/// Standard deviation of points along their second principal direction.
double spread(const std::vector<Eigen::Vector3d>& points) {
  if (points.size() < 3) return 0.0;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (const auto& p : points) scatter += (p - mean) * (p - mean).transpose();
  scatter /= static_cast<double>(points.size());
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(scatter);
  return std::sqrt(std::max(0.0, solver.eigenvalues()(1)));
}

/// Fits the transform to the matches (local covariances); nullopt when degenerate.
std::optional<RigidAlignment> fit(const MapDescription& a, const MapDescription& b,
                                  const std::vector<std::pair<int, int>>& pairs,
                                  const AssociationOptions& options) {
  std::vector<PointPair> points;
  std::vector<Eigen::Vector3d> positions;
  for (const auto& [i, j] : pairs) {
    points.push_back(point_pair(a.objects[i], b.objects[j], true, options.distance_noise));
    positions.push_back(a.objects[i].position);
  }
  if (spread(positions) < options.min_spread) return std::nullopt;
  return align_points(points);
}

/// Index of each id in a map (objects sorted by id).
int index_of(const MapDescription& map, LandmarkId id) {
  const auto it = std::lower_bound(
      map.objects.begin(), map.objects.end(), id,
      [](const ObjectDescription& object, LandmarkId key) { return object.id < key; });
  return it != map.objects.end() && it->id == id ? static_cast<int>(it - map.objects.begin()) : -1;
}

}  // namespace

std::vector<std::string> AssociationOptions::validate() const {
  std::vector<std::string> problems;
  const auto require = [&](bool ok, const std::string& key, double value, const std::string& rule) {
    if (!ok) {
      problems.push_back("association." + key + " = " + std::to_string(value) + ": must be " +
                         rule);
    }
  };
  require(min_observations >= 1, "min_observations", min_observations, ">= 1");
  require(min_detection_ratio >= 0.0 && min_detection_ratio <= 1.0, "min_detection_ratio",
          min_detection_ratio, "in [0, 1]");
  require(std::isfinite(search_max_sigma) && search_max_sigma > 0.0, "search_max_sigma",
          search_max_sigma, "finite and > 0");
  require(descriptor_neighbours >= 2, "descriptor_neighbours", descriptor_neighbours, ">= 2");
  require(descriptor_chi2_probability > 0.0 && descriptor_chi2_probability < 1.0,
          "descriptor_chi2_probability", descriptor_chi2_probability, "in (0, 1)");
  require(candidates_per_object >= 1, "candidates_per_object", candidates_per_object, ">= 1");
  require(min_descriptor_matches >= 1, "min_descriptor_matches", min_descriptor_matches, ">= 1");
  require(consistency_chi2_probability > 0.0 && consistency_chi2_probability < 1.0,
          "consistency_chi2_probability", consistency_chi2_probability, "in (0, 1)");
  require(std::isfinite(distance_noise) && distance_noise >= 0.0, "distance_noise", distance_noise,
          "finite and >= 0");
  require(min_inliers >= 3, "min_inliers", min_inliers, ">= 3");
  require(std::isfinite(min_spread) && min_spread >= 0.0, "min_spread", min_spread,
          "finite and >= 0");
  require(ambiguity_ratio > 0.0 && ambiguity_ratio <= 1.0, "ambiguity_ratio", ambiguity_ratio,
          "in (0, 1]");
  require(match_chi2_probability > 0.0 && match_chi2_probability < 1.0, "match_chi2_probability",
          match_chi2_probability, "in (0, 1)");
  require(std::isfinite(match_margin) && match_margin >= 0.0, "match_margin", match_margin,
          "finite and >= 0");
  require(max_hypotheses >= 1, "max_hypotheses", max_hypotheses, ">= 1");
  require(max_candidates >= 3, "max_candidates", max_candidates, ">= 3");
  require(max_clique_expansions >= 1, "max_clique_expansions",
          static_cast<double>(max_clique_expansions), ">= 1");
  if (start_up_axis != "unknown" && start_up_vector(start_up_axis).isZero()) {
    problems.push_back("association.start_up_axis = " + start_up_axis +
                       ": must be unknown, +x, -x, +y, -y, +z or -z");
  }
  require(std::isfinite(max_start_tilt) && max_start_tilt > 0.0 && max_start_tilt <= 180.0,
          "max_start_tilt", max_start_tilt, "in (0, 180] degrees");
  return problems;
}

std::string to_string(AlignmentStatus status) {
  switch (status) {
    case AlignmentStatus::kAligned:
      return "aligned";
    case AlignmentStatus::kTooFewObjects:
      return "too few objects";
    case AlignmentStatus::kTooFewCandidates:
      return "too few candidates";
    case AlignmentStatus::kTooFewInliers:
      return "too few inliers";
    case AlignmentStatus::kDegenerate:
      return "degenerate";
    case AlignmentStatus::kAmbiguous:
      return "ambiguous";
    case AlignmentStatus::kTilted:
      return "tilted";
  }
  return "unknown";
}

Eigen::Vector3d start_up_vector(const std::string& axis) {
  const std::array<double, 3> v = body_axis_vector(axis);
  return {v[0], v[1], v[2]};
}

bool keeps_level(const Eigen::Isometry3d& T_a_b, const lie::Matrix6d& covariance,
                 const AssociationOptions& options) {
  const Eigen::Vector3d up = start_up_vector(options.start_up_axis);
  if (up.isZero()) return true;
  const double cosine = std::clamp(up.dot(T_a_b.linear() * up), -1.0, 1.0);
  // The fit's uncertainty about the horizontal axes (the rotation block of the left
  // perturbation, in a's frame, without its part about the up axis).
  const Eigen::Matrix3d across = Eigen::Matrix3d::Identity() - up * up.transpose();
  const Eigen::Matrix3d tilt_covariance =
      across * covariance.bottomRightCorner<3, 3>() * across.transpose();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(tilt_covariance,
                                                              Eigen::EigenvaluesOnly);
  const double sigma = std::sqrt(std::max(0.0, solver.eigenvalues()(2)));
  return std::acos(cosine) <= options.max_start_tilt * std::numbers::pi / 180.0 + 3.0 * sigma;
}

PointPair point_pair(const ObjectDescription& a, const ObjectDescription& b, bool local,
                     double distance_noise) {
  const Eigen::Matrix3d floor = distance_noise * distance_noise * Eigen::Matrix3d::Identity();
  return {a.position, b.position, (local ? a.transform_covariance() : a.covariance) + floor,
          local ? b.transform_covariance() : b.covariance};
}

double mahalanobis_squared(const ObjectDescription& a, const ObjectDescription& b,
                           const AssociationOptions& options) {
  const Eigen::Matrix3d covariance =
      a.covariance + b.covariance +
      options.distance_noise * options.distance_noise * Eigen::Matrix3d::Identity();
  return symmetric3::inverse_quadratic(symmetric3::lower_of(covariance), a.position - b.position)
      .value_or(kInfinity);
}

std::vector<Match> match_with_transform(const MapDescription& a, const MapDescription& b,
                                        const Eigen::Isometry3d& T_a_b, Covariances which,
                                        const AssociationOptions& options,
                                        const lie::Matrix6d* transform_covariance) {
  const auto covariance_of = [which](const ObjectDescription& object) -> const Eigen::Matrix3d& {
    switch (which) {
      case Covariances::kTransform:
        return object.transform_covariance();
      case Covariances::kLocal:
        return object.local_covariance;
      case Covariances::kMarginal:
        break;
    }
    return object.covariance;
  };
  const double gate = UpdaterHelper::chi2_quantile(options.match_chi2_probability, 3);
  const std::size_t na = a.objects.size(), nb = b.objects.size();
  const Eigen::Matrix3d& R = T_a_b.linear();
  const double noise = options.distance_noise * options.distance_noise;
  // 1. Every pair within the gate (a trace bound rejects most pairs cheaply: d^2 >= |r|^2 / trace).
  // b's side of every pair's covariance, in a's frame: R C_b R^T, plus J Sigma J^T for an
  // uncertain transform (J = [I, -[T p_b]x] for T = exp(eps^) T_hat).
  std::vector<Eigen::Vector3d> transformed(nb);
  std::vector<Eigen::Matrix3d> covariance_b(nb);
  std::vector<double> trace_b(nb);
  for (std::size_t j = 0; j < nb; ++j) {
    transformed[j] = T_a_b * b.objects[j].position;
    const Eigen::Matrix3d& own = covariance_of(b.objects[j]);
    trace_b[j] = own.trace();
    covariance_b[j] = R * own * R.transpose();
    if (transform_covariance != nullptr) {
      Eigen::Matrix<double, 3, 6> J;
      J.leftCols<3>().setIdentity();
      J.rightCols<3>() = -lie::skew(transformed[j]);
      const Eigen::Matrix3d from_transform = J * *transform_covariance * J.transpose();
      covariance_b[j] += from_transform;
      trace_b[j] += from_transform.trace();
    }
  }
  struct Scored {
    int i, j;
    double d2;
  };
  std::vector<Scored> within;
  std::vector<double> best_a(na, kInfinity), second_a(na, kInfinity);
  std::vector<double> best_b(nb, kInfinity), second_b(nb, kInfinity);
  std::vector<int> partner_a(na, -1), partner_b(nb, -1);
  const auto note = [](double d2, int other, double& best, double& second, int& partner) {
    if (d2 < best) {
      second = best;
      best = d2;
      partner = other;
    } else if (d2 < second) {
      second = d2;
    }
  };
  // Pairs beyond the gate plus the margin cannot matter (neither as best nor as a close second).
  const double relevant = gate + options.match_margin;
  // The trace bound first for all of b at once, in flat arrays (a loop the compiler vectorizes),
  // with a margin so that it keeps a superset of the pairs the exact test below keeps: most
  // pairs are far apart, and this pass is most of the cost of a map-to-map match.
  std::vector<double> bx(nb), by(nb), bz(nb);
  for (std::size_t j = 0; j < nb; ++j) {
    bx[j] = transformed[j].x();
    by[j] = transformed[j].y();
    bz[j] = transformed[j].z();
  }
  std::vector<unsigned char> near(nb);
  for (std::size_t i = 0; i < na; ++i) {
    const ObjectDescription& x = a.objects[i];
    const Eigen::Matrix3d& covariance_x = covariance_of(x);
    const double trace_x = covariance_x.trace() + 3.0 * noise;
    const double px = x.position.x(), py = x.position.y(), pz = x.position.z();
    for (std::size_t j = 0; j < nb; ++j) {
      const double dx = px - bx[j], dy = py - by[j], dz = pz - bz[j];
      const double bound = relevant * (trace_x + trace_b[j]);
      near[j] = !(dx * dx + dy * dy + dz * dz > bound + 1e-9 * std::abs(bound)) ? 1 : 0;
    }
    for (std::size_t j = 0; j < nb; ++j) {
      if (near[j] == 0) continue;
      const ObjectDescription& y = b.objects[j];
      if (!classes_compatible(x.object_class, y.object_class, options)) continue;
      const Eigen::Vector3d residual = x.position - transformed[j];
      if (residual.squaredNorm() > relevant * (trace_x + trace_b[j])) continue;
      symmetric3::Lower covariance = symmetric3::lower_of_sum(covariance_x, covariance_b[j]);
      covariance[0] += noise;
      covariance[3] += noise;
      covariance[5] += noise;
      const auto distance = symmetric3::inverse_quadratic(covariance, residual);
      if (!distance) continue;
      const double d2 = *distance;
      if (d2 > relevant) continue;
      note(d2, static_cast<int>(j), best_a[i], second_a[i], partner_a[i]);
      note(d2, static_cast<int>(i), best_b[j], second_b[j], partner_b[j]);
      if (d2 <= gate) within.push_back({static_cast<int>(i), static_cast<int>(j), d2});
    }
  }
  // 2. Mutual best, with the margin over both objects' second best.
  std::vector<Match> matches;
  for (const Scored& pair : within) {
    if (partner_a[pair.i] != pair.j || partner_b[pair.j] != pair.i) continue;
    if (second_a[pair.i] < pair.d2 + options.match_margin) continue;
    if (second_b[pair.j] < pair.d2 + options.match_margin) continue;
    matches.push_back({a.objects[pair.i].id, b.objects[pair.j].id, pair.d2});
  }
  std::sort(matches.begin(), matches.end(),
            [](const Match& x, const Match& y) { return x.id_a < y.id_a; });
  return matches;
}

namespace {

/// The objects of a map whose local covariance's largest standard deviation is at most max_sigma;
/// with archived_by_marginal, an archived object's local covariance is its marginal (in the test
/// and in the copy kept).
MapDescription well_placed(const MapDescription& map, double max_sigma, bool archived_by_marginal) {
  MapDescription kept;
  kept.robot = map.robot;
  kept.frame = map.frame;
  const double bound = max_sigma * max_sigma;
  for (const ObjectDescription& object : map.objects) {
    const bool by_marginal = archived_by_marginal && object.archived;
    // A symmetric matrix's largest eigenvalue is at least its largest diagonal entry and at most
    // its largest Gershgorin row bound: most objects are decided without the eigenvalues.
    const Eigen::Matrix3d& C = by_marginal ? object.covariance : object.local_covariance;
    const double largest_diagonal = C.diagonal().maxCoeff();
    const double gershgorin =
        (C.diagonal() + C.cwiseAbs().rowwise().sum() - C.diagonal().cwiseAbs()).maxCoeff();
    bool placed = false;
    if (gershgorin <= bound) {
      placed = true;
    } else if (!(largest_diagonal > bound)) {
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> solver(C, Eigen::EigenvaluesOnly);
      placed = solver.eigenvalues()(2) <= bound;
    }
    if (placed) {
      kept.objects.push_back(object);
      if (by_marginal) kept.objects.back().local_covariance = object.covariance;
    }
  }
  return kept;
}

/// The outcome of a search with fewer candidates than min_inliers.
PairAlignment too_few_candidates(std::size_t candidates) {
  PairAlignment result;
  result.candidates = static_cast<int>(candidates);
  result.status = AlignmentStatus::kTooFewCandidates;
  return result;
}

/// Steps 2-5 of a search (align_maps, align_in_frame) on its candidates: the consistency graph,
/// the largest rigid hypothesis and its rival, every correspondence the transform supports.
PairAlignment align_candidates(const MapDescription& a, const MapDescription& b,
                               const DistanceTable& table_a, const DistanceTable& table_b,
                               const std::vector<Candidate>& candidates,
                               const AssociationOptions& options) {
  const auto min_inliers = static_cast<std::size_t>(options.min_inliers);
  if (candidates.size() < min_inliers) return too_few_candidates(candidates.size());
  PairAlignment result;
  result.candidates = static_cast<int>(candidates.size());
  // 2. Consistency graph.
  const double bound = UpdaterHelper::chi2_quantile(options.consistency_chi2_probability, 1);
  const ConsistencyGraph graph = consistency_graph(candidates, table_a, table_b, bound);
  result.consistency_edges = graph.edges();

  // 3. Its maximum clique and the transform of it. Distances cannot tell a layout from its mirror
  //    image, and loose covariances let chance sets through: a clique whose own transform does
  //    not bring min_inliers of its members within the match gate is set aside and the next
  //    largest tried (max_hypotheses times).
  const double gate = UpdaterHelper::chi2_quantile(options.match_chi2_probability, 3);
  const auto residual_within_gate = [&](const Candidate& candidate, const Eigen::Isometry3d& T) {
    const PointPair pair =
        point_pair(a.objects[candidate.a], b.objects[candidate.b], true, options.distance_noise);
    const Eigen::Matrix3d& R = T.linear();
    const Eigen::Vector3d residual = pair.p_target - T * pair.p_source;
    const auto distance = symmetric3::inverse_quadratic(
        pair.covariance_target, R * pair.covariance_source * R.transpose(), residual);
    return distance && *distance <= gate;
  };
  // The largest rigid hypothesis among the allowed candidates: its transform and how many of its
  // clique's members it brings within the gate.
  struct Hypothesis {
    RigidAlignment fit;
    int inliers = 0;
  };
  const auto find_hypothesis = [&](std::vector<bool> allowed, int minimum) {
    std::optional<Hypothesis> found;
    for (int attempt = 0; attempt < options.max_hypotheses && !found; ++attempt) {
      // Smaller cliques are of no use here: the search cuts them from the start.
      const CliqueResult clique =
          maximum_clique(graph, options.max_clique_expansions, allowed, minimum);
      result.cliques_exact = result.cliques_exact && clique.exact;
      if (static_cast<int>(clique.vertices.size()) < minimum) break;
      std::vector<std::pair<int, int>> pairs;
      for (int v : clique.vertices) pairs.emplace_back(candidates[v].a, candidates[v].b);
      const auto fitted = fit(a, b, pairs, options);
      int inliers = 0;
      if (fitted) {
        for (int v : clique.vertices)
          inliers += residual_within_gate(candidates[v], fitted->T_target_source);
      }
      if (fitted && inliers >= minimum) {
        found = Hypothesis{*fitted, inliers};
      } else {
        for (int v : clique.vertices) allowed[v] = false;
      }
    }
    return found;
  };
  const auto best =
      find_hypothesis(std::vector<bool>(candidates.size(), true), options.min_inliers);
  if (!best) {
    result.status = AlignmentStatus::kTooFewInliers;
    return result;
  }
  result.clique_size = best->inliers;
  const std::optional<RigidAlignment> clique_fit = best->fit;
  // A best hypothesis that turns the start frames over is refused outright: the up axis only ever
  // adds a refusal (the next clique is not tried in its place, and rivals still count).
  if (!keeps_level(clique_fit->T_target_source, clique_fit->covariance, options)) {
    result.status = AlignmentStatus::kTilted;
    return result;
  }

  // 4. Rival hypothesis: the largest rigid hypothesis among the candidates this transform
  //    rejects (a symmetric or repetitive layout has one nearly as large). Sets of 3 always fit,
  //    so a rival needs at least 4.
  std::vector<bool> rejected(candidates.size(), false);
  for (std::size_t v = 0; v < candidates.size(); ++v) {
    rejected[v] = !residual_within_gate(candidates[v], clique_fit->T_target_source);
  }
  const int rival_minimum = std::max(
      4, static_cast<int>(std::ceil(options.ambiguity_ratio * static_cast<double>(best->inliers))));
  const auto rival = find_hypothesis(rejected, rival_minimum);
  result.rival_clique_size = rival ? rival->inliers : 0;
  result.clique_fit_chi2 = clique_fit->chi2;
  result.clique_fit_largest_residual = clique_fit->largest_residual;
  if (rival) {
    result.status = AlignmentStatus::kAmbiguous;
    return result;
  }

  // 5. Every correspondence the transform supports, then the transform refitted to them.
  Eigen::Isometry3d T = clique_fit->T_target_source;
  std::vector<Match> matches;
  std::optional<RigidAlignment> final_fit = clique_fit;
  for (int pass = 0; pass < 2; ++pass) {
    matches = match_with_transform(a, b, T, Covariances::kTransform, options);
    if (matches.size() < min_inliers) break;
    std::vector<std::pair<int, int>> pairs;
    for (const Match& match : matches)
      pairs.emplace_back(index_of(a, match.id_a), index_of(b, match.id_b));
    final_fit = fit(a, b, pairs, options);
    if (!final_fit) break;
    T = final_fit->T_target_source;
  }
  if (matches.size() < min_inliers) {
    result.status = AlignmentStatus::kTooFewInliers;
    return result;
  }
  if (!final_fit) {
    result.status = AlignmentStatus::kDegenerate;
    return result;
  }
  if (!keeps_level(T, final_fit->covariance, options)) {
    result.status = AlignmentStatus::kTilted;
    return result;
  }
  result.status = AlignmentStatus::kAligned;
  result.T_a_b = T;
  result.covariance = final_fit->covariance;
  result.matches = std::move(matches);
  return result;
}

}  // namespace

PreparedMap::PreparedMap(const MapDescription& map, const AssociationOptions& options)
    // Archived objects take part by their marginals unless archived_local_covariance.
    : parts_(std::make_unique<const Parts>(Parts{
          well_placed(map, options.search_max_sigma, !options.archived_local_covariance),
          options.distance_noise, options.descriptor_neighbours, std::nullopt, std::nullopt})) {}

const DistanceTable& PreparedMap::Parts::table() const {
  if (!table_made) table_made.emplace(placed, distance_noise);
  return *table_made;
}

const Descriptors& PreparedMap::Parts::descriptors() const {
  if (!descriptors_made) descriptors_made = descriptors_of(placed, table(), descriptor_neighbours);
  return *descriptors_made;
}

PreparedMap::~PreparedMap() = default;
PreparedMap::PreparedMap(PreparedMap&&) noexcept = default;
PreparedMap& PreparedMap::operator=(PreparedMap&&) noexcept = default;

PairAlignment align_maps(const MapDescription& a, const MapDescription& b,
                         const AssociationOptions& options) {
  return align_maps(PreparedMap(a, options), PreparedMap(b, options), options);
}

PairAlignment align_maps(const PreparedMap& prepared_a, const PreparedMap& prepared_b,
                         const AssociationOptions& options) {
  const auto min_inliers = static_cast<std::size_t>(options.min_inliers);
  // The search and the matching use the well-placed objects.
  const MapDescription& a = prepared_a.parts_->placed;
  const MapDescription& b = prepared_b.parts_->placed;
  if (a.objects.size() < min_inliers || b.objects.size() < min_inliers) return {};
  // 1. Candidates from the objects' surroundings.
  return align_candidates(a, b, prepared_a.parts_->table(), prepared_b.parts_->table(),
                          find_candidates(a, b, prepared_a.parts_->descriptors(),
                                          prepared_b.parts_->descriptors(), options),
                          options);
}

PairAlignment align_in_frame(const PreparedMap& prepared_a, const PreparedMap& prepared_b,
                             const AssociationOptions& options) {
  const auto min_inliers = static_cast<std::size_t>(options.min_inliers);
  const MapDescription& a = prepared_a.parts_->placed;
  const MapDescription& b = prepared_b.parts_->placed;
  if (a.objects.size() < min_inliers || b.objects.size() < min_inliers) return {};
  // 1. Candidates: the pairs whose positions agree in the common frame on their marginals (a
  //    marginal is the object's uncertainty in the frame, the move's included).
  const double gate = UpdaterHelper::chi2_quantile(options.match_chi2_probability, 3);
  const double noise = options.distance_noise * options.distance_noise;
  std::vector<Candidate> candidates;
  for (std::size_t i = 0; i < a.objects.size(); ++i) {
    const ObjectDescription& x = a.objects[i];
    for (std::size_t j = 0; j < b.objects.size(); ++j) {
      const ObjectDescription& y = b.objects[j];
      if (!classes_compatible(x.object_class, y.object_class, options)) continue;
      // The trace bound first (d^2 >= |r|^2 / trace): most pairs are far apart.
      const double trace = x.covariance.trace() + y.covariance.trace() + 3.0 * noise;
      if ((x.position - y.position).squaredNorm() > gate * trace) continue;
      const double d2 = mahalanobis_squared(x, y, options);
      // The score orders candidates for max_candidates: the closer, the better.
      if (d2 <= gate) {
        candidates.push_back({static_cast<int>(i), static_cast<int>(j), gate - d2});
      }
    }
  }
  keep_best_candidates(candidates, options.max_candidates);
  if (candidates.size() < min_inliers) return too_few_candidates(candidates.size());
  return align_candidates(a, b, prepared_a.parts_->table(), prepared_b.parts_->table(), candidates,
                          options);
}

}  // namespace concord::association

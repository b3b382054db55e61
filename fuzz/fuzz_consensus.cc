// libFuzzer target: a neighbour's marginal, as a hostile team member may send it, fused into a
// robot's state. fuzz_marginal checks the decoding; here what from_wire accepts from arbitrary
// bytes is fused (Estimator::fuse, eq. 19-21 with the chi-square refusal) into a robot holding
// objects 100-103 in its joint state with two poses and 104-105 archived, as a daemon does with
// the marginals of a round. Never crash, and the robot's state stays usable whatever the
// neighbour sent: finite means, a finite symmetric covariance without negative directions beyond
// round-off, finite archived marginals, and a marginal the robot can still send.
#include <Eigen/Eigenvalues>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "concord/daemon/wire.h"
#include "concord/estimator/estimator.h"
#include "concord/v1/concord.pb.h"

namespace {

using concord::LandmarkId;
using concord::State;

/// Aborts (a finding) naming what did not hold.
void check(bool condition, const char* what) {
  if (condition) return;
  std::fprintf(stderr, "fuzz_consensus: %s\n", what);
  std::abort();
}

/// Two poses and four objects in the joint state, with a fixed correlated covariance, and two
/// archived objects (the seeds' marginals hold the same ids near the same positions).
State robot_state() {
  State state;
  state.poses.push_back({0, Eigen::Isometry3d::Identity()});
  Eigen::Isometry3d second = Eigen::Isometry3d::Identity();
  second.translation() = Eigen::Vector3d(1.0, 0.1, 0.0);
  state.poses.push_back({1, second});
  const double xyz[6][3] = {{4.0, 1.0, 0.5}, {5.5, -2.0, 1.0}, {7.0, 0.5, 0.2},
                            {6.0, 3.0, 1.5}, {2.0, -4.0, 0.3}, {9.0, 2.5, 0.8}};
  for (int i = 0; i < 4; ++i) {
    concord::ObjectLandmark landmark;
    landmark.id = 100 + i;
    landmark.p_world = Eigen::Vector3d(xyz[i][0], xyz[i][1], xyz[i][2]);
    landmark.p_linearization = landmark.p_world;
    landmark.last_observed_frame = 1;
    state.landmarks.push_back(landmark);
  }
  for (int i = 4; i < 6; ++i) {
    const LandmarkId id = 100 + i;
    state.archived[id] = {id, Eigen::Vector3d(xyz[i][0], xyz[i][1], xyz[i][2]),
                          0.04 * Eigen::Matrix3d::Identity()};
    state.archived_last_observed[id] = 0;
  }
  // A covariance with correlations between everything: A A^T + 0.01 I for a fixed A.
  const int n = state.dimension();
  Eigen::MatrixXd A(n, n);
  for (int r = 0; r < n; ++r)
    for (int c = 0; c < n; ++c) A(r, c) = 0.02 * std::sin(1.0 + 3.0 * r + 7.0 * c);
  state.covariance = A * A.transpose() + 0.01 * Eigen::MatrixXd::Identity(n, n);
  state.covariance.topLeftCorner<6, 6>() += 1e-6 * Eigen::Matrix<double, 6, 6>::Identity();
  return state;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > (1 << 16)) return 0;
  concord::v1::Marginal wire;
  if (!wire.ParseFromArray(data, static_cast<int>(size))) return 0;
  std::string error;
  auto marginal = concord::daemon::from_wire(wire, error);
  if (!marginal) return 0;

  static const State state = robot_state();
  concord::Estimator estimator(concord::EstimatorOptions{}, concord::StereoCamera{}, state);
  std::vector<concord::WeightedMarginal> neighbours(1);
  neighbours[0].weight = 0.5;  // two robots (Metropolis-Hastings)
  neighbours[0].marginal = std::move(*marginal);
  neighbours[0].sender = 2;  // its claims kept and tested against (claim_history_rounds)
  (void)estimator.fuse(neighbours);
  // The same claim a round later: tested against the first (and the robot's fused state).
  (void)estimator.fuse(neighbours);
  // And as a quarantined peer's: tested, not fused (Estimator::witness).
  (void)estimator.witness(neighbours);

  const State& fused = estimator.state();
  for (const auto& landmark : fused.landmarks) check(landmark.p_world.allFinite(), "finite means");
  for (const auto& pose : fused.poses)
    check(pose.T_world_body.matrix().allFinite(), "finite poses");
  check(fused.covariance.allFinite(), "a finite covariance");
  const double scale = fused.covariance.cwiseAbs().maxCoeff();
  check((fused.covariance - fused.covariance.transpose()).cwiseAbs().maxCoeff() <=
            1e-9 * (1.0 + scale),
        "a symmetric covariance");
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> solver(fused.covariance,
                                                              Eigen::EigenvaluesOnly);
  check(solver.eigenvalues().minCoeff() >= -1e-9 * (1.0 + scale),
        "no negative direction in the covariance");
  for (const auto& [id, object] : fused.archived) {
    check(object.p_world.allFinite() && object.covariance.allFinite(), "finite archived marginals");
  }
  const concord::Marginal sent = estimator.marginal(estimator.object_ids());
  check(sent.well_formed() && sent.mean.allFinite(), "a marginal the robot can send");
  return 0;
}

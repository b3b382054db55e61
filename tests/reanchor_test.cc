// StateHelper::reanchor: moving a state into another frame with an uncertain transform (issue 11,
// robots that start at unknown poses). Means are moved exactly; the covariance matches a
// Monte-Carlo sample of the moved errors.
#include <gtest/gtest.h>

#include <random>

#include "concord/estimator/lie.h"
#include "concord/estimator/state_helper.h"
#include "concord/estimator/updater_helper.h"
#include "test_support.h"

namespace concord {
namespace {

Eigen::Isometry3d transform(double yaw, const Eigen::Vector3d& t) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
               Eigen::AngleAxisd(0.1, Eigen::Vector3d::UnitX()).toRotationMatrix();
  T.translation() = t;
  return T;
}

/// Sample covariances of a moved state's errors (the joint state's, and archived object 9's):
/// true state = exp(eps) T_hat for poses, p_hat + p~ for landmarks, the archived object with its
/// own error; the true transform from `true_transform(x, y)`, x the state's error draw and y a
/// standard normal 6-vector. The moved truth's error against `moved`, in the state's convention.
struct MovedSample {
  Eigen::MatrixXd state;
  Eigen::Matrix3d archived;
};

template <typename TrueTransform>
MovedSample sample_moved(const State& state, const State& moved, TrueTransform true_transform,
                         std::mt19937& random) {
  const int n = state.dimension();
  const Eigen::LLT<Eigen::MatrixXd> state_llt(state.covariance);
  const Eigen::LLT<Eigen::Matrix3d> archived_llt(state.archived.at(9).covariance);
  std::normal_distribution<double> normal;
  MovedSample sample{Eigen::MatrixXd::Zero(n, n), Eigen::Matrix3d::Zero()};
  const int draws = 20000;
  for (int draw = 0; draw < draws; ++draw) {
    const Eigen::VectorXd x = state_llt.matrixL() * testing::random_vector(n, random);
    lie::Vector6d y;
    for (int k = 0; k < 6; ++k) y(k) = normal(random);
    const Eigen::Isometry3d T_true = true_transform(x, y);
    Eigen::VectorXd error(n);
    for (int i = 0; i < state.num_poses(); ++i) {
      const int index = state.pose_index(i);
      const Eigen::Isometry3d truth =
          T_true * lie::se3_exp(x.segment<6>(index)) * state.poses[i].T_world_body;
      error.segment<6>(index) = lie::se3_log(truth * moved.poses[i].T_world_body.inverse());
    }
    for (int j = 0; j < state.num_landmarks(); ++j) {
      const int index = state.landmark_index(j);
      const Eigen::Vector3d truth = T_true * (state.landmarks[j].p_world + x.segment<3>(index));
      error.segment<3>(index) = truth - moved.landmarks[j].p_world;
    }
    sample.state += error * error.transpose();
    Eigen::Vector3d z{normal(random), normal(random), normal(random)};  // in order
    const Eigen::Vector3d archived_truth =
        T_true * (state.archived.at(9).p_world + archived_llt.matrixL() * z);
    const Eigen::Vector3d archived_error = archived_truth - moved.archived.at(9).p_world;
    sample.archived += archived_error * archived_error.transpose();
  }
  sample.state /= draws;
  sample.archived /= draws;
  return sample;
}

TEST(ReanchorTest, MovesMeansAndLinearizationPoints) {
  std::mt19937 random(1);
  State state = testing::random_state(3, 2, random);
  state.archived[500] = {500, Eigen::Vector3d(1, 2, 3), 0.2 * Eigen::Matrix3d::Identity()};
  const State before = state;
  const Eigen::Isometry3d T = transform(1.2, Eigen::Vector3d(5, -3, 1));
  StateHelper::reanchor(state, T, lie::Matrix6d::Zero());
  for (int i = 0; i < 3; ++i) {
    EXPECT_TRUE(state.poses[i].T_world_body.isApprox(T * before.poses[i].T_world_body, 1e-12));
  }
  for (int j = 0; j < 2; ++j) {
    EXPECT_TRUE(state.landmarks[j].p_world.isApprox(T * before.landmarks[j].p_world, 1e-12));
    EXPECT_TRUE(state.landmarks[j].p_linearization.isApprox(T * before.landmarks[j].p_linearization,
                                                            1e-12));
  }
  EXPECT_TRUE(state.archived.at(500).p_world.isApprox(T * Eigen::Vector3d(1, 2, 3), 1e-12));
  // A certain transform rotates the archived covariance and keeps its eigenvalues.
  EXPECT_NEAR(state.archived.at(500).covariance.trace(), 0.6, 1e-12);
  // The identity with no uncertainty changes nothing.
  State same = before;
  StateHelper::reanchor(same, Eigen::Isometry3d::Identity(), lie::Matrix6d::Zero());
  EXPECT_TRUE(same.covariance.isApprox(before.covariance, 1e-12));
}

TEST(ReanchorTest, CovarianceMatchesMonteCarlo) {
  std::mt19937 random(7);
  State state = testing::random_state(2, 2, random);
  state.covariance *= 0.01;  // small errors: the first-order model holds
  state.archived[9] = {9, Eigen::Vector3d(4, 1, 0), 0.02 * Eigen::Matrix3d::Identity()};
  const Eigen::Isometry3d T = transform(0.7, Eigen::Vector3d(2, 8, -1));
  lie::Matrix6d sigma = lie::Matrix6d::Zero();
  sigma.diagonal() << 0.02, 0.01, 0.03, 2e-4, 1e-4, 3e-4;
  State moved = state;
  StateHelper::reanchor(moved, T, sigma);

  // The true transform exp(e) T, e of covariance sigma.
  const Eigen::LLT<lie::Matrix6d> transform_llt(sigma);
  const MovedSample sample = sample_moved(
      state, moved,
      [&](const Eigen::VectorXd&, const lie::Vector6d& y) {
        return Eigen::Isometry3d(lie::se3_exp(transform_llt.matrixL() * y) * T);
      },
      random);
  EXPECT_LT((sample.state - moved.covariance).norm() / moved.covariance.norm(), 0.05);
  EXPECT_LT((sample.archived - moved.archived.at(9).covariance).norm() /
                moved.archived.at(9).covariance.norm(),
            0.05);
}

TEST(ReanchorTest, ATransformFoundFromTheStatesOwnMapCarriesItsPosesErrorNotTwice) {
  // A transform fitted to the robot's map as it stood relative to one of its poses: the map
  // shares that pose's error e_c, so T_hat = exp(-e_ind) T exp(e_c) (docs/association.md, "A
  // move that keeps the map's drift"). Monte-Carlo over that model against the correlated move.
  std::mt19937 random(11);
  State state = testing::random_state(3, 2, random);
  state.covariance *= 0.01;
  state.archived[9] = {9, Eigen::Vector3d(4, 1, 0), 0.02 * Eigen::Matrix3d::Identity()};
  const Eigen::Isometry3d T = transform(-0.9, Eigen::Vector3d(-4, 2, 3));
  lie::Matrix6d independent = lie::Matrix6d::Zero();
  independent.diagonal() << 0.01, 0.02, 0.01, 1e-4, 3e-4, 2e-4;
  const int slot = 2;
  const int pose = state.pose_index(slot);
  const lie::Matrix6d adjoint = lie::adjoint(T);
  const lie::Matrix6d whole =
      independent + adjoint * state.covariance.block<6, 6>(pose, pose) * adjoint.transpose();
  State moved = state;
  StateHelper::reanchor(moved, T, whole, slot, independent);
  // The pose the transform came from now knows only the transform's own error.
  const lie::Matrix6d at_pose = moved.covariance.block<6, 6>(pose, pose);
  EXPECT_TRUE(at_pose.isApprox(independent, 1e-9));

  const Eigen::LLT<lie::Matrix6d> transform_llt(independent);
  const MovedSample sample = sample_moved(
      state, moved,
      [&](const Eigen::VectorXd& x, const lie::Vector6d& y) {
        return Eigen::Isometry3d(lie::se3_exp(transform_llt.matrixL() * y) * T *
                                 lie::se3_exp(-x.segment<6>(pose)));
      },
      random);
  EXPECT_LT((sample.state - moved.covariance).norm() / moved.covariance.norm(), 0.05);
  EXPECT_LT((sample.archived - moved.archived.at(9).covariance).norm() /
                moved.archived.at(9).covariance.norm(),
            0.05);
  // Taking the same transform as independent of the state counts the pose's error twice.
  State twice = state;
  StateHelper::reanchor(twice, T, whole);
  EXPECT_GT((sample.state - twice.covariance).norm() / twice.covariance.norm(), 0.2);
  EXPECT_THROW(StateHelper::reanchor(twice, T, whole, 3, independent), std::invalid_argument);
}

TEST(ReanchorTest, AnObservationAfterTheMoveCannotSeeTheTransformsError) {
  // Objects whose estimates have moved from their first estimates (the points their pose
  // Jacobians are taken at). The transform's error is a rigid move of the whole state, which an
  // object observation (relative to the robot) cannot see: the covariance the move adds must lie
  // in the null space of every first-estimate observation Jacobian, or each later observation
  // would claim to tell the robot the team frame's rotation.
  std::mt19937 random(5);
  State state = testing::random_state(3, 3, random);
  for (ObjectLandmark& landmark : state.landmarks) {
    landmark.p_world = 5.0 * testing::random_vector(3, random);
    landmark.p_linearization = landmark.p_world + testing::random_vector(3, random, 0.5);
  }
  const Eigen::Isometry3d T = transform(0.9, Eigen::Vector3d(3, -4, 0.5));
  lie::Matrix6d sigma = lie::Matrix6d::Zero();
  sigma.diagonal() << 0.04, 0.02, 0.01, 3e-3, 1e-3, 2e-3;
  State certain = state;
  StateHelper::reanchor(certain, T, lie::Matrix6d::Zero());
  State uncertain = state;
  StateHelper::reanchor(uncertain, T, sigma);
  const Eigen::MatrixXd added = uncertain.covariance - certain.covariance;
  ASSERT_GT(added.norm(), 1e-3);
  for (int i = 0; i < state.num_poses(); ++i) {
    for (int j = 0; j < state.num_landmarks(); ++j) {
      const Eigen::Matrix<double, 4, 3> jacobian_point =
          testing::random_spd(4, random).topLeftCorner<4, 3>();
      Eigen::MatrixXd H = Eigen::MatrixXd::Zero(4, state.dimension());
      H.block<4, 6>(0, state.pose_index(i)) =
          UpdaterHelper::pose_jacobian(jacobian_point, uncertain.landmarks[j].p_linearization);
      H.block<4, 3>(0, state.landmark_index(j)) = jacobian_point;
      const Eigen::Matrix4d seen = H * added * H.transpose();
      EXPECT_LT(seen.norm(), 1e-12 * (H * H.transpose()).norm() * added.norm())
          << "pose " << i << ", object " << j;
    }
  }
  // Each object's marginal still takes the transform's rotation about the new origin (at its
  // first estimate): its position uncertainty grows by at least the translation's.
  for (int j = 0; j < state.num_landmarks(); ++j) {
    const int index = state.landmark_index(j);
    const double grown = added.block(index, index, 3, 3).trace();
    EXPECT_GT(grown, sigma.topLeftCorner(3, 3).trace());
  }
}

TEST(ReanchorTest, TheWorldUpAxisTurnsWithTheFrameAndTakesTheTransformsTilt) {
  // A state with a world up axis (the level prior's) tilted off its reference: the mean turns
  // with the frame, and the tilt's covariance, with its correlations, matches a Monte-Carlo
  // sample of the moved up axis's error, the transform's own rotation error included.
  std::mt19937 random(11);
  State state = testing::random_state(2, 1, random);
  state.has_world_up = true;
  state.world_up = WorldUp::around(Eigen::Vector3d(0.03, 0.01, 1.0));
  state.world_up.tilt = Eigen::Vector2d(0.02, -0.015);
  state.covariance = 1e-4 * testing::random_spd(state.dimension(), random, 0.05, 1.0);
  const Eigen::Isometry3d T = transform(0.7, Eigen::Vector3d(2, 8, -1));
  lie::Matrix6d sigma = lie::Matrix6d::Zero();
  sigma.diagonal() << 0.02, 0.01, 0.03, 2e-4, 1e-4, 3e-4;
  State moved = state;
  StateHelper::reanchor(moved, T, sigma);
  EXPECT_TRUE(moved.world_up.direction().isApprox(T.linear() * state.world_up.direction(), 1e-12));
  EXPECT_EQ(moved.world_up.tilt, state.world_up.tilt);

  // Sample the true up axis in the old frame and the true transform; the moved truth's tilt
  // against the moved estimate's, in the moved basis: t solves u ~ reference + basis t.
  const int index = state.world_up_index();
  const Eigen::LLT<Eigen::MatrixXd> state_llt(state.covariance);
  const Eigen::LLT<lie::Matrix6d> transform_llt(sigma);
  const int draws = 20000;
  Eigen::MatrixXd sample = Eigen::MatrixXd::Zero(2, 2);
  Eigen::MatrixXd cross = Eigen::MatrixXd::Zero(2, 6);  // with the newest pose's error
  for (int draw = 0; draw < draws; ++draw) {
    const Eigen::VectorXd x =
        state_llt.matrixL() * testing::random_vector(state.dimension(), random);
    const Eigen::Isometry3d T_true =
        lie::se3_exp(transform_llt.matrixL() * testing::random_vector(6, random)) * T;
    WorldUp up = state.world_up;
    up.tilt += x.segment<2>(index);
    const Eigen::Vector3d truth = T_true.linear() * up.direction();
    const WorldUp& estimate = moved.world_up;
    const Eigen::Vector2d tilt =
        estimate.basis.transpose() * truth / estimate.reference.dot(truth);
    const Eigen::Vector2d error = tilt - estimate.tilt;
    sample += error * error.transpose();
    const int pose = state.pose_index(1);
    const Eigen::Isometry3d pose_truth =
        T_true * lie::se3_exp(x.segment<6>(pose)) * state.poses[1].T_world_body;
    cross += error * lie::se3_log(pose_truth * moved.poses[1].T_world_body.inverse()).transpose();
  }
  sample /= draws;
  cross /= draws;
  const Eigen::Matrix2d predicted = moved.covariance.block<2, 2>(index, index);
  EXPECT_LT((sample - predicted).norm() / predicted.norm(), 0.05);
  const Eigen::MatrixXd predicted_cross = moved.covariance.block(index, state.pose_index(1), 2, 6);
  // Each cross entry within four standard errors of its Monte-Carlo mean: the pose's
  // translation error, widened by the transform's, is much larger than the tilt's.
  const Eigen::MatrixXd pose_block = moved.covariance.block(state.pose_index(1), state.pose_index(1), 6, 6);
  for (int row = 0; row < 2; ++row) {
    for (int column = 0; column < 6; ++column) {
      const double standard_error =
          std::sqrt((predicted(row, row) * pose_block(column, column) +
                     predicted_cross(row, column) * predicted_cross(row, column)) /
                    draws);
      EXPECT_LT(std::abs(cross(row, column) - predicted_cross(row, column)), 4.0 * standard_error)
          << "tilt " << row << ", pose error " << column;
    }
  }
  // The transform's rotation error widened the tilt beyond its own.
  const double widened = state.covariance.block<2, 2>(index, index).trace() + 0.5 * 3e-4;
  EXPECT_GT(predicted.trace(), widened);
}

}  // namespace
}  // namespace concord

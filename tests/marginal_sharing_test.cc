// Compact, event-triggered sharing of marginals (issue 13): the KL divergence against a hand
// computation, the float32 wire form (positive definite whatever the rounding, about half the
// bytes), what a link's sender sends and what its receiver fuses, and a simulated team that
// sends far fewer bytes for the same accuracy.
#include <gtest/gtest.h>

#include <Eigen/Cholesky>
#include <cmath>
#include <random>

#include "concord/config/options_file.h"
#include "concord/estimator/marginal_sharing.h"
#include "replay/team_replay.h"
#include "sim/simulator.h"
#include "test_paths.h"
#include "test_support.h"

namespace concord {
namespace {

TEST(MarginalSharing, KlDivergenceMatchesTheClosedForm) {
  const ObjectEstimate q{1, Eigen::Vector3d::Zero(), Eigen::Matrix3d::Identity()};
  ObjectEstimate p{1, Eigen::Vector3d(1.0, 0.0, 0.0), Eigen::Matrix3d::Zero()};
  p.covariance.diagonal() << 1.0, 2.0, 3.0;
  // 0.5 (tr(Sq^-1 Sp) + d^T Sq^-1 d - 3 + ln(det Sq / det Sp)) = 0.5 (6 + 1 - 3 - ln 6).
  EXPECT_NEAR(kl_divergence(p, q), 0.5 * (4.0 - std::log(6.0)), 1e-12);
  EXPECT_NEAR(kl_divergence(p, p), 0.0, 1e-12);
  EXPECT_GT(kl_divergence(q, p), 0.0);
  ObjectEstimate singular = q;
  singular.covariance(2, 2) = 0.0;
  EXPECT_TRUE(std::isinf(kl_divergence(p, singular)));
}

/// A marginal of `landmarks` objects in one dense block, far from the origin, with correlations
/// close to 1 (a shared pose error) and eigenvalues spread over nine orders of magnitude.
Marginal correlated_marginal(int landmarks, std::mt19937& random) {
  const int n = 3 * landmarks;
  Eigen::MatrixXd covariance = testing::random_spd(n, random, 1e-6, 1e-3);
  const Eigen::MatrixXd shared = testing::random_vector(n, random, 1.0);
  covariance += 1e3 * shared * shared.transpose();  // nearly rank one on top
  Eigen::VectorXd mean = testing::random_vector(n, random, 5.0);
  mean.array() += 1234.5;
  std::vector<LandmarkId> ids;
  for (int k = 0; k < landmarks; ++k) ids.push_back(10 + 7 * k);
  return Marginal(ids, mean, covariance);
}

TEST(MarginalSharing, Float32FormStaysPositiveDefiniteAndClose) {
  std::mt19937 random(3);
  const Marginal marginal = correlated_marginal(12, random);
  const CompactMarginal wire = compact(marginal);
  ASSERT_EQ(wire.blocks.size(), 1u);
  EXPECT_FALSE(wire.blocks[0].cholesky_lower.empty());  // went in float
  const Marginal back = expand(wire);
  ASSERT_TRUE(back.well_formed());
  EXPECT_EQ(back.ids, marginal.ids);
  const Eigen::MatrixXd& covariance = back.blocks[0];
  EXPECT_EQ(Eigen::LLT<Eigen::MatrixXd>(covariance).info(), Eigen::Success);
  EXPECT_LT((covariance - marginal.blocks[0]).norm(), 1e-5 * marginal.blocks[0].norm());
  // Means relative to the origin: float resolution of the offsets, not of 1234 m.
  EXPECT_LT((back.mean - marginal.mean).cwiseAbs().maxCoeff(), 1e-5);
  // Every landmark's own 3x3 marginal is close in information terms too.
  for (std::size_t k = 0; k < marginal.ids.size(); ++k) {
    EXPECT_LT(kl_divergence(landmark_estimate(back, k), landmark_estimate(marginal, k)), 1e-3);
  }
  // About half the bytes of doubles (8 per id, mean and upper triangle).
  const long long doubles = 8 * (12 + 36 + 36 * 37 / 2);
  EXPECT_LT(wire.bytes(), doubles * 6 / 10);
}

TEST(MarginalSharing, ABlockThatIsNotPositiveDefiniteTravelsInDoubleAndBadShapesAreRefused) {
  Eigen::Matrix3d indefinite = Eigen::Matrix3d::Identity();
  indefinite(2, 2) = -1.0;
  const Marginal marginal({5}, Eigen::Vector3d(1.0, 2.0, 3.0), indefinite);
  const CompactMarginal wire = compact(marginal);
  ASSERT_EQ(wire.blocks.size(), 1u);
  EXPECT_TRUE(wire.blocks[0].cholesky_lower.empty());
  EXPECT_EQ(wire.blocks[0].packed_upper.size(), 6u);
  EXPECT_TRUE(expand(wire).blocks.at(0).isApprox(indefinite, 0.0));

  CompactMarginal bad = compact(Marginal({5}, Eigen::Vector3d::Zero(), Eigen::Matrix3d::Identity()));
  bad.mean_offsets.pop_back();
  EXPECT_TRUE(expand(bad).ids.empty());
  bad = compact(Marginal({5}, Eigen::Vector3d::Zero(), Eigen::Matrix3d::Identity()));
  bad.blocks[0].landmarks = 2;
  EXPECT_TRUE(expand(bad).ids.empty());
  bad = compact(Marginal({5}, Eigen::Vector3d::Zero(), Eigen::Matrix3d::Identity()));
  bad.blocks[0].cholesky_lower.push_back(1.0F);
  EXPECT_TRUE(expand(bad).ids.empty());
}

/// Three independent landmarks 1, 2, 3 at x = id, unit covariance; landmark 4 in a joint block
/// with landmark 5.
Marginal three_and_a_pair() {
  Marginal marginal;
  marginal.ids = {1, 2, 3, 4, 5};
  marginal.mean = Eigen::VectorXd::Zero(15);
  for (int k = 0; k < 5; ++k) marginal.mean(3 * k) = k + 1;
  for (int k = 0; k < 3; ++k) marginal.blocks.emplace_back(Eigen::Matrix3d::Identity());
  Eigen::MatrixXd pair = Eigen::MatrixXd::Identity(6, 6);
  pair.block<3, 3>(0, 3) = pair.block<3, 3>(3, 0) = 0.5 * Eigen::Matrix3d::Identity();
  marginal.blocks.push_back(pair);
  return marginal;
}

TEST(MarginalSharing, OnlyChangedLandmarksAreSentAndTheReceiverFusesTheLastOfTheOthers) {
  MarginalSender sender;
  MarginalReceiver receiver;
  const std::vector<LandmarkId> common = {1, 2, 3, 4, 5};
  Marginal now = three_and_a_pair();

  // Round 1: nothing sent before, so everything goes.
  Marginal sent = sender.select(now, 0.1);
  EXPECT_EQ(sent.ids, common);
  sender.delivered(sent);
  EXPECT_EQ(receiver.complete(sent, common).ids.size(), 5u);

  // Round 2: landmark 2 moved by 2 sigma (KL 2), landmark 5 by 0.1 sigma (KL 0.005).
  now.mean(3 * 1) += 2.0;
  now.mean(3 * 4 + 1) += 0.1;
  sent = sender.select(now, 0.1);
  EXPECT_EQ(sent.ids, std::vector<LandmarkId>{2});
  sender.delivered(sent);
  const Marginal fused = receiver.complete(sent, common);
  ASSERT_TRUE(fused.well_formed());
  ASSERT_EQ(fused.ids.size(), 5u);
  EXPECT_EQ(fused.ids.front(), 2);
  EXPECT_DOUBLE_EQ(fused.mean(0), 4.0);  // landmark 2, new
  // The others as last received, each its own block (their joint claim is not repeated).
  EXPECT_EQ(fused.blocks.size(), 5u);
  for (std::size_t k = 1; k < fused.ids.size(); ++k) {
    const LandmarkId id = fused.ids[k];
    EXPECT_DOUBLE_EQ(fused.mean(3 * static_cast<Eigen::Index>(k)), static_cast<double>(id));
  }

  // The small moves add up: against what was last sent, not last round.
  for (int round = 0; round < 3; ++round) now.mean(3 * 4 + 1) += 0.2;
  sent = sender.select(now, 0.1);
  EXPECT_EQ(sent.ids, std::vector<LandmarkId>{5});
  sender.delivered(sent);

  // A landmark no longer common is forgotten by the receiver.
  const Marginal fewer = receiver.complete(Marginal(), {1, 2});
  EXPECT_EQ(fewer.ids.size(), 2u);
  EXPECT_EQ(receiver.complete(Marginal(), {1, 2, 3}).ids.size(), 2u);

  // Threshold 0 sends everything; after a reset everything goes again.
  EXPECT_EQ(sender.select(now, 0.0).ids.size(), 5u);
  EXPECT_TRUE(sender.select(now, 0.1).ids.empty());
  sender.reset();
  EXPECT_EQ(sender.select(now, 0.1).ids.size(), 5u);
}

TEST(MarginalSharing, ACapSendsTheNeverSentFirstThenTheLargestMovesAndTheRestLater) {
  MarginalSender sender;
  Marginal now = three_and_a_pair();  // landmarks 1, 2, 3 alone, 4 and 5 in one block, sigma 1

  // Everything is new: two a round, in the marginal's order, until all were sent.
  std::vector<LandmarkId> sent_ids;
  for (int round = 0; round < 3; ++round) {
    const Marginal sent = sender.select(now, 0.1, 2);
    ASSERT_TRUE(sent.well_formed());
    EXPECT_LE(sent.ids.size(), 2u);
    sender.delivered(sent);
    sent_ids.insert(sent_ids.end(), sent.ids.begin(), sent.ids.end());
  }
  EXPECT_EQ(sent_ids, (std::vector<LandmarkId>{1, 2, 3, 4, 5}));
  EXPECT_TRUE(sender.select(now, 0.1, 2).ids.empty());

  // Three moved beyond the threshold (by 1, 3 and 2 sigma): the cap takes the two largest, in
  // the marginal's order, and the third goes next round.
  now.mean(3 * 0) += 1.0;  // landmark 1
  now.mean(3 * 2) += 3.0;  // landmark 3
  now.mean(3 * 4) += 2.0;  // landmark 5
  Marginal sent = sender.select(now, 0.1, 2);
  EXPECT_EQ(sent.ids, (std::vector<LandmarkId>{3, 5}));
  sender.delivered(sent);
  EXPECT_EQ(sender.select(now, 0.1, 2).ids, std::vector<LandmarkId>{1});
  // With threshold 0 the cap alone: everything is a candidate, the largest moves first.
  EXPECT_EQ(sender.select(now, 0.0, 1).ids, std::vector<LandmarkId>{1});
  EXPECT_EQ(sender.select(now, 0.0, 0).ids.size(), 5u);

  // A robot's cap a round is split evenly over its links, at least one each; 0 is no cap.
  EXPECT_EQ(link_landmark_cap(210, 14), 15);
  EXPECT_EQ(link_landmark_cap(210, 49), 4);
  EXPECT_EQ(link_landmark_cap(10, 20), 1);
  EXPECT_EQ(link_landmark_cap(10, 0), 10);
  EXPECT_EQ(link_landmark_cap(0, 3), 0);
}

TEST(MarginalSharing, AReceiverKeepsAtMostItsLimitOfLandmarks) {
  // A peer cannot grow the store without bound: new ids beyond the limit are not kept, known
  // ones still update.
  MarginalReceiver receiver(2);
  receiver.ingest(three_and_a_pair());
  EXPECT_EQ(receiver.size(), 2u);
  Marginal moved = three_and_a_pair();
  moved.mean(0) = 42.0;  // landmark 1, kept
  const Marginal fused = receiver.complete(moved, {1, 2, 3, 4, 5});
  EXPECT_EQ(receiver.size(), 2u);
  EXPECT_EQ(fused.ids.size(), 5u);  // this round's message itself is fused whole
  const Marginal later = receiver.build(Marginal(), {1, 2, 3, 4, 5});
  ASSERT_EQ(later.ids.size(), 2u);
  EXPECT_EQ(later.ids.front(), 1);
  EXPECT_DOUBLE_EQ(later.mean(0), 42.0);
}

double translation_rmse(const replay::ReplayResult& result, const dataset::Dataset& data) {
  double sum = 0.0;
  int count = 0;
  for (std::size_t r = 0; r < result.robots.size(); ++r) {
    const auto& trajectory = result.robots[r].trajectory;
    for (std::size_t k = 0; k < trajectory.size(); ++k, ++count) {
      sum += (trajectory[k].translation() - data.robots[r].groundtruth[k].translation())
                 .squaredNorm();
    }
  }
  return std::sqrt(sum / count);
}

TEST(MarginalSharing, SplitBlocksKeepEachRunsJointMarginalAndGrowWithTheLandmarks) {
  std::mt19937 random(8);
  Marginal marginal = correlated_marginal(12, random);
  // A second block (an archived object) stays as it is.
  marginal.ids.push_back(500);
  marginal.mean.conservativeResize(39);
  marginal.mean.tail<3>() = Eigen::Vector3d(1.0, 2.0, 3.0);
  marginal.blocks.push_back(testing::random_spd(3, random, 0.1, 1.0));
  EXPECT_EQ(split_blocks(marginal, 0).blocks.size(), 2u);  // 0: as it is
  const Marginal diagonal = split_blocks(marginal, 1);
  ASSERT_TRUE(diagonal.well_formed());
  EXPECT_EQ(diagonal.ids, marginal.ids);
  EXPECT_EQ(diagonal.mean, marginal.mean);
  ASSERT_EQ(diagonal.blocks.size(), 13u);
  for (std::size_t k = 0; k < 13; ++k) {
    const ObjectEstimate own = landmark_estimate(marginal, k);
    EXPECT_EQ(diagonal.blocks[k], own.covariance) << k;
    EXPECT_EQ(landmark_estimate(diagonal, k).p_world, own.p_world) << k;
  }
  // Runs of at most 5: the 12 landmarks' block as 5, 5 and 2 (each its diagonal block of the
  // joint one, the correlations within a run kept), the archived one as it was.
  const Marginal runs = split_blocks(marginal, 5);
  ASSERT_TRUE(runs.well_formed());
  ASSERT_EQ(runs.blocks.size(), 4u);
  EXPECT_EQ(runs.blocks[0], marginal.blocks[0].block(0, 0, 15, 15));
  EXPECT_EQ(runs.blocks[1], marginal.blocks[0].block(15, 15, 15, 15));
  EXPECT_EQ(runs.blocks[2], marginal.blocks[0].block(30, 30, 6, 6));
  EXPECT_EQ(runs.blocks[3], marginal.blocks[1]);
  EXPECT_EQ(split_blocks(marginal, 12).blocks.size(), 2u);
  // Bytes on the wire: a joint block grows with the square of its landmarks, the diagonal form
  // with their number.
  const auto bytes = [](const Marginal& m) { return static_cast<double>(compact(m).bytes()); };
  const Marginal small = correlated_marginal(10, random), middle = correlated_marginal(20, random),
                 large = correlated_marginal(40, random);
  EXPECT_GT(bytes(large), 10.0 * bytes(small));
  // The same bytes for every further landmark (44: id, float mean, 3x3 Cholesky triangle).
  const auto diagonal_bytes = [&](const Marginal& m) { return bytes(split_blocks(m, 1)); };
  const double per_landmark = (diagonal_bytes(middle) - diagonal_bytes(small)) / 10;
  EXPECT_EQ(per_landmark, 44.0);
  EXPECT_EQ(diagonal_bytes(large) - diagonal_bytes(middle), 20 * per_landmark);
  EXPECT_LT(diagonal_bytes(large), 0.2 * bytes(large));
  // Runs of 4: linear too (40 landmarks: twice the bytes of 20).
  EXPECT_EQ(bytes(split_blocks(large, 4)) - 24, 2 * (bytes(split_blocks(middle, 4)) - 24));
  EXPECT_TRUE(split_blocks(Marginal(), 1).ids.empty());
}

TEST(MarginalSharing, TheBlockSizeIsReadFromTheConfigAndANegativeOneIsNamed) {
  const EstimatorOptions read =
      config::parse_estimator_options("consensus: {share_block_landmarks: 4}\n", "test");
  EXPECT_EQ(read.consensus.share_block_landmarks, 4);
  EstimatorOptions bad;
  bad.consensus.share_block_landmarks = -1;
  const std::vector<std::string> problems = bad.validate();
  ASSERT_EQ(problems.size(), 1u);
  EXPECT_NE(problems.front().find("consensus.share_block_landmarks"), std::string::npos);
  EXPECT_THROW(
      (void)config::parse_estimator_options("consensus: {share_block_landmarks: -2}\n", "test"),
      config::ConfigError);
}

TEST(MarginalSharing, ASimulatedTeamSendsFarFewerBytesForTheSameAccuracy) {
  sim::SimulationOptions simulation;
  simulation.robots = 4;
  simulation.frames = testing::kSanitized ? 60 : 120;
  simulation.objects = simulation.objects * simulation.frames / 150;
  simulation.seed = 21;
  simulation.points_per_frame = 0;
  const dataset::Dataset data = sim::simulate(simulation);
  EstimatorOptions options = config::load_estimator_options(std::string(CONCORD_SOURCE_DIR) +
                                                             "/configs/sensors/sim.yaml");
  replay::ReplayOptions replay_options;
  const replay::ReplayResult every_round = replay::run_team(data, options, replay_options);
  options.consensus.share_kl_threshold = 0.01;
  options.consensus.share_float32 = true;
  const replay::ReplayResult triggered = replay::run_team(data, options, replay_options);
  replay_options.consensus = false;
  const replay::ReplayResult separate = replay::run_team(data, options, replay_options);

  // Measured (Release): 2.8x fewer bytes, trajectory RMSE +1.4 %.
  EXPECT_LT(triggered.statistics.marginal_bytes, every_round.statistics.marginal_bytes / 2);
  const double rmse_every_round = translation_rmse(every_round, data);
  const double rmse_triggered = translation_rmse(triggered, data);
  EXPECT_LT(rmse_triggered, 1.05 * rmse_every_round);
  EXPECT_LT(rmse_triggered, translation_rmse(separate, data));

  // Each landmark in a block of its own: fewer bytes again (measured: 5.6x fewer than
  // triggered over 120 frames, 2.7x over the sanitizers' 60), still better than separate, but it loses what the joint blocks said about the
  // objects' relative positions (measured: 0.150 m against 0.125 m triggered, 0.179 m
  // separate; docs/results-sharing.md).
  options.consensus.share_block_landmarks = 1;
  replay_options.consensus = true;
  const replay::ReplayResult diagonal = replay::run_team(data, options, replay_options);
  EXPECT_LT(diagonal.statistics.marginal_bytes, triggered.statistics.marginal_bytes / 2);
  EXPECT_LT(translation_rmse(diagonal, data), translation_rmse(separate, data));
}

}  // namespace
}  // namespace concord

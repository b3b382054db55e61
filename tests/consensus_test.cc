// Proposition 2 against brute-force Gaussian conditioning, the information average of eq. (19),
// the handling of partial holders, safeguards and Metropolis weights.
#include "concord/estimator/consensus.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <limits>
#include <map>
#include <random>

#include "allocation_counter.h"
#include "concord/estimator/estimator.h"
#include "concord/estimator/lie.h"
#include "concord/estimator/state_helper.h"
#include "concord/estimator/updater_helper.h"
#include "replay/team_replay.h"
#include "test_support.h"

namespace concord {
namespace {

/// Replaces the marginal of `slots` of a random state with `poses` poses and `landmarks`
/// landmarks by Proposition 2 and checks it against brute-force conditioning in the error-state
/// coordinates (x = everything else, y = the chosen landmarks). Returns the state before and
/// after and the shift A (mu_y_bar - mu_y) of x.
struct Replaced {
  State before, after;
  Eigen::VectorXd shift;
  std::vector<int> x;
};

Replaced check_proposition_two(unsigned seed, int poses, int landmarks,
                               const std::vector<int>& slots) {
  std::mt19937 random(seed);
  Replaced out;
  out.before = testing::random_state(poses, landmarks, random);
  out.after = out.before;
  const auto k = static_cast<Eigen::Index>(3 * slots.size());
  std::vector<LandmarkId> slot_ids;
  for (const int slot : slots) slot_ids.push_back(out.before.landmarks[slot].id);
  const Eigen::VectorXd old_mean = Consensus::marginal(out.before, slot_ids).mean;
  const Eigen::VectorXd new_mean = old_mean + testing::random_vector(k, random, 0.1);
  const Eigen::MatrixXd new_covariance = testing::random_spd(k, random, 0.02, 0.3);
  EXPECT_TRUE(Consensus::replace_marginal(out.after, slots, new_mean, new_covariance));

  std::vector<int> y;
  for (int slot : slots)
    for (int c = 0; c < 3; ++c) y.push_back(out.before.landmark_index(slot) + c);
  for (int i = 0; i < out.before.dimension(); ++i)
    if (std::find(y.begin(), y.end(), i) == y.end()) out.x.push_back(i);
  const std::vector<int>& x = out.x;
  const Eigen::MatrixXd& P = out.before.covariance;
  const Eigen::MatrixXd A = P(x, y) * P(y, y).inverse();
  const Eigen::MatrixXd conditional = P(x, x) - A * P(y, x);
  const Eigen::MatrixXd& Q = out.after.covariance;
  // (14): the new marginal of y is exactly the given one ...
  EXPECT_TRUE(Q(y, y).isApprox(new_covariance, 1e-10));
  // ... the cross block is A Sigma_y_bar, and the conditional of x given y is unchanged.
  EXPECT_TRUE(Q(x, y).isApprox(A * new_covariance, 1e-10));
  EXPECT_TRUE(Q.isApprox(Q.transpose(), 1e-14));
  const Eigen::MatrixXd new_conditional = Q(x, x) - Q(x, y) * Q(y, y).inverse() * Q(y, x);
  EXPECT_TRUE(new_conditional.isApprox(conditional, 1e-9));
  // Mean: x shifts by A (mu_y_bar - mu_y); poses through exp (eq. 21, left perturbation); the
  // replaced landmarks take the new mean.
  out.shift = A * (new_mean - old_mean);
  for (int pose = 0; pose < poses; ++pose) {
    const Eigen::Isometry3d expected =
        lie::se3_exp(out.shift.segment<6>(6 * pose)) * out.before.poses[pose].T_world_body;
    EXPECT_TRUE(out.after.poses[pose].T_world_body.matrix().isApprox(expected.matrix(), 1e-10));
  }
  for (std::size_t i = 0; i < slots.size(); ++i) {
    EXPECT_TRUE(out.after.landmarks[slots[i]].p_world.isApprox(
        new_mean.segment<3>(3 * static_cast<Eigen::Index>(i)), 1e-12));
  }
  return out;
}

TEST(Proposition2, KeepsTheConditionalAndSetsTheMarginal) {
  // y = landmarks 0 and 2: landmark 1 is in x, between them.
  const Replaced r = check_proposition_two(21, 2, 3, {0, 2});
  EXPECT_TRUE(r.after.landmarks[1].p_world.isApprox(
      r.before.landmarks[1].p_world + r.shift.tail<3>(), 1e-10));
}

TEST(Proposition2, EveryLandmarkReplacedKeepsThePosesConditional) {
  // y = every landmark: x (the poses) is the covariance's leading block, which Proposition 2
  // updates in place.
  const Replaced r = check_proposition_two(23, 3, 4, {0, 1, 2, 3});
  EXPECT_EQ(r.x.back(), static_cast<int>(r.x.size()) - 1);
}

TEST(Proposition2, AMarginalFusedWithUnknownCorrelationMovesTheRestButNeverShrinksIt) {
  // An archived object rejoining: its new marginal is more certain in some directions and less
  // in others. The rest of the state moves exactly as with replace_marginal, and its
  // covariance is at least what it was (replace_marginal shrinks it).
  std::mt19937 random(7);
  const State before = testing::random_state(3, 4, random);
  const int slot = 2;
  const Eigen::Index index = before.landmark_index(slot);
  const Eigen::Matrix3d own = before.covariance.block<3, 3>(index, index);
  Eigen::Matrix3d target = own;
  target(0, 0) *= 0.2;  // more certain along x
  target(2, 2) *= 3.0;  // less certain along z
  const Eigen::Vector3d mean = before.landmarks[slot].p_world + Eigen::Vector3d(0.1, -0.2, 0.05);

  State kept = before;
  ASSERT_TRUE(Consensus::replace_marginal_keeping_the_rest(kept, slot, mean, target));
  State plain = before;
  ASSERT_TRUE(Consensus::replace_marginal(plain, {slot}, mean, target));

  // The landmark takes the new marginal; everything moves as with replace_marginal.
  const Eigen::Matrix3d landmark_block = kept.covariance.block<3, 3>(index, index);
  EXPECT_TRUE(landmark_block.isApprox(target, 1e-12));
  EXPECT_TRUE(kept.landmarks[slot].p_world.isApprox(mean, 1e-12));
  for (std::size_t i = 0; i < before.poses.size(); ++i) {
    EXPECT_TRUE(kept.poses[i].T_world_body.isApprox(plain.poses[i].T_world_body, 1e-12)) << i;
  }
  for (std::size_t j = 0; j < before.landmarks.size(); ++j) {
    EXPECT_TRUE(kept.landmarks[j].p_world.isApprox(plain.landmarks[j].p_world, 1e-12)) << j;
  }
  // The rest: at least its old covariance with kept, less than it with replace_marginal.
  std::vector<int> rest;
  for (int i = 0; i < before.dimension(); ++i) {
    if (i < index || i >= index + 3) rest.push_back(i);
  }
  const auto smallest_change = [&](const State& after) {
    const Eigen::MatrixXd change = after.covariance(rest, rest) - before.covariance(rest, rest);
    return Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(change).eigenvalues().minCoeff();
  };
  EXPECT_GE(smallest_change(kept), -1e-12);
  EXPECT_LT(smallest_change(plain), -1e-4);
  EXPECT_EQ(Eigen::LLT<Eigen::MatrixXd>(kept.covariance).info(), Eigen::Success);
  EXPECT_TRUE(kept.covariance.isApprox(kept.covariance.transpose(), 0.0));

  // A new marginal nowhere more certain than the own one: replace_marginal exactly.
  State wider = before, wider_plain = before;
  ASSERT_TRUE(Consensus::replace_marginal_keeping_the_rest(wider, slot, mean, 2.0 * own));
  ASSERT_TRUE(Consensus::replace_marginal(wider_plain, {slot}, mean, 2.0 * own));
  EXPECT_TRUE(wider.covariance.isApprox(wider_plain.covariance, 0.0));
}

/// One pose and landmark 5 at the origin, all with unit covariance and no correlation.
State single_landmark_state() {
  State state;
  state.poses.push_back({0, Eigen::Isometry3d::Identity()});
  state.landmarks.push_back({5, Eigen::Vector3d::Zero(), 0});
  state.rebuild_landmark_index();
  state.covariance = Eigen::MatrixXd::Identity(9, 9);
  return state;
}

ConsensusOptions no_safeguards() {
  ConsensusOptions options;
  options.neighbour_chi2_probability = 0.0;
  return options;
}

/// A state with 6 in-state landmarks (ids 100-105) and 2 archived objects (40, 41), and three
/// neighbours: one holds everything (a joint block of 6 and the archived ones as blocks of their
/// own), one the landmarks 100-102 and object 40, and one landmark 100 far away (refused by the
/// chi-square test). Landmarks 100-102 and 103-105 are averaged as groups of three; the archived
/// objects one by one.
struct WorkspaceCase {
  State state;
  std::vector<WeightedMarginal> neighbours;
};

WorkspaceCase workspace_case() {
  std::mt19937 random(31);
  WorkspaceCase out;
  out.state = testing::random_state(3, 6, random);
  out.state.archived[40] = {40, Eigen::Vector3d(1, 2, 3), 0.5 * Eigen::Matrix3d::Identity()};
  out.state.archived[41] = {41, Eigen::Vector3d(4, 5, 6), 0.7 * Eigen::Matrix3d::Identity()};
  Marginal everything = Consensus::marginal(out.state, out.state.object_ids());
  everything.mean += testing::random_vector(everything.mean.size(), random, 0.05);
  Marginal some = Consensus::marginal(out.state, {100, 101, 102, 40});
  some.mean += testing::random_vector(some.mean.size(), random, 0.05);
  Marginal far = Consensus::marginal(out.state, {100});
  far.mean += Eigen::Vector3d(100, 0, 0);
  out.neighbours = {{0.25, everything, 1}, {0.25, some, 2}, {0.25, far, 3}};
  return out;
}

TEST(ConsensusWorkspace, ARoundOfAShapeSeenBeforeAllocatesNothing) {
  if (!testing::counting_allocations()) {
    GTEST_SKIP() << "a sanitizer build: allocations are not counted";
  }
  const WorkspaceCase c = workspace_case();
  for (const double kl_threshold : {0.0, 1e-9}) {
    ConsensusOptions options;
    options.fuse_kl_threshold = kl_threshold;
    // The answer without a workspace (fresh buffers).
    State expected = c.state;
    const ConsensusReport expected_report = Consensus::fuse(expected, c.neighbours, options);
    ASSERT_EQ(expected_report.landmarks_refused, 1);
    ASSERT_EQ(expected_report.landmarks_fused, 8);
    ASSERT_EQ(expected_report.groups, 4);  // two groups of three landmarks, two archived objects

    // Rounds of two shapes: every neighbour, and one neighbour holding half the landmarks
    // (Proposition 2 then moves the other landmarks too, a state not led by x).
    const std::vector<WeightedMarginal> one{c.neighbours[1]};
    ConsensusWorkspace workspace;
    State first = c.state;
    Consensus::fuse(first, c.neighbours, options, workspace);  // sizes the buffers
    State first_one = c.state;
    Consensus::fuse(first_one, one, options, workspace);
    const std::size_t before_copy = testing::allocations();
    State second = c.state;
    State second_one = c.state;
    const std::size_t before = testing::allocations();
    EXPECT_GT(before, before_copy);  // the counter sees allocations (the copies')
    const ConsensusReport& report = Consensus::fuse(second, c.neighbours, options, workspace);
    EXPECT_EQ(testing::allocations(), before) << "kl threshold " << kl_threshold;
    EXPECT_EQ(report.landmarks_fused, expected_report.landmarks_fused);
    EXPECT_EQ(report.refused_per_neighbour, expected_report.refused_per_neighbour);
    const int fused_one = Consensus::fuse(second_one, one, options, workspace).landmarks_fused;
    EXPECT_EQ(testing::allocations(), before) << "kl threshold " << kl_threshold;
    EXPECT_EQ(fused_one, 4);
    // The same numbers as with fresh buffers, to the bit.
    EXPECT_EQ(second.covariance, expected.covariance);
    for (int slot = 0; slot < second.num_landmarks(); ++slot) {
      EXPECT_EQ(second.landmarks[slot].p_world, expected.landmarks[slot].p_world);
    }
    EXPECT_EQ(second.archived.at(40).covariance, expected.archived.at(40).covariance);
    EXPECT_EQ(second_one.covariance, first_one.covariance);
  }
}

TEST(ConsensusMarginal, IntoAMarginalOfTheSameShapeTheArchivedBlocksAllocateNothing) {
  std::mt19937 random(37);
  State state = testing::random_state(2, 4, random);
  for (LandmarkId id = 40; id < 60; ++id) {
    state.archived[id] = {id, Eigen::Vector3d::Constant(static_cast<double>(id)),
                          (1.0 + 0.01 * static_cast<double>(id)) * Eigen::Matrix3d::Identity()};
  }
  // In-state and archived ids mixed, one unknown: in-state first, then archived, in this order.
  std::vector<LandmarkId> ids{45, 101, 41, 999, 100};
  for (LandmarkId id = 50; id < 60; ++id) ids.push_back(id);
  const Marginal fresh = Consensus::marginal(state, ids);
  ASSERT_EQ(fresh.ids.size(), 14u);
  EXPECT_EQ(fresh.ids[0], 101u);
  EXPECT_EQ(fresh.ids[1], 100u);
  EXPECT_EQ(fresh.ids[2], 45u);
  ASSERT_EQ(fresh.blocks.size(), 13u);  // the joint block, then a 3x3 an archived object
  EXPECT_EQ(fresh.blocks[0].rows(), 6);
  EXPECT_EQ(fresh.blocks[1], state.archived.at(45).covariance);
  EXPECT_EQ(fresh.mean.segment<3>(3), state.landmarks[state.landmark_slot(100)].p_world);

  Marginal reused;
  Consensus::marginal(state, ids, reused);
  const std::size_t before = testing::allocations();
  Consensus::marginal(state, ids, reused);
  // Nothing: the 12 archived blocks and the joint block are reused, and the lists of where the
  // landmarks are are kept between calls.
  if (testing::counting_allocations()) {
    EXPECT_EQ(testing::allocations() - before, 0u);
  }
  EXPECT_EQ(reused.ids, fresh.ids);
  EXPECT_EQ(reused.mean, fresh.mean);
  EXPECT_TRUE(testing::same_blocks(reused.blocks, fresh.blocks));
  // Fewer landmarks into the same storage: nothing left over.
  Consensus::marginal(state, {41, 100}, reused);
  EXPECT_EQ(reused.ids, (std::vector<LandmarkId>{100, 41}));
  ASSERT_EQ(reused.blocks.size(), 2u);
  EXPECT_EQ(reused.mean.size(), 6);
  EXPECT_EQ(reused.blocks[1], state.archived.at(41).covariance);
}

TEST(ConsensusMarginal, AscendingIdsAreFoundAsIdsInAnyOrderAre) {
  // Ascending ids are merged with the state's objects and its archive; ids in any other order are
  // looked up one by one. Both must find the same objects: ids held and not held, in-state and
  // archived interleaved, an archive far longer than the list (its walk gives way to a search)
  // and a repeated id.
  std::mt19937 random(41);
  State state = testing::random_state(2, 5, random);  // in-state ids 100-104
  for (LandmarkId id = 3; id < 400; id += 3) {
    state.archived[id] = {id, Eigen::Vector3d::Constant(static_cast<double>(id)),
                          (1.0 + 0.001 * static_cast<double>(id)) * Eigen::Matrix3d::Identity()};
  }
  const std::vector<LandmarkId> ascending{2, 3, 99, 101, 102, 102, 104, 105, 201, 390, 399, 500};
  const std::vector<LandmarkId> reversed(ascending.rbegin(), ascending.rend());
  const Marginal merged = Consensus::marginal(state, ascending);
  const Marginal looked_up = Consensus::marginal(state, reversed);
  // In-state first (101, 102 twice, 104), then archived (the multiples of 3); 2 and 500 are not
  // held.
  EXPECT_EQ(merged.ids, (std::vector<LandmarkId>{101, 102, 102, 104, 3, 99, 105, 201, 390, 399}));
  ASSERT_TRUE(merged.well_formed());
  ASSERT_EQ(looked_up.ids.size(), merged.ids.size());
  // The same objects, each with the same mean and the same covariance with every other.
  const Eigen::MatrixXd merged_dense = merged.dense_covariance();
  const Eigen::MatrixXd looked_up_dense = looked_up.dense_covariance();
  const auto position = [](const Marginal& m, LandmarkId id) {
    return static_cast<Eigen::Index>(std::find(m.ids.begin(), m.ids.end(), id) - m.ids.begin());
  };
  for (std::size_t a = 0; a < merged.ids.size(); ++a) {
    const Eigen::Index i = position(looked_up, merged.ids[a]);
    ASSERT_LT(i, static_cast<Eigen::Index>(looked_up.ids.size())) << merged.ids[a];
    EXPECT_EQ(merged.mean.segment<3>(3 * static_cast<Eigen::Index>(a)),
              looked_up.mean.segment<3>(3 * i));
    for (std::size_t b = 0; b < merged.ids.size(); ++b) {
      const Eigen::Index j = position(looked_up, merged.ids[b]);
      const Eigen::Matrix3d merged_block = merged_dense.block<3, 3>(
          3 * static_cast<Eigen::Index>(a), 3 * static_cast<Eigen::Index>(b));
      const Eigen::Matrix3d looked_up_block = looked_up_dense.block<3, 3>(3 * i, 3 * j);
      EXPECT_EQ(merged_block, looked_up_block) << merged.ids[a] << ", " << merged.ids[b];
    }
  }
  EXPECT_EQ(merged.mean.segment<3>(3 * 9), state.archived.at(399).p_world);
  const Eigen::Index row = state.landmark_index(state.landmark_slot(101));
  const Eigen::Index column = state.landmark_index(state.landmark_slot(104));
  const Eigen::Matrix3d cross = merged_dense.block<3, 3>(0, 9);
  const Eigen::Matrix3d expected = state.covariance.block<3, 3>(row, column);
  EXPECT_EQ(cross, expected);
}

TEST(ConsensusMarginal, ACutOfTheWholeMarginalIsTheMarginalOfTheCut) {
  // A robot builds the marginal of everything it holds once a round and cuts each neighbour's
  // out of it: for ascending ids the cut must equal the marginal built from the state for those
  // ids, to the bit (ids, means and blocks: in-state ones a sub-block of the joint block, in the
  // joint block's order, then the archived ones' 3x3 blocks).
  std::mt19937 random(43);
  State state = testing::random_state(3, 6, random);  // in-state ids 100-105
  for (LandmarkId id = 5; id < 300; id += 5) {
    if (state.landmark_slot(id) >= 0) continue;  // an object is in the state or archived
    state.archived[id] = {id, Eigen::Vector3d::Constant(static_cast<double>(id)),
                          (1.0 + 0.002 * static_cast<double>(id)) * Eigen::Matrix3d::Identity()};
  }
  const Marginal whole = Consensus::marginal(state, state.object_ids());
  ASSERT_GT(whole.blocks.front().rows(), 3);  // the joint block leads
  std::vector<std::vector<LandmarkId>> cuts{
      {},                               // nothing
      {1, 2, 999},                      // nothing held
      {101, 104},                       // in-state only, not adjacent in the joint block
      {100, 101, 102, 103, 104, 105},   // the whole joint block
      {5, 150, 295},                    // archived only
      {3, 5, 100, 103, 105, 120, 121},  // mixed, with ids not held
  };
  // Random subsets of what the robot holds and some it does not.
  std::bernoulli_distribution keep(0.4);
  for (int draw = 0; draw < 20; ++draw) {
    std::vector<LandmarkId> cut;
    for (LandmarkId id = 0; id < 310; ++id)
      if (keep(random)) cut.push_back(id);
    cuts.push_back(std::move(cut));
  }
  Marginal reused;  // one output for every cut: storage of another shape must not leak through
  for (const auto& ids : cuts) {
    const Marginal expected = Consensus::marginal(state, ids);
    Consensus::select(whole, ids, reused);
    ASSERT_TRUE(reused.well_formed());
    EXPECT_EQ(reused.ids, expected.ids);
    EXPECT_EQ(reused.mean, expected.mean);
    EXPECT_TRUE(testing::same_blocks(reused.blocks, expected.blocks)) << ids.size() << " ids";
  }
}

/// A random state whose in-state landmarks are renamed `ids` (as many as it has) and whose
/// archive holds `archived` (unit-ish covariances, positions near the in-state ones).
State renamed_state(int poses, const std::vector<LandmarkId>& ids,
                    const std::vector<LandmarkId>& archived, std::mt19937& random) {
  State state = testing::random_state(poses, static_cast<int>(ids.size()), random);
  for (std::size_t j = 0; j < ids.size(); ++j) state.landmarks[j].id = ids[j];
  state.rebuild_landmark_index();
  for (LandmarkId id : archived) {
    state.archived[id] = {id, Eigen::Vector3d(0.1 * static_cast<double>(id), 1.0, 1.0),
                          (0.3 + 0.001 * static_cast<double>(id)) * Eigen::Matrix3d::Identity()};
  }
  return state;
}

TEST(ConsensusAverage, ASharedMarginalFusesAsTheCutOfWhatTheRobotHolds) {
  // The replay builds every robot's marginal of all it holds once a round, and each neighbour
  // fuses the part of it that it holds itself. That must give, to the bit, what fusing the
  // marginal of the common ids (what a daemon receives, Consensus::select) gives: the same
  // holders, groups, order and numbers, whatever the shared marginal holds besides.
  std::mt19937 random(47);
  const State robot =
      renamed_state(3, {100, 101, 102, 103, 104, 105}, {10, 13, 16, 19, 22}, random);
  const std::vector<LandmarkId> robot_ids = robot.object_ids();
  std::vector<State> neighbours{
      // More in its joint block than the robot holds, and some of its archived objects.
      renamed_state(3, {100, 101, 102, 103, 104, 105, 106, 107}, {10, 16, 40}, random),
      // Part of the robot's in-state landmarks, not adjacent, with others between; one the
      // robot archived (13) in its joint block.
      renamed_state(2, {13, 98, 101, 103, 104, 200}, {19, 22, 41}, random),
      // Nothing in common.
      renamed_state(2, {300, 301}, {50}, random),
  };
  std::vector<SharedMarginal> shared(neighbours.size());
  std::vector<WeightedShare> shares;
  std::vector<WeightedMarginal> cuts;
  for (std::size_t j = 0; j < neighbours.size(); ++j) {
    Consensus::marginal(neighbours[j], neighbours[j].object_ids(), shared[j].marginal());
    ASSERT_TRUE(shared[j].index());
    shares.push_back({0.2, &shared[j]});
    cuts.push_back({0.2, {}});
    Consensus::select(shared[j].marginal(), robot_ids, cuts.back().marginal);
  }
  ASSERT_EQ(cuts[0].marginal.blocks.size(), 3u);  // a cut of the joint block, two archived
  ASSERT_EQ(cuts[1].marginal.ids.size(), 6u);     // 13, 101, 103, 104 in the joint; 19, 22
  ASSERT_TRUE(cuts[2].marginal.ids.empty());
  // The block sizes of each cut, counted on the shared marginal.
  for (std::size_t j = 0; j < neighbours.size(); ++j) {
    std::vector<int> per_block;
    shared[j].count_common(robot_ids, per_block);
    std::vector<int> expected;
    for (const Eigen::MatrixXd& block : cuts[j].marginal.blocks) {
      expected.push_back(static_cast<int>(block.rows() / 3));
    }
    per_block.erase(std::remove(per_block.begin(), per_block.end(), 0), per_block.end());
    EXPECT_EQ(per_block, expected) << "neighbour " << j;
  }
  for (const ConsensusOptions& options : {no_safeguards(), ConsensusOptions()}) {
    State expected = robot;
    const ConsensusReport expected_report = Consensus::fuse(expected, cuts, options);
    ASSERT_GT(expected_report.landmarks_fused, 6);
    State fused = robot;
    ConsensusWorkspace workspace;
    const ConsensusReport& report = Consensus::fuse(fused, shares, options, workspace);
    EXPECT_EQ(report.landmarks_fused, expected_report.landmarks_fused);
    EXPECT_EQ(report.groups, expected_report.groups);
    EXPECT_EQ(report.neighbours_skipped, expected_report.neighbours_skipped);
    EXPECT_EQ(report.landmarks_refused, expected_report.landmarks_refused);
    EXPECT_EQ(report.refused_per_neighbour, expected_report.refused_per_neighbour);
    EXPECT_EQ(report.tested_per_neighbour, expected_report.tested_per_neighbour);
    EXPECT_EQ(fused.covariance, expected.covariance);
    for (int slot = 0; slot < fused.num_landmarks(); ++slot) {
      EXPECT_EQ(fused.landmarks[slot].p_world, expected.landmarks[slot].p_world);
    }
    for (const auto& [id, object] : expected.archived) {
      EXPECT_EQ(fused.archived.at(id).p_world, object.p_world) << id;
      EXPECT_EQ(fused.archived.at(id).covariance, object.covariance) << id;
    }
    for (std::size_t k = 0; k < fused.poses.size(); ++k) {
      EXPECT_EQ(fused.poses[k].T_world_body.matrix(), expected.poses[k].T_world_body.matrix());
    }
  }
  // A shared marginal with a non-finite entry anywhere is left out whole, and counted.
  SharedMarginal broken;
  broken.marginal() = shared[0].marginal();
  broken.marginal().blocks.back()(0, 0) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(broken.index());
  State without = robot;
  Consensus::fuse(without, std::vector<WeightedMarginal>{cuts[1]}, no_safeguards());
  State with = robot;
  ConsensusWorkspace workspace;
  const std::vector<WeightedShare> with_broken{{0.2, &broken}, {0.2, &shared[1]}};
  EXPECT_EQ(Consensus::fuse(with, with_broken, no_safeguards(), workspace).neighbours_skipped, 1);
  EXPECT_EQ(with.covariance, without.covariance);
}

TEST(ConsensusAverage, IdenticalMarginalsAreANoOp) {
  std::mt19937 random(22);
  State state = testing::random_state(2, 3, random);
  const State before = state;
  const Marginal own = Consensus::marginal(state, state.object_ids());
  const auto report = Consensus::fuse(state, {{1.0 / 3, own}, {1.0 / 3, own}}, no_safeguards());
  EXPECT_EQ(report.landmarks_fused, 3);
  EXPECT_TRUE(state.covariance.isApprox(before.covariance, 1e-10));
  for (int i = 0; i < 3; ++i) {
    EXPECT_TRUE(state.landmarks[i].p_world.isApprox(before.landmarks[i].p_world, 1e-10));
  }
  EXPECT_TRUE(state.poses[1].T_world_body.isApprox(before.poses[1].T_world_body, 1e-10));
}

TEST(ConsensusAverage, TwoMarginalsGiveTheClosedFormInformationAverage) {
  // One landmark, own N(m1, 1 I), neighbour N(m2, 4 I), weights 1/2 each:
  // information 0.5 + 0.125 = 0.625 -> covariance 1.6 I, mean 1.6 (0.5 m1 + 0.125 m2).
  State state;
  state.poses.push_back({0, Eigen::Isometry3d::Identity()});
  state.landmarks.push_back({5, Eigen::Vector3d(1.0, 2.0, 3.0), 0});
  state.rebuild_landmark_index();
  state.covariance = Eigen::MatrixXd::Identity(9, 9);
  Marginal neighbour{{5}, Eigen::Vector3d(3.0, 2.0, -1.0), 4.0 * Eigen::Matrix3d::Identity()};
  Consensus::fuse(state, {{0.5, neighbour}}, no_safeguards());
  const Eigen::Vector3d expected =
      1.6 * (0.5 * Eigen::Vector3d(1, 2, 3) + 0.125 * Eigen::Vector3d(3, 2, -1));
  EXPECT_TRUE(state.landmarks[0].p_world.isApprox(expected, 1e-12));
  const Eigen::Matrix3d block = state.covariance.block<3, 3>(6, 6);
  EXPECT_TRUE(block.isApprox(1.6 * Eigen::Matrix3d::Identity(), 1e-12));
  // The pose is uncorrelated with the landmark: untouched.
  EXPECT_TRUE(state.poses[0].T_world_body.isApprox(Eigen::Isometry3d::Identity(), 1e-14));
}

TEST(ConsensusAverage, ArchivedObjectsAverageIndependently) {
  State state;
  state.poses.push_back({0, Eigen::Isometry3d::Identity()});
  state.covariance = Eigen::MatrixXd::Identity(6, 6);
  state.archived[9] = {9, Eigen::Vector3d(0, 0, 0), Eigen::Matrix3d::Identity()};
  Marginal neighbour{{9}, Eigen::Vector3d(2, 0, 0), Eigen::Matrix3d::Identity()};
  Consensus::fuse(state, {{0.5, neighbour}}, no_safeguards());
  EXPECT_TRUE(state.archived[9].p_world.isApprox(Eigen::Vector3d(1, 0, 0), 1e-12));
  EXPECT_TRUE(state.archived[9].covariance.isApprox(Eigen::Matrix3d::Identity(), 1e-12));
}

TEST(ConsensusAverage, NonHoldersLeaveTheirWeightToTheRobot) {
  // Landmark 5 is held by neighbour a only; neighbour b (weight 1/3) holds another one.
  State state = single_landmark_state();
  Marginal a{{5}, Eigen::Vector3d(3, 0, 0), Eigen::Matrix3d::Identity()};
  Marginal b{{6}, Eigen::Vector3d(0, 0, 0), Eigen::Matrix3d::Identity()};
  Consensus::fuse(state, {{1.0 / 3, a}, {1.0 / 3, b}}, no_safeguards());
  // Equal covariances: the mean is the weighted mean with own weight 2/3.
  EXPECT_TRUE(state.landmarks[0].p_world.isApprox(Eigen::Vector3d(1, 0, 0), 1e-12));
}

TEST(ConsensusMarginal, ArchivedObjectsAreIndependentBlocks) {
  std::mt19937 random(5);
  State state = testing::random_state(2, 2, random);
  state.archived[40] = {40, Eigen::Vector3d(1, 2, 3), 2.0 * Eigen::Matrix3d::Identity()};
  state.archived[41] = {41, Eigen::Vector3d(4, 5, 6), 3.0 * Eigen::Matrix3d::Identity()};
  const Marginal m = Consensus::marginal(state, state.object_ids());
  ASSERT_TRUE(m.well_formed());
  ASSERT_EQ(m.blocks.size(), 3u);  // the two in-state landmarks jointly, then one per archived
  EXPECT_EQ(m.blocks[0].rows(), 6);
  EXPECT_TRUE(m.blocks[2].isApprox(3.0 * Eigen::Matrix3d::Identity(), 1e-15));
  const Eigen::MatrixXd dense = m.dense_covariance();
  EXPECT_TRUE(dense.block(6, 0, 6, 6).isZero(0.0));
}

TEST(ConsensusAverage, BlockDiagonalMarginalIsAveragedBlockByBlock) {
  // A neighbour's marginal claims nothing about landmarks in different blocks: fusing it equals
  // fusing its blocks one after another as separate marginals of the same weight.
  std::mt19937 random(8);
  State grouped = testing::random_state(2, 4, random);
  const State original = grouped;
  State successive = grouped;
  const std::vector<LandmarkId> ids = grouped.object_ids();
  Marginal blocked;
  blocked.ids = ids;
  blocked.mean = Eigen::VectorXd::Random(12);
  blocked.blocks = {testing::random_spd(6, random, 0.02, 0.3),
                    testing::random_spd(3, random, 0.02, 0.3),
                    testing::random_spd(3, random, 0.02, 0.3)};
  Consensus::fuse(grouped, {{0.25, blocked}}, no_safeguards());
  const Marginal first{{ids[0], ids[1]}, blocked.mean.head(6), blocked.blocks[0]};
  const Marginal second{{ids[2]}, blocked.mean.segment(6, 3), blocked.blocks[1]};
  const Marginal third{{ids[3]}, blocked.mean.tail(3), blocked.blocks[2]};
  for (const Marginal* part : {&first, &second, &third}) {
    Consensus::fuse(successive, {{0.25, *part}}, no_safeguards());
  }
  EXPECT_TRUE(grouped.covariance.isApprox(successive.covariance, 1e-9));
  for (int i = 0; i < 4; ++i) {
    EXPECT_TRUE(grouped.landmarks[i].p_world.isApprox(successive.landmarks[i].p_world, 1e-6));
  }
  // ... and differs from averaging the same numbers as one dense marginal (which claims zero
  // correlation between the blocks).
  State dense_state = original;
  Consensus::fuse(dense_state, {{0.25, Marginal(ids, blocked.mean, blocked.dense_covariance())}},
                  no_safeguards());
  EXPECT_FALSE(dense_state.covariance.isApprox(grouped.covariance, 1e-6));
}

TEST(ConsensusAverage, GroupsEqualSuccessivePropositionTwoReplacements) {
  // Neighbour a holds landmarks {0, 1}, neighbour b holds {1, 2}: three holder groups, {0}: a,
  // {1}: a+b, {2}: b. fuse() replaces them together; the reference replaces group by group on
  // the full state, each from the state the previous one left.
  std::mt19937 random(17);
  State state = testing::random_state(3, 3, random);
  const std::vector<LandmarkId> ids = state.object_ids();
  // Neighbours close to the robot (a few cm), as in a running team.
  auto random_marginal = [&](std::vector<LandmarkId> subset) {
    const auto d = static_cast<Eigen::Index>(3 * subset.size());
    Marginal m = Consensus::marginal(state, subset);
    m.mean += 0.03 * Eigen::VectorXd::Random(d);
    m.blocks = {testing::random_spd(d, random, 0.02, 0.3)};
    return m;
  };
  const Marginal a = random_marginal({ids[0], ids[1]});
  const Marginal b = random_marginal({ids[1], ids[2]});
  const double w = 0.3;
  State reference = state;
  auto average_into = [&](int slot, std::vector<std::pair<const Marginal*, int>> holders) {
    // Information average of the reference's current marginal of `slot` and the holders'.
    const Marginal own = Consensus::marginal(reference, {reference.landmarks[slot].id});
    double own_weight = 1.0 - w * static_cast<double>(holders.size());
    Eigen::Matrix3d information = own_weight * own.blocks[0].inverse();
    Eigen::Vector3d vector = information * own.mean;
    for (const auto& [m, position] : holders) {
      const Eigen::Matrix3d c = m->blocks[0].block<3, 3>(3 * position, 3 * position);
      information += w * c.inverse();
      vector += w * c.inverse() * m->mean.segment<3>(3 * position);
    }
    const Eigen::Matrix3d covariance = information.inverse();
    ASSERT_TRUE(Consensus::replace_marginal(reference, {slot}, covariance * vector, covariance));
  };
  // Group order of fuse(): by holder set {a} < {a, b} < {b}.
  average_into(reference.landmark_slot(ids[0]), {{&a, 0}});
  average_into(reference.landmark_slot(ids[1]), {{&a, 1}, {&b, 0}});
  average_into(reference.landmark_slot(ids[2]), {{&b, 1}});
  const auto report = Consensus::fuse(state, {{w, a}, {w, b}}, no_safeguards());
  EXPECT_EQ(report.groups, 3);
  EXPECT_EQ(report.landmarks_fused, 3);
  EXPECT_TRUE(state.covariance.isApprox(reference.covariance, 1e-9));
  for (int i = 0; i < 3; ++i) {
    EXPECT_TRUE(state.landmarks[i].p_world.isApprox(reference.landmarks[i].p_world, 1e-9));
  }
  // Poses: one exp(sum of corrections) against a product of exps: equal to second order in
  // the (centimetre) corrections.
  const Eigen::Matrix<double, 6, 1> difference =
      lie::se3_log(reference.poses[2].T_world_body.inverse() * state.poses[2].T_world_body);
  EXPECT_LT(difference.norm(), 1e-4);
}

TEST(ConsensusSafeguards, RepeatedIdsMakeAMarginalMalformed) {
  State state = single_landmark_state();
  const State before = state;
  Marginal twice{{5, 5}, Eigen::VectorXd::Zero(6), Eigen::MatrixXd::Identity(6, 6)};
  const auto report = Consensus::fuse(state, {{0.5, twice}}, no_safeguards());
  EXPECT_EQ(report.neighbours_skipped, 1);
  EXPECT_EQ(report.landmarks_fused, 0);
  EXPECT_TRUE(state.covariance.isApprox(before.covariance, 0.0));
}

TEST(ConsensusSafeguards, MalformedAndIllConditionedMarginalsAreSkipped) {
  State state = single_landmark_state();
  const State before = state;
  Marginal wrong_size{{5}, Eigen::Vector2d(1, 1), Eigen::Matrix3d::Identity()};
  Marginal indefinite{{5}, Eigen::Vector3d(1, 1, 1), -Eigen::Matrix3d::Identity()};
  Eigen::Matrix3d nearly_singular = Eigen::Matrix3d::Identity();
  nearly_singular(2, 2) = 1e-15;
  Marginal ill{{5}, Eigen::Vector3d(1, 1, 1), nearly_singular};
  Marginal not_finite{{5}, Eigen::Vector3d(NAN, 0, 0), Eigen::Matrix3d::Identity()};
  const auto report =
      Consensus::fuse(state, {{0.2, wrong_size}, {0.2, indefinite}, {0.2, ill}, {0.2, not_finite}},
                      no_safeguards());
  EXPECT_EQ(report.neighbours_skipped, 4);
  EXPECT_EQ(report.landmarks_fused, 0);
  EXPECT_TRUE(state.landmarks[0].p_world.isApprox(before.landmarks[0].p_world));
}

TEST(ConsensusSafeguards, ANonFiniteEntryAnywhereMakesAMarginalMalformed) {
  // Marginal::well_formed tests finiteness in one sum (x * 0 is NaN for an infinite or NaN x):
  // every kind of non-finite value, in the mean, a joint block and an archived block, at the
  // first, a middle and the last entry.
  std::mt19937 random(12);
  State state = testing::random_state(2, 3, random);
  state.archived[40] = {40, Eigen::Vector3d(1, 2, 3), 0.5 * Eigen::Matrix3d::Identity()};
  const Marginal good = Consensus::marginal(state, state.object_ids());
  ASSERT_EQ(good.blocks.size(), 2u);
  ASSERT_TRUE(good.well_formed());
  const double bad_values[] = {std::numeric_limits<double>::infinity(),
                               -std::numeric_limits<double>::infinity(),
                               std::numeric_limits<double>::quiet_NaN()};
  for (const double bad : bad_values) {
    for (int where = 0; where < 3; ++where) {
      Marginal m = good;
      Eigen::Index entries[] = {0, m.mean.size() / 2, m.mean.size() - 1};
      m.mean(entries[where]) = bad;
      EXPECT_FALSE(m.well_formed()) << bad << " in the mean at " << entries[where];
      for (std::size_t b = 0; b < good.blocks.size(); ++b) {
        Marginal block = good;
        Eigen::MatrixXd& covariance = block.blocks[b];
        const Eigen::Index cells[] = {0, covariance.size() / 2, covariance.size() - 1};
        covariance(cells[where]) = bad;
        EXPECT_FALSE(block.well_formed()) << bad << " in block " << b << " at " << cells[where];
      }
    }
  }
  // Large finite values are finite.
  Marginal large = good;
  large.mean *= 1e300;
  EXPECT_TRUE(large.well_formed());
}

TEST(ConsensusAverage, ANeighboursIdsInAnyOrderFuseAsSorted) {
  // A marginal's landmarks are found by id whatever the order of its ids and blocks (a peer's
  // message may list them in any order): the archived objects' 3x3 blocks in a shuffled order
  // fuse exactly as sorted by id. (The in-state landmarks are one joint block, first in both:
  // the order of in-state groups is part of the average, see GroupsEqualSuccessive...)
  std::mt19937 random(44);
  State base = testing::random_state(2, 2, random);
  for (LandmarkId id : {40, 41, 42, 43, 44}) {
    base.archived[id] = {id, testing::random_vector(3, random, 1.0),
                         testing::random_spd(3, random, 0.2, 0.6)};
  }
  const Eigen::VectorXd joint_mean =
      Consensus::marginal(base, {100, 101}).mean + testing::random_vector(6, random, 0.05);
  const Eigen::MatrixXd joint_covariance = testing::random_spd(6, random, 0.2, 0.6);
  std::map<LandmarkId, ObjectEstimate> theirs;
  for (const auto& [id, own] : base.archived) {
    theirs[id] = {id, own.p_world + testing::random_vector(3, random, 0.05),
                  testing::random_spd(3, random, 0.2, 0.6)};
  }
  const auto marginal_in = [&](const std::vector<LandmarkId>& archived_order) {
    Marginal m{{100, 101}, joint_mean, joint_covariance};
    m.mean.conservativeResize(6 + 3 * static_cast<Eigen::Index>(archived_order.size()));
    for (std::size_t i = 0; i < archived_order.size(); ++i) {
      const ObjectEstimate& estimate = theirs.at(archived_order[i]);
      m.ids.push_back(estimate.id);
      m.mean.segment<3>(6 + 3 * static_cast<Eigen::Index>(i)) = estimate.p_world;
      m.blocks.push_back(estimate.covariance);
    }
    return m;
  };
  State sorted = base, shuffled = base;
  const auto a =
      Consensus::fuse(sorted, {{0.4, marginal_in({40, 41, 42, 43, 44})}}, no_safeguards());
  const auto b =
      Consensus::fuse(shuffled, {{0.4, marginal_in({43, 40, 44, 42, 41})}}, no_safeguards());
  EXPECT_EQ(a.landmarks_fused, 7);
  EXPECT_EQ(b.landmarks_fused, 7);
  EXPECT_TRUE(shuffled.covariance.isApprox(sorted.covariance, 1e-14));
  for (const auto& [id, estimate] : sorted.archived) {
    EXPECT_TRUE(shuffled.archived.at(id).p_world.isApprox(estimate.p_world, 1e-14)) << id;
    EXPECT_TRUE(shuffled.archived.at(id).covariance.isApprox(estimate.covariance, 1e-14)) << id;
  }
  for (std::size_t j = 0; j < sorted.landmarks.size(); ++j) {
    EXPECT_TRUE(shuffled.landmarks[j].p_world.isApprox(sorted.landmarks[j].p_world, 1e-14)) << j;
  }
  // Not a test that cannot fail: the fuse moved the state.
  EXPECT_FALSE(sorted.archived.at(42).p_world.isApprox(base.archived.at(42).p_world, 1e-6));
}

TEST(ConsensusSafeguards, NeighboursBeyondTheChiSquareBoundAreRefusedAndCounted) {
  // Own N(0, I), neighbours N(d, I): the difference has covariance 2 I, so the 99.9 % bound of
  // chi2(3) (16.27) is crossed at |d| = sqrt(2 * 16.27) = 5.70.
  State state = single_landmark_state();
  ConsensusOptions options;
  options.neighbour_chi2_probability = 0.999;
  Marginal near{{5}, Eigen::Vector3d(5.6, 0, 0), Eigen::Matrix3d::Identity()};
  Marginal far{{5}, Eigen::Vector3d(5.8, 0, 0), Eigen::Matrix3d::Identity()};
  Marginal other{{6}, Eigen::Vector3d(100, 0, 0), Eigen::Matrix3d::Identity()};
  const auto report =
      Consensus::fuse(state, {{0.25, far}, {0.25, near}, {0.25, other}}, options);
  EXPECT_EQ(report.landmarks_refused, 1);
  EXPECT_EQ(report.refused_per_neighbour, (std::vector<int>{1, 0, 0}));
  EXPECT_EQ(report.tested_per_neighbour, (std::vector<int>{1, 1, 0}));
  // The near one is averaged with weight 1/4, the robot keeps 3/4 (the refused and the
  // non-holder's weights included): equal covariances, so the mean is 5.6 / 4.
  EXPECT_NEAR(state.landmarks[0].p_world.x(), 1.4, 1e-12);
}

// --- A neighbour's claims against its own earlier ones (ConsensusOptions::claim_history_rounds)
// ---

/// What one round of claims does: the robot (own landmark 5 at the origin, covariance `own`
/// I) fuses one claim N(mean, covariance) of `sender` about landmark 5 through `workspace`.
const ConsensusReport& fuse_claim(ConsensusWorkspace& workspace, const ConsensusOptions& options,
                                  int sender, const Eigen::Vector3d& mean,
                                  const Eigen::Matrix3d& covariance, double own = 1.0) {
  State state = single_landmark_state();
  state.covariance *= own;
  std::vector<WeightedMarginal> claim{{0.25, Marginal{{5}, mean, covariance}, sender}};
  return Consensus::fuse(state, claim, options, workspace);
}

TEST(ConsensusClaims, AClaimThatMovedBeyondTheNeighboursOwnEarlierClaimIsRefused) {
  // The neighbour claims N(0.05 k e_x, 0.01 I) at round k: each claim alone is close to the
  // robot's own N(0, I) (the chi-square test of the two passes up to 4 m), but two consistent
  // estimates of one point differ by at most 2 (0.01 + 0.01) I in covariance, so from the
  // first claim on a move beyond sqrt(0.04 chi2_3(99.9 %)) = 0.81 m is refused.
  ConsensusOptions options;
  const double bound = UpdaterHelper::chi2_quantile(options.neighbour_chi2_probability, 3);
  const Eigen::Matrix3d claimed = 0.01 * Eigen::Matrix3d::Identity();
  int first_beyond = 0;
  while (std::pow(0.05 * first_beyond, 2) / 0.04 <= bound) ++first_beyond;
  ASSERT_EQ(first_beyond, 17);
  ConsensusWorkspace workspace;
  for (int k = 0; k <= first_beyond + 3; ++k) {
    const auto& report =
        fuse_claim(workspace, options, 7, Eigen::Vector3d(0.05 * k, 0, 0), claimed);
    const int refused = k >= first_beyond ? 1 : 0;
    EXPECT_EQ(report.claims_refused, refused) << k;
    EXPECT_EQ(report.landmarks_refused, refused) << k;
    EXPECT_EQ(report.refused_per_neighbour, std::vector<int>{refused}) << k;
    EXPECT_EQ(report.landmarks_fused, 1 - refused) << k;
  }
  // Without the neighbour's id, or with the test off, nothing is refused.
  for (const auto& [sender, rounds] : {std::pair{-1, 200}, std::pair{7, 0}}) {
    ConsensusOptions off = options;
    off.claim_history_rounds = rounds;
    ConsensusWorkspace fresh;
    for (int k = 0; k <= first_beyond + 3; ++k) {
      EXPECT_EQ(fuse_claim(fresh, off, sender, Eigen::Vector3d(0.05 * k, 0, 0), claimed)
                    .landmarks_refused,
                0)
          << k;
    }
  }
  // Claims older than the window are forgotten: with a window of 10 rounds no two claims it
  // compares are more than 0.5 m apart.
  ConsensusOptions window = options;
  window.claim_history_rounds = 10;
  ConsensusWorkspace windowed;
  for (int k = 0; k <= 3 * first_beyond; ++k) {
    EXPECT_EQ(
        fuse_claim(windowed, window, 7, Eigen::Vector3d(0.05 * k, 0, 0), claimed).claims_refused, 0)
        << k;
  }
  // Another neighbour's claims are kept apart: the same claim from robot 8 is its first.
  EXPECT_EQ(fuse_claim(workspace, options, 8, Eigen::Vector3d(2.0, 0, 0), claimed).claims_refused,
            0);
}

TEST(ConsensusClaims, AConsistentFiltersEstimatesPassAndAnOverconfidentOnesAreRefused) {
  // A neighbour estimates a static point with a Kalman filter (prior N(x0, 4 I) with x0 drawn
  // from it, one measurement of covariance 0.25 I a round) and claims its estimate every round.
  // Claimed as they are, its claims agree with its earlier ones (the bound holds for any two
  // consistent estimates); claimed with a hundredth of the covariance, the estimate moves by
  // more than its claims allow.
  std::mt19937 random(2026);
  std::normal_distribution<double> normal;
  const auto draw = [&](double sigma) -> Eigen::Vector3d {
    return Eigen::Vector3d(normal(random), normal(random), normal(random)) * sigma;
  };
  const ConsensusOptions options;
  int tests = 0, refused_honest = 0, refused_overconfident = 0;
  for (int trial = 0; trial < 40; ++trial) {
    const Eigen::Vector3d truth = draw(1.0);
    Eigen::Vector3d mean = truth + draw(2.0);
    Eigen::Matrix3d covariance = 4.0 * Eigen::Matrix3d::Identity();
    ConsensusWorkspace honest, overconfident;
    for (int round = 0; round < 100; ++round) {
      const Eigen::Matrix3d noise = 0.25 * Eigen::Matrix3d::Identity();
      const Eigen::Matrix3d gain = covariance * (covariance + noise).inverse();
      mean += gain * (truth + draw(0.5) - mean);
      covariance = (Eigen::Matrix3d::Identity() - gain) * covariance;
      ++tests;
      // The robot's own covariance is wide: the test against it never refuses here.
      refused_honest += fuse_claim(honest, options, 3, mean, covariance, 1e4).claims_refused;
      refused_overconfident +=
          fuse_claim(overconfident, options, 3, mean, 0.01 * covariance, 1e4).claims_refused;
    }
  }
  EXPECT_LE(refused_honest, tests / 1000);
  EXPECT_GT(refused_overconfident, tests / 10);
}

TEST(ConsensusClaims, EachNeighbourAndLandmarkKeepsItsOwnClaimsAsLandmarksComeAndGo) {
  // 300 archived objects (ids 1000, 1007, ...), the robot's own covariance wide (its own test
  // never refuses), three neighbours (robots 9, 2 and 4, in that inbox order) that start
  // claiming each object at their own rounds (so the history gains entries all over the id
  // range for 20 rounds), each claim N(x_k, 0.01 I). With a window of 25 rounds:
  //  - from round 30 to 69 robot 9 claims every fifth object 1 m away (beyond the 0.81 m its
  //    own claims allow): exactly those claims are refused, robot 9's only, for as long as it
  //    makes them (longer than the window: a claim gives way only to a consistent one);
  //  - from round 70 robot 9 claims as before: nothing refused (the moved claims were not kept);
  //  - robot 2 stops claiming every fourth object after round 20 and claims it 1 m away from
  //    round 47 on: it has not claimed it for longer than the window, so its earlier claims
  //    are forgotten and nothing is refused (round 47 comes before the history's periodic
  //    clean-up drops the entries: the forgetting must not wait for it).
  constexpr int kObjects = 300;
  const std::array<int, 3> senders{9, 2, 4};
  const auto id_of = [](int k) { return LandmarkId{1000 + 7 * k}; };
  const auto x_of = [](int k) { return Eigen::Vector3d(0.1 * k, 0.0, 1.0); };
  const auto first_round = [](int k, int sender) { return (13 * k + 5 * sender) % 20; };
  ConsensusOptions options;
  options.claim_history_rounds = 25;
  const Eigen::Matrix3d claimed = 0.01 * Eigen::Matrix3d::Identity();
  ConsensusWorkspace workspace;
  for (int round = 0; round < 80; ++round) {
    State state;
    state.poses.push_back({0, Eigen::Isometry3d::Identity()});
    state.covariance = Eigen::MatrixXd::Identity(6, 6);
    for (int k = 0; k < kObjects; ++k) {
      state.archived[id_of(k)] = {id_of(k), x_of(k), 1e4 * Eigen::Matrix3d::Identity()};
    }
    std::vector<WeightedMarginal> inbox;
    std::vector<int> expected(senders.size(), 0);
    for (std::size_t j = 0; j < senders.size(); ++j) {
      const int sender = senders[j];
      std::vector<LandmarkId> ids;
      std::vector<Eigen::Vector3d> means;
      for (int k = 0; k < kObjects; ++k) {
        if (round < first_round(k, sender)) continue;
        Eigen::Vector3d mean = x_of(k);
        if (sender == 9 && round >= 30 && round < 70 && k % 5 == 0) {
          mean.x() += 1.0;
          ++expected[j];
        }
        if (sender == 2 && k % 4 == 0) {
          if (round > 20 && round < 47) continue;
          if (round >= 47) mean.x() += 1.0;
        }
        ids.push_back(id_of(k));
        means.push_back(mean);
      }
      Marginal marginal;
      marginal.ids = ids;
      marginal.mean.resize(3 * static_cast<Eigen::Index>(ids.size()));
      for (std::size_t a = 0; a < ids.size(); ++a) {
        marginal.mean.segment<3>(3 * static_cast<Eigen::Index>(a)) = means[a];
        marginal.blocks.push_back(claimed);
      }
      inbox.push_back({0.25, marginal, sender});
    }
    const ConsensusReport& report = Consensus::fuse(state, inbox, options, workspace);
    EXPECT_EQ(report.refused_per_neighbour, expected) << round;
    EXPECT_EQ(report.claims_refused, expected[0]) << round;
  }
}

TEST(ConsensusClaims, AWitnessedNeighbourKeepsItsHistoryWhileItIsNotFused) {
  // Robot 7 claims landmark 5 at the origin, then 1 m away (beyond the 0.81 m its own claims
  // allow; within the robot's own unit covariance), and is then left out of the fuse for 250
  // rounds (longer than the 200-round window; robot 8 keeps the rounds going). Witnessed
  // meanwhile, its lie is still refused when it is fused again; not witnessed, its history is
  // forgotten and the lie comes back as a first claim.
  const ConsensusOptions options;
  ASSERT_GT(250, options.claim_history_rounds);
  const Eigen::Matrix3d claimed = 0.01 * Eigen::Matrix3d::Identity();
  const auto claim = [&](int sender, double x) {
    return WeightedMarginal{0.25, Marginal{{5}, Eigen::Vector3d(x, 0, 0), claimed}, sender};
  };
  for (const bool witnessed : {true, false}) {
    ConsensusWorkspace workspace;
    const auto round = [&](std::vector<WeightedMarginal> inbox) {
      State state = single_landmark_state();
      return Consensus::fuse(state, inbox, options, workspace).claims_refused;
    };
    for (int k = 0; k < 10; ++k) EXPECT_EQ(round({claim(7, 0.0), claim(8, 0.0)}), 0);
    EXPECT_EQ(round({claim(7, 1.0), claim(8, 0.0)}), 1);
    int refused_while_out = 0;
    for (int k = 0; k < 250; ++k) {
      EXPECT_EQ(round({claim(8, 0.0)}), 0);
      if (witnessed) {
        refused_while_out +=
            Consensus::witness(single_landmark_state(), {claim(7, 1.0)}, options, workspace);
      }
    }
    EXPECT_EQ(refused_while_out, witnessed ? 250 : 0);
    EXPECT_EQ(round({claim(7, 1.0), claim(8, 0.0)}), witnessed ? 1 : 0) << witnessed;
  }
}

TEST(ConsensusClaims, TheRobotsMoveForgetsTheClaims) {
  // After Estimator::reanchor the neighbours' claims are in another frame: a claim 1 m from
  // the one before, refused before the move, is taken after it.
  EstimatorOptions options;
  const Eigen::Matrix3d claimed = 0.01 * Eigen::Matrix3d::Identity();
  const auto claim = [&](double x) {
    return std::vector<WeightedMarginal>{
        {0.25, Marginal{{5}, Eigen::Vector3d(x, 0, 0), claimed}, 4}};
  };
  for (const bool move : {false, true}) {
    Estimator estimator(options, StereoCamera{}, single_landmark_state());
    EXPECT_EQ(estimator.fuse(claim(0.0)).claims_refused, 0);
    EXPECT_EQ(estimator.fuse(claim(1.0)).claims_refused, 1);
    if (move)
      estimator.reanchor(Eigen::Isometry3d::Identity(), Eigen::Matrix<double, 6, 6>::Zero());
    EXPECT_EQ(estimator.fuse(claim(1.0)).claims_refused, move ? 0 : 1) << move;
  }
}

TEST(ConsensusAverage, CorrelatedAxesGiveTheInformationAverageInAndOutOfTheState) {
  // Eq. (19) for one in-state landmark and one archived object whose covariances (the robot's
  // and two neighbours') have correlated axes, against the average computed with general
  // inverses: sum_j w_j P_j^-1, its inverse, and the weighted information vector.
  std::mt19937 random(71);
  State state;
  state.poses.push_back({0, Eigen::Isometry3d::Identity()});
  state.landmarks.push_back({5, testing::random_vector(3, random), 0});
  state.rebuild_landmark_index();
  state.covariance = Eigen::MatrixXd::Identity(9, 9);
  state.covariance.block<3, 3>(6, 6) = testing::random_spd(3, random, 0.1, 2.0);
  state.archived[9] = {9, testing::random_vector(3, random),
                       testing::random_spd(3, random, 0.1, 2.0)};
  const State before = state;
  const double weights[] = {0.3, 0.25};
  std::vector<WeightedMarginal> neighbours;
  for (const double weight : weights) {
    Marginal m;
    m.ids = {5, 9};
    m.mean = before.landmarks[0].p_world.replicate(2, 1) + testing::random_vector(6, random, 0.3);
    m.mean.tail<3>() += before.archived.at(9).p_world - before.landmarks[0].p_world;
    m.blocks = {testing::random_spd(3, random, 0.1, 2.0), testing::random_spd(3, random, 0.1, 2.0)};
    neighbours.push_back({weight, m});
  }
  const auto report = Consensus::fuse(state, neighbours, no_safeguards());
  ASSERT_EQ(report.landmarks_fused, 2);
  for (int which = 0; which < 2; ++which) {
    const Eigen::Matrix3d own_covariance =
        which == 0 ? Eigen::Matrix3d(before.covariance.block<3, 3>(6, 6))
                   : before.archived.at(9).covariance;
    const Eigen::Vector3d own_mean =
        which == 0 ? before.landmarks[0].p_world : before.archived.at(9).p_world;
    Eigen::Matrix3d information = (1.0 - weights[0] - weights[1]) * own_covariance.inverse();
    Eigen::Vector3d vector = information * own_mean;
    for (std::size_t j = 0; j < neighbours.size(); ++j) {
      const Marginal& m = neighbours[j].marginal;
      const Eigen::Matrix3d their_information = m.blocks[static_cast<std::size_t>(which)].inverse();
      information += weights[j] * their_information;
      vector += weights[j] * their_information * m.mean.segment<3>(3 * which);
    }
    const Eigen::Matrix3d covariance = information.inverse();
    const Eigen::Vector3d mean = covariance * vector;
    const Eigen::Vector3d fused_mean =
        which == 0 ? state.landmarks[0].p_world : state.archived.at(9).p_world;
    const Eigen::Matrix3d fused_covariance =
        which == 0 ? Eigen::Matrix3d(state.covariance.block<3, 3>(6, 6))
                   : state.archived.at(9).covariance;
    EXPECT_TRUE(fused_mean.isApprox(mean, 1e-12)) << which;
    EXPECT_TRUE(fused_covariance.isApprox(covariance, 1e-12)) << which;
    EXPECT_FALSE(fused_mean.isApprox(own_mean, 1e-3)) << which;  // it moved
  }
}

TEST(ConsensusSafeguards, TheChiSquareTestWeighsTheDifferenceByTheFullSumOfCovariances) {
  // Own and neighbour covariances with correlated axes: a neighbour's mean is refused just
  // beyond the 99.9 % bound of d^T (P_own + P_theirs)^-1 d and accepted just inside it, in
  // directions that the sum's diagonal alone would misjudge.
  std::mt19937 random(29);
  ConsensusOptions options;
  options.neighbour_chi2_probability = 0.999;
  const double bound = UpdaterHelper::chi2_quantile(0.999, 3);
  for (int trial = 0; trial < 20; ++trial) {
    State state = single_landmark_state();
    state.covariance.block<3, 3>(6, 6) = testing::random_spd(3, random, 0.05, 3.0);
    const Eigen::Matrix3d theirs = testing::random_spd(3, random, 0.05, 3.0);
    const Eigen::Matrix3d sum = state.covariance.block<3, 3>(6, 6) + theirs;
    const Eigen::Vector3d direction = testing::random_vector(3, random).normalized();
    const double distance = direction.dot(sum.inverse() * direction);  // of a unit step
    for (const double scale : {0.999, 1.001}) {
      State trial_state = state;
      const Eigen::Vector3d mean = direction * std::sqrt(scale * bound / distance);
      const auto report =
          Consensus::fuse(trial_state, {{0.5, Marginal{{5}, mean, theirs}}}, options);
      EXPECT_EQ(report.landmarks_refused, scale > 1.0 ? 1 : 0) << trial << " " << scale;
      EXPECT_EQ(report.landmarks_fused, scale > 1.0 ? 0 : 1) << trial << " " << scale;
    }
  }
}

TEST(ConsensusAverage, LandmarksInDifferentBlocksOfANeighbourAreAveragedSeparately) {
  // The robot holds landmarks 5 and 6 strongly correlated (a common offset); the neighbour
  // sends them as two independent blocks. Averaging them jointly would take the neighbour's
  // block-diagonal claim at face value and shrink the variance of their common offset below what
  // either member knows; averaged separately, the common direction keeps at least the robot's
  // own information scaled by the weights.
  State state;
  state.poses.push_back({0, Eigen::Isometry3d::Identity()});
  state.landmarks.push_back({5, Eigen::Vector3d::Zero(), 0});
  state.landmarks.push_back({6, Eigen::Vector3d(1, 0, 0), 0});
  state.rebuild_landmark_index();
  state.covariance = Eigen::MatrixXd::Identity(12, 12);
  for (int k = 0; k < 3; ++k) {
    state.covariance(6 + k, 9 + k) = state.covariance(9 + k, 6 + k) = 0.9;
  }
  Marginal neighbour;
  neighbour.ids = {5, 6};
  neighbour.mean = Eigen::VectorXd::Zero(6);
  neighbour.mean(3) = 1.0;
  neighbour.blocks = {Eigen::Matrix3d::Identity(), Eigen::Matrix3d::Identity()};
  Consensus::fuse(state, {{0.5, neighbour}}, no_safeguards());
  // Variance of the common offset (x5 + x6) / 2: the robot claims (1 + 0.9) / 2 = 0.95, the
  // neighbour's independent blocks claim 0.5. A joint average would give
  // 1 / (0.5 / 0.95 + 0.5 / 0.5) = 0.655; separate averages must not go below that of a single
  // one-landmark average of the robot's prior with the neighbour's (0.5 / 0.95 ... ): check it
  // stays above the joint-average value.
  Eigen::Vector2d half(0.5, 0.5);
  Eigen::Matrix2d x_block;
  x_block << state.covariance(6, 6), state.covariance(6, 9), state.covariance(9, 6),
      state.covariance(9, 9);
  EXPECT_GT(half.dot(x_block * half), 0.7);
}

TEST(ConsensusEventTriggered, SettledLandmarksAreLeftOutAndTheRestFusedAsAlone) {
  // The neighbour agrees exactly with the robot on two of its three landmarks and disagrees on
  // one: with consensus.fuse_kl_threshold, the two are left out (their average is the robot's
  // own: KL 0) and the third is fused exactly as if the neighbour had sent it alone.
  std::mt19937 random(23);
  const State start = testing::random_state(2, 3, random);
  Marginal neighbour = Consensus::marginal(start, start.object_ids());
  const LandmarkId moved = neighbour.ids[1];
  neighbour.mean.segment<3>(3) += Eigen::Vector3d(0.3, -0.2, 0.1);
  Marginal alone;
  alone.ids = {moved};
  alone.mean = neighbour.mean.segment<3>(3);
  alone.blocks = {neighbour.blocks.front().block<3, 3>(3, 3)};

  ConsensusOptions options = no_safeguards();
  options.fuse_kl_threshold = 1e-3;
  State triggered = start;
  const auto report = Consensus::fuse(triggered, {{0.5, neighbour}}, options);
  EXPECT_EQ(report.landmarks_settled, 2);
  EXPECT_EQ(report.landmarks_fused, 1);
  State reference = start;
  const auto reference_report = Consensus::fuse(reference, {{0.5, alone}}, no_safeguards());
  EXPECT_EQ(reference_report.landmarks_fused, 1);
  EXPECT_TRUE(triggered.covariance.isApprox(reference.covariance, 1e-12));
  for (int i = 0; i < 3; ++i) {
    EXPECT_TRUE(triggered.landmarks[i].p_world.isApprox(reference.landmarks[i].p_world, 1e-12));
  }
  // Fused alone, the moved landmark drags its correlated neighbours along (Proposition 2);
  // without the threshold the whole joint block is averaged and they are held where both robots
  // agree they are: a different step.
  State every = start;
  const auto every_report = Consensus::fuse(every, {{0.5, neighbour}}, no_safeguards());
  EXPECT_EQ(every_report.landmarks_settled, 0);
  EXPECT_EQ(every_report.landmarks_fused, 3);
  EXPECT_TRUE(every.landmarks[0].p_world.isApprox(start.landmarks[0].p_world, 1e-12));
  EXPECT_GT((reference.landmarks[0].p_world - start.landmarks[0].p_world).norm(), 1e-4);

  // A threshold above the moved landmark's step leaves the state exactly as it was.
  options.fuse_kl_threshold = 1e6;
  State untouched = start;
  const auto none = Consensus::fuse(untouched, {{0.5, neighbour}}, options);
  EXPECT_EQ(none.landmarks_settled, 3);
  EXPECT_EQ(none.landmarks_fused, 0);
  EXPECT_TRUE(untouched.covariance.isApprox(start.covariance, 0.0));
  EXPECT_TRUE(untouched.landmarks[1].p_world.isApprox(start.landmarks[1].p_world, 0.0));
}

TEST(CovarianceIntersection, MinimizesTheDeterminantAndKeepsTheMeanBetween) {
  ObjectEstimate a{1, Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(1.0, 4.0, 1.0).asDiagonal()};
  ObjectEstimate b{1, Eigen::Vector3d(1, 1, 1), Eigen::Vector3d(4.0, 1.0, 1.0).asDiagonal()};
  const auto fused = Consensus::covariance_intersection(a, b);
  ASSERT_TRUE(fused);
  // Brute force over the weight.
  double best = std::numeric_limits<double>::infinity();
  for (int k = 0; k <= 1000; ++k) {
    const double w = k / 1000.0;
    const Eigen::Matrix3d information =
        w * a.covariance.inverse() + (1.0 - w) * b.covariance.inverse();
    best = std::min(best, information.inverse().determinant());
  }
  EXPECT_NEAR(fused->covariance.determinant(), best, 1e-6 * best);
  // Symmetric inputs: w = 1/2; the mean lies between the two.
  EXPECT_NEAR(fused->p_world.z(), 0.5, 1e-6);
  EXPECT_GT(fused->p_world.x(), 0.0);
  EXPECT_LT(fused->p_world.x(), 1.0);
  // Not positive definite: refused.
  ObjectEstimate bad = b;
  bad.covariance = -bad.covariance;
  EXPECT_FALSE(Consensus::covariance_intersection(a, bad));
}

TEST(MetropolisWeights, AreDoublyStochasticAndOneOverNOnCompleteGraphs) {
  EXPECT_DOUBLE_EQ(Consensus::metropolis_weight(2, 2), 1.0 / 3);
  for (auto kind :
       {replay::GraphKind::kComplete, replay::GraphKind::kRing, replay::GraphKind::kRandom}) {
    const int n = 7;
    const auto graph = replay::make_graph(kind, n, 5);
    Eigen::MatrixXd A = Eigen::MatrixXd::Zero(n, n);
    for (int i = 0; i < n; ++i) {
      for (int j : graph[i]) {
        A(i, j) = Consensus::metropolis_weight(graph[i].size(), graph[j].size());
      }
      A(i, i) = 1.0 - A.row(i).sum();
    }
    EXPECT_TRUE(A.isApprox(A.transpose()));
    EXPECT_TRUE(A.rowwise().sum().isApprox(Eigen::VectorXd::Ones(n)));
    EXPECT_GE(A.minCoeff(), 0.0);
    if (kind == replay::GraphKind::kComplete) {
      EXPECT_TRUE(A.isApprox(Eigen::MatrixXd::Constant(n, n, 1.0 / n)));
    }
  }
}

}  // namespace
}  // namespace concord

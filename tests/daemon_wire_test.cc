// Wire conversions of the daemon: exact round trips, and malformed messages rejected with a
// reason instead of crashing or producing garbage estimates.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "allocation_counter.h"
#include "checkpoint.h"
#include "concord/daemon/wire.h"
#include "concord/estimator/consensus.h"
#include "concord/frontend/detections.h"
#include "concord/v1/concord.pb.h"
#include "test_support.h"

namespace concord::daemon {
namespace {

Marginal block_marginal(std::mt19937& random) {
  Marginal m;
  m.ids = {3, 7, 11, 12};
  m.mean = Eigen::VectorXd::Random(12);
  m.blocks = {testing::random_spd(6, random), testing::random_spd(3, random),
              testing::random_spd(3, random)};
  return m;
}

TEST(DaemonWire, MarginalRoundTripIsExact) {
  std::mt19937 random(3);
  const Marginal original = block_marginal(random);
  v1::Marginal message;
  to_wire(original, message);
  // Through bytes, as on the network.
  v1::Marginal parsed;
  ASSERT_TRUE(parsed.ParseFromString(message.SerializeAsString()));
  std::string error;
  const auto back = from_wire(parsed, error);
  ASSERT_TRUE(back) << error;
  EXPECT_EQ(back->ids, original.ids);
  EXPECT_EQ(back->mean, original.mean);
  ASSERT_EQ(back->blocks.size(), 3u);
  // Upper triangles travel; the blocks were symmetric, so they come back bit for bit.
  for (std::size_t b = 0; b < 3; ++b) {
    const Eigen::MatrixXd symmetric =
        original.blocks[b].triangularView<Eigen::Upper>().toDenseMatrix() +
        original.blocks[b].triangularView<Eigen::StrictlyUpper>().toDenseMatrix().transpose();
    EXPECT_EQ(back->blocks[b], symmetric);
  }
  // The double form's blocks travel in the flat fields: no message a block.
  EXPECT_EQ(parsed.blocks_size(), 0);
  EXPECT_EQ(std::vector<std::uint32_t>(parsed.block_landmarks().begin(), parsed.block_landmarks().end()),
            (std::vector<std::uint32_t>{2, 1, 1}));
  EXPECT_EQ(parsed.packed_upper_size(), 21 + 6 + 6);
}

TEST(DaemonWire, ACutEncodedWithoutTheCopyIsTheCutsEncoding) {
  // A daemon encodes each neighbour's cut of the marginal it built once straight from that
  // marginal. The bytes must be those of the cut made first (sub_marginal): every subset of a
  // marginal with a joint block of 4 landmarks and 3 archived ones, into one reused message.
  std::mt19937 random(5);
  Marginal full;
  full.ids = {20, 21, 22, 23, 4, 9, 15};
  full.mean = Eigen::VectorXd::Random(21);
  full.blocks = {testing::random_spd(12, random), testing::random_spd(3, random),
                 testing::random_spd(3, random), testing::random_spd(3, random)};
  v1::Marginal direct;  // reused: nothing of an earlier cut may stay in it
  for (unsigned mask = 0; mask < (1U << full.ids.size()); ++mask) {
    std::vector<bool> keep(full.ids.size());
    for (std::size_t k = 0; k < keep.size(); ++k) keep[k] = ((mask >> k) & 1U) != 0;
    v1::Marginal expected;
    to_wire(sub_marginal(full, keep), expected);
    to_wire(full, keep, direct);
    ASSERT_EQ(direct.SerializeAsString(), expected.SerializeAsString()) << "mask " << mask;
  }
  // The keep flags of a list of ids, as select() finds them.
  std::vector<bool> keep;
  Consensus::kept_by(full, {4, 15, 21, 23, 99}, keep);
  EXPECT_EQ(keep, (std::vector<bool>{false, true, false, true, true, false, true}));
}

TEST(DaemonWire, AMarginalReadIntoOneOfTheSameShapeReusesItsStorage) {
  std::mt19937 random(5);
  const Marginal first = block_marginal(random);
  Marginal second = block_marginal(random);
  second.mean *= 2.0;
  v1::Marginal first_message, second_message;
  to_wire(first, first_message);
  to_wire(second, second_message);
  std::string error;
  Marginal reused;
  ASSERT_TRUE(from_wire(first_message, error, reused)) << error;
  const std::size_t before = testing::allocations();
  ASSERT_TRUE(from_wire(second_message, error, reused)) << error;
  if (testing::counting_allocations()) {
    EXPECT_EQ(testing::allocations(), before);
  }
  // The same marginal as read into a fresh one, to the bit.
  const auto fresh = from_wire(second_message, error);
  ASSERT_TRUE(fresh) << error;
  EXPECT_EQ(reused.ids, fresh->ids);
  EXPECT_EQ(reused.mean, fresh->mean);
  EXPECT_TRUE(testing::same_blocks(reused.blocks, fresh->blocks));
  // A smaller marginal into the same storage: its own blocks only, nothing left over.
  Marginal small;
  small.ids = {4};
  small.mean = Eigen::Vector3d(1, 2, 3);
  small.blocks = {testing::random_spd(3, random)};
  v1::Marginal small_message;
  to_wire(small, small_message);
  ASSERT_TRUE(from_wire(small_message, error, reused)) << error;
  EXPECT_EQ(reused.ids, small.ids);
  EXPECT_EQ(reused.mean, small.mean);
  ASSERT_EQ(reused.blocks.size(), 1u);
  EXPECT_EQ(reused.blocks[0], from_wire(small_message, error)->blocks[0]);
}

TEST(DaemonWire, MarginalBlocksAsMessagesAreStillRead) {
  // The same marginal with a CovarianceBlock message a block (the float32 form's layout, and
  // what a sender may use for doubles too) reads back to the same numbers.
  std::mt19937 random(3);
  const Marginal original = block_marginal(random);
  v1::Marginal flat;
  to_wire(original, flat);
  v1::Marginal messages;
  messages.mutable_landmark_ids()->CopyFrom(flat.landmark_ids());
  messages.mutable_mean()->CopyFrom(flat.mean());
  int offset = 0;
  for (const std::uint32_t landmarks : flat.block_landmarks()) {
    v1::CovarianceBlock* block = messages.add_blocks();
    block->set_landmarks(landmarks);
    const int values = static_cast<int>(3 * landmarks * (3 * landmarks + 1) / 2);
    for (int i = 0; i < values; ++i) block->add_packed_upper(flat.packed_upper(offset + i));
    offset += values;
  }
  std::string error;
  const auto from_flat = from_wire(flat, error);
  const auto from_messages = from_wire(messages, error);
  ASSERT_TRUE(from_flat && from_messages) << error;
  ASSERT_EQ(from_messages->blocks.size(), from_flat->blocks.size());
  for (std::size_t b = 0; b < from_flat->blocks.size(); ++b) {
    EXPECT_EQ(from_messages->blocks[b], from_flat->blocks[b]);
  }
  // Both forms at once are refused.
  v1::Marginal both = messages;
  both.mutable_block_landmarks()->CopyFrom(flat.block_landmarks());
  both.mutable_packed_upper()->CopyFrom(flat.packed_upper());
  EXPECT_FALSE(from_wire(both, error));
  EXPECT_NE(error.find("both"), std::string::npos);
}

TEST(DaemonWire, MalformedMarginalsAreRejectedWithAReason) {
  std::mt19937 random(4);
  v1::Marginal good;
  to_wire(block_marginal(random), good);
  std::string error;

  v1::Marginal short_mean = good;
  short_mean.mutable_mean()->RemoveLast();
  EXPECT_FALSE(from_wire(short_mean, error));
  EXPECT_NE(error.find("mean"), std::string::npos);

  v1::Marginal short_block = good;
  short_block.mutable_packed_upper()->RemoveLast();
  EXPECT_FALSE(from_wire(short_block, error));
  EXPECT_NE(error.find("packed"), std::string::npos);

  v1::Marginal extra_values = good;
  extra_values.add_packed_upper(1.0);
  EXPECT_FALSE(from_wire(extra_values, error));
  EXPECT_NE(error.find("beyond"), std::string::npos);

  v1::Marginal missing_block = good;  // the last block and its values gone
  missing_block.mutable_block_landmarks()->RemoveLast();
  for (int i = 0; i < 6; ++i) missing_block.mutable_packed_upper()->RemoveLast();
  EXPECT_FALSE(from_wire(missing_block, error));
  EXPECT_NE(error.find("cover"), std::string::npos);

  v1::Marginal too_many = good;
  too_many.set_block_landmarks(0, 40);
  EXPECT_FALSE(from_wire(too_many, error));

  v1::Marginal empty_block = good;
  empty_block.set_block_landmarks(1, 0);
  EXPECT_FALSE(from_wire(empty_block, error));

  v1::Marginal values_only = good;  // values and no block sizes
  values_only.clear_block_landmarks();
  EXPECT_FALSE(from_wire(values_only, error));

  v1::Marginal not_finite = good;
  not_finite.set_mean(2, std::numeric_limits<double>::quiet_NaN());
  EXPECT_FALSE(from_wire(not_finite, error));

  v1::Marginal empty;
  const auto nothing = from_wire(empty, error);
  ASSERT_TRUE(nothing);
  EXPECT_TRUE(nothing->ids.empty());
}

TEST(DaemonWire, Float32MarginalsArriveAsTheReceiverModelsThemAndBadOnesAreRejected) {
  std::mt19937 random(5);
  const Marginal original = block_marginal(random);
  const CompactMarginal compact_form = compact(original);
  v1::Marginal message;
  to_wire(compact_form, message);
  v1::Marginal parsed;
  ASSERT_TRUE(parsed.ParseFromString(message.SerializeAsString()));
  EXPECT_EQ(parsed.mean_size(), 0);
  EXPECT_EQ(parsed.mean_offsets_size(), 12);
  EXPECT_EQ(parsed.blocks(0).cholesky_lower_size(), 21);
  std::string error;
  const auto back = from_wire(parsed, error);
  ASSERT_TRUE(back) << error;
  // Exactly what concord replay fuses for the same marginal (expand(compact(...))).
  const Marginal modelled = quantized(original);
  EXPECT_EQ(back->ids, modelled.ids);
  EXPECT_EQ(back->mean, modelled.mean);
  ASSERT_EQ(back->blocks.size(), modelled.blocks.size());
  for (std::size_t b = 0; b < modelled.blocks.size(); ++b) EXPECT_EQ(back->blocks[b], modelled.blocks[b]);
  // Fewer bytes than the double form (measured 232 against 387 for these four landmarks; the
  // origin's 3 doubles weigh on so small a marginal).
  v1::Marginal doubles;
  to_wire(original, doubles);
  EXPECT_LT(parsed.ByteSizeLong(), doubles.ByteSizeLong() * 65 / 100);

  v1::Marginal short_origin = parsed;
  short_origin.mutable_origin()->RemoveLast();
  EXPECT_FALSE(from_wire(short_origin, error));
  EXPECT_NE(error.find("origin"), std::string::npos);
  v1::Marginal short_offsets = parsed;
  short_offsets.mutable_mean_offsets()->RemoveLast();
  EXPECT_FALSE(from_wire(short_offsets, error));
  v1::Marginal both = parsed;
  both.mutable_blocks(1)->add_packed_upper(1.0);
  EXPECT_FALSE(from_wire(both, error));
  v1::Marginal short_factor = parsed;
  short_factor.mutable_blocks(2)->mutable_cholesky_lower()->RemoveLast();
  EXPECT_FALSE(from_wire(short_factor, error));
  v1::Marginal not_finite = parsed;
  not_finite.mutable_blocks(0)->set_cholesky_lower(4, std::numeric_limits<float>::infinity());
  EXPECT_FALSE(from_wire(not_finite, error));
  v1::Marginal mixed = parsed;
  mixed.add_mean(1.0);  // a double mean next to the float form
  EXPECT_FALSE(from_wire(mixed, error));
}

TEST(DaemonWire, SensorFrameRoundTrip) {
  FrameInput frame;
  frame.frame = 12;
  Eigen::Isometry3d motion = Eigen::Isometry3d::Identity();
  motion.linear() = Eigen::AngleAxisd(0.1, Eigen::Vector3d(0, 0, 1)).toRotationMatrix();
  motion.translation() = Eigen::Vector3d(1.0, 0.2, -0.1);
  frame.T_previous_current = motion;
  std::mt19937 random(3);
  frame.odometry_covariance = concord::testing::random_spd(6, random, 1e-4, 1e-2);
  frame.objects.push_back({5, Eigen::Vector4d(100, 50, 90, 50)});
  frame.features.push_back({77, Eigen::Vector4d(0.1, 0.2, 0.05, 0.2)});
  frame.features.push_back({78, Eigen::Vector4d(0.3, 0.2, 0.25, 0.2), Eigen::Vector2d(0.4, 0.6)});
  v1::SensorFrame message;
  to_wire(frame, 1.5, message);
  std::string error;
  const auto back = from_wire(message, error);
  ASSERT_TRUE(back) << error;
  EXPECT_EQ(back->frame, 12);
  ASSERT_TRUE(back->T_previous_current);
  EXPECT_TRUE(back->T_previous_current->isApprox(motion, 1e-12));
  ASSERT_TRUE(back->odometry_covariance);
  EXPECT_TRUE(back->odometry_covariance->isApprox(*frame.odometry_covariance, 1e-15));
  ASSERT_EQ(back->objects.size(), 1u);
  EXPECT_EQ(back->objects[0].id, 5);
  EXPECT_EQ(back->objects[0].uv, frame.objects[0].uv);
  ASSERT_EQ(back->features.size(), 2u);
  EXPECT_EQ(back->features[0].id, 77);
  EXPECT_EQ(back->features[0].sigma, Eigen::Vector2d::Zero());    // the configured noise
  EXPECT_EQ(back->features[1].sigma, Eigen::Vector2d(0.4, 0.6));  // its own
}

TEST(DaemonWire, ASensorFrameCarriesOneClassPerObjectOrNone) {
  FrameInput frame;
  frame.frame = 4;
  frame.objects.push_back({5, Eigen::Vector4d(100, 50, 90, 50)});
  frame.objects.push_back({9, Eigen::Vector4d(200, 60, 180, 60)});
  const std::vector<int> classes{3, frontend::kMaxClassNumber};
  v1::SensorFrame message;
  to_wire(frame, 0.4, message, &classes);
  std::string error;
  std::vector<int> back_classes{7};
  ASSERT_TRUE(from_wire(message, error, &back_classes)) << error;
  EXPECT_EQ(back_classes, classes);

  // None is fine (the classes are then unknown); anything else must be one per object.
  message.clear_object_classes();
  ASSERT_TRUE(from_wire(message, error, &back_classes)) << error;
  EXPECT_TRUE(back_classes.empty());
  message.add_object_classes(1);
  EXPECT_FALSE(from_wire(message, error, &back_classes));
  EXPECT_NE(error.find("1 object classes for 2 objects"), std::string::npos) << error;
  message.add_object_classes(2);
  message.add_object_classes(3);
  EXPECT_FALSE(from_wire(message, error));
  message.clear_object_classes();
  message.add_object_classes(1);
  message.add_object_classes(static_cast<std::uint32_t>(frontend::kMaxClassNumber) + 1);
  EXPECT_FALSE(from_wire(message, error));
  EXPECT_NE(error.find("object class 1000001 above"), std::string::npos) << error;
}

TEST(DaemonWire, MalformedSensorFramesAreRejected) {
  std::string error;
  v1::SensorFrame negative;
  negative.set_frame(-1);
  EXPECT_FALSE(from_wire(negative, error));

  v1::SensorFrame bad_quaternion;
  bad_quaternion.set_frame(1);
  bad_quaternion.mutable_odometry()->set_qw(2.0);
  EXPECT_FALSE(from_wire(bad_quaternion, error));
  EXPECT_NE(error.find("quaternion"), std::string::npos);

  v1::SensorFrame not_finite;
  not_finite.set_frame(1);
  auto* observation = not_finite.add_objects();
  observation->set_u_left(std::numeric_limits<double>::infinity());
  EXPECT_FALSE(from_wire(not_finite, error));

  // A feature's own noise: both sigmas > 0, or both 0.
  for (const auto& [left, right] :
       {std::pair{0.5, 0.0}, std::pair{-0.5, 0.5}, std::pair{std::nan(""), 0.5},
        std::pair{1e-300, 0.5}, std::pair{0.5, 1e300}}) {
    v1::SensorFrame noisy;
    noisy.set_frame(1);
    auto* feature = noisy.add_features();
    feature->set_sigma_left(left);
    feature->set_sigma_right(right);
    EXPECT_FALSE(from_wire(noisy, error));
    EXPECT_NE(error.find("sigma_left and sigma_right must both be > 0 or both 0"),
              std::string::npos)
        << error;
  }

  // odometry_covariance: none, or 21 values of a positive definite 6x6 matrix.
  v1::SensorFrame covariance;
  covariance.set_frame(1);
  for (int row = 0; row < 6; ++row)
    for (int column = row; column < 6; ++column)
      covariance.add_odometry_covariance(row == column ? 0.01 : 0.0);
  EXPECT_TRUE(from_wire(covariance, error)) << error;
  covariance.set_odometry_covariance(0, -1.0);
  EXPECT_FALSE(from_wire(covariance, error));
  EXPECT_NE(error.find("positive definite"), std::string::npos) << error;
  covariance.set_odometry_covariance(0, std::nan(""));
  EXPECT_FALSE(from_wire(covariance, error));
  covariance.add_odometry_covariance(1.0);
  EXPECT_FALSE(from_wire(covariance, error));
  EXPECT_NE(error.find("expected 21"), std::string::npos) << error;
}

}  // namespace
}  // namespace concord::daemon

namespace concord::daemon {
namespace {

TEST(DaemonCheckpoint, KeepsADetectionOffsetApartFromItsObject) {
  std::mt19937 random(9);
  Checkpoint checkpoint;
  checkpoint.robot_id = 1;
  checkpoint.state = concord::testing::random_state(2, 2, random);
  checkpoint.state.landmarks[1].id = checkpoint.state.landmarks[0].id;  // object 100's offset
  checkpoint.state.landmarks[1].detection_offset = true;
  checkpoint.state.rebuild_landmark_index();
  {
    // A displacement in space keeps its kind.
    Checkpoint displaced = checkpoint;
    displaced.state.landmarks[1].displacement = true;
    std::string error;
    const auto back = parse_checkpoint(serialize_checkpoint(displaced), error);
    ASSERT_TRUE(back) << error;
    EXPECT_TRUE(back->state.landmarks[1].detection_offset);
    EXPECT_TRUE(back->state.landmarks[1].displacement);
    EXPECT_FALSE(back->state.landmarks[0].displacement);
  }
  std::string error;
  const auto back = parse_checkpoint(serialize_checkpoint(checkpoint), error);
  ASSERT_TRUE(back) << error;
  ASSERT_EQ(back->state.landmarks.size(), 2u);
  EXPECT_FALSE(back->state.landmarks[0].detection_offset);
  EXPECT_TRUE(back->state.landmarks[1].detection_offset);
  EXPECT_FALSE(back->state.landmarks[1].displacement);
  EXPECT_FALSE(back->state.landmarks[1].archived);
  EXPECT_EQ(back->state.landmark_slot(100), 0);
  EXPECT_EQ(back->state.offset_slot(100), 1);
  EXPECT_EQ(back->state.object_ids(), std::vector<LandmarkId>{100});
}

TEST(DaemonCheckpoint, RoundTripsTheFilterStateAndPendingObjectsAndRefusesDamage) {
  std::mt19937 random(8);
  Checkpoint checkpoint;
  checkpoint.robot_id = 2;
  checkpoint.round = 41;
  checkpoint.frames = {40, 41};
  checkpoint.timestamps = {4.0, 4.1};
  checkpoint.poses = {Eigen::Isometry3d::Identity(), Eigen::Isometry3d::Identity()};
  checkpoint.state = concord::testing::random_state(3, 2, random);
  checkpoint.state.landmarks[0].archived = true;  // a consider state (object_archive_mode)
  // Both calibration entries: a disparity offset and a tilted world up axis (the level prior).
  checkpoint.state.has_disparity_offset = true;
  checkpoint.state.disparity_offset = -0.2;
  checkpoint.state.has_world_up = true;
  checkpoint.state.world_up = WorldUp::around(Eigen::Vector3d(0.02, -0.01, 1.0));
  checkpoint.state.world_up.tilt = Eigen::Vector2d(0.01, 0.03);
  checkpoint.state.covariance =
      concord::testing::random_spd(checkpoint.state.dimension(), random, 0.05, 1.0);
  checkpoint.pending[9] = {{40, Eigen::Vector4d(0.1, 0.2, 0.05, 0.2)},
                           {41, Eigen::Vector4d(0.11, 0.2, 0.06, 0.2)}};
  checkpoint.state.landmarks[1].used_observations = {{39, Eigen::Vector4d(0.3, -0.1, 0.25, -0.1)},
                                                     {41, Eigen::Vector4d(0.31, -0.1, 0.26, -0.1)}};
  // Two archived objects (object_archive_mode marginal), one with what the robot knew of it
  // relative to itself when it archived it, one without.
  checkpoint.state.archived[700] = {700, Eigen::Vector3d(4, -2, 1),
                                    concord::testing::random_spd(3, random, 0.5, 2)};
  checkpoint.state.archived_last_observed[700] = 30;
  const Eigen::Matrix3d local = concord::testing::random_spd(3, random, 0.01, 0.1);
  checkpoint.state.archived_local_covariance[700] = 0.5 * (local + local.transpose());
  checkpoint.state.archived[701] = {701, Eigen::Vector3d(1, 5, 0),
                                    concord::testing::random_spd(3, random, 0.5, 2)};
  const std::string bytes = serialize_checkpoint(checkpoint);
  std::string error;
  const auto back = parse_checkpoint(bytes, error);
  ASSERT_TRUE(back) << error;
  EXPECT_EQ(back->round, 41u);
  EXPECT_TRUE(back->state.covariance.isApprox(checkpoint.state.covariance, 0.0));
  ASSERT_EQ(back->state.landmarks.size(), 2u);
  EXPECT_EQ(back->state.landmarks[1].p_linearization,
            checkpoint.state.landmarks[1].p_linearization);
  EXPECT_TRUE(back->state.landmarks[0].archived);
  EXPECT_FALSE(back->state.landmarks[1].archived);
  EXPECT_TRUE(back->state.landmarks[0].used_observations.empty());
  ASSERT_EQ(back->state.landmarks[1].used_observations.size(), 2u);
  EXPECT_EQ(back->state.landmarks[1].used_observations[1].frame, 41);
  EXPECT_EQ(back->state.landmarks[1].used_observations[1].xy,
            checkpoint.state.landmarks[1].used_observations[1].xy);
  EXPECT_TRUE(back->state.has_disparity_offset);
  EXPECT_EQ(back->state.disparity_offset, -0.2);
  ASSERT_TRUE(back->state.has_world_up);
  EXPECT_EQ(back->state.world_up.reference, checkpoint.state.world_up.reference);
  EXPECT_EQ(back->state.world_up.basis, checkpoint.state.world_up.basis);
  EXPECT_EQ(back->state.world_up.tilt, checkpoint.state.world_up.tilt);
  ASSERT_EQ(back->pending.size(), 1u);
  ASSERT_EQ(back->pending.at(9).size(), 2u);
  EXPECT_EQ(back->pending.at(9)[1].frame, 41);
  EXPECT_EQ(back->pending.at(9)[1].xy, checkpoint.pending[9][1].xy);
  ASSERT_EQ(back->state.archived.size(), 2u);
  EXPECT_EQ(back->state.archived.at(700).covariance, checkpoint.state.archived.at(700).covariance);
  EXPECT_EQ(back->state.archived_last_observed.at(700), 30);
  ASSERT_EQ(back->state.archived_local_covariance.size(), 1u);
  EXPECT_EQ(back->state.archived_local_covariance.at(700),
            checkpoint.state.archived_local_covariance.at(700));
  {
    // A local covariance that is no covariance is refused, checksum or not.
    Checkpoint bad = checkpoint;
    bad.state.archived_local_covariance[700](0, 0) = -1.0;
    EXPECT_FALSE(parse_checkpoint(serialize_checkpoint(bad), error));
    EXPECT_NE(error.find("local covariance"), std::string::npos) << error;
  }
  // Every truncation and any flipped byte is refused with a reason, never read.
  for (std::size_t size = 0; size < bytes.size(); size += 7) {
    EXPECT_FALSE(parse_checkpoint(bytes.substr(0, size), error)) << size;
  }
  std::string flipped = bytes;
  flipped[bytes.size() / 2] ^= 0x10;
  EXPECT_FALSE(parse_checkpoint(flipped, error));
  EXPECT_NE(error.find("checksum"), std::string::npos) << error;
  // A world up axis whose basis is not perpendicular to its reference is refused, checksum or no.
  Checkpoint skewed = checkpoint;
  skewed.state.world_up.basis.col(0) = skewed.state.world_up.reference;
  EXPECT_FALSE(parse_checkpoint(serialize_checkpoint(skewed), error));
  EXPECT_NE(error.find("world up"), std::string::npos) << error;
}

}  // namespace
}  // namespace concord::daemon

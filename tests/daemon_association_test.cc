// The negotiated association in the daemons (issue 11): the wire form of the negotiation is exact
// and refuses malformed descriptions (bounds, non-finite values, indefinite covariances, bad
// links and transforms) without stalling a lockstep round; ConsensusExchanges wired to each other
// and concordd processes in lockstep reproduce concord replay's negotiated run (team ids, frames,
// estimates) on a simulated team with private ids and unknown starts.
#include <gtest/gtest.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <thread>

#include "concord/association/negotiation.h"
#include "concord/config/options_file.h"
#include "concord/daemon/association_session.h"
#include "concord/daemon/consensus_exchange.h"
#include "concord/daemon/negotiation_wire.h"
#include "concord/dataset/dataset.h"
#include "concord/dataset/result_io.h"
#include "concord/estimator/estimator.h"
#include "concord/v1/concord.pb.h"
#include "launch/launch.h"
#include "launch/process.h"
#include "replay/team_replay.h"
#include "sim/simulator.h"
#include "test_paths.h"

namespace concord::daemon {
namespace {

namespace fs = std::filesystem;
using namespace std::chrono_literals;

using testing::kSanitized;
using testing::kSource;

/// Frames of the negotiated team: every robot has aligned by frame 61, so the sanitizer builds
/// run 80 frames and Release the longer 150.
constexpr int kNegotiatedFrames = kSanitized ? 80 : 150;

/// A small team with private ids and unknown starts whose robots align within its frames. The
/// objects are as dense along the paths as the simulator's default count over 150 frames (the
/// state's size, which sets the filter's cost per frame, does not grow on shorter runs); robots 1
/// and 2 align at frames 46 and 61 with 80 frames or more.
dataset::Dataset negotiated_team(int frames) {
  sim::SimulationOptions options;
  options.robots = 3;
  options.frames = frames;
  options.objects = options.objects * frames / 150;
  options.points_per_frame = 0;
  options.classes = 4;
  options.private_ids = true;
  options.unknown_start = true;
  options.seed = 3;
  return sim::simulate(options);
}

association::NegotiationMessage sample_message() {
  association::NegotiationMessage message;
  message.sender = 1;
  message.frame = 1;
  association::MapDescription map;
  map.robot = 1;
  map.frame = 1;
  for (int n = 0; n < 3; ++n) {
    association::ObjectDescription object;
    object.id = 10 + n;
    object.object_class = n - 1;
    object.observations = 7 + n;
    object.position = Eigen::Vector3d(0.1 * n, 1.0 / 3.0, -2.0 + n);
    object.covariance << 0.3, 0.01, 0.0, 0.01, 0.2, 0.02, 0.0, 0.02, 0.1;
    object.local_covariance = 0.5 * object.covariance;
    object.archived = n == 1;
    map.objects.push_back(object);
  }
  map.pose_frame = 33;
  map.pose_covariance = 0.004 * lie::Matrix6d::Identity();
  map.pose_covariance(2, 3) = map.pose_covariance(3, 2) = 0.0005;
  message.map = std::make_shared<const association::MapDescription>(map);
  association::OwnerRecord record;
  record.owner = 0;
  record.version = 4;
  record.links.push_back(association::ObjectLink::make(association::object_key(0, 3),
                                                       association::object_key(1, 11), 1.25));
  association::FrameEdge edge;
  edge.frame_a = 0;
  edge.frame_b = 1;
  edge.T_a_b = Eigen::Translation3d(1.0, 2.0, 3.0) *
               Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized());
  edge.covariance = 0.01 * lie::Matrix6d::Identity();
  edge.covariance(0, 5) = edge.covariance(5, 0) = 0.001;
  edge.round = 15;
  edge.owner = 0;
  edge.robot_b = 1;
  edge.drift_a = 0.003 * lie::Matrix6d::Identity();
  edge.drift_b = map.pose_covariance;
  edge.pose_frame_a = 14;
  edge.pose_frame_b = 15;
  association::FrameCorrection correction;
  correction.frame = 0;
  correction.moves_b_side = false;
  correction.T =
      Eigen::Translation3d(-0.5, 0.25, 0.0) * Eigen::AngleAxisd(0.2, Eigen::Vector3d(0, 0, 1));
  correction.covariance = 0.02 * lie::Matrix6d::Identity();
  correction.covariance(1, 4) = correction.covariance(4, 1) = 0.003;
  correction.round = 40;
  edge.corrections.push_back(correction);
  record.frame_edges.push_back(edge);
  message.records.push_back(std::make_shared<const association::OwnerRecord>(record));
  message.held = {{0, 4}, {1, 9}, {3, 2}};
  return message;
}

std::optional<association::NegotiationMessage> decode(const v1::Negotiation& wire,
                                                      std::string& error,
                                                      NegotiationLimits limits = {}) {
  return from_wire(wire, 1, limits, error);
}

TEST(NegotiationWire, RoundTripIsExact) {
  const auto message = sample_message();
  v1::Negotiation wire;
  to_wire(message, wire);
  // Through bytes, as on a connection.
  v1::Negotiation parsed;
  ASSERT_TRUE(parsed.ParseFromString(wire.SerializeAsString()));
  std::string error;
  const auto decoded = decode(parsed, error);
  ASSERT_TRUE(decoded) << error;
  EXPECT_EQ(decoded->sender, 1);
  EXPECT_EQ(decoded->frame, 1);
  ASSERT_TRUE(decoded->map);
  ASSERT_EQ(decoded->map->objects.size(), 3u);
  for (std::size_t n = 0; n < 3; ++n) {
    const auto& a = message.map->objects[n];
    const auto& b = decoded->map->objects[n];
    EXPECT_EQ(a.id, b.id);
    EXPECT_EQ(a.object_class, b.object_class);
    EXPECT_EQ(a.observations, b.observations);
    EXPECT_EQ(a.position, b.position);  // bit for bit
    EXPECT_EQ(a.covariance, b.covariance);
    EXPECT_EQ(a.local_covariance, b.local_covariance);
    EXPECT_EQ(a.archived, b.archived);
  }
  EXPECT_TRUE(decoded->map->objects[1].archived);
  EXPECT_EQ(decoded->map->pose_frame, 33);
  EXPECT_EQ(decoded->map->pose_covariance, message.map->pose_covariance);
  ASSERT_EQ(decoded->records.size(), 1u);
  const auto& record = *decoded->records[0];
  EXPECT_EQ(record.owner, 0);
  EXPECT_EQ(record.version, 4);
  ASSERT_EQ(record.links.size(), 1u);
  EXPECT_EQ(record.links[0].a, message.records[0]->links[0].a);
  EXPECT_EQ(record.links[0].b, message.records[0]->links[0].b);
  EXPECT_EQ(record.links[0].mahalanobis_squared, 1.25);
  ASSERT_EQ(record.frame_edges.size(), 1u);
  EXPECT_EQ(record.frame_edges[0].T_a_b.matrix(),
            message.records[0]->frame_edges[0].T_a_b.matrix());
  EXPECT_EQ(record.frame_edges[0].covariance, message.records[0]->frame_edges[0].covariance);
  EXPECT_EQ(record.frame_edges[0].round, 15);
  EXPECT_EQ(record.frame_edges[0].robot_b, 1);
  EXPECT_EQ(record.frame_edges[0].drift_a, message.records[0]->frame_edges[0].drift_a);
  EXPECT_EQ(record.frame_edges[0].drift_b, message.records[0]->frame_edges[0].drift_b);
  EXPECT_EQ(record.frame_edges[0].pose_frame_a, 14);
  EXPECT_EQ(record.frame_edges[0].pose_frame_b, 15);
  ASSERT_EQ(record.frame_edges[0].corrections.size(), 1u);
  const auto& sent = message.records[0]->frame_edges[0].corrections[0];
  const auto& got = record.frame_edges[0].corrections[0];
  EXPECT_EQ(got.frame, 0);
  EXPECT_FALSE(got.moves_b_side);
  EXPECT_EQ(got.T.matrix(), sent.T.matrix());
  EXPECT_EQ(got.covariance, sent.covariance);
  EXPECT_EQ(got.round, 40);
  EXPECT_EQ(decoded->held, message.held);
}

TEST(NegotiationWire, AMapDescriptionWrittenOnceGoesIntoEveryMessageThatCarriesIt) {
  // A daemon writes a round's description once and copies it into each neighbour's message.
  auto message = sample_message();
  v1::MapDescription map;
  to_wire(*message.map, map);
  v1::Negotiation direct, copied;
  to_wire(message, direct);
  to_wire(message, map, copied);
  EXPECT_EQ(copied.SerializeAsString(), direct.SerializeAsString());
  // A message without a description (not a describing round) carries none, whatever was written.
  message.map.reset();
  v1::Negotiation without;
  to_wire(message, map, without);
  EXPECT_FALSE(without.has_map());
  EXPECT_EQ(without.records_size(), 1);
  // Writing another description into the same object replaces the old one whole.
  association::MapDescription smaller = *sample_message().map;
  smaller.objects.resize(1);
  to_wire(smaller, map);
  EXPECT_EQ(map.objects_size(), 1);
}

TEST(NegotiationWire, MalformedDescriptionsAreRefusedNamingTheProblem) {
  const auto message = sample_message();
  v1::Negotiation good;
  to_wire(message, good);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  struct Case {
    std::string name;
    std::function<void(v1::Negotiation&)> corrupt;
    std::string expected;  // part of the error
  };
  const std::vector<Case> cases = {
      {"nan position",
       [&](v1::Negotiation& m) { m.mutable_map()->mutable_objects(1)->set_position(0, nan); },
       "non-finite position"},
      {"infinite covariance",
       [&](v1::Negotiation& m) {
         m.mutable_map()->mutable_objects(0)->set_covariance(
             3, std::numeric_limits<double>::infinity());
       },
       "positive definite"},
      {"indefinite covariance",
       [&](v1::Negotiation& m) {
         m.mutable_map()->mutable_objects(2)->set_local_covariance(0, -1.0);
       },
       "positive definite"},
      {"short covariance",
       [&](v1::Negotiation& m) {
         m.mutable_map()->mutable_objects(2)->mutable_covariance()->RemoveLast();
       },
       "positive definite"},
      {"two positions",
       [&](v1::Negotiation& m) { m.mutable_map()->mutable_objects(0)->add_position(1.0); },
       "position of 4 values"},
      {"unsorted ids", [&](v1::Negotiation& m) { m.mutable_map()->mutable_objects(2)->set_id(5); },
       "not sorted"},
      {"negative id", [&](v1::Negotiation& m) { m.mutable_map()->mutable_objects(0)->set_id(-4); },
       "out of range"},
      {"bad class",
       [&](v1::Negotiation& m) { m.mutable_map()->mutable_objects(0)->set_object_class(-7); },
       "class"},
      {"map in another frame", [&](v1::Negotiation& m) { m.mutable_map()->set_frame(2); },
       "description in frame 2"},
      {"link of others",
       [&](v1::Negotiation& m) {
         m.mutable_records(0)->mutable_links(0)->set_a(association::object_key(2, 1));
         m.mutable_records(0)->mutable_links(0)->set_b(association::object_key(3, 1));
       },
       "malformed link"},
      {"nan link",
       [&](v1::Negotiation& m) {
         m.mutable_records(0)->mutable_links(0)->set_mahalanobis_squared(nan);
       },
       "malformed link"},
      {"not a rotation",
       [&](v1::Negotiation& m) { m.mutable_records(0)->mutable_frame_edges(0)->set_t_a_b(0, 2.0); },
       "rigid motion"},
      {"edge covariance",
       [&](v1::Negotiation& m) {
         m.mutable_records(0)->mutable_frame_edges(0)->set_covariance(0, nan);
       },
       "covariance"},
      {"edge drift not a covariance",
       [&](v1::Negotiation& m) {
         m.mutable_records(0)->mutable_frame_edges(0)->set_drift_b(0, -1.0);
       },
       "frame edge drift malformed"},
      {"edge drift beyond any use",
       [&](v1::Negotiation& m) {
         m.mutable_records(0)->mutable_frame_edges(0)->set_drift_a(0, 1e300);
       },
       "frame edge drift malformed"},
      {"edge to its own robot",
       [&](v1::Negotiation& m) { m.mutable_records(0)->mutable_frame_edges(0)->set_robot_b(0); },
       "frame edge drift malformed"},
      {"description pose covariance",
       [&](v1::Negotiation& m) { m.mutable_map()->set_pose_covariance(20, nan); },
       "description pose"},
      {"description pose frame", [&](v1::Negotiation& m) { m.mutable_map()->set_pose_frame(-7); },
       "description pose"},
      {"edge of another owner",
       [&](v1::Negotiation& m) { m.mutable_records(0)->mutable_frame_edges(0)->set_owner(5); },
       "malformed frame edge"},
      {"correction not a rotation",
       [&](v1::Negotiation& m) {
         m.mutable_records(0)->mutable_frame_edges(0)->mutable_corrections(0)->set_t(5, 3.0);
       },
       "malformed frame edge correction"},
      {"correction covariance",
       [&](v1::Negotiation& m) {
         m.mutable_records(0)->mutable_frame_edges(0)->mutable_corrections(0)->set_covariance(0,
                                                                                              -1.0);
       },
       "malformed frame edge correction"},
      {"correction frame out of range",
       [&](v1::Negotiation& m) {
         m.mutable_records(0)->mutable_frame_edges(0)->mutable_corrections(0)->set_frame(-9);
       },
       "malformed frame edge correction"},
      {"too many corrections",
       [&](v1::Negotiation& m) {
         auto* edge = m.mutable_records(0)->mutable_frame_edges(0);
         const v1::FrameCorrection one = edge->corrections(0);
         for (int k = 0; k < 16; ++k) *edge->add_corrections() = one;
       },
       "malformed frame edge"},
      {"frame out of range", [&](v1::Negotiation& m) { m.set_frame(-5); }, "out of range"},
      {"held version of no robot",
       [&](v1::Negotiation& m) { m.mutable_held(1)->set_owner(1u << 30); },
       "held record version out of range"},
      {"held version out of range",
       [&](v1::Negotiation& m) { m.mutable_held(0)->set_version(0xffffffffu); },
       "held record version out of range"},
  };
  for (const Case& c : cases) {
    v1::Negotiation wire = good;
    c.corrupt(wire);
    std::string error;
    EXPECT_FALSE(decode(wire, error)) << c.name;
    EXPECT_NE(error.find(c.expected), std::string::npos) << c.name << ": " << error;
  }
  // Bounds: objects per description, records per message, links and edges per record.
  NegotiationLimits limits;
  limits.max_description_objects = 2;
  std::string error;
  EXPECT_FALSE(decode(good, error, limits));
  EXPECT_NE(error.find("above the limit of 2"), std::string::npos) << error;
  limits = {};
  limits.max_records = 0;
  EXPECT_FALSE(decode(good, error, limits));
  limits = {};
  limits.max_records = 2;  // one record, three held versions
  EXPECT_FALSE(decode(good, error, limits));
  EXPECT_NE(error.find("3 held record versions, above the limit of 2"), std::string::npos) << error;
  limits = {};
  limits.max_links_per_record = 0;
  EXPECT_FALSE(decode(good, error, limits));
  limits = {};
  limits.max_frame_edges_per_record = 0;
  EXPECT_FALSE(decode(good, error, limits));
  EXPECT_TRUE(decode(good, error)) << error;
}

/// Robot `robot`'s identity in these tests, and the keys of robots 0..robots-1.
std::shared_ptr<const net::RobotIdentity> robot_identity(int robot) {
  return std::make_shared<const net::RobotIdentity>(
      net::RobotIdentity::from_seed_for_tests("association robot " + std::to_string(robot)));
}
net::MemberKeys robot_keys(int robots) {
  net::MemberKeys keys;
  for (int robot = 0; robot < robots; ++robot)
    keys.emplace(robot, robot_identity(robot)->public_key());
  return keys;
}

/// `message` through bytes, as on a connection.
v1::Negotiation through_bytes(const v1::Negotiation& message) {
  v1::Negotiation parsed;
  EXPECT_TRUE(parsed.ParseFromString(message.SerializeAsString()));
  return parsed;
}

TEST(NegotiationWire, OwnRecordsGoOutSignedAndRelaysPassTheOwnersSignatureOn) {
  // sample_message's record is robot 0's: robot 0 signs it, robot 1 reads it and relays it to
  // robot 2 as it holds it (its own signer leaves another owner's signature as it is).
  const RecordSigner robot0(0, robot_identity(0), robot_keys(3));
  const RecordSigner robot1(1, robot_identity(1), robot_keys(3));
  const RecordSigner robot2(2, robot_identity(2), robot_keys(3));
  v1::Negotiation wire;
  to_wire(sample_message(), wire, &robot0);
  ASSERT_EQ(wire.records(0).signature().size(), net::kSignatureBytes);
  std::string error;
  std::uint64_t unsigned_records = 0;
  const auto at_robot1 = from_wire(through_bytes(wire), 0, {}, error, &robot1, &unsigned_records);
  ASSERT_TRUE(at_robot1) << error;
  ASSERT_EQ(at_robot1->records.size(), 1u);
  EXPECT_EQ(unsigned_records, 0u);
  association::NegotiationMessage relayed = *at_robot1;
  relayed.sender = 1;
  relayed.map.reset();
  v1::Negotiation relayed_wire;
  to_wire(relayed, relayed_wire, &robot1);
  EXPECT_EQ(relayed_wire.records(0).signature(), wire.records(0).signature());
  const auto at_robot2 =
      from_wire(through_bytes(relayed_wire), 1, {}, error, &robot2, &unsigned_records);
  ASSERT_TRUE(at_robot2) << error;
  EXPECT_EQ(at_robot2->records.size(), 1u);
  EXPECT_EQ(unsigned_records, 0u);
  // The same signature for the same version: signed once.
  v1::Negotiation again;
  to_wire(sample_message(), again, &robot0);
  EXPECT_EQ(again.records(0).signature(), wire.records(0).signature());
}

TEST(NegotiationWire, RecordsNotSignedByTheirOwnerAreLeftOutAndCounted) {
  const RecordSigner robot0(0, robot_identity(0), robot_keys(3));
  const RecordSigner robot2(2, robot_identity(2), robot_keys(3));
  v1::Negotiation signed_wire;
  to_wire(sample_message(), signed_wire, &robot0);
  struct Case {
    const char* name;
    std::function<void(v1::Negotiation&)> change;
  };
  const std::vector<Case> cases = {
      {"unsigned", [](v1::Negotiation& m) { m.mutable_records(0)->clear_signature(); }},
      {"a newer version under the old signature",
       [](v1::Negotiation& m) { m.mutable_records(0)->set_version(5); }},
      {"a link changed",
       [](v1::Negotiation& m) {
         m.mutable_records(0)->mutable_links(0)->set_mahalanobis_squared(0.5);
       }},
      {"a frame edge's transform changed",
       [](v1::Negotiation& m) {
         auto* t = m.mutable_records(0)->mutable_frame_edges(0)->mutable_t_a_b();
         t->Set(3, t->Get(3) + 1.0);
       }},
      {"a correction's round changed",
       [](v1::Negotiation& m) {
         m.mutable_records(0)->mutable_frame_edges(0)->mutable_corrections(0)->set_round(41);
       }},
      {"signed by another member (robot 1) for robot 0",
       [](v1::Negotiation& m) {
         m.mutable_records(0)->set_signature(robot_identity(1)->sign("anything"));
       }},
  };
  for (const Case& c : cases) {
    v1::Negotiation wire = signed_wire;
    c.change(wire);
    std::string error;
    std::uint64_t unsigned_records = 0;
    const auto decoded = from_wire(through_bytes(wire), 1, {}, error, &robot2, &unsigned_records);
    ASSERT_TRUE(decoded) << c.name << ": " << error;  // the rest of the message is taken
    EXPECT_TRUE(decoded->records.empty()) << c.name;
    EXPECT_EQ(unsigned_records, 1u) << c.name;
    EXPECT_TRUE(decoded->map) << c.name;
    // Without identities the same bytes are taken (signatures are not checked).
    const auto unchecked = from_wire(through_bytes(wire), 1, {}, error);
    ASSERT_TRUE(unchecked) << c.name << ": " << error;
    EXPECT_EQ(unchecked->records.size(), 1u) << c.name;
  }
  // A record of robot 0 that robot 2 made up and signed with its own key.
  association::OwnerRecord forged = *sample_message().records[0];
  forged.version = 1000;
  forged.signature = robot_identity(2)->sign(record_signing_bytes(forged));
  association::NegotiationMessage message = sample_message();
  message.records = {std::make_shared<const association::OwnerRecord>(forged)};
  v1::Negotiation forged_wire;
  to_wire(message, forged_wire, &robot2);
  EXPECT_EQ(forged_wire.records(0).signature(), forged.signature);  // relayed as it holds it
  std::string error;
  std::uint64_t unsigned_records = 0;
  const RecordSigner robot1(1, robot_identity(1), robot_keys(3));
  const auto decoded =
      from_wire(through_bytes(forged_wire), 2, {}, error, &robot1, &unsigned_records);
  ASSERT_TRUE(decoded) << error;
  EXPECT_TRUE(decoded->records.empty());
  EXPECT_EQ(unsigned_records, 1u);
  // A signature of the wrong size is malformed whatever the receiver checks.
  v1::Negotiation short_signature = signed_wire;
  short_signature.mutable_records(0)->set_signature("short");
  EXPECT_FALSE(from_wire(short_signature, 1, {}, error));
  EXPECT_NE(error.find("signature of 5 bytes"), std::string::npos) << error;
}

/// Exchanges that deliver to each other directly, optionally corrupting what one robot sends.
struct Team {
  Team(int robots, ConsensusConfig config,
       std::function<void(int, v1::Envelope&)> corrupt = nullptr) {
    for (int i = 0; i < robots; ++i) {
      exchanges.push_back(std::make_unique<ConsensusExchange>(
          config, [this, i, corrupt](int robot, const v1::Envelope& envelope) {
            v1::Envelope sent = envelope;
            if (corrupt) corrupt(i, sent);
            exchanges[robot]->on_message(i, sent);
            return true;
          }));
    }
  }
  void connect_all() {
    for (std::size_t i = 0; i < exchanges.size(); ++i)
      for (std::size_t j = 0; j < exchanges.size(); ++j)
        if (i != j) exchanges[i]->on_peer(static_cast<int>(j), true);
  }
  std::vector<std::unique_ptr<ConsensusExchange>> exchanges;
};

struct TeamRun {
  std::vector<std::vector<Eigen::Isometry3d>> trajectories;
  std::vector<std::vector<ObjectEstimate>> objects;
  std::vector<std::vector<LandmarkId>> team_ids;
  std::vector<int> frames;
  std::vector<ExchangeCounters> counters;
  std::vector<association::NegotiationCounters> negotiation;
  int timed_out = 0;
};

/// The team on `inputs` with one thread per robot, as concordd's estimator threads do.
TeamRun run_exchanges(const dataset::TeamInputs& inputs, const EstimatorOptions& options,
                      const association::NegotiationOptions& negotiation,
                      std::function<void(int, v1::Envelope&)> corrupt = nullptr,
                      const std::vector<int>& members = {}, bool identities = false) {
  ConsensusConfig config;
  config.mode = ConsensusMode::kLockstep;
  config.round_deadline = std::chrono::seconds(30);
  const int robots = static_cast<int>(inputs.robots.size());
  Team team(robots, config, std::move(corrupt));
  std::vector<std::unique_ptr<AssociationSession>> sessions;
  for (int i = 0; i < robots; ++i) {
    sessions.push_back(std::make_unique<AssociationSession>(i, i, negotiation, members));
    team.exchanges[i]->set_association(sessions[i].get());
    if (identities) {
      team.exchanges[i]->set_record_signer(
          std::make_shared<RecordSigner>(i, robot_identity(i), robot_keys(robots)));
    }
  }
  team.connect_all();
  // spdlog makes its logger registry at first use, inside the library, which ThreadSanitizer does
  // not see: made here, before the robots' threads (as concordd's main thread makes it before
  // its own), its making happens before their log lines.
  spdlog::default_logger_raw();
  TeamRun run;
  run.trajectories.resize(robots);
  run.objects.resize(robots);
  run.team_ids.resize(robots);
  run.frames.resize(robots);
  std::atomic<int> timed_out{0};
  std::vector<std::thread> threads;
  for (int i = 0; i < robots; ++i) {
    threads.emplace_back([&, i] {
      const dataset::RobotInputs& robot = inputs.robots[i];
      Estimator estimator(options, inputs.camera, Eigen::Isometry3d::Identity(), 0);
      for (int k = 0; k < robot.num_frames(); ++k) {
        const FrameInput input = robot.frame_input(k);
        estimator.process(input);
        sessions[i]->observe(input.objects, robot.object_classes[k], estimator);
        timed_out +=
            team.exchanges[i]->run_round(static_cast<std::uint64_t>(k), estimator).timed_out;
        run.trajectories[i].push_back(estimator.current_pose());
      }
      run.objects[i] = estimator.objects();
      run.team_ids[i] = sessions[i]->team_ids(run.objects[i]);
      run.frames[i] = sessions[i]->frame();
    });
  }
  for (auto& thread : threads) thread.join();
  run.timed_out = timed_out;
  for (int i = 0; i < robots; ++i) {
    run.counters.push_back(team.exchanges[i]->counters());
    run.negotiation.push_back(sessions[i]->counters());
  }
  return run;
}

/// Two labellings name the same partition of (robot, object) pairs into teams.
void expect_same_partition(const std::vector<std::vector<ObjectEstimate>>& objects,
                           const std::vector<std::vector<LandmarkId>>& a,
                           const std::vector<std::vector<LandmarkId>>& b) {
  std::map<LandmarkId, LandmarkId> a_to_b, b_to_a;
  for (std::size_t i = 0; i < objects.size(); ++i) {
    ASSERT_EQ(a[i].size(), b[i].size());
    for (std::size_t n = 0; n < a[i].size(); ++n) {
      EXPECT_EQ(a[i][n] < 0, b[i][n] < 0) << "robot " << i << " object " << objects[i][n].id;
      if (a[i][n] < 0 || b[i][n] < 0) continue;
      const auto [x, new_x] = a_to_b.emplace(a[i][n], b[i][n]);
      const auto [y, new_y] = b_to_a.emplace(b[i][n], a[i][n]);
      EXPECT_EQ(x->second, b[i][n]);
      EXPECT_EQ(y->second, a[i][n]);
    }
  }
}

/// The exchanges on the negotiated team against `concord replay`'s negotiated run: the same
/// frames, trajectories, objects and team ids.
void expect_exchanges_reproduce_the_replay(const association::NegotiationOptions& negotiation,
                                           long long& frame_corrections) {
  const dataset::Dataset data = negotiated_team(kNegotiatedFrames);
  const dataset::TeamInputs inputs = dataset::sensor_inputs(data);
  const EstimatorOptions options =
      config::load_estimator_options(kSource / "configs/sensors/sim.yaml");
  replay::ReplayOptions replay_options;
  replay_options.negotiation = negotiation;
  const auto reference = replay::run_team(inputs, options, replay_options);
  ASSERT_EQ(reference.association, replay::AssociationMode::kNegotiated);

  const TeamRun run = run_exchanges(inputs, options, negotiation);
  EXPECT_EQ(run.timed_out, 0);
  int moved = 0, shared = 0;
  std::vector<std::vector<LandmarkId>> reference_ids;
  for (int i = 0; i < 3; ++i) {
    const auto& expected = reference.robots[i];
    moved += expected.moved ? 1 : 0;
    EXPECT_EQ(run.frames[i], expected.trajectory_frames.back()) << "robot " << i;
    ASSERT_EQ(run.trajectories[i].size(), expected.trajectory.size());
    for (std::size_t k = 0; k < expected.trajectory.size(); ++k)
      ASSERT_TRUE(run.trajectories[i][k].isApprox(expected.trajectory[k], 1e-9))
          << "robot " << i << " frame " << k;
    ASSERT_EQ(run.objects[i].size(), expected.objects.size());
    for (std::size_t o = 0; o < expected.objects.size(); ++o) {
      EXPECT_EQ(run.objects[i][o].id, expected.objects[o].id);
      EXPECT_TRUE(run.objects[i][o].p_world.isApprox(expected.objects[o].p_world, 1e-9));
    }
    for (LandmarkId id : run.team_ids[i]) shared += id >= 0 ? 1 : 0;
    reference_ids.push_back(expected.team_ids);
    EXPECT_EQ(run.counters[i].negotiations_refused, 0u);
    EXPECT_GT(run.counters[i].negotiation_seconds, 0.0) << "robot " << i;
  }
  expect_same_partition(run.objects, run.team_ids, reference_ids);
  // The run means something: robots moved into the team frame and share objects.
  EXPECT_GE(moved, 1);
  EXPECT_GT(shared, 10);
  EXPECT_GT(run.counters[0].marginals_fused, 20u);
  frame_corrections = reference.statistics.frame_corrections;
  EXPECT_EQ(reference.statistics.records_not_owned, 0);  // honest owners decide their own pairs
}

TEST(DaemonAssociation, ExchangesReproduceTheNegotiatedReplay) {
  long long corrections = -1;
  expect_exchanges_reproduce_the_replay(
      config::load_negotiation_options(kSource / "configs/sensors/sim.yaml"), corrections);
  EXPECT_EQ(corrections, 0);  // right edges: revisited, never corrected
}

TEST(DaemonAssociation, ExchangesReproduceTheNegotiatedReplayWithFrameCorrections) {
  // A revisit gate of almost zero calls any offset of two maps in one frame a misalignment, and
  // an ambiguity ratio of 2 takes the accepted alignment for a rival only when it matches twice
  // what the revisit's transform does: the edges are corrected (by what the revisits find) and
  // the robots behind them move within the team frame. The corrections travel in the owners'
  // records, and every daemon moves in the round the replay's robot does.
  association::NegotiationOptions negotiation =
      config::load_negotiation_options(kSource / "configs/sensors/sim.yaml");
  negotiation.revisit_chi2_probability = 1e-9;
  negotiation.revisit_interval = 1;
  negotiation.revisit_ambiguity_ratio = 2.0;
  long long corrections = 0;
  expect_exchanges_reproduce_the_replay(negotiation, corrections);
  EXPECT_GE(corrections, 1);
}

/// negotiated_team(frames) as the exchanges take it, with configs/sensors/sim.yaml.
struct NegotiatedInputs {
  dataset::TeamInputs inputs;
  EstimatorOptions options;
  association::NegotiationOptions negotiation;
};
NegotiatedInputs negotiated_inputs(int frames) {
  const std::filesystem::path config = kSource / "configs/sensors/sim.yaml";
  return {dataset::sensor_inputs(negotiated_team(frames)), config::load_estimator_options(config),
          config::load_negotiation_options(config)};
}

TEST(DaemonAssociation, MalformedDescriptionsAreCountedAndNeverStallTheRound) {
  // Robot 2 sends every description with a NaN position: its neighbours refuse them (counted),
  // the rounds go on without waiting, and robots 0 and 1 still negotiate between themselves.
  // Robots 0 and 1 align at frame 46: 60 frames under the sanitizers, 80 in Release.
  const int frames = kSanitized ? 60 : 80;
  const NegotiatedInputs team = negotiated_inputs(frames);
  const TeamRun run =
      run_exchanges(team.inputs, team.options, team.negotiation, [](int sender, v1::Envelope& e) {
        if (sender != 2 || !e.has_landmark_set() || !e.landmark_set().negotiation().has_map())
          return;
        auto* map = e.mutable_landmark_set()->mutable_negotiation()->mutable_map();
        if (map->objects_size() > 0)
          map->mutable_objects(0)->set_position(0, std::numeric_limits<double>::quiet_NaN());
      });
  EXPECT_EQ(run.timed_out, 0);
  EXPECT_GT(run.counters[0].negotiations_refused, 0u);
  EXPECT_EQ(run.counters[0].negotiations_refused, run.counters[1].negotiations_refused);
  EXPECT_EQ(run.counters[2].negotiations_refused, 0u);
  for (int i = 0; i < 3; ++i)
    EXPECT_EQ(run.trajectories[i].size(), static_cast<std::size_t>(frames));
}

/// The forged run ended as the honest one: the same frames, trajectories, objects and teams.
void expect_same_run(const TeamRun& honest, const TeamRun& forged) {
  ASSERT_EQ(forged.trajectories.size(), honest.trajectories.size());
  for (std::size_t i = 0; i < honest.trajectories.size(); ++i) {
    EXPECT_EQ(forged.frames[i], honest.frames[i]) << "robot " << i;
    ASSERT_EQ(forged.trajectories[i].size(), honest.trajectories[i].size());
    for (std::size_t k = 0; k < honest.trajectories[i].size(); ++k)
      ASSERT_TRUE(forged.trajectories[i][k].isApprox(honest.trajectories[i][k], 1e-9))
          << "robot " << i << " frame " << k;
    ASSERT_EQ(forged.objects[i].size(), honest.objects[i].size());
  }
  expect_same_partition(honest.objects, honest.team_ids, forged.team_ids);
}

TEST(DaemonAssociation, RecordsForgedForARobotOutsideTheMembersChangeNothing) {
  // Robot 2 (a key holder) adds to every negotiation message a record it made up for robot 9,
  // which is not in the team: links that would put robot 0's and robot 1's objects of the same
  // private ids into one team each. Robots 0 and 1 refuse it (counted) and the team ends as the
  // same team without the forgery does: the same trajectories, objects and team ids.
  const int frames = kSanitized ? 60 : 80;
  const NegotiatedInputs team = negotiated_inputs(frames);
  const std::vector<int> members{0, 1, 2};
  const TeamRun honest =
      run_exchanges(team.inputs, team.options, team.negotiation, nullptr, members);
  std::atomic<std::uint32_t> version{0};
  const TeamRun forged = run_exchanges(
      team.inputs, team.options, team.negotiation,
      [&version](int sender, v1::Envelope& e) {
        if (sender != 2 || !e.has_landmark_set() || !e.landmark_set().has_negotiation()) return;
        v1::OwnerRecord* record = e.mutable_landmark_set()->mutable_negotiation()->add_records();
        record->set_owner(9);
        record->set_version(++version);  // newer each time: taken if not refused
        for (LandmarkId id = 0; id < 20; ++id) {
          for (const int robot : {0, 1}) {
            v1::ObjectLink* link = record->add_links();
            link->set_a(association::object_key(robot, id));
            link->set_b(association::object_key(9, id));
            link->set_mahalanobis_squared(0.1);
          }
        }
      },
      members);
  EXPECT_EQ(forged.timed_out, 0);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(forged.counters[i].negotiations_refused, 0u) << "robot " << i;
    EXPECT_EQ(honest.negotiation[i].records_refused, 0) << "robot " << i;
    if (i < 2) {
      EXPECT_GT(forged.negotiation[i].records_refused, 0) << "robot " << i;
    } else {
      EXPECT_EQ(forged.negotiation[i].records_refused, 0);
    }
  }
  expect_same_run(honest, forged);
}

TEST(DaemonAssociation, WithIdentitiesRecordsForgedForAMemberChangeNothing) {
  // Robot 2 (a key holder with its own identity) adds to every negotiation message a record it
  // made up for robot 0, a member, under ever higher versions, signed with its own key: links
  // that would put robot 0's and robot 1's objects of the same private ids into one team each.
  // Without identities robot 1 would take it as robot 0's newest record. With them robots 0 and
  // 1 leave it out (counted) and the team ends as the same team without the forgery does: the
  // same trajectories, objects and team ids; and honest records, signed and relayed, are all taken.
  const int frames = kSanitized ? 60 : 80;
  const NegotiatedInputs team = negotiated_inputs(frames);
  const std::vector<int> members{0, 1, 2};
  const TeamRun honest =
      run_exchanges(team.inputs, team.options, team.negotiation, nullptr, members, true);
  std::atomic<int> version{1000};
  const TeamRun forged = run_exchanges(
      team.inputs, team.options, team.negotiation,
      [&version](int sender, v1::Envelope& e) {
        if (sender != 2 || !e.has_landmark_set() || !e.landmark_set().has_negotiation()) return;
        association::OwnerRecord record;
        record.owner = 0;
        record.version = ++version;  // newer each time: taken if not refused
        for (LandmarkId id = 0; id < 20; ++id) {
          record.links.push_back(association::ObjectLink::make(
              association::object_key(0, id), association::object_key(1, id), 0.1));
        }
        record.signature = robot_identity(2)->sign(record_signing_bytes(record));
        association::NegotiationMessage message;
        message.records = {std::make_shared<const association::OwnerRecord>(record)};
        v1::Negotiation wire;
        to_wire(message, wire);
        *e.mutable_landmark_set()->mutable_negotiation()->add_records() = wire.records(0);
      },
      members, true);
  EXPECT_EQ(honest.timed_out, 0);
  EXPECT_EQ(forged.timed_out, 0);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(honest.counters[i].records_unsigned, 0u) << "robot " << i;
    EXPECT_EQ(forged.counters[i].negotiations_refused, 0u) << "robot " << i;
    if (i < 2) {
      EXPECT_GT(forged.counters[i].records_unsigned, 0u) << "robot " << i;
    } else {
      EXPECT_EQ(forged.counters[i].records_unsigned, 0u);
    }
  }
  expect_same_run(honest, forged);
  // The negotiation did its work with signed records: robots aligned and shared objects.
  EXPECT_GT(honest.negotiation[0].links_accepted + honest.negotiation[1].links_accepted, 0);
}

/// Robot 2's own owner records in its negotiation messages: left out (forge false), or with
/// links of its objects 0-19 with robot 0's objects of the same ids, signed with robot 2's key
/// (forge true). Robot 0 owns the pair (2 + 0 is even: the lower index), so those links are its
/// decisions, not robot 2's.
std::function<void(int, v1::Envelope&)> change_robot_2s_records(bool forge) {
  return [forge](int sender, v1::Envelope& e) {
    if (sender != 2 || !e.has_landmark_set() || !e.landmark_set().has_negotiation()) return;
    v1::Negotiation& negotiation = *e.mutable_landmark_set()->mutable_negotiation();
    google::protobuf::RepeatedPtrField<v1::OwnerRecord> kept;
    for (const v1::OwnerRecord& wire : negotiation.records()) {
      if (wire.owner() != 2) {
        *kept.Add() = wire;
        continue;
      }
      if (!forge) continue;
      v1::Negotiation one;
      *one.add_records() = wire;
      std::string error;
      const auto parsed = from_wire(one, 2, {}, error);
      ASSERT_TRUE(parsed && parsed->records.size() == 1) << error;
      association::OwnerRecord record = *parsed->records[0];
      for (LandmarkId id = 0; id < 20; ++id) {
        record.links.push_back(association::ObjectLink::make(association::object_key(0, id),
                                                             association::object_key(2, id), 0.1));
      }
      std::sort(record.links.begin(), record.links.end(),
                [](const association::ObjectLink& x, const association::ObjectLink& y) {
                  return x.a != y.a ? x.a < y.a : x.b < y.b;
                });
      record.signature = robot_identity(2)->sign(record_signing_bytes(record));
      association::NegotiationMessage message;
      message.records = {std::make_shared<const association::OwnerRecord>(std::move(record))};
      v1::Negotiation rewritten;
      to_wire(message, rewritten);
      *kept.Add() = rewritten.records(0);
    }
    negotiation.mutable_records()->Swap(&kept);
  };
}

TEST(DaemonAssociation, RecordsDecidingAnotherOwnersPairsChangeNothing) {
  // Robot 2, a member with its own identity, puts into every record of its own links that are
  // robot 0's to decide, and signs them: the signature is good, the decisions are not robot 2's.
  // Robots 0 and 1 drop those records whole (counted), and the team ends as the team in which
  // robot 2's records never reach the others does: the same trajectories, objects and team ids.
  ASSERT_FALSE(association::owns_pair(2, 0));
  const int frames = kSanitized ? 60 : 80;
  const NegotiatedInputs team = negotiated_inputs(frames);
  const std::vector<int> members{0, 1, 2};
  const TeamRun withheld = run_exchanges(team.inputs, team.options, team.negotiation,
                                         change_robot_2s_records(false), members, true);
  const TeamRun forged = run_exchanges(team.inputs, team.options, team.negotiation,
                                       change_robot_2s_records(true), members, true);
  EXPECT_EQ(withheld.timed_out, 0);
  EXPECT_EQ(forged.timed_out, 0);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(withheld.negotiation[i].records_not_owned, 0) << "robot " << i;
    EXPECT_EQ(forged.counters[i].records_unsigned, 0u) << "robot " << i;  // signed by its owner
    EXPECT_EQ(forged.counters[i].negotiations_refused, 0u) << "robot " << i;
    if (i < 2) {
      EXPECT_GT(forged.negotiation[i].records_not_owned, 0) << "robot " << i;
    } else {
      EXPECT_EQ(forged.negotiation[i].records_not_owned, 0);
    }
  }
  expect_same_run(withheld, forged);
  // Robots 0 and 1 still negotiate their own pair.
  EXPECT_GT(withheld.negotiation[0].links_accepted + withheld.negotiation[1].links_accepted, 0);
}

/// Ports of this test process, below Linux's ephemeral range (as daemon_process_test.cc).
std::uint16_t association_port(int offset) {
  return static_cast<std::uint16_t>(11000 + (getpid() % 700) * 30 + offset);
}

TEST(DaemonAssociation, AnObjectsClassIsTheMostFrequentOfItsDetectionsClasses) {
  AssociationSession session(1, 1, association::NegotiationOptions{});
  const Estimator estimator(EstimatorOptions{}, StereoCamera{}, Eigen::Isometry3d::Identity(), 0);
  const auto at = [](LandmarkId id) { return StereoObservation{id, Eigen::Vector4d(1, 2, 0, 2)}; };
  session.observe({at(4), at(8)}, {2, 5}, estimator);
  session.observe({at(4), at(8)}, {3, 5}, estimator);
  session.observe({at(4)}, {3}, estimator);
  session.observe({at(9)}, {}, estimator);  // a frame whose detections carry no class
  std::vector<ObjectEstimate> objects(4);
  objects[0].id = 4;
  objects[1].id = 8;
  objects[2].id = 9;
  objects[3].id = 12;  // never detected
  EXPECT_EQ(session.object_classes(objects),
            (std::vector<int>{3, 5, association::kUnknownClass, association::kUnknownClass}));
}

TEST(DaemonAssociation, ASessionRefusesOwnerRecordsOfRobotsOutsideItsMembers) {
  // The daemon hands its session the configured members: a key holder's record made up for a
  // robot outside them is dropped and counted, a member's is taken.
  AssociationSession session(0, association::kWorldFrame, association::NegotiationOptions{},
                             {0, 1, 2});
  association::NegotiationMessage message;
  message.sender = 1;
  message.frame = association::kWorldFrame;
  for (const int owner : {1, 2, 40, 1 << 20})
    message.records.push_back(std::make_shared<const association::OwnerRecord>(
        association::OwnerRecord{owner, 1, {}, {}}));
  session.receive(message, 0);
  EXPECT_EQ(session.counters().records_refused, 2);
  EXPECT_EQ(session.counters().records_redundant, 0);
  session.receive(message, 1);  // the members' records again: held, so redundant
  EXPECT_EQ(session.counters().records_refused, 4);
  EXPECT_EQ(session.counters().records_redundant, 2);
}

TEST(DaemonAssociation, DaemonsInLockstepMatchTheNegotiatedReplay) {
  const fs::path out =
      fs::path(CONCORD_BINARY_DIR) / "test-out" / ("association-" + std::to_string(getpid()));
  fs::remove_all(out);
  const fs::path dataset_folder = out / "dataset";
  dataset::write_dataset(negotiated_team(kNegotiatedFrames), dataset_folder);

  launch::LaunchOptions options;
  options.dataset = dataset_folder;
  options.out = out / "team";
  options.concordd = CONCORD_DAEMON_PATH;
  options.estimator_config = kSource / "configs/sensors/sim.yaml";
  options.base_port = association_port(25);
  options.http_base_port = association_port(28) + 10;
  options.timeout = 240s;
  options.rate_hz =
      60.0;  // pacing (the lockstep results do not depend on it): time to ask /objects
  // While the team runs, robot 0 serves team ids in /objects (polled with a deadline).
  launch::LaunchResult result;
  std::atomic<bool> finished{false};
  std::thread team([&] {
    result = launch::launch_team(options, 3, nullptr);
    finished = true;
  });
  bool served_team_id = false;
  const auto deadline = std::chrono::steady_clock::now() + 240s;
  while (!finished && !served_team_id && std::chrono::steady_clock::now() < deadline) {
    if (const auto body =
            launch::http_get("127.0.0.1", options.http_base_port, "/objects", 1000ms)) {
      const auto objects = nlohmann::json::parse(*body, nullptr, false);
      if (!objects.is_discarded() && objects.contains("objects"))
        for (const auto& object : objects["objects"])
          served_team_id = served_team_id || object.value("team_id", -1) >= 0;
    }
    if (!served_team_id) std::this_thread::sleep_for(20ms);
  }
  team.join();
  EXPECT_TRUE(served_team_id) << "no object with a team id in robot 0's /objects";
  ASSERT_FALSE(result.timed_out);
  for (int code : result.exit_codes) ASSERT_EQ(code, 0);

  // The replay on the same files.
  const dataset::Dataset data = dataset::read_dataset(dataset_folder);
  const auto reference = replay::run_team(
      dataset::sensor_inputs(data), config::load_estimator_options(options.estimator_config), [&] {
        replay::ReplayOptions replay_options;
        replay_options.negotiation = config::load_negotiation_options(options.estimator_config);
        return replay_options;
      }());
  std::vector<std::vector<ObjectEstimate>> objects(3);
  std::vector<std::vector<LandmarkId>> team_ids(3), reference_ids(3);
  int moved = 0;
  for (int robot = 0; robot < 3; ++robot) {
    const auto& expected = reference.robots[robot];
    const fs::path folder = options.out / dataset::robot_folder_name(robot);
    const auto trajectory = dataset::read_trajectory_kitti(folder / "trajectory.kitti");
    ASSERT_EQ(trajectory.size(), expected.trajectory.size());
    for (std::size_t k = 0; k < trajectory.size(); ++k)
      ASSERT_TRUE(trajectory[k].isApprox(expected.trajectory[k], 1e-6))
          << "robot " << robot << " frame " << k;
    objects[robot] = dataset::read_objects_csv(folder / "objects.csv", &team_ids[robot]);
    ASSERT_EQ(objects[robot].size(), expected.objects.size());
    for (std::size_t o = 0; o < objects[robot].size(); ++o) {
      EXPECT_EQ(objects[robot][o].id, expected.objects[o].id);
      EXPECT_TRUE(objects[robot][o].p_world.isApprox(expected.objects[o].p_world, 1e-6));
    }
    reference_ids[robot] = expected.team_ids;
    const dataset::AlignmentRecord alignment =
        dataset::read_alignment_json(folder / "alignment.json");
    EXPECT_EQ(alignment.moved, expected.moved) << "robot " << robot;
    EXPECT_EQ(alignment.aligned_at_frame, expected.aligned_at_frame) << "robot " << robot;
    EXPECT_EQ(alignment.team_frame_robot, std::optional<int>(expected.trajectory_frames.back()));
    EXPECT_TRUE(alignment.T_team_own.isApprox(expected.T_team_own, 1e-6));
    moved += alignment.moved ? 1 : 0;
    std::ifstream stats_file(folder / "stats.json");
    const auto stats = nlohmann::json::parse(stats_file);
    EXPECT_EQ(stats["association"], "negotiated");
    EXPECT_EQ(stats["negotiation"]["negotiations_refused"], 0);
    EXPECT_GT(stats["negotiation"]["bytes_sent"].get<double>(), 0.0);
    // The negotiation's CPU time is counted, and is a part of the daemon's.
    const double negotiation_seconds = stats["negotiation"]["seconds"].get<double>();
    EXPECT_GT(negotiation_seconds, 0.0);
    EXPECT_LT(negotiation_seconds,
              stats["cpu_user_seconds"].get<double>() + stats["cpu_system_seconds"].get<double>());
    // Its parts add up to it; each was counted (every robot sends, receives and decides).
    double parts = 0.0;
    for (const char* part : {"encode", "decode", "decide", "relabel"}) {
      const double seconds = stats["negotiation"]["seconds_by_part"][part].get<double>();
      EXPECT_GT(seconds, 0.0) << part;
      parts += seconds;
    }
    EXPECT_NEAR(parts, negotiation_seconds, 1e-9 * (1.0 + negotiation_seconds));
  }
  expect_same_partition(objects, team_ids, reference_ids);
  EXPECT_GE(moved, 1);
}

}  // namespace
}  // namespace concord::daemon

// libFuzzer target: the negotiated association's decisions on what a hostile team member sends.
// fuzz_marginal checks the decoding of a Negotiation; here what from_wire accepts goes on, as
// robot 2's message, into robot 0's Negotiator for five describing rounds (robot 0 describing a
// map of its own each time, as a daemon does), so that descriptions, owner records, frame
// edges and their corrections reach the searches (robot 0 owns the pair with robot 2), the
// confirmations, the union-find of team ids and the moves into the team frame. Records that
// decide robot 0's objects or frame come from robot 1, relayed by robot 2 (robot 1 owns its
// pair with robot 0): robot 2's own on that pair are refused (records_not_owned). Never crash or
// hang, and whatever the negotiator decides stays usable: a move of the state it asks for is a
// finite rigid motion with a finite, symmetric covariance (the daemon applies it to its estimator),
// its own frame's transform stays finite, and each of robot 0's objects is shared with a neighbour
// once at most. Half the inputs meet a negotiator that knows the team's members: it relays no
// record of any other owner.
#include <Eigen/Geometry>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <set>
#include <string>
#include <utility>

#include "concord/association/negotiation.h"
#include "concord/daemon/negotiation_wire.h"
#include "concord/v1/concord.pb.h"

namespace {

using concord::association::MapDescription;
using concord::association::ObjectDescription;

/// Robot 0's own map in its start frame: twelve objects of two classes in an irregular layout
/// (not flat: its mirror image is no rival), well placed (the seeds hold the same layout moved
/// into robot 2's frame).
MapDescription own_map() {
  MapDescription map;
  map.robot = 0;
  map.frame = 0;
  const double xyz[12][3] = {{4.9, -4.2, 2.0},  {1.1, 0.4, 1.1},  {0.9, 0.1, 0.1},
                             {6.5, -5.2, 0.3},  {6.4, 3.9, 0.4},  {3.3, 1.5, 2.8},
                             {8.7, -1.2, 2.9},  {0.7, 4.3, 0.9},  {2.2, -4.6, 0.9},
                             {12.2, -3.8, 1.7}, {9.6, -1.5, 1.6}, {0.9, -5.3, 0.6}};
  for (int i = 0; i < 12; ++i) {
    ObjectDescription object;
    object.id = 100 + i;
    object.object_class = i % 2;
    object.position = Eigen::Vector3d(xyz[i][0], xyz[i][1], xyz[i][2]);
    object.covariance = 0.01 * Eigen::Matrix3d::Identity();
    object.local_covariance = 0.01 * Eigen::Matrix3d::Identity();
    object.observations = 20;
    map.objects.push_back(object);
  }
  return map;
}

/// Aborts (a finding) naming what did not hold.
void check(bool condition, const char* what) {
  if (condition) return;
  std::fprintf(stderr, "fuzz_negotiation: %s\n", what);
  std::abort();
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > (1 << 16)) return 0;
  concord::v1::Negotiation wire;
  if (!wire.ParseFromArray(data, static_cast<int>(size))) return 0;
  std::string error;
  const auto message =
      concord::daemon::from_wire(wire, 2, concord::daemon::NegotiationLimits{}, error);
  if (!message) return 0;

  static const MapDescription map = own_map();
  concord::association::Negotiator negotiator(0, 0, concord::association::NegotiationOptions{});
  // Half the inputs (by the first byte, the wire's first tag) meet a daemon's negotiator, which
  // holds owner records of its team's members only.
  const bool membership = size > 0 && (data[0] & 1) != 0;
  if (membership) negotiator.set_members({0, 1, 2, 3});
  const int interval = negotiator.options().description_interval;
  for (int k = 0; k < 5; ++k) {
    // Each description leaves out another object, as a robot's map changes: a search's
    // transform is confirmed only by descriptions that match objects the first did not.
    MapDescription described = map;
    described.objects.erase(described.objects.begin() + k);
    const int round = k * interval;
    negotiator.set_own_map(std::move(described), round);
    (void)negotiator.message_for(2, round);
    negotiator.receive(*message, round);
    if (const auto move = negotiator.finish_round(round)) {
      check(move->T_new_old.matrix().allFinite(), "a move of the state is finite");
      const Eigen::Matrix3d R = move->T_new_old.linear();
      check((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() < 1e-6,
            "a move's rotation is a rotation");
      check(move->covariance.allFinite(), "a move's covariance is finite");
      check((move->covariance - move->covariance.transpose()).cwiseAbs().maxCoeff() <=
                1e-9 * (1.0 + move->covariance.cwiseAbs().maxCoeff()),
            "a move's covariance is symmetric");
      check(move->independent.allFinite(), "a move's independent covariance is finite");
      check(move->pose_frame >= -1, "a move's correlated pose frame is -1 or a frame");
    }
    if (membership) {
      for (const auto& record : negotiator.message_for(3, round).records)
        check(record->owner >= 0 && record->owner <= 3, "a member relays members' records only");
    }
    check(negotiator.T_frame_start().matrix().allFinite(), "the start frame's transform is finite");
    check(negotiator.covariance_frame_start().allFinite(),
          "the start frame's covariance is finite");
    std::set<concord::LandmarkId> own;
    // A member's record may link robot 0's ids that it never described (an honest owner links
    // only what it was shown): robot 0 keeps such links in its union-find like every other member,
    // so that team ids agree across the team, and its consensus finds nothing of them to fuse.
    for (const auto& [own_id, other_id] : negotiator.shared_objects(2)) {
      check(own_id >= 0 && other_id >= 0, "shared ids are private ids");
      check(own.insert(own_id).second, "an object is shared with a neighbour once");
    }
  }
  return 0;
}

#pragma once
/// \file
/// What robots exchange to find out which of their objects are the same: a compact description of
/// each one's object map (class, position, covariance, how often it was observed) in the frame its
/// state is in, and the keys that name one robot's object in a team.

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <map>
#include <vector>

#include "concord/estimator/state.h"
#include "concord/estimator/types.h"

namespace concord::association {

/// Frame ids: a robot's start frame is named by the robot's index; kWorldFrame is the shared world
/// frame of robots whose start poses are known.
inline constexpr int kWorldFrame = -1;

/// Unknown class (the detector reports none).
inline constexpr int kUnknownClass = -1;

/// A robot's object in the team: (robot, private id) packed as robot * 2^40 + id. Private ids must
/// be in [0, 2^40) and robots in [0, 2^23) (asserted).
using ObjectKey = std::int64_t;
ObjectKey object_key(int robot, LandmarkId id);
int robot_of(ObjectKey key);
LandmarkId id_of(ObjectKey key);

/// One object as a robot describes it.
struct ObjectDescription {
  LandmarkId id = 0;  ///< the robot's private id
  int object_class = kUnknownClass;
  /// Position in the description's frame.
  Eigen::Vector3d position = Eigen::Vector3d::Zero();
  /// Marginal covariance of the position in the description's frame: for comparing positions of
  /// two maps in one frame.
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
  /// What the robot knows of the object relative to itself, without the drift its whole map
  /// shares: for the geometry of its map (distances between its objects, which a transform to
  /// another frame leaves as they are). In the state: the covariance conditioned on the robot's
  /// current pose. Archived: conditioned on the pose the robot had when it archived it
  /// (State::archived_local_covariance; the marginal when none was recorded), since the objects
  /// a robot mapped at about the same time share the drift it had then, however far it has
  /// drifted since. A search across frames takes an archived object's marginal instead unless
  /// association.archived_local_covariance (PreparedMap).
  Eigen::Matrix3d local_covariance = Eigen::Matrix3d::Identity();
  /// Whether the object has left the robot's joint state (archived), so that local_covariance
  /// is relative to an earlier pose than the current one.
  bool archived = false;
  /// The covariance a transform between this map and another frame's must account for: relative
  /// to the robot's current pose, as one transform aligns the maps where both robots are now. An
  /// archived object's error relative to that pose includes the drift since it was archived,
  /// which the description does not carry: its marginal stands for it.
  const Eigen::Matrix3d& transform_covariance() const {
    return archived ? covariance : local_covariance;
  }
  /// Frames in which the robot observed it.
  int observations = 0;
};

/// A robot's object map as it describes it to its neighbours.
struct MapDescription {
  int robot = 0;
  /// The frame its positions are in (kWorldFrame or the index of the robot whose start frame).
  int frame = kWorldFrame;
  /// Objects sorted by id.
  std::vector<ObjectDescription> objects;
  /// The robot's newest pose when it described the map (its frame index; -1 unknown) and that
  /// pose's covariance, a left perturbation in the description's frame: the map's drift. A map
  /// is right relative to the robot up to its local covariances, and the whole of it shares the
  /// pose's error in its frame, so a transform fitted on local covariances (alignment.h) leaves
  /// both maps' drift to be added (docs/association.md, "A move that keeps the map's drift").
  int pose_frame = -1;
  Eigen::Matrix<double, 6, 6> pose_covariance = Eigen::Matrix<double, 6, 6>::Zero();

  /// Bytes on the wire in a fixed-width encoding: 16 bytes of header and 21 floats (the pose's
  /// frame and covariance), then per object an 8-byte id, a 2-byte class, a 2-byte observation
  /// count, a 1-byte archived flag and 15 floats (position, upper triangles of both
  /// covariances).
  std::size_t wire_size() const;
};

/// What a robot counts of its own detections, per private id: frames observed, the votes for
/// each class (a detector may report different classes for one object), and misses: frames in
/// which the object was in view and not detected.
///
/// In view means in front of the left camera at the state's newest pose, within the depth range
/// (the 5 % to 95 % quantiles of the detections' depths) and the image region that the robot's
/// own detections have covered so far, shrunk by a tenth of its size on every side: the view is
/// learned from the detections themselves, with no image size or range to configure, and errs
/// towards counting no miss. A real object is detected in most frames that show it; a false
/// detection is not detected again where it was, though the robot still looks there (describe_map's
/// min_detection_ratio).
class ObservationTally {
 public:
  /// Adds one frame's detections, after the filter's step on that frame: classes is parallel to
  /// observations or empty (no classes). The detections count for their objects and extend the
  /// view (through `camera`); then each object of `state` in view at its newest pose that the
  /// frame did not detect counts a miss. Objects the robot never detected are not counted.
  void add(const std::vector<StereoObservation>& observations, const std::vector<int>& classes,
           const State& state, const StereoCamera& camera);
  int observations(LandmarkId id) const;
  int misses(LandmarkId id) const;
  /// The class with most votes (ties: the smallest), or kUnknownClass.
  int object_class(LandmarkId id) const;

 private:
  struct Entry {
    int frames = 0;
    int misses = 0;
    /// The add() call that last detected it (frames_added_ numbering).
    int last_detected = -1;
    std::map<int, int> votes;
  };
  std::map<LandmarkId, Entry> entries_;
  int frames_added_ = 0;
  /// The view so far: the extent of the detections in normalized left-image coordinates, and a
  /// histogram of their depths (from the disparity; log-spaced bins).
  bool view_known_ = false;
  Eigen::Vector2d view_min_ = Eigen::Vector2d::Zero(), view_max_ = Eigen::Vector2d::Zero();
  std::vector<long long> depth_histogram_;
  long long depths_ = 0;
};

/// The description of a robot's map: every object it holds with at least min_observations frames
/// of detections, in the frame the state is in. An archived object's local_covariance is the
/// one the state recorded when it archived it (when there is one, and the marginal is not the
/// smaller); otherwise its marginal. A search takes it only with
/// AssociationOptions::archived_local_covariance (PreparedMap). min_detection_ratio: an object
/// detected in fewer than this fraction of the frames it was in view (detections / (detections
/// + misses), ObservationTally) is left out as a likely false detection (0: none is).
MapDescription describe_map(const State& state, int robot, int frame, const ObservationTally& tally,
                            int min_observations, double min_detection_ratio = 0.0);

}  // namespace concord::association

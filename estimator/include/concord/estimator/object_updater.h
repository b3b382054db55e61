#pragma once
/// \file
/// Object landmarks (persistent features): the update of in-state objects from stereo
/// detections (§V-D) and the initialization of new ones (§V-E, eq. 29-30).

#include <map>
#include <vector>

#include "concord/estimator/options.h"
#include "concord/estimator/state.h"
#include "concord/estimator/updater_helper.h"

namespace concord {

/// What one frame's object processing did (counters for logs and metrics).
struct ObjectUpdateStats {
  int observations = 0;
  int updated = 0;      ///< observations used in the update
  int rejected = 0;     ///< observations rejected by the gates
  int initialized = 0;  ///< new objects added to the state
  int init_failed = 0;  ///< initialization attempts rejected
  int reactivated = 0;  ///< archived objects that rejoined the state
  int archived = 0;     ///< objects that left the joint state this frame
};

class ObjectUpdater {
 public:
  ObjectUpdater(const EstimatorOptions& options, const StereoCamera& camera);

  /// Processes the objects observed at the state's newest frame: 1. update with observations
  /// of in-state objects (gated), 2. initialize objects with enough observations in the window,
  /// 3. archive objects not observed for object_archive_after_frames.
  ObjectUpdateStats process(State& state, const std::vector<StereoObservation>& objects);

 private:
  /// Returns false when the observation is rejected by the gates.
  bool passes_gates(const State& state, const LinearizedTrack& linearized) const;
  bool try_initialize(State& state, LandmarkId id, const std::vector<TrackObservation>& track);
  void archive_stale(State& state, int frame, ObjectUpdateStats& stats) const;

  EstimatorOptions options_;
  StereoCamera camera_;
  double noise_variance_;  ///< normalized units squared
  double chi2_threshold_4dof_;
  /// Observations of objects not yet in the state, within the window.
  std::map<LandmarkId, std::vector<TrackObservation>> pending_;
};

}  // namespace concord

#pragma once
/// \file
/// The daemon's checkpoint (OUT/checkpoint.bin): the filter state (estimator/state.h is plain
/// data; it is serialized here, not in estimator/, which does no I/O), the round, and the
/// processed frames' trajectory. Written atomically with the outputs; read at start to resume.
/// The file is untrusted input: every count and value is checked, and a checksum detects a
/// damaged file.

#include <Eigen/Geometry>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "concord/estimator/object_updater.h"
#include "concord/estimator/state.h"

namespace concord::daemon {

struct Checkpoint {
  int robot_id = 0;
  /// The last round (frame index) processed.
  std::uint64_t round = 0;
  /// Every processed frame: frame index, timestamp and estimate (as in trajectory.kitti).
  std::vector<int> frames;
  std::vector<double> timestamps;
  std::vector<Eigen::Isometry3d> poses;
  /// The estimator's filter state after that round, and the object observations waiting for an
  /// initialization: with both the restored filter continues exactly.
  State state;
  PendingObjects pending;
};

/// The checkpoint as bytes.
[[nodiscard]] std::string serialize_checkpoint(const Checkpoint& checkpoint);
/// Parses bytes written by serialize_checkpoint; std::nullopt with `error` set if they are
/// damaged, truncated, of another format version, or hold non-finite or inconsistent values.
[[nodiscard]] std::optional<Checkpoint> parse_checkpoint(const std::string& bytes,
                                                         std::string& error);

}  // namespace concord::daemon

#pragma once
/// \file
/// Conversions between the estimator's types and the concord.v1 wire messages. Decoding checks
/// every size and number (a peer or sensor process may send anything) and says what is wrong;
/// encoding is exact (doubles travel bit for bit), so the network does not change the math.

#include <optional>
#include <string>
#include <vector>

#include "concord/estimator/marginal_sharing.h"
#include "concord/estimator/types.h"

namespace concord::v1 {
class Marginal;
class SensorFrame;
class Pose;
}  // namespace concord::v1

namespace concord::daemon {

/// Writes `marginal` into `out` (ids, mean, each covariance block as its packed upper triangle).
void to_wire(const Marginal& marginal, v1::Marginal& out);
/// The landmarks of `full` with keep[k] set (one flag a landmark, Consensus::kept_by), encoded
/// as to_wire encodes sub_marginal(full, keep), without making that copy.
void to_wire(const Marginal& full, const std::vector<bool>& keep, v1::Marginal& out);
/// The float32 form (consensus.share_float32); from_wire reads either.
void to_wire(const CompactMarginal& marginal, v1::Marginal& out);
/// The Marginal a message carries, or std::nullopt with `error` saying what is malformed.
[[nodiscard]] std::optional<Marginal> from_wire(const v1::Marginal& message, std::string& error);
/// The same into `out`, reusing its storage (covariance blocks of the sizes it already holds are
/// overwritten, not allocated again); false with `error` set when malformed (`out` then holds
/// no meaningful marginal).
[[nodiscard]] bool from_wire(const v1::Marginal& message, std::string& error, Marginal& out);

void to_wire(const Eigen::Isometry3d& pose, v1::Pose& out);
/// Rejects non-finite values and quaternions far from unit length (normalizes the rest).
[[nodiscard]] std::optional<Eigen::Isometry3d> from_wire(const v1::Pose& message,
                                                         std::string& error);

/// A frame as a SensorFrame message (timestamp = frame index when none is known), with the class
/// of each object observation when `object_classes` is given (parallel to frame.objects).
void to_wire(const FrameInput& frame, double timestamp, v1::SensorFrame& out,
             const std::vector<int>* object_classes = nullptr);
/// The FrameInput a SensorFrame carries, or std::nullopt with `error` saying what is malformed
/// (negative frame index, bad odometry pose, non-finite observations, object classes that are
/// not one per object observation or above frontend::kMaxClassNumber). `object_classes`, when
/// given, receives the classes (empty when the message has none).
[[nodiscard]] std::optional<FrameInput> from_wire(const v1::SensorFrame& message,
                                                  std::string& error,
                                                  std::vector<int>* object_classes = nullptr);

}  // namespace concord::daemon

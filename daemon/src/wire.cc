#include "concord/daemon/wire.h"

#include <Eigen/Cholesky>
#include <cmath>

#include "concord/frontend/detections.h"
#include "concord/v1/concord.pb.h"

namespace concord::daemon {

namespace {

void to_wire(const StereoObservation& observation, v1::StereoObservation& out) {
  out.set_id(observation.id);
  out.set_u_left(observation.uv[0]);
  out.set_v_left(observation.uv[1]);
  out.set_u_right(observation.uv[2]);
  out.set_v_right(observation.uv[3]);
  out.set_sigma_left(observation.sigma(0));
  out.set_sigma_right(observation.sigma(1));
}

bool from_wire(const google::protobuf::RepeatedPtrField<v1::StereoObservation>& messages,
               std::vector<StereoObservation>& out, const char* what, std::string& error) {
  out.reserve(static_cast<std::size_t>(messages.size()));
  for (const v1::StereoObservation& message : messages) {
    StereoObservation observation;
    observation.id = message.id();
    observation.uv = {message.u_left(), message.v_left(), message.u_right(), message.v_right()};
    if (!observation.uv.allFinite()) {
      error = std::string(what) + " observation of id " + std::to_string(observation.id) +
              " has a non-finite coordinate";
      return false;
    }
    observation.sigma = {message.sigma_left(), message.sigma_right()};
    if (!valid_observation_sigma(observation.sigma)) {
      error = std::string(what) + " observation of id " + std::to_string(observation.id) +
              ": sigma_left and sigma_right must both be > 0 or both 0 (from 1e-6 to 1e6 "
              "when given)";
      return false;
    }
    out.push_back(observation);
  }
  return true;
}

}  // namespace

void to_wire(const Marginal& marginal, v1::Marginal& out) {
  out.mutable_landmark_ids()->Assign(marginal.ids.begin(), marginal.ids.end());
  out.mutable_mean()->Assign(marginal.mean.data(), marginal.mean.data() + marginal.mean.size());
  auto* sizes = out.mutable_block_landmarks();
  auto* packed = out.mutable_packed_upper();
  Eigen::Index values = 0;
  for (const Eigen::MatrixXd& block : marginal.blocks) values += block.rows() * (block.rows() + 1) / 2;
  sizes->Reserve(static_cast<int>(marginal.blocks.size()));
  packed->Reserve(static_cast<int>(values));
  for (const Eigen::MatrixXd& block : marginal.blocks) {
    sizes->AddAlreadyReserved(static_cast<std::uint32_t>(block.rows() / 3));
    for (Eigen::Index row = 0; row < block.rows(); ++row) {
      for (Eigen::Index column = row; column < block.cols(); ++column) {
        packed->AddAlreadyReserved(block(row, column));
      }
    }
  }
}

void to_wire(const Marginal& full, const std::vector<bool>& keep, v1::Marginal& out) {
  thread_local CutLayout layout;
  layout.assign(full, keep);
  out.clear_landmark_ids();
  out.clear_mean();
  for (const Eigen::Index position : layout.kept) {
    out.add_landmark_ids(full.ids[static_cast<std::size_t>(position)]);
    for (int axis = 0; axis < 3; ++axis) out.add_mean(full.mean(3 * position + axis));
  }
  auto* sizes = out.mutable_block_landmarks();
  auto* packed = out.mutable_packed_upper();
  sizes->Clear();
  packed->Clear();
  Eigen::Index values = 0;
  for (const CutLayout::Block& cut : layout.blocks)
    values += 3 * cut.size() * (3 * cut.size() + 1) / 2;
  packed->Reserve(static_cast<int>(values));
  for (std::size_t b = 0; b < layout.blocks.size(); ++b) {
    const CutLayout::Block& cut = layout.blocks[b];
    const Eigen::Index n = cut.size();
    if (n == 0) continue;
    sizes->Add(static_cast<std::uint32_t>(n));
    const Eigen::MatrixXd& source = full.blocks[b];
    for (Eigen::Index r = 0; r < 3 * n; ++r) {
      const Eigen::Index source_row = layout.source_row(cut, r);
      for (Eigen::Index c = r; c < 3 * n; ++c) {
        packed->AddAlreadyReserved(source(source_row, layout.source_row(cut, c)));
      }
    }
  }
}

void to_wire(const CompactMarginal& marginal, v1::Marginal& out) {
  out.mutable_landmark_ids()->Assign(marginal.ids.begin(), marginal.ids.end());
  out.mutable_origin()->Assign(marginal.origin.data(), marginal.origin.data() + 3);
  out.mutable_mean_offsets()->Assign(marginal.mean_offsets.begin(), marginal.mean_offsets.end());
  for (const CompactMarginal::Block& block : marginal.blocks) {
    v1::CovarianceBlock* message = out.add_blocks();
    message->set_landmarks(static_cast<std::uint32_t>(block.landmarks));
    message->mutable_cholesky_lower()->Assign(block.cholesky_lower.begin(),
                                              block.cholesky_lower.end());
    message->mutable_packed_upper()->Assign(block.packed_upper.begin(), block.packed_upper.end());
  }
}

namespace {

/// A block of `landmarks` fits after `covered` of a marginal's k landmarks.
bool block_fits(std::size_t landmarks, std::size_t covered, std::size_t k, std::string& error) {
  if (landmarks != 0 && covered + landmarks <= k) return true;
  error = "marginal: covariance blocks do not match the " + std::to_string(k) + " landmarks";
  return false;
}

/// The blocks covered every one of the k landmarks.
bool blocks_cover(std::size_t covered, std::size_t k, std::string& error) {
  if (covered == k) return true;
  error = "marginal: covariance blocks cover " + std::to_string(covered) + " of " +
          std::to_string(k) + " landmarks";
  return false;
}

/// The float32 form (origin and mean_offsets present): every size checked before anything is
/// read, then expanded; the reconstructed marginal must be finite and well formed.
std::optional<Marginal> compact_from_wire(const v1::Marginal& message, std::string& error) {
  const auto k = static_cast<std::size_t>(message.landmark_ids_size());
  if (message.block_landmarks_size() != 0 || message.packed_upper_size() != 0) {
    error = "marginal (float32): covariance blocks in both forms";
    return std::nullopt;
  }
  if (message.origin_size() != 3 || static_cast<std::size_t>(message.mean_offsets_size()) != 3 * k ||
      message.mean_size() != 0) {
    error = "marginal (float32): " + std::to_string(message.origin_size()) + " origin and " +
            std::to_string(message.mean_offsets_size()) + " offset values for " +
            std::to_string(k) + " landmarks";
    return std::nullopt;
  }
  CompactMarginal compact;
  compact.ids.assign(message.landmark_ids().begin(), message.landmark_ids().end());
  compact.origin = Eigen::Vector3d(message.origin(0), message.origin(1), message.origin(2));
  compact.mean_offsets.assign(message.mean_offsets().begin(), message.mean_offsets().end());
  std::size_t covered = 0;
  for (const v1::CovarianceBlock& block : message.blocks()) {
    const std::size_t landmarks = block.landmarks();
    if (!block_fits(landmarks, covered, k, error)) return std::nullopt;
    const std::size_t d = 3 * landmarks;
    const std::size_t triangle = d * (d + 1) / 2;
    const auto floats = static_cast<std::size_t>(block.cholesky_lower_size());
    const auto doubles = static_cast<std::size_t>(block.packed_upper_size());
    if (!((floats == triangle && doubles == 0) || (floats == 0 && doubles == triangle))) {
      error = "marginal: a block of " + std::to_string(landmarks) + " landmarks needs " +
              std::to_string(triangle) + " values, got " + std::to_string(floats) +
              " float and " + std::to_string(doubles) + " double";
      return std::nullopt;
    }
    CompactMarginal::Block out;
    out.landmarks = static_cast<int>(landmarks);
    out.cholesky_lower.assign(block.cholesky_lower().begin(), block.cholesky_lower().end());
    out.packed_upper.assign(block.packed_upper().begin(), block.packed_upper().end());
    compact.blocks.push_back(std::move(out));
    covered += landmarks;
  }
  if (!blocks_cover(covered, k, error)) return std::nullopt;
  Marginal marginal = expand(compact);
  if (marginal.ids.size() != k || !marginal.well_formed()) {
    error = "marginal (float32): non-finite mean or covariance";
    return std::nullopt;
  }
  return marginal;
}

}  // namespace

std::optional<Marginal> from_wire(const v1::Marginal& message, std::string& error) {
  Marginal marginal;
  if (!from_wire(message, error, marginal)) return std::nullopt;
  return marginal;
}

bool from_wire(const v1::Marginal& message, std::string& error, Marginal& marginal) {
  if (message.origin_size() > 0 || message.mean_offsets_size() > 0) {
    std::optional<Marginal> compact = compact_from_wire(message, error);
    if (!compact) return false;
    marginal = std::move(*compact);
    return true;
  }
  const auto k = static_cast<std::size_t>(message.landmark_ids_size());
  if (static_cast<std::size_t>(message.mean_size()) != 3 * k) {
    error = "marginal: " + std::to_string(message.mean_size()) + " mean values for " +
            std::to_string(k) + " landmarks";
    return false;
  }
  marginal.ids.assign(message.landmark_ids().begin(), message.landmark_ids().end());
  marginal.mean = Eigen::Map<const Eigen::VectorXd>(message.mean().data(), message.mean_size());
  std::size_t covered = 0;
  const bool flat = message.block_landmarks_size() > 0 || message.packed_upper_size() > 0;
  if (flat && message.blocks_size() > 0) {
    error = "marginal: covariance blocks in both forms";
    return false;
  }
  std::size_t blocks_used = 0;
  // Every block's size is checked against the landmarks and the values left before it is read.
  const auto read_block = [&](std::size_t landmarks, const double* values, std::size_t available,
                              std::size_t& used) {
    if (!block_fits(landmarks, covered, k, error)) return false;
    const auto d = static_cast<Eigen::Index>(3 * landmarks);
    const auto needed = static_cast<std::size_t>(d * (d + 1) / 2);
    if (available != needed && !(flat && available > needed)) {
      error = "marginal: a block of " + std::to_string(landmarks) + " landmarks needs " +
              std::to_string(needed) + " packed values, got " + std::to_string(available);
      return false;
    }
    if (blocks_used == marginal.blocks.size()) marginal.blocks.emplace_back();
    Eigen::MatrixXd& covariance = marginal.blocks[blocks_used++];  // storage reused
    if (covariance.rows() != d || covariance.cols() != d) covariance.resize(d, d);
    std::size_t index = 0;
    for (Eigen::Index row = 0; row < d; ++row) {
      for (Eigen::Index column = row; column < d; ++column) {
        covariance(row, column) = covariance(column, row) = values[index++];
      }
    }
    used = needed;
    covered += landmarks;
    return true;
  };
  if (flat) {
    const auto total = static_cast<std::size_t>(message.packed_upper_size());
    std::size_t offset = 0;
    for (const std::uint32_t landmarks : message.block_landmarks()) {
      std::size_t used = 0;
      if (!read_block(landmarks, message.packed_upper().data() + offset, total - offset, used)) {
        return false;
      }
      offset += used;
    }
    if (offset != total) {
      error = "marginal: " + std::to_string(total - offset) +
              " packed values beyond the covariance blocks";
      return false;
    }
  } else {
    for (const v1::CovarianceBlock& block : message.blocks()) {
      std::size_t used = 0;
      if (!read_block(block.landmarks(), block.packed_upper().data(),
                      static_cast<std::size_t>(block.packed_upper_size()), used)) {
        return false;
      }
    }
  }
  marginal.blocks.resize(blocks_used);
  if (!blocks_cover(covered, k, error)) return false;
  if (!marginal.well_formed()) {
    error = "marginal: non-finite mean or covariance";
    return false;
  }
  return true;
}

void to_wire(const Eigen::Isometry3d& pose, v1::Pose& out) {
  const Eigen::Quaterniond q(pose.rotation());
  out.set_x(pose.translation().x());
  out.set_y(pose.translation().y());
  out.set_z(pose.translation().z());
  out.set_qw(q.w());
  out.set_qx(q.x());
  out.set_qy(q.y());
  out.set_qz(q.z());
}

std::optional<Eigen::Isometry3d> from_wire(const v1::Pose& message, std::string& error) {
  const Eigen::Vector3d t(message.x(), message.y(), message.z());
  Eigen::Quaterniond q(message.qw(), message.qx(), message.qy(), message.qz());
  if (!t.allFinite() || !q.coeffs().allFinite()) {
    error = "pose: non-finite value";
    return std::nullopt;
  }
  if (std::abs(q.norm() - 1.0) > 1e-3) {
    error = "pose: quaternion norm " + std::to_string(q.norm()) + " is not 1";
    return std::nullopt;
  }
  q.normalize();
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = q.toRotationMatrix();
  pose.translation() = t;
  return pose;
}

void to_wire(const FrameInput& frame, double timestamp, v1::SensorFrame& out,
             const std::vector<int>* object_classes) {
  out.set_frame(frame.frame);
  out.set_timestamp(timestamp);
  if (frame.T_previous_current) to_wire(*frame.T_previous_current, *out.mutable_odometry());
  if (frame.odometry_covariance) {
    for (int row = 0; row < 6; ++row)
      for (int column = row; column < 6; ++column)
        out.add_odometry_covariance((*frame.odometry_covariance)(row, column));
  }
  for (const auto& observation : frame.objects) to_wire(observation, *out.add_objects());
  for (const auto& observation : frame.features) to_wire(observation, *out.add_features());
  if (object_classes != nullptr) {
    for (const int object_class : *object_classes)
      out.add_object_classes(static_cast<std::uint32_t>(object_class));
  }
}

std::optional<FrameInput> from_wire(const v1::SensorFrame& message, std::string& error,
                                    std::vector<int>* object_classes) {
  FrameInput frame;
  if (message.frame() < 0 || message.frame() > std::numeric_limits<int>::max()) {
    error = "sensor frame: frame index " + std::to_string(message.frame()) + " out of range";
    return std::nullopt;
  }
  frame.frame = static_cast<int>(message.frame());
  if (message.has_odometry()) {
    auto pose = from_wire(message.odometry(), error);
    if (!pose) {
      error = "sensor frame " + std::to_string(frame.frame) + ": odometry " + error;
      return std::nullopt;
    }
    frame.T_previous_current = *pose;
  }
  if (message.odometry_covariance_size() != 0) {
    // 6x6 on [rho; phi], upper triangle row by row: validated (finite, symmetric positive
    // definite), then it replaces the configured odometry noise for this frame.
    if (message.odometry_covariance_size() != 21) {
      error = "sensor frame " + std::to_string(frame.frame) + ": odometry_covariance has " +
              std::to_string(message.odometry_covariance_size()) + " values, expected 21 or none";
      return std::nullopt;
    }
    Eigen::Matrix<double, 6, 6> covariance;
    int index = 0;
    for (int row = 0; row < 6; ++row)
      for (int column = row; column < 6; ++column)
        covariance(row, column) = covariance(column, row) = message.odometry_covariance(index++);
    if (!covariance.allFinite() ||
        Eigen::LLT<Eigen::Matrix<double, 6, 6>>(covariance).info() != Eigen::Success) {
      error = "sensor frame " + std::to_string(frame.frame) +
              ": odometry_covariance is not finite and positive definite";
      return std::nullopt;
    }
    frame.odometry_covariance = covariance;
  }
  if (!from_wire(message.objects(), frame.objects, "object", error) ||
      !from_wire(message.features(), frame.features, "feature", error)) {
    error = "sensor frame " + std::to_string(frame.frame) + ": " + error;
    return std::nullopt;
  }
  if (message.object_classes_size() != 0) {
    if (message.object_classes_size() != message.objects_size()) {
      error = "sensor frame " + std::to_string(frame.frame) + ": " +
              std::to_string(message.object_classes_size()) + " object classes for " +
              std::to_string(message.objects_size()) + " objects, expected one each or none";
      return std::nullopt;
    }
    for (const std::uint32_t object_class : message.object_classes()) {
      if (object_class > static_cast<std::uint32_t>(frontend::kMaxClassNumber)) {
        error = "sensor frame " + std::to_string(frame.frame) + ": object class " +
                std::to_string(object_class) + " above " +
                std::to_string(frontend::kMaxClassNumber);
        return std::nullopt;
      }
    }
  }
  if (object_classes != nullptr)
    object_classes->assign(message.object_classes().begin(), message.object_classes().end());
  return frame;
}

}  // namespace concord::daemon

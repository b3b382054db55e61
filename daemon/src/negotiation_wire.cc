#include "concord/daemon/negotiation_wire.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

#include "concord/estimator/symmetric3.h"
#include "concord/v1/concord.pb.h"

namespace concord::daemon {

namespace {

constexpr std::int64_t kMaxPrivateId = (std::int64_t{1} << 40) - 1;
constexpr int kMaxRobot = (1 << 23) - 1;

template <int N>
void add_upper(const Eigen::Matrix<double, N, N>& matrix,
               google::protobuf::RepeatedField<double>& out) {
  for (int row = 0; row < N; ++row)
    for (int column = row; column < N; ++column) out.Add(matrix(row, column));
}

/// The largest magnitude of a covariance entry a peer may send (m^2, rad^2, m rad): a standard
/// deviation of 10^6 m. Larger values say nothing a robot can use, and sums of them (a move
/// composes several) could overflow.
constexpr double kMaxCovarianceEntry = 1e12;

/// A symmetric matrix from its packed upper triangle; false unless finite, bounded
/// (kMaxCovarianceEntry) and positive definite.
template <int N>
bool read_upper(const google::protobuf::RepeatedField<double>& values,
                Eigen::Matrix<double, N, N>& out) {
  if (values.size() != N * (N + 1) / 2) return false;
  int index = 0;
  for (int row = 0; row < N; ++row)
    for (int column = row; column < N; ++column)
      out(row, column) = out(column, row) = values.Get(index++);
  if (!out.allFinite() || out.cwiseAbs().maxCoeff() > kMaxCovarianceEntry) return false;
  // An object's covariance (two per described object) in closed form, as often as descriptions
  // come.
  if constexpr (N == 3) return symmetric3::positive_definite(symmetric3::lower_of(out));
  return Eigen::LLT<Eigen::Matrix<double, N, N>>(out).info() == Eigen::Success;
}

/// A covariance that may be zero: none (zero), or 21 finite values of a positive semi-definite
/// matrix.
bool read_upper_or_zero(const google::protobuf::RepeatedField<double>& values,
                        Eigen::Matrix<double, 6, 6>& out) {
  out.setZero();
  if (values.empty()) return true;
  if (values.size() != 21) return false;
  int index = 0;
  for (int row = 0; row < 6; ++row)
    for (int column = row; column < 6; ++column)
      out(row, column) = out(column, row) = values.Get(index++);
  if (!out.allFinite() || out.cwiseAbs().maxCoeff() > kMaxCovarianceEntry) return false;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> solver(out,
                                                                          Eigen::EigenvaluesOnly);
  return solver.info() == Eigen::Success &&
         solver.eigenvalues().minCoeff() >= -1e-9 * std::max(1.0, solver.eigenvalues().maxCoeff());
}

/// A pose's frame index: -1 (unknown) or a frame.
bool valid_pose_frame(std::int64_t frame) {
  return frame >= -1 && frame <= std::numeric_limits<int>::max();
}

bool valid_frame(int frame) { return frame >= association::kWorldFrame && frame <= kMaxRobot; }

/// Corrections of one frame edge a peer may send (an owner makes at most
/// association.max_corrections of them).
constexpr int kMaxCorrectionsPerEdge = 16;

/// A rigid motion from 12 values ([R | t] row by row); false unless finite and rigid.
bool read_rigid(const google::protobuf::RepeatedField<double>& values, Eigen::Isometry3d& out) {
  if (values.size() != 12) return false;
  Eigen::Matrix<double, 3, 4> matrix;
  for (int row = 0; row < 3; ++row)
    for (int column = 0; column < 4; ++column) matrix(row, column) = values.Get(4 * row + column);
  const Eigen::Matrix3d R = matrix.leftCols<3>();
  if (!matrix.allFinite() ||
      (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > 1e-6 ||
      R.determinant() < 0.0) {
    return false;
  }
  out = Eigen::Isometry3d::Identity();
  out.linear() = R;
  out.translation() = matrix.col(3);
  return true;
}

void add_rigid(const Eigen::Isometry3d& T, google::protobuf::RepeatedField<double>& out) {
  for (int row = 0; row < 3; ++row) {
    for (int column = 0; column < 3; ++column) out.Add(T.linear()(row, column));
    out.Add(T.translation()(row));
  }
}

bool valid_key(association::ObjectKey key) {
  return key >= 0 && association::robot_of(key) <= kMaxRobot;
}

bool read_map(const v1::MapDescription& message, int sender, const NegotiationLimits& limits,
              association::MapDescription& map, std::string& error) {
  if (message.objects_size() > limits.max_description_objects) {
    error = "description of " + std::to_string(message.objects_size()) +
            " objects, above the limit of " + std::to_string(limits.max_description_objects);
    return false;
  }
  map.robot = sender;
  map.frame = message.frame();
  if (!valid_pose_frame(message.pose_frame()) ||
      !read_upper_or_zero(message.pose_covariance(), map.pose_covariance)) {
    error =
        "description pose: frame out of range or covariance not 21 finite values of a "
        "positive semi-definite matrix";
    return false;
  }
  map.pose_frame = static_cast<int>(message.pose_frame());
  map.objects.reserve(static_cast<std::size_t>(message.objects_size()));
  for (const v1::ObjectDescription& object : message.objects()) {
    association::ObjectDescription entry;
    entry.id = object.id();
    // The error's prefix, made only for an error (a description holds hundreds of objects).
    const auto what = [&entry] { return "description object " + std::to_string(entry.id); };
    if (entry.id < 0 || entry.id > kMaxPrivateId) {
      error = what() + ": id out of range";
      return false;
    }
    if (!map.objects.empty() && entry.id <= map.objects.back().id) {
      error = what() + ": ids not sorted and unique";
      return false;
    }
    if (object.object_class() < association::kUnknownClass) {
      error = what() + ": class " + std::to_string(object.object_class());
      return false;
    }
    entry.object_class = object.object_class();
    if (object.observations() > static_cast<std::uint32_t>(std::numeric_limits<int>::max())) {
      error = what() + ": observation count out of range";
      return false;
    }
    entry.observations = static_cast<int>(object.observations());
    if (object.position_size() != 3) {
      error = what() + ": position of " + std::to_string(object.position_size()) + " values";
      return false;
    }
    entry.position = Eigen::Vector3d(object.position(0), object.position(1), object.position(2));
    if (!entry.position.allFinite()) {
      error = what() + ": non-finite position";
      return false;
    }
    if (!read_upper<3>(object.covariance(), entry.covariance) ||
        !read_upper<3>(object.local_covariance(), entry.local_covariance)) {
      error = what() + ": covariance not 6 finite values of a positive definite matrix";
      return false;
    }
    entry.archived = object.archived();
    map.objects.push_back(std::move(entry));
  }
  return true;
}

bool read_record(const v1::OwnerRecord& message, const NegotiationLimits& limits,
                 association::OwnerRecord& record, std::string& error) {
  const std::string what = "owner record of robot " + std::to_string(message.owner());
  if (message.owner() > static_cast<std::uint32_t>(kMaxRobot) ||
      message.version() > static_cast<std::uint32_t>(std::numeric_limits<int>::max())) {
    error = what + ": owner or version out of range";
    return false;
  }
  if (message.links_size() > limits.max_links_per_record ||
      message.frame_edges_size() > limits.max_frame_edges_per_record) {
    error = what + ": " + std::to_string(message.links_size()) + " links and " +
            std::to_string(message.frame_edges_size()) + " frame edges, above the limits";
    return false;
  }
  if (!message.signature().empty() && message.signature().size() != net::kSignatureBytes) {
    error = what + ": signature of " + std::to_string(message.signature().size()) +
            " bytes (expected " + std::to_string(net::kSignatureBytes) + ")";
    return false;
  }
  record.owner = static_cast<int>(message.owner());
  record.version = static_cast<int>(message.version());
  record.signature = message.signature();
  for (const v1::ObjectLink& link : message.links()) {
    // An owner links one of its own objects with another robot's, the smaller key first.
    const bool ours = association::robot_of(link.a()) == record.owner ||
                      association::robot_of(link.b()) == record.owner;
    if (!valid_key(link.a()) || !valid_key(link.b()) || link.a() >= link.b() || !ours ||
        association::robot_of(link.a()) == association::robot_of(link.b()) ||
        !std::isfinite(link.mahalanobis_squared()) || link.mahalanobis_squared() < 0.0) {
      error =
          what + ": malformed link " + std::to_string(link.a()) + "-" + std::to_string(link.b());
      return false;
    }
    record.links.push_back({link.a(), link.b(), link.mahalanobis_squared()});
  }
  for (const v1::FrameEdge& edge : message.frame_edges()) {
    association::FrameEdge out;
    out.frame_a = edge.frame_a();
    out.frame_b = edge.frame_b();
    if (!valid_frame(out.frame_a) || !valid_frame(out.frame_b) || out.frame_a == out.frame_b ||
        edge.owner() != message.owner() || edge.round() < 0 ||
        edge.round() > std::numeric_limits<int>::max() || edge.t_a_b_size() != 12 ||
        edge.corrections_size() > kMaxCorrectionsPerEdge) {
      error = what + ": malformed frame edge";
      return false;
    }
    out.owner = record.owner;
    out.round = static_cast<int>(edge.round());
    if (!read_rigid(edge.t_a_b(), out.T_a_b)) {
      error = what + ": frame edge transform is not a finite rigid motion";
      return false;
    }
    if (!read_upper<6>(edge.covariance(), out.covariance)) {
      error = what + ": frame edge covariance not 21 finite values of a positive definite matrix";
      return false;
    }
    if (edge.robot_b() > static_cast<std::uint32_t>(kMaxRobot) ||
        edge.robot_b() == message.owner() || !valid_pose_frame(edge.pose_frame_a()) ||
        !valid_pose_frame(edge.pose_frame_b()) ||
        !read_upper_or_zero(edge.drift_a(), out.drift_a) ||
        !read_upper_or_zero(edge.drift_b(), out.drift_b)) {
      error = what + ": frame edge drift malformed (robot, pose frames or covariances)";
      return false;
    }
    out.robot_b = static_cast<int>(edge.robot_b());
    out.pose_frame_a = static_cast<int>(edge.pose_frame_a());
    out.pose_frame_b = static_cast<int>(edge.pose_frame_b());
    for (const v1::FrameCorrection& correction : edge.corrections()) {
      association::FrameCorrection in;
      in.frame = correction.frame();
      in.moves_b_side = correction.moves_b_side();
      if (!valid_frame(in.frame) || correction.round() < 0 ||
          correction.round() > std::numeric_limits<int>::max() ||
          !read_rigid(correction.t(), in.T) ||
          !read_upper<6>(correction.covariance(), in.covariance)) {
        error = what + ": malformed frame edge correction";
        return false;
      }
      in.round = static_cast<int>(correction.round());
      out.corrections.push_back(in);
    }
    record.frame_edges.push_back(out);
  }
  return true;
}

}  // namespace

void to_wire(const association::MapDescription& map, v1::MapDescription& out) {
  out.Clear();
  out.set_frame(map.frame);
  out.set_pose_frame(map.pose_frame);
  add_upper<6>(map.pose_covariance, *out.mutable_pose_covariance());
  out.mutable_objects()->Reserve(static_cast<int>(map.objects.size()));
  for (const association::ObjectDescription& object : map.objects) {
    v1::ObjectDescription* entry = out.add_objects();
    entry->set_id(object.id);
    entry->set_object_class(object.object_class);
    entry->set_observations(static_cast<std::uint32_t>(std::max(object.observations, 0)));
    entry->mutable_position()->Add(object.position.data(), object.position.data() + 3);
    add_upper<3>(object.covariance, *entry->mutable_covariance());
    add_upper<3>(object.local_covariance, *entry->mutable_local_covariance());
    entry->set_archived(object.archived);
  }
}

namespace {

/// Everything of `message` but its map description: the frame, the held versions, the records.
void write_all_but_map(const association::NegotiationMessage& message, v1::Negotiation& out,
                       const RecordSigner* signer) {
  out.set_frame(message.frame);
  for (const auto& [owner, version] : message.held) {
    v1::RecordVersion* entry = out.add_held();
    entry->set_owner(static_cast<std::uint32_t>(owner));
    entry->set_version(static_cast<std::uint32_t>(version));
  }
  for (const auto& shared : message.records) {
    if (!shared) continue;
    const association::OwnerRecord& record = *shared;
    v1::OwnerRecord* entry = out.add_records();
    entry->set_owner(static_cast<std::uint32_t>(record.owner));
    entry->set_version(static_cast<std::uint32_t>(record.version));
    // The owner's signature as received, or this robot's of its own record.
    const std::string signature = signer ? signer->signature_of(record) : record.signature;
    if (!signature.empty()) entry->set_signature(signature);
    for (const association::ObjectLink& link : record.links) {
      v1::ObjectLink* l = entry->add_links();
      l->set_a(link.a);
      l->set_b(link.b);
      l->set_mahalanobis_squared(link.mahalanobis_squared);
    }
    for (const association::FrameEdge& edge : record.frame_edges) {
      v1::FrameEdge* e = entry->add_frame_edges();
      e->set_frame_a(edge.frame_a);
      e->set_frame_b(edge.frame_b);
      add_rigid(edge.T_a_b, *e->mutable_t_a_b());
      add_upper<6>(edge.covariance, *e->mutable_covariance());
      e->set_round(edge.round);
      e->set_owner(static_cast<std::uint32_t>(edge.owner));
      e->set_robot_b(static_cast<std::uint32_t>(edge.robot_b));
      add_upper<6>(edge.drift_a, *e->mutable_drift_a());
      add_upper<6>(edge.drift_b, *e->mutable_drift_b());
      e->set_pose_frame_a(edge.pose_frame_a);
      e->set_pose_frame_b(edge.pose_frame_b);
      for (const association::FrameCorrection& correction : edge.corrections) {
        v1::FrameCorrection* c = e->add_corrections();
        c->set_frame(correction.frame);
        c->set_moves_b_side(correction.moves_b_side);
        add_rigid(correction.T, *c->mutable_t());
        add_upper<6>(correction.covariance, *c->mutable_covariance());
        c->set_round(correction.round);
      }
    }
  }
}

}  // namespace

void to_wire(const association::NegotiationMessage& message, v1::Negotiation& out,
             const RecordSigner* signer) {
  if (message.map) to_wire(*message.map, *out.mutable_map());
  write_all_but_map(message, out, signer);
}

void to_wire(const association::NegotiationMessage& message, const v1::MapDescription& map,
             v1::Negotiation& out, const RecordSigner* signer) {
  if (message.map) *out.mutable_map() = map;
  write_all_but_map(message, out, signer);
}

std::optional<association::NegotiationMessage> from_wire(const v1::Negotiation& message, int sender,
                                                         const NegotiationLimits& limits,
                                                         std::string& error,
                                                         const RecordSigner* signer,
                                                         std::uint64_t* records_unsigned) {
  association::NegotiationMessage out;
  out.sender = sender;
  out.frame = message.frame();
  if (sender < 0 || sender > kMaxRobot || !valid_frame(out.frame)) {
    error = "negotiation: sender or frame out of range";
    return std::nullopt;
  }
  if (message.has_map()) {
    association::MapDescription map;
    if (!read_map(message.map(), sender, limits, map, error)) {
      error = "negotiation: " + error;
      return std::nullopt;
    }
    if (map.frame != out.frame) {
      error = "negotiation: description in frame " + std::to_string(map.frame) +
              ", sender in frame " + std::to_string(out.frame);
      return std::nullopt;
    }
    out.map = std::make_shared<const association::MapDescription>(std::move(map));
  }
  if (message.records_size() > limits.max_records) {
    error = "negotiation: " + std::to_string(message.records_size()) +
            " owner records, above the limit of " + std::to_string(limits.max_records);
    return std::nullopt;
  }
  for (const v1::OwnerRecord& record : message.records()) {
    association::OwnerRecord entry;
    if (!read_record(record, limits, entry, error)) {
      error = "negotiation: " + error;
      return std::nullopt;
    }
    if (signer && !signer->verifies(entry)) {  // forged, altered or unsigned: not taken
      if (records_unsigned) ++*records_unsigned;
      continue;
    }
    out.records.push_back(std::make_shared<const association::OwnerRecord>(std::move(entry)));
  }
  // One held version an owner at most, as many as records may come.
  if (message.held_size() > limits.max_records) {
    error = "negotiation: " + std::to_string(message.held_size()) +
            " held record versions, above the limit of " + std::to_string(limits.max_records);
    return std::nullopt;
  }
  for (const v1::RecordVersion& held : message.held()) {
    if (held.owner() > static_cast<std::uint32_t>(kMaxRobot) ||
        held.version() > static_cast<std::uint32_t>(std::numeric_limits<int>::max())) {
      error = "negotiation: held record version out of range";
      return std::nullopt;
    }
    out.held.emplace_back(static_cast<int>(held.owner()), static_cast<int>(held.version()));
  }
  return out;
}

namespace {

/// Big-endian, fixed-width appends of the signed bytes.
class SignedBytes {
 public:
  explicit SignedBytes(std::string_view tag) : bytes_(tag) {}
  void u32(std::uint32_t value) { big_endian(value); }
  void i32(int value) { big_endian(static_cast<std::uint32_t>(value)); }
  void i64(std::int64_t value) { big_endian(static_cast<std::uint64_t>(value)); }
  void f64(double value) {
    std::uint64_t bits = 0;
    std::memcpy(&bits, &value, sizeof bits);
    big_endian(bits);
  }
  void rigid(const Eigen::Isometry3d& T) {  // as add_rigid writes it
    for (int row = 0; row < 3; ++row) {
      for (int column = 0; column < 3; ++column) f64(T.linear()(row, column));
      f64(T.translation()(row));
    }
  }
  void upper(const Eigen::Matrix<double, 6, 6>& matrix) {  // as add_upper writes it
    for (int row = 0; row < 6; ++row)
      for (int column = row; column < 6; ++column) f64(matrix(row, column));
  }
  std::string take() { return std::move(bytes_); }

 private:
  template <typename Unsigned>
  void big_endian(Unsigned value) {
    for (int shift = 8 * static_cast<int>(sizeof value) - 8; shift >= 0; shift -= 8)
      bytes_.push_back(static_cast<char>(value >> shift));
  }
  std::string bytes_;
};

/// Own signatures kept (a neighbour that missed a version gets the newest, not an old one).
constexpr std::size_t kOwnSignaturesKept = 4;

}  // namespace

std::string record_signing_bytes(const association::OwnerRecord& record) {
  SignedBytes out("concord-owner-record-v1");
  out.i32(record.owner);
  out.i32(record.version);
  out.u32(static_cast<std::uint32_t>(record.links.size()));
  for (const association::ObjectLink& link : record.links) {
    out.i64(link.a);
    out.i64(link.b);
    out.f64(link.mahalanobis_squared);
  }
  out.u32(static_cast<std::uint32_t>(record.frame_edges.size()));
  for (const association::FrameEdge& edge : record.frame_edges) {
    out.i32(edge.frame_a);
    out.i32(edge.frame_b);
    out.rigid(edge.T_a_b);
    out.upper(edge.covariance);
    out.i32(edge.round);
    out.i32(edge.owner);
    out.i32(edge.robot_b);
    out.upper(edge.drift_a);
    out.upper(edge.drift_b);
    out.i32(edge.pose_frame_a);
    out.i32(edge.pose_frame_b);
    out.u32(static_cast<std::uint32_t>(edge.corrections.size()));
    for (const association::FrameCorrection& correction : edge.corrections) {
      out.i32(correction.frame);
      out.u32(correction.moves_b_side ? 1 : 0);
      out.rigid(correction.T);
      out.upper(correction.covariance);
      out.i32(correction.round);
    }
  }
  return out.take();
}

RecordSigner::RecordSigner(int robot, std::shared_ptr<const net::RobotIdentity> identity,
                           net::MemberKeys member_keys)
    : robot_(robot), identity_(std::move(identity)), member_keys_(std::move(member_keys)) {}

std::string RecordSigner::signature_of(const association::OwnerRecord& record) const {
  if (!record.signature.empty() || record.owner != robot_ || !identity_) return record.signature;
  std::lock_guard lock(mutex_);
  const auto known = own_signatures_.find(record.version);
  if (known != own_signatures_.end()) return known->second;
  std::string signature = identity_->sign(record_signing_bytes(record));
  own_signatures_[record.version] = signature;
  while (own_signatures_.size() > kOwnSignaturesKept)
    own_signatures_.erase(own_signatures_.begin());
  return signature;
}

bool RecordSigner::verifies(const association::OwnerRecord& record) const {
  const auto key = member_keys_.find(record.owner);
  return key != member_keys_.end() &&
         key->second.verify(record_signing_bytes(record), record.signature);
}

}  // namespace concord::daemon

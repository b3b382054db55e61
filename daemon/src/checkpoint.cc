#include "checkpoint.h"

#include <Eigen/Cholesky>
#include <cmath>
#include <cstring>
#include <limits>

namespace concord::daemon {

namespace {

constexpr char kMagic[] = "CONCORD-CHECKPOINT-9\n";
constexpr std::size_t kMagicBytes = sizeof(kMagic) - 1;

std::uint64_t fnv1a(const char* data, std::size_t size) {
  std::uint64_t hash = 1469598103934665603ull;
  for (std::size_t i = 0; i < size; ++i) {
    hash ^= static_cast<unsigned char>(data[i]);
    hash *= 1099511628211ull;
  }
  return hash;
}

class Writer {
 public:
  template <typename T>
  void put(T value) {
    char bytes[sizeof(T)];
    std::memcpy(bytes, &value, sizeof(T));
    out.append(bytes, sizeof(T));
  }
  void pose(const Eigen::Isometry3d& T) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) put<double>(T.matrix()(r, c));
  }
  std::string out;
};

class Reader {
 public:
  explicit Reader(const std::string& bytes) : bytes_(bytes) {}
  template <typename T>
  bool get(T& value) {
    if (bytes_.size() - offset_ < sizeof(T)) return false;
    std::memcpy(&value, bytes_.data() + offset_, sizeof(T));
    offset_ += sizeof(T);
    if constexpr (std::is_floating_point_v<T>) return std::isfinite(value);
    return true;
  }
  bool pose(Eigen::Isometry3d& T) {
    T = Eigen::Isometry3d::Identity();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c)
        if (!get<double>(T.matrix()(r, c))) return false;
    // A rotation block must be a rotation.
    const Eigen::Matrix3d R = T.linear();
    return (R * R.transpose() - Eigen::Matrix3d::Identity()).norm() < 1e-6 &&
           std::abs(R.determinant() - 1.0) < 1e-6;
  }
  /// A count of items of at least `item_bytes` each that the rest of the input can hold.
  bool count(std::uint32_t& n, std::size_t item_bytes) {
    return get(n) && static_cast<std::uint64_t>(n) * item_bytes <= bytes_.size() - offset_;
  }
  std::size_t offset() const { return offset_; }

 private:
  const std::string& bytes_;
  std::size_t offset_ = 0;
};

}  // namespace

std::string serialize_checkpoint(const Checkpoint& checkpoint) {
  Writer w;
  w.out.append(kMagic, kMagicBytes);
  w.put<std::int32_t>(checkpoint.robot_id);
  w.put<std::uint64_t>(checkpoint.round);
  w.put<std::uint32_t>(static_cast<std::uint32_t>(checkpoint.frames.size()));
  for (std::size_t i = 0; i < checkpoint.frames.size(); ++i) {
    w.put<std::int32_t>(checkpoint.frames[i]);
    w.put<double>(checkpoint.timestamps[i]);
    w.pose(checkpoint.poses[i]);
  }
  const State& state = checkpoint.state;
  w.put<std::uint32_t>(static_cast<std::uint32_t>(state.poses.size()));
  for (const PoseClone& clone : state.poses) {
    w.put<std::int32_t>(clone.frame);
    w.pose(clone.T_world_body);
  }
  w.put<std::uint32_t>(static_cast<std::uint32_t>(state.landmarks.size()));
  for (const ObjectLandmark& landmark : state.landmarks) {
    w.put<std::int64_t>(landmark.id);
    for (int i = 0; i < 3; ++i) w.put<double>(landmark.p_world[i]);
    w.put<std::int32_t>(landmark.last_observed_frame);
    for (int i = 0; i < 3; ++i) w.put<double>(landmark.p_linearization[i]);
    // 0 active, 1 archived (consider), 2 a detection offset in the image, 3 a detection
    // displacement in space.
    w.put<std::uint8_t>(landmark.detection_offset ? (landmark.displacement ? 3 : 2)
                        : landmark.archived       ? 1
                                                  : 0);
    w.put<std::uint32_t>(static_cast<std::uint32_t>(landmark.used_observations.size()));
    for (const TrackObservation& observation : landmark.used_observations) {
      w.put<std::int32_t>(observation.frame);
      for (int i = 0; i < 4; ++i) w.put<double>(observation.xy[i]);
    }
  }
  w.put<std::uint32_t>(static_cast<std::uint32_t>(state.archived.size()));
  for (const auto& [id, object] : state.archived) {
    w.put<std::int64_t>(id);
    for (int i = 0; i < 3; ++i) w.put<double>(object.p_world[i]);
    for (int i = 0; i < 9; ++i) w.put<double>(object.covariance.data()[i]);
    const auto last = state.archived_last_observed.find(id);
    w.put<std::int32_t>(last == state.archived_last_observed.end() ? -1 : last->second);
    const auto local = state.archived_local_covariance.find(id);
    w.put<std::uint8_t>(local == state.archived_local_covariance.end() ? 0 : 1);
    if (local != state.archived_local_covariance.end()) {
      for (int r = 0; r < 3; ++r)
        for (int c = r; c < 3; ++c) w.put<double>(local->second(r, c));
    }
  }
  w.put<std::uint32_t>(static_cast<std::uint32_t>(checkpoint.pending.size()));
  for (const auto& [id, track] : checkpoint.pending) {
    w.put<std::int64_t>(id);
    w.put<std::uint32_t>(static_cast<std::uint32_t>(track.size()));
    for (const TrackObservation& observation : track) {
      w.put<std::int32_t>(observation.frame);
      for (int i = 0; i < 4; ++i) w.put<double>(observation.xy[i]);
    }
  }
  w.put<std::uint8_t>(state.has_disparity_offset ? 1 : 0);
  w.put<double>(state.disparity_offset);
  w.put<std::uint8_t>(state.has_world_up ? 1 : 0);
  for (int i = 0; i < 3; ++i) w.put<double>(state.world_up.reference[i]);
  for (int i = 0; i < 6; ++i) w.put<double>(state.world_up.basis.data()[i]);
  for (int i = 0; i < 2; ++i) w.put<double>(state.world_up.tilt[i]);
  const auto dimension = static_cast<std::uint32_t>(state.covariance.rows());
  w.put<std::uint32_t>(dimension);
  for (Eigen::Index i = 0; i < state.covariance.size(); ++i)
    w.put<double>(state.covariance.data()[i]);
  w.put<std::uint64_t>(fnv1a(w.out.data(), w.out.size()));
  return std::move(w.out);
}

std::optional<Checkpoint> parse_checkpoint(const std::string& bytes, std::string& error) {
  auto fail = [&](const std::string& what) -> std::optional<Checkpoint> {
    error = "checkpoint: " + what;
    return std::nullopt;
  };
  if (bytes.size() < kMagicBytes + sizeof(std::uint64_t) ||
      bytes.compare(0, kMagicBytes, kMagic) != 0)
    return fail("not a Concord checkpoint of this format version");
  const std::size_t body = bytes.size() - sizeof(std::uint64_t);
  std::uint64_t stored = 0;
  std::memcpy(&stored, bytes.data() + body, sizeof stored);
  if (stored != fnv1a(bytes.data(), body)) return fail("checksum mismatch (damaged file)");
  const std::string content = bytes.substr(kMagicBytes, body - kMagicBytes);
  Reader r(content);
  Checkpoint checkpoint;
  std::int32_t robot = 0;
  std::uint32_t n = 0;
  if (!r.get(robot) || !r.get(checkpoint.round) || !r.count(n, 4 + 8 + 96))
    return fail("truncated header");
  checkpoint.robot_id = robot;
  for (std::uint32_t i = 0; i < n; ++i) {
    std::int32_t frame = 0;
    double timestamp = 0.0;
    Eigen::Isometry3d pose;
    if (!r.get(frame) || !r.get(timestamp) || !r.pose(pose) || frame < 0)
      return fail("bad trajectory entry " + std::to_string(i));
    checkpoint.frames.push_back(frame);
    checkpoint.timestamps.push_back(timestamp);
    checkpoint.poses.push_back(pose);
  }
  State& state = checkpoint.state;
  if (!r.count(n, 4 + 96) || n == 0) return fail("bad pose window");
  for (std::uint32_t i = 0; i < n; ++i) {
    PoseClone clone;
    std::int32_t frame = 0;
    if (!r.get(frame) || !r.pose(clone.T_world_body)) return fail("bad pose " + std::to_string(i));
    clone.frame = frame;
    state.poses.push_back(clone);
  }
  if (!r.count(n, 8 + 24 + 4 + 24 + 1 + 4)) return fail("bad landmark count");
  for (std::uint32_t i = 0; i < n; ++i) {
    ObjectLandmark landmark;
    std::int32_t last = 0;
    std::uint8_t archived = 0;
    if (!r.get(landmark.id) || !r.get(landmark.p_world[0]) || !r.get(landmark.p_world[1]) ||
        !r.get(landmark.p_world[2]) || !r.get(last) || !r.get(landmark.p_linearization[0]) ||
        !r.get(landmark.p_linearization[1]) || !r.get(landmark.p_linearization[2]) ||
        !r.get(archived) || archived > 3)
      return fail("bad landmark " + std::to_string(i));
    landmark.last_observed_frame = last;
    landmark.archived = archived == 1;
    landmark.detection_offset = archived >= 2;
    landmark.displacement = archived == 3;
    std::uint32_t used = 0;
    if (!r.count(used, 4 + 32)) return fail("bad landmark " + std::to_string(i));
    for (std::uint32_t j = 0; j < used; ++j) {
      TrackObservation observation;
      bool ok = r.get(observation.frame);
      for (int k = 0; ok && k < 4; ++k) ok = r.get(observation.xy[k]);
      if (!ok) return fail("bad used observation of landmark " + std::to_string(i));
      landmark.used_observations.push_back(observation);
    }
    state.landmarks.push_back(landmark);
  }
  if (!r.count(n, 8 + 96 + 4 + 1)) return fail("bad archived object count");
  for (std::uint32_t i = 0; i < n; ++i) {
    ObjectEstimate object;
    std::int32_t last = 0;
    std::uint8_t has_local = 0;
    bool ok = r.get(object.id);
    for (int j = 0; ok && j < 3; ++j) ok = r.get(object.p_world[j]);
    for (int j = 0; ok && j < 9; ++j) ok = r.get(object.covariance.data()[j]);
    if (!ok || !r.get(last) || !r.get(has_local) || has_local > 1)
      return fail("bad archived object " + std::to_string(i));
    if (has_local == 1) {
      Eigen::Matrix3d local;
      for (int row = 0; ok && row < 3; ++row) {
        for (int col = row; ok && col < 3; ++col) {
          ok = r.get(local(row, col));
          local(col, row) = local(row, col);
        }
      }
      if (!ok || Eigen::LLT<Eigen::Matrix3d>(local).info() != Eigen::Success)
        return fail("bad local covariance of archived object " + std::to_string(i));
      state.archived_local_covariance[object.id] = local;
    }
    if (last >= 0) state.archived_last_observed[object.id] = last;
    state.archived[object.id] = object;
  }
  if (!r.count(n, 8 + 4)) return fail("bad pending object count");
  for (std::uint32_t i = 0; i < n; ++i) {
    LandmarkId id = 0;
    std::uint32_t observations = 0;
    if (!r.get(id) || !r.count(observations, 4 + 32) || checkpoint.pending.count(id) != 0)
      return fail("bad pending object " + std::to_string(i));
    std::vector<TrackObservation>& track = checkpoint.pending[id];
    for (std::uint32_t j = 0; j < observations; ++j) {
      TrackObservation observation;
      bool ok = r.get(observation.frame);
      for (int k = 0; ok && k < 4; ++k) ok = r.get(observation.xy[k]);
      if (!ok) return fail("bad pending observation of object " + std::to_string(id));
      track.push_back(observation);
    }
  }
  std::uint8_t has_disparity_offset = 0, has_world_up = 0;
  if (!r.get(has_disparity_offset) || has_disparity_offset > 1 || !r.get(state.disparity_offset))
    return fail("bad disparity offset entry");
  state.has_disparity_offset = has_disparity_offset == 1;
  bool world_up_read = r.get(has_world_up) && has_world_up <= 1;
  WorldUp& world_up = state.world_up;
  for (int i = 0; world_up_read && i < 3; ++i) world_up_read = r.get(world_up.reference[i]);
  for (int i = 0; world_up_read && i < 6; ++i) world_up_read = r.get(world_up.basis.data()[i]);
  for (int i = 0; world_up_read && i < 2; ++i) world_up_read = r.get(world_up.tilt[i]);
  // The reference a unit vector, the basis two unit vectors perpendicular to it and each other.
  Eigen::Matrix3d frame;
  frame << world_up.reference, world_up.basis;
  if (!world_up_read ||
      (frame.transpose() * frame - Eigen::Matrix3d::Identity()).norm() > 1e-6 ||
      world_up.tilt.norm() > 1.0)
    return fail("bad world up entry");
  state.has_world_up = has_world_up == 1;
  std::uint32_t dimension = 0;
  if (!r.get(dimension) || dimension != static_cast<std::uint32_t>(state.dimension()) ||
      static_cast<std::uint64_t>(dimension) * dimension * 8 != content.size() - r.offset())
    return fail("covariance size does not match the state");
  state.covariance.resize(dimension, dimension);
  for (Eigen::Index i = 0; i < state.covariance.size(); ++i)
    if (!r.get(state.covariance.data()[i])) return fail("non-finite covariance");
  state.rebuild_landmark_index();
  return checkpoint;
}

}  // namespace concord::daemon

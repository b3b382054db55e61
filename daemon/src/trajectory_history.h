#pragma once
/// \file
/// The processed frames' trajectory, for /trajectory and the outputs, kept so that readers never
/// copy the whole history under the lock the estimator thread takes: full chunks of 1024 points
/// are immutable and shared, so a snapshot copies one pointer per chunk plus the open chunk
/// (at most 1023 points), and the formatting happens outside the lock.

#include <Eigen/Geometry>
#include <cstddef>
#include <memory>
#include <vector>

#include "concord/dataset/result_io.h"

namespace concord::daemon {

struct TrajectoryPoint {
  int frame = 0;                                           ///< the source's frame index (the round)
  double timestamp = 0.0;                                  ///< seconds
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  ///< T_world_body
  /// Its online covariance (right perturbation); zero when unknown (a resumed history).
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
};

class TrajectoryHistory {
 public:
  static constexpr std::size_t kChunkPoints = 1024;
  using Chunk = std::vector<TrajectoryPoint>;

  /// An immutable view of the history at one moment.
  struct Snapshot {
    std::vector<std::shared_ptr<const Chunk>> sealed;
    Chunk open;

    std::size_t size() const { return sealed.size() * kChunkPoints + open.size(); }
    template <typename Function>
    void for_each(Function&& function) const {
      for (const auto& chunk : sealed)
        for (const TrajectoryPoint& point : *chunk) function(point);
      for (const TrajectoryPoint& point : open) function(point);
    }
    std::vector<int> frames() const {
      std::vector<int> out;
      out.reserve(size());
      for_each([&](const TrajectoryPoint& p) { out.push_back(p.frame); });
      return out;
    }
    std::vector<double> timestamps() const {
      std::vector<double> out;
      out.reserve(size());
      for_each([&](const TrajectoryPoint& p) { out.push_back(p.timestamp); });
      return out;
    }
    std::vector<dataset::PoseCovariance> pose_covariances() const {
      std::vector<dataset::PoseCovariance> out;
      out.reserve(size());
      for_each([&](const TrajectoryPoint& p) { out.push_back({p.frame, p.covariance}); });
      return out;
    }
    std::vector<Eigen::Isometry3d> poses() const {
      std::vector<Eigen::Isometry3d> out;
      out.reserve(size());
      for_each([&](const TrajectoryPoint& p) { out.push_back(p.pose); });
      return out;
    }
  };

  void push(const TrajectoryPoint& point) {
    open_.push_back(point);
    if (open_.size() == kChunkPoints) {
      sealed_.push_back(std::make_shared<const Chunk>(std::move(open_)));
      open_ = Chunk();
      open_.reserve(kChunkPoints);
    }
  }
  std::size_t size() const { return sealed_.size() * kChunkPoints + open_.size(); }
  bool empty() const { return size() == 0; }
  /// The newest point; the history must not be empty.
  const TrajectoryPoint& back() const {
    return open_.empty() ? sealed_.back()->back() : open_.back();
  }
  /// O(size / kChunkPoints + kChunkPoints): cheap enough under a lock.
  Snapshot snapshot() const { return Snapshot{sealed_, open_}; }

 private:
  std::vector<std::shared_ptr<const Chunk>> sealed_;
  Chunk open_;
};

}  // namespace concord::daemon

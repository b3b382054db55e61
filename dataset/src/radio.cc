#include "concord/dataset/radio.h"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <utility>

#include "concord/dataset/dataset.h"
#include "text_parsing.h"

namespace concord::dataset {

std::vector<std::vector<Eigen::Vector3d>> RadioLimits::positions_of(const Dataset& dataset) {
  std::vector<std::vector<Eigen::Vector3d>> positions;
  for (const auto& robot : dataset.robots) {
    if (static_cast<int>(robot.groundtruth.size()) < robot.num_frames())
      throw std::invalid_argument("radio limits (range, nearest, max degree) need the ground truth "
                                  "of every robot's frames: robot " +
                                  std::to_string(robot.index) + " has too little");
    auto& track = positions.emplace_back();
    for (const auto& pose : robot.groundtruth) track.push_back(pose.translation());
  }
  return positions;
}

std::vector<std::vector<Eigen::Vector3d>> read_true_positions(const std::filesystem::path& dataset,
                                                              const std::vector<int>& robots) {
  std::vector<std::vector<Eigen::Vector3d>> positions;
  for (const int robot : robots) {
    const auto file = dataset / robot_folder_name(robot) / "groundtruth.kitti";
    if (!std::filesystem::is_regular_file(file))
      throw DatasetError(file.string() + ": not found (a simulated radio needs every robot's "
                                         "ground truth)");
    auto& track = positions.emplace_back();
    for (const auto& pose : text_parsing::read_kitti_poses(file)) track.push_back(pose.translation());
  }
  return positions;
}

std::vector<std::vector<int>> limit_graph(const std::vector<std::vector<int>>& candidates,
                                          const std::vector<Eigen::Vector3d>& positions,
                                          const RadioLimits& limits) {
  const int robots = static_cast<int>(candidates.size());
  auto distance = [&](int i, int j) { return (positions[i] - positions[j]).norm(); };
  // 1. Range.
  std::vector<std::vector<int>> in_range(robots);
  for (int i = 0; i < robots; ++i)
    for (int j : candidates[i])
      if (limits.range_m <= 0.0 || distance(i, j) <= limits.range_m) in_range[i].push_back(j);
  if (limits.nearest <= 0 && limits.max_degree <= 0) {
    for (auto& neighbours : in_range) std::sort(neighbours.begin(), neighbours.end());
    return in_range;  // range only: no ordering by distance needed
  }
  // 2. Nearest: an edge when either end has the other among its `nearest` closest.
  std::vector<std::vector<bool>> keep(robots, std::vector<bool>(robots, false));
  for (int i = 0; i < robots; ++i) {
    std::vector<int> order = in_range[i];
    std::sort(order.begin(), order.end(), [&](int a, int b) {
      const double da = distance(i, a), db = distance(i, b);
      return da != db ? da < db : a < b;
    });
    if (limits.nearest > 0 && static_cast<int>(order.size()) > limits.nearest)
      order.resize(static_cast<std::size_t>(limits.nearest));
    for (int j : order) keep[i][j] = keep[j][i] = true;
  }
  // 3. Degree: the shortest edges first, each while both ends have room.
  std::vector<std::pair<int, int>> edges;
  for (int i = 0; i < robots; ++i)
    for (int j = i + 1; j < robots; ++j)
      if (keep[i][j]) edges.emplace_back(i, j);
  std::stable_sort(edges.begin(), edges.end(), [&](const auto& a, const auto& b) {
    return distance(a.first, a.second) < distance(b.first, b.second);
  });
  std::vector<std::vector<int>> graph(robots);
  for (const auto& [i, j] : edges) {
    if (limits.max_degree > 0 && (static_cast<int>(graph[i].size()) >= limits.max_degree ||
                                  static_cast<int>(graph[j].size()) >= limits.max_degree))
      continue;
    graph[i].push_back(j);
    graph[j].push_back(i);
  }
  for (auto& neighbours : graph) std::sort(neighbours.begin(), neighbours.end());
  return graph;
}

}  // namespace concord::dataset

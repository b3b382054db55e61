#include "concord/association/team_ids.h"

#include <algorithm>
#include <iterator>
#include <numeric>
#include <span>

namespace concord::association {

namespace {

/// Whether two ascending lists of robots share one.
bool share_a_robot(std::span<const int> x, std::span<const int> y) {
  auto i = x.begin();
  auto j = y.begin();
  while (i != x.end() && j != y.end()) {
    if (*i == *j) return true;
    if (*i < *j) {
      ++i;
    } else {
      ++j;
    }
  }
  return false;
}

}  // namespace

ObjectLink ObjectLink::make(ObjectKey x, ObjectKey y, double mahalanobis_squared) {
  return {std::min(x, y), std::max(x, y), mahalanobis_squared};
}

ObjectKey TeamIds::team_id(ObjectKey key) const {
  const auto it = team_of.find(key);
  return it == team_of.end() ? -1 : it->second;
}

TeamIds assign_team_ids(std::vector<ObjectLink> links) {
  // Duplicates: the strongest copy of a link counts, the others are ignored.
  std::sort(links.begin(), links.end(), [](const ObjectLink& x, const ObjectLink& y) {
    if (x.a != y.a) return x.a < y.a;
    if (x.b != y.b) return x.b < y.b;
    return x.mahalanobis_squared < y.mahalanobis_squared;
  });
  links.erase(std::unique(links.begin(), links.end()), links.end());  // == compares a and b
  std::sort(links.begin(), links.end(), [](const ObjectLink& x, const ObjectLink& y) {
    if (x.mahalanobis_squared != y.mahalanobis_squared) {
      return x.mahalanobis_squared < y.mahalanobis_squared;
    }
    return x.a != y.a ? x.a < y.a : x.b < y.b;
  });
  // Nodes are the keys that appear in links; a component remembers its robots (ascending; a
  // node that was never merged holds none here and has its own key's robot).
  std::vector<ObjectKey> keys;
  keys.reserve(2 * links.size());
  for (const ObjectLink& link : links) {
    keys.push_back(link.a);
    keys.push_back(link.b);
  }
  std::sort(keys.begin(), keys.end());
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  const auto node = [&](ObjectKey key) {
    return static_cast<int>(std::lower_bound(keys.begin(), keys.end(), key) - keys.begin());
  };
  std::vector<int> parent(keys.size());
  std::iota(parent.begin(), parent.end(), 0);
  std::vector<std::vector<int>> merged_robots(keys.size());
  std::vector<int> own_robot(keys.size());
  for (std::size_t n = 0; n < keys.size(); ++n) own_robot[n] = robot_of(keys[n]);
  const auto robots = [&](int root) -> std::span<const int> {
    if (merged_robots[root].empty()) return {&own_robot[root], 1};
    return merged_robots[root];
  };
  const auto find = [&](int n) {
    while (parent[n] != n) n = parent[n] = parent[parent[n]];
    return n;
  };

  TeamIds ids;
  std::vector<bool> linked(keys.size(), false);
  std::vector<int> robots_union;
  for (const ObjectLink& link : links) {
    const int node_a = node(link.a), node_b = node(link.b);
    int x = find(node_a), y = find(node_b);
    if (x == y) {
      linked[node_a] = linked[node_b] = true;
      continue;
    }
    if (share_a_robot(robots(x), robots(y))) {
      ++ids.conflicts;
      continue;
    }
    if (robots(x).size() < robots(y).size()) std::swap(x, y);
    parent[y] = x;
    robots_union.clear();
    const std::span<const int> rx = robots(x), ry = robots(y);
    std::set_union(rx.begin(), rx.end(), ry.begin(), ry.end(), std::back_inserter(robots_union));
    merged_robots[x] = robots_union;
    std::vector<int>().swap(merged_robots[y]);
    linked[node_a] = linked[node_b] = true;
  }
  // Team id: the smallest key of the component (keys are ascending, so the first seen).
  std::vector<std::map<ObjectKey, std::vector<ObjectKey>>::iterator> team_of_root(
      keys.size(), ids.members.end());
  for (std::size_t n = 0; n < keys.size(); ++n) {
    if (!linked[n]) continue;
    const int root = find(static_cast<int>(n));
    auto& team = team_of_root[root];
    // New teams come in ascending order of their ids: each goes at the end of the map.
    if (team == ids.members.end()) team = ids.members.emplace_hint(ids.members.end(), keys[n],
                                                                    std::vector<ObjectKey>());
    ids.team_of.emplace_hint(ids.team_of.end(), keys[n], team->first);
    team->second.push_back(keys[n]);
  }
  return ids;
}

}  // namespace concord::association

#include "concord/association/team_ids.h"

#include <algorithm>
#include <numeric>
#include <set>

namespace concord::association {

ObjectLink ObjectLink::make(ObjectKey x, ObjectKey y, double mahalanobis_squared) {
  return {std::min(x, y), std::max(x, y), mahalanobis_squared};
}

ObjectKey TeamIds::team_id(ObjectKey key) const {
  const auto it = team_of.find(key);
  return it == team_of.end() ? -1 : it->second;
}

TeamIds assign_team_ids(std::vector<ObjectLink> links) {
  std::sort(links.begin(), links.end(), [](const ObjectLink& x, const ObjectLink& y) {
    if (x.mahalanobis_squared != y.mahalanobis_squared) {
      return x.mahalanobis_squared < y.mahalanobis_squared;
    }
    return x.a != y.a ? x.a < y.a : x.b < y.b;
  });
  // Nodes are the keys that appear in links; a component remembers its robots.
  std::vector<ObjectKey> keys;
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
  std::vector<std::set<int>> robots(keys.size());
  for (std::size_t n = 0; n < keys.size(); ++n) robots[n].insert(robot_of(keys[n]));
  const auto find = [&](int n) {
    while (parent[n] != n) n = parent[n] = parent[parent[n]];
    return n;
  };

  TeamIds ids;
  std::set<std::pair<ObjectKey, ObjectKey>> seen;
  std::vector<bool> linked(keys.size(), false);
  for (const ObjectLink& link : links) {
    if (!seen.emplace(link.a, link.b).second) continue;
    int x = find(node(link.a)), y = find(node(link.b));
    if (x == y) {
      linked[node(link.a)] = linked[node(link.b)] = true;
      continue;
    }
    const bool overlap = std::any_of(robots[x].begin(), robots[x].end(),
                                     [&](int robot) { return robots[y].contains(robot); });
    if (overlap) {
      ++ids.conflicts;
      continue;
    }
    if (robots[x].size() < robots[y].size()) std::swap(x, y);
    parent[y] = x;
    robots[x].insert(robots[y].begin(), robots[y].end());
    robots[y].clear();
    linked[node(link.a)] = linked[node(link.b)] = true;
  }
  // Team id: the smallest key of the component (keys are ascending, so the first seen).
  std::map<int, ObjectKey> smallest;
  for (std::size_t n = 0; n < keys.size(); ++n) {
    if (!linked[n]) continue;
    const int root = find(static_cast<int>(n));
    smallest.emplace(root, keys[n]);
    const ObjectKey team = smallest.at(root);
    ids.team_of[keys[n]] = team;
    ids.members[team].push_back(keys[n]);
  }
  return ids;
}

}  // namespace concord::association

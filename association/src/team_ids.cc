#include "concord/association/team_ids.h"

#include <algorithm>
#include <iterator>
#include <numeric>
#include <span>
#include <unordered_set>

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
  TeamIdIndex index;
  index.set_links(0, std::move(links));
  return index.ids();
}

bool TeamIdIndex::set_links(int source, std::vector<ObjectLink> links) {
  stage(source, std::move(links));
  return commit();
}

void TeamIdIndex::stage(int source, std::vector<ObjectLink> links) {
  // The smaller key first; a link of a key with itself says nothing.
  for (ObjectLink& link : links) {
    if (link.a > link.b) std::swap(link.a, link.b);
  }
  std::erase_if(links, [](const ObjectLink& link) { return link.a == link.b; });
  // One link a pair, the strongest (records usually come sorted: see OwnerRecord).
  const auto by_keys = [](const ObjectLink& x, const ObjectLink& y) {
    if (x.a != y.a) return x.a < y.a;
    if (x.b != y.b) return x.b < y.b;
    return x.mahalanobis_squared < y.mahalanobis_squared;
  };
  if (!std::is_sorted(links.begin(), links.end(), by_keys)) {
    std::sort(links.begin(), links.end(), by_keys);
  }
  links.erase(std::unique(links.begin(), links.end()), links.end());  // == compares a and b
  std::vector<ObjectLink>& before = sources_[source];
  // The difference, both lists ascending by (a, b); add() also takes a new strength.
  const auto key_less = [](const ObjectLink& x, const ObjectLink& y) {
    return x.a != y.a ? x.a < y.a : x.b < y.b;
  };
  auto old_link = before.begin();
  auto new_link = links.begin();
  while (old_link != before.end() || new_link != links.end()) {
    if (new_link == links.end() || (old_link != before.end() && key_less(*old_link, *new_link))) {
      remove(source, *old_link++);
    } else if (old_link == before.end() || key_less(*new_link, *old_link)) {
      add(source, *new_link++);
    } else {
      if (old_link->mahalanobis_squared != new_link->mahalanobis_squared) add(source, *new_link);
      ++old_link;
      ++new_link;
    }
  }
  if (links.empty()) {
    sources_.erase(source);
  } else {
    before = std::move(links);
  }
}

TeamIdIndex::Edge* TeamIdIndex::edge_in(std::vector<Edge>& edges, ObjectKey to) {
  const auto it =
      std::find_if(edges.begin(), edges.end(), [&](const Edge& e) { return e.other == to; });
  return it == edges.end() ? nullptr : &*it;
}

TeamIdIndex::Edge* TeamIdIndex::edge(ObjectKey from, ObjectKey to) {
  const auto edges = adjacent_.find(from);
  return edges == adjacent_.end() ? nullptr : edge_in(edges->second, to);
}

namespace {

double strongest_of(const std::vector<std::pair<int, double>>& sources) {
  double strongest = sources.front().second;
  for (const auto& [source, d2] : sources) strongest = std::min(strongest, d2);
  return strongest;
}

}  // namespace

void TeamIdIndex::add(int source, const ObjectLink& link) {
  // (A reference to a's edges survives the insertion of b's: rehashing moves no element.)
  std::vector<Edge>& edges_a = adjacent_[link.a];
  Edge* forward = edge_in(edges_a, link.b);
  if (forward == nullptr) {
    adjacent_[link.b].push_back({link.a, link.mahalanobis_squared, false, {}});
    forward = &edges_a.emplace_back(Edge{link.b, link.mahalanobis_squared, false, {}});
    added_.push_back(link);
  } else {
    only_added_ = false;
  }
  auto& sources = forward->sources;
  const auto it = std::find_if(sources.begin(), sources.end(),
                               [&](const auto& entry) { return entry.first == source; });
  if (it == sources.end()) {
    sources.emplace_back(source, link.mahalanobis_squared);
  } else {
    it->second = link.mahalanobis_squared;
  }
  forward->strongest = strongest_of(sources);
  touched_.push_back(link.a);
  touched_.push_back(link.b);
}

void TeamIdIndex::remove(int source, const ObjectLink& link) {
  Edge* forward = edge(link.a, link.b);
  if (forward == nullptr) return;
  only_added_ = false;
  auto& sources = forward->sources;
  std::erase_if(sources, [&](const auto& entry) { return entry.first == source; });
  if (sources.empty()) {
    if (forward->conflict) --conflicts_;
    for (const auto& side : {std::pair{link.a, link.b}, std::pair{link.b, link.a}}) {
      const ObjectKey from = side.first, to = side.second;
      auto& edges = adjacent_.at(from);
      edges.erase(std::find_if(edges.begin(), edges.end(),
                               [&](const Edge& e) { return e.other == to; }));
      if (edges.empty()) adjacent_.erase(from);
    }
  } else {
    forward->strongest = strongest_of(sources);
  }
  touched_.push_back(link.a);
  touched_.push_back(link.b);
}

bool TeamIdIndex::part_holds_robot(ObjectKey start,
                                   std::unordered_map<ObjectKey, bool>& known) const {
  if (const auto it = known.find(start); it != known.end()) return it->second;
  std::vector<ObjectKey> part{start};
  std::unordered_set<ObjectKey> seen{start};
  bool holds = false;
  for (std::size_t next = 0; next < part.size(); ++next) {
    holds = holds || robot_of(part[next]) == robot_;
    const auto edges = adjacent_.find(part[next]);
    if (edges == adjacent_.end()) continue;
    for (const Edge& e : edges->second) {
      if (seen.insert(e.other).second) part.push_back(e.other);
    }
  }
  for (const ObjectKey key : part) known.emplace(key, holds);
  return holds;
}

std::vector<ObjectKey>* TeamIdIndex::members_of(ObjectKey key) {
  const auto team = ids_.team_of.find(key);
  return team == ids_.team_of.end() ? nullptr : &ids_.members.at(team->second);
}

void TeamIdIndex::merge_added(std::vector<ObjectKey>& unresolved) {
  // Links of each key among those not merged in yet: a key in no team whose links are all
  // among them is new to the link graph (a team of its own).
  std::unordered_map<ObjectKey, int> pending;
  for (const ObjectLink& link : added_) {
    ++pending[link.a];
    ++pending[link.b];
  }
  const auto is_new = [&](ObjectKey key) {
    const auto edges = adjacent_.find(key);
    return edges != adjacent_.end() &&
           edges->second.size() == static_cast<std::size_t>(pending[key]);
  };
  // Whether each part (as the link graph stands now) holds the robot's objects, found once a
  // part.
  std::unordered_map<ObjectKey, bool> holds_robot;
  // Merging copies the two teams: work in proportion to their sizes. A change that would cost
  // much more than the links it adds (a long chain of links into one team, as a peer could
  // send) leaves the rest of its links to the union-find of their parts, which is O(n log n).
  const std::size_t budget = 8 * added_.size() + 4096;
  std::size_t work = 0;
  std::vector<ObjectKey> merged;
  for (auto link_it = added_.begin(); link_it != added_.end(); ++link_it) {
    const ObjectLink& link = *link_it;
    if (work > budget) {
      for (; link_it != added_.end(); ++link_it) {
        unresolved.push_back(link_it->a);
        unresolved.push_back(link_it->b);
      }
      return;
    }
    std::vector<ObjectKey>* team_a = members_of(link.a);
    std::vector<ObjectKey>* team_b = members_of(link.b);
    // Neither key in a team, for a robot's index: a link within a part that holds none of the
    // robot's objects (the part as the link graph stands now, every added link in it) is
    // nothing to this index, whatever the links decide there.
    if (team_a == nullptr && team_b == nullptr && robot_ >= 0 &&
        !part_holds_robot(link.a, holds_robot)) {
      --pending[link.a];
      --pending[link.b];
      continue;
    }
    // A key in no team that is not new: a key of a part left out (robot_) or one whose links
    // were all conflicts. Worked out in full.
    if ((team_a == nullptr && !is_new(link.a)) || (team_b == nullptr && !is_new(link.b))) {
      unresolved.push_back(link.a);
      unresolved.push_back(link.b);
      continue;
    }
    --pending[link.a];
    --pending[link.b];
    if (team_a != nullptr && team_a == team_b) continue;  // one team already
    // A new key is a team of its own.
    const std::span<const ObjectKey> keys_a =
        team_a != nullptr ? std::span<const ObjectKey>(*team_a) : std::span(&link.a, 1);
    const std::span<const ObjectKey> keys_b =
        team_b != nullptr ? std::span<const ObjectKey>(*team_b) : std::span(&link.b, 1);
    // The robots of each team are ascending with its keys (a key's robot is its high bits).
    bool conflict = false;
    for (auto i = keys_a.begin(), j = keys_b.begin(); i != keys_a.end() && j != keys_b.end();) {
      const int ri = robot_of(*i), rj = robot_of(*j);
      if (ri == rj) {
        conflict = true;
        break;
      }
      if (ri < rj) {
        ++i;
      } else {
        ++j;
      }
    }
    if (conflict) {
      unresolved.push_back(link.a);
      unresolved.push_back(link.b);
      continue;
    }
    work += keys_a.size() + keys_b.size();
    merged.clear();
    std::merge(keys_a.begin(), keys_a.end(), keys_b.begin(), keys_b.end(),
               std::back_inserter(merged));
    const ObjectKey team = merged.front();  // the smallest key
    for (const ObjectKey old_team : {keys_a.front(), keys_b.front()}) {
      if (old_team != team) ids_.members.erase(old_team);
    }
    for (const ObjectKey key : merged) ids_.team_of[key] = team;
    ids_.members[team] = merged;
  }
}

bool TeamIdIndex::commit() {
  if (touched_.empty()) return false;
  ++commits_;
  // The connected parts of the link graph to work out again, from the keys that start them: the
  // parts of the touched keys, or when links were only added, of those merge_added() left.
  std::vector<ObjectKey> starts;
  if (only_added_) {
    merge_added(starts);
    touched_.clear();
  } else {
    starts.swap(touched_);
  }
  added_.clear();
  only_added_ = true;
  if (starts.empty()) {
    ++merge_only_commits_;
    ids_.conflicts = conflicts_;
    return true;
  }
  // The parts as they are now. They hold every old team of their keys too: a key of an old part
  // reaches a start without a removed link.
  std::unordered_set<ObjectKey> seen;
  // Part by part (breadth first from each touched key not reached yet); with a robot, the keys of
  // parts without its objects lose their old teams and get none.
  std::vector<ObjectKey> keys, part, unworked;
  for (const ObjectKey start : starts) {
    if (!seen.insert(start).second) continue;
    part.assign(1, start);
    bool holds_robot = robot_ < 0 || robot_of(start) == robot_;
    for (std::size_t next = 0; next < part.size(); ++next) {
      const auto edges = adjacent_.find(part[next]);
      if (edges == adjacent_.end()) continue;
      for (const Edge& e : edges->second) {
        if (!seen.insert(e.other).second) continue;
        part.push_back(e.other);
        holds_robot = holds_robot || robot_of(e.other) == robot_;
      }
    }
    std::vector<ObjectKey>& into = holds_robot ? keys : unworked;
    into.insert(into.end(), part.begin(), part.end());
  }
  for (const ObjectKey key : unworked) {
    const auto team = ids_.team_of.find(key);
    if (team == ids_.team_of.end()) continue;
    ids_.members.erase(team->second);
    ids_.team_of.erase(team);
  }
  // Conflicts of unworked parts are not counted (the union-find's marks of their links go).
  for (const ObjectKey key : unworked) {
    const auto edges = adjacent_.find(key);
    if (edges == adjacent_.end()) continue;
    for (Edge& e : edges->second) {
      if (e.other > key && e.conflict) {
        e.conflict = false;
        --conflicts_;
      }
    }
  }
  std::sort(keys.begin(), keys.end());
  // Their old teams go.
  for (const ObjectKey key : keys) {
    const auto team = ids_.team_of.find(key);
    if (team == ids_.team_of.end()) continue;
    ids_.members.erase(team->second);
    ids_.team_of.erase(team);
  }
  // Their links, strongest first (then by keys).
  std::vector<ObjectLink> links;
  for (const ObjectKey key : keys) {
    const auto edges = adjacent_.find(key);
    if (edges == adjacent_.end()) continue;
    for (Edge& e : edges->second) {
      if (e.other < key) continue;
      if (e.conflict) {
        e.conflict = false;
        --conflicts_;
      }
      links.push_back({key, e.other, e.strongest});
    }
  }
  std::sort(links.begin(), links.end(), [](const ObjectLink& x, const ObjectLink& y) {
    if (x.mahalanobis_squared != y.mahalanobis_squared) {
      return x.mahalanobis_squared < y.mahalanobis_squared;
    }
    return x.a != y.a ? x.a < y.a : x.b < y.b;
  });
  // Union-find over the region's keys; a component remembers its robots (ascending; a node that
  // was never merged holds none here and has its own key's robot).
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
      edge(link.a, link.b)->conflict = true;
      ++conflicts_;
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
  std::vector<ObjectKey> team_of_root(keys.size(), -1);
  for (std::size_t n = 0; n < keys.size(); ++n) {
    if (!linked[n]) continue;
    ObjectKey& team = team_of_root[find(static_cast<int>(n))];
    if (team < 0) team = keys[n];
    ids_.team_of.emplace(keys[n], team);
    ids_.members[team].push_back(keys[n]);
  }
  ids_.conflicts = conflicts_;
  return true;
}

}  // namespace concord::association

#pragma once
/// \file
/// One team id per physical object, consistent over any number of robots: a union-find over the
/// accepted pairwise correspondences (links). A team id never holds two objects of one robot (a
/// robot's objects are distinct by its own account); a link that would make it do so is a
/// conflict, left out and counted. Links are taken strongest first (smallest Mahalanobis
/// distance, then by their keys), so every robot that knows the same links computes the same ids.

#include <map>
#include <unordered_map>
#include <utility>
#include <vector>

#include "concord/association/map_description.h"

namespace concord::association {

/// An accepted correspondence between two robots' objects.
struct ObjectLink {
  ObjectKey a = 0;  ///< the smaller key
  ObjectKey b = 0;
  /// Squared Mahalanobis distance when accepted (smaller is stronger).
  double mahalanobis_squared = 0.0;

  /// A link with a < b.
  static ObjectLink make(ObjectKey x, ObjectKey y, double mahalanobis_squared);
  bool operator==(const ObjectLink& other) const { return a == other.a && b == other.b; }
};

/// Team ids of the linked objects.
struct TeamIds {
  /// Team id of every object in some team (the smallest key of its team); objects absent here are
  /// unshared (team id -1 in outputs).
  std::map<ObjectKey, ObjectKey> team_of;
  /// Members of each team, ascending.
  std::map<ObjectKey, std::vector<ObjectKey>> members;
  /// Links left out because they would put two objects of one robot in one team.
  int conflicts = 0;

  /// Team id of a key, or -1.
  ObjectKey team_id(ObjectKey key) const;
};

/// Union-find over the links (duplicates ignored), strongest first, conflicts left out.
TeamIds assign_team_ids(std::vector<ObjectLink> links);

/// The team ids of a set of links that changes a source at a time (a source: one owner's record),
/// kept equal to assign_team_ids over the union of every source's links. The union-find's
/// decisions on a link depend only on the stronger links of the same connected part of the link
/// graph (conflicting links included), so a change is worked out again only on the parts it
/// touches: a robot that hears of one owner's new record does not redo the whole team.
class TeamIdIndex {
 public:
  /// An index of the whole link graph's team ids.
  TeamIdIndex() = default;
  /// An index for one robot: ids() holds the team ids of the connected parts of the link graph
  /// that hold an object of `robot` (equal there to the whole union-find's; the union-find's
  /// decisions in a part depend on that part's links only), and `conflicts` counts the links
  /// left out in those parts. Parts without the robot's objects are linked but not worked out:
  /// a robot needs the ids of its own objects, and at many robots most parts are others'.
  explicit TeamIdIndex(int robot) : robot_(robot) {}

  /// Replaces the links of `source` (duplicates: the strongest copy counts; a link may come from
  /// several sources, the strongest counts). ids() follows at the next commit().
  void stage(int source, std::vector<ObjectLink> links);
  /// Works the staged changes into ids(); true when any link of the union changed.
  bool commit();
  /// stage() and commit().
  bool set_links(int source, std::vector<ObjectLink> links);
  const TeamIds& ids() const { return ids_; }
  /// Commits that changed something, and of those the ones that merged teams over added links
  /// only (no part worked out again).
  long long commits() const { return commits_; }
  long long merge_only_commits() const { return merge_only_commits_; }

 private:
  /// A link as seen from one of its keys.
  struct Edge {
    ObjectKey other = 0;
    /// Kept on the smaller key's side only: the smallest squared distance any source gives the
    /// link, whether the union-find left it out, and the distance each source gives it.
    double strongest = 0.0;
    bool conflict = false;
    std::vector<std::pair<int, double>> sources;
  };
  void add(int source, const ObjectLink& link);
  void remove(int source, const ObjectLink& link);
  /// commit()'s shortcut when links were only added (none removed or re-weighed): each added
  /// link that joins two teams (or a new key and a team, or two new keys) without putting two
  /// objects of one robot together is worked in by merging them. Exact: such a link would have
  /// been taken by the union-find over all links, whatever its strength, and it leaves every
  /// other decision as it was (the teams it merges only grow within conflict-free final teams,
  /// and a conflict stays one). The keys of the other added links go to `unresolved`: their
  /// parts are worked out again (which also redoes whatever was merged in them).
  void merge_added(std::vector<ObjectKey>& unresolved);
  /// The members of `key`'s team, or nullptr for a key in no team.
  std::vector<ObjectKey>* members_of(ObjectKey key);
  /// Whether the connected part of the link graph that holds `start` holds an object of robot_;
  /// `known` keeps the answer for every key of each part looked at.
  bool part_holds_robot(ObjectKey start, std::unordered_map<ObjectKey, bool>& known) const;
  /// The link's edge on key `from`'s side, or nullptr.
  Edge* edge(ObjectKey from, ObjectKey to);
  /// The edge to `to` among one key's edges, or nullptr.
  static Edge* edge_in(std::vector<Edge>& edges, ObjectKey to);

  /// The robot whose parts are worked out, or -1 for all.
  int robot_ = -1;
  /// Every source's links, ascending by (a, b), one per pair.
  std::map<int, std::vector<ObjectLink>> sources_;
  /// The link graph of the union of the sources' links: each key's links.
  std::unordered_map<ObjectKey, std::vector<Edge>> adjacent_;
  /// Keys of links changed since the last commit.
  std::vector<ObjectKey> touched_;
  /// Links new to the union since the last commit (in the order added), and whether every
  /// change since then was one of them (else commit() works the touched parts out again).
  std::vector<ObjectLink> added_;
  bool only_added_ = true;
  long long commits_ = 0;
  long long merge_only_commits_ = 0;
  int conflicts_ = 0;
  TeamIds ids_;
};

}  // namespace concord::association

#pragma once
/// \file
/// One team id per physical object, consistent over any number of robots: a union-find over the
/// accepted pairwise correspondences (links). A team id never holds two objects of one robot (a
/// robot's objects are distinct by its own account); a link that would make it do so is a
/// conflict, left out and counted. Links are taken strongest first (smallest Mahalanobis
/// distance, then by their keys), so every robot that knows the same links computes the same ids.

#include <map>
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

}  // namespace concord::association

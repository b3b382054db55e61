#pragma once
/// \file
/// Maximum clique of an undirected graph by branch and bound with greedy colouring bounds (Tomita
/// and Seki's MCQ): the consistency graph of candidate correspondences has a vertex per candidate
/// and an edge between two candidates whose geometry agrees; the largest set of mutually consistent
/// candidates is its maximum clique (as in CLIPPER, which relaxes it to a densest subgraph).
/// Deterministic: vertices are ordered by degree (then index) and the first maximum found is kept.

#include <cstdint>
#include <vector>

namespace concord::association {

/// An undirected graph on vertices 0..n-1 as adjacency bit sets.
class ConsistencyGraph {
 public:
  explicit ConsistencyGraph(int vertices = 0);

  int size() const { return vertices_; }
  /// Adds the edge {a, b} (a != b, both in range; asserted).
  void add_edge(int a, int b);
  /// Adds the edges {a, b} for every b > a whose bit is set in `upper` (words() words laid out
  /// as row(); bits at or below a, and beyond size(), must be clear; asserted). Row a's words
  /// are or-ed in whole and each b's bit for a is set: the same graph as add_edge one by one.
  void add_edges_above(int a, const std::uint64_t* upper);
  bool adjacent(int a, int b) const {
    return (rows_[static_cast<std::size_t>(a) * words_ + (b >> 6)] >> (b & 63)) & 1U;
  }
  int degree(int vertex) const;
  /// The adjacency bits of a vertex: words() words, bit b of word w for vertex 64 w + b.
  const std::uint64_t* row(int vertex) const {
    return rows_.data() + static_cast<std::size_t>(vertex) * words_;
  }
  std::size_t words() const { return words_; }
  /// Number of edges.
  long long edges() const;

 private:
  int vertices_ = 0;
  std::size_t words_ = 0;
  std::vector<std::uint64_t> rows_;
};

/// A clique and how it was found.
struct CliqueResult {
  /// Vertices of the clique, ascending.
  std::vector<int> vertices;
  /// Whether the search finished (the clique is a maximum); false when it stopped at the budget
  /// (the clique is then the largest found).
  bool exact = true;
  /// Branch-and-bound nodes expanded.
  long long expansions = 0;
};

/// A maximum clique of `graph` among the vertices with allowed[v] (all when allowed is empty),
/// expanding at most max_expansions nodes. With min_size, a caller that has no use for a smaller
/// clique says so: branches that cannot reach min_size vertices are cut from the start, and the
/// result is empty when no clique has that many (a maximum clique of at least min_size vertices
/// is the same one the search without it returns, found with fewer expansions).
CliqueResult maximum_clique(const ConsistencyGraph& graph, long long max_expansions,
                            const std::vector<bool>& allowed = {}, int min_size = 0);

}  // namespace concord::association

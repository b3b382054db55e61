#include "concord/association/max_clique.h"

#include <algorithm>
#include <bit>
#include <cassert>
#include <numeric>
#include <utility>

namespace concord::association {

ConsistencyGraph::ConsistencyGraph(int vertices)
    : vertices_(vertices),
      words_((static_cast<std::size_t>(vertices) + 63) / 64),
      rows_(static_cast<std::size_t>(vertices) * words_, 0) {}

void ConsistencyGraph::add_edge(int a, int b) {
  assert(a != b && a >= 0 && b >= 0 && a < vertices_ && b < vertices_);
  rows_[static_cast<std::size_t>(a) * words_ + (b >> 6)] |= std::uint64_t{1} << (b & 63);
  rows_[static_cast<std::size_t>(b) * words_ + (a >> 6)] |= std::uint64_t{1} << (a & 63);
}

void ConsistencyGraph::add_edges_above(int a, const std::uint64_t* upper) {
  assert(a >= 0 && a < vertices_);
  std::uint64_t* row_a = rows_.data() + static_cast<std::size_t>(a) * words_;
  const std::uint64_t a_bit = std::uint64_t{1} << (a & 63);
  for (std::size_t w = 0; w < words_; ++w) {
    std::uint64_t bits = upper[w];
    if (bits == 0) continue;
    row_a[w] |= bits;
    do {
      const int b = static_cast<int>(w * 64) + std::countr_zero(bits);
      assert(b > a && b < vertices_);
      rows_[static_cast<std::size_t>(b) * words_ + (static_cast<std::size_t>(a) >> 6)] |= a_bit;
      bits &= bits - 1;
    } while (bits != 0);
  }
}

int ConsistencyGraph::degree(int vertex) const {
  int count = 0;
  for (std::size_t w = 0; w < words_; ++w) {
    count += std::popcount(rows_[static_cast<std::size_t>(vertex) * words_ + w]);
  }
  return count;
}

long long ConsistencyGraph::edges() const {
  long long twice = 0;
  for (int v = 0; v < vertices_; ++v) twice += degree(v);
  return twice / 2;
}

namespace {

/// MCQ: candidates are kept in colour order; a branch is cut when the clique so far plus the
/// colour of the candidate cannot beat the best.
class CliqueSearch {
 public:
  CliqueSearch(const ConsistencyGraph& graph, long long max_expansions, int min_size)
      : graph_(graph),
        max_expansions_(max_expansions),
        floor_(static_cast<std::size_t>(std::max(min_size - 1, 0))) {}

  CliqueResult run(std::vector<int> candidates) {
    // Initial order: degree descending, then index (deterministic).
    std::vector<int> degree(graph_.size(), 0);
    for (int v : candidates) degree[v] = graph_.degree(v);
    std::stable_sort(candidates.begin(), candidates.end(),
                     [&](int a, int b) { return degree[a] > degree[b]; });
    // One set of buffers a depth (a clique holds at most every candidate), made once: the search
    // allocates nothing per expansion.
    levels_.resize(candidates.size() + 1);
    std::vector<int> clique;
    clique.reserve(candidates.size());
    expand(clique, candidates);
    CliqueResult result;
    result.vertices = best_;
    std::sort(result.vertices.begin(), result.vertices.end());
    result.exact = !stopped_;
    result.expansions = expansions_;
    return result;
  }

 private:
  /// The buffers of one depth of the search.
  struct Level {
    std::vector<int> ordered, colours, next;
  };

  /// Greedy sequential colouring of `candidates` (in their order); returns them sorted by colour
  /// (in their order within a colour) with the colour (1-based) of each.
  void colour(const std::vector<int>& candidates, std::vector<int>& ordered,
              std::vector<int>& colours) {
    // A vertex goes to the first class holding none of its neighbours. Each class keeps the
    // union of its members' neighbours (the graph is undirected: v is adjacent to a member
    // exactly when v is among the members' neighbours), so the test is one bit a class, and a
    // vertex that joins a class adds its row to that union.
    const std::size_t words = graph_.words();
    std::size_t classes = 0;
    class_bits_.clear();
    class_sizes_.clear();
    colours.resize(candidates.size());  // first the class of each candidate, in their order
    for (std::size_t n = 0; n < candidates.size(); ++n) {
      const int v = candidates[n];
      const std::size_t word = static_cast<std::size_t>(v) >> 6;
      const std::uint64_t mask = std::uint64_t{1} << (v & 63);
      std::size_t c = 0;
      while (c < classes && (class_bits_[c * words + word] & mask) != 0) ++c;
      if (c == classes) {
        ++classes;
        class_bits_.resize(class_bits_.size() + words, 0);
        class_sizes_.push_back(0);
      }
      colours[n] = static_cast<int>(c);
      ++class_sizes_[c];
      const std::uint64_t* row = graph_.row(v);
      std::uint64_t* neighbours = class_bits_.data() + c * words;
      for (std::size_t w = 0; w < words; ++w) neighbours[w] |= row[w];
    }
    // Counting sort by class, stable: class_sizes_ becomes each class's first position.
    int position = 0;
    for (int& size : class_sizes_) position += std::exchange(size, position);
    ordered.resize(candidates.size());
    for (std::size_t n = 0; n < candidates.size(); ++n) {
      ordered[static_cast<std::size_t>(class_sizes_[static_cast<std::size_t>(colours[n])]++)] =
          candidates[n];
    }
    // Colours in the sorted order: class c's members now end at class_sizes_[c].
    std::size_t n = 0;
    for (std::size_t c = 0; c < classes; ++c) {
      for (; n < static_cast<std::size_t>(class_sizes_[c]); ++n) {
        colours[n] = static_cast<int>(c) + 1;
      }
    }
  }

  void expand(std::vector<int>& clique, const std::vector<int>& candidates) {
    if (stopped_) return;
    if (++expansions_ > max_expansions_) {
      stopped_ = true;
      return;
    }
    Level& level = levels_[clique.size()];
    std::vector<int>& ordered = level.ordered;
    std::vector<int>& colours = level.colours;
    std::vector<int>& next = level.next;
    colour(candidates, ordered, colours);
    for (int i = static_cast<int>(ordered.size()) - 1; i >= 0; --i) {
      if (clique.size() + static_cast<std::size_t>(colours[i]) <= bound()) return;
      const int v = ordered[i];
      clique.push_back(v);
      // v's neighbours among the candidates before it, in their order: each candidate is
      // written, and kept by advancing past it when adjacent (no branch to mispredict).
      const std::uint64_t* row = graph_.row(v);
      next.resize(static_cast<std::size_t>(i));
      std::size_t kept = 0;
      for (int j = 0; j < i; ++j) {
        const int u = ordered[j];
        next[kept] = u;
        kept += (row[u >> 6] >> (u & 63)) & 1U;
      }
      next.resize(kept);
      if (next.empty()) {
        if (clique.size() > bound()) best_ = clique;
      } else {
        expand(clique, next);
      }
      clique.pop_back();
      if (stopped_) return;
    }
  }

  /// The size a new clique must beat: the best so far, or min_size - 1 before one that large.
  std::size_t bound() const { return std::max(best_.size(), floor_); }

  const ConsistencyGraph& graph_;
  long long max_expansions_;
  std::size_t floor_;
  long long expansions_ = 0;
  bool stopped_ = false;
  std::vector<int> best_;
  /// colour()'s neighbours of each class's members (words() words a class) and class sizes,
  /// reused between calls.
  std::vector<std::uint64_t> class_bits_;
  std::vector<int> class_sizes_;
  /// levels_[d]: the buffers of the expansion of a clique of d vertices.
  std::vector<Level> levels_;
};

}  // namespace

CliqueResult maximum_clique(const ConsistencyGraph& graph, long long max_expansions,
                            const std::vector<bool>& allowed, int min_size) {
  std::vector<int> candidates;
  for (int v = 0; v < graph.size(); ++v) {
    if (allowed.empty() || allowed[v]) candidates.push_back(v);
  }
  if (candidates.empty()) return {};
  return CliqueSearch(graph, max_expansions, min_size).run(std::move(candidates));
}

}  // namespace concord::association

#pragma once
// The median used by the front-end's statistics (flow, residuals, per-track figures).

#include <algorithm>
#include <cstddef>
#include <vector>

namespace concord::frontend {

/// The upper median of a sample (the element at size / 2 after sorting; 0 when empty).
inline double median_of(std::vector<double> values) {
  if (values.empty()) return 0.0;
  const auto middle = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), middle, values.end());
  return *middle;
}

}  // namespace concord::frontend

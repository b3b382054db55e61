#pragma once
/// \file
/// Counts the heap allocations of the calling thread, for tests that a code path allocates
/// nothing. The test executable replaces malloc, calloc and realloc (forwarding to glibc's own);
/// operator new and Eigen's dynamic matrices allocate through them. Sanitizer builds own malloc:
/// there nothing is counted and counting_allocations() is false.

#include <cstddef>

namespace concord::testing {

/// Whether this build counts allocations.
bool counting_allocations();

/// Allocations (malloc, calloc, realloc) made by this thread so far.
std::size_t allocations();

}  // namespace concord::testing

#include "allocation_counter.h"

#if CONCORD_COUNT_ALLOCATIONS

#include <cstdlib>

extern "C" {
// glibc's allocator under its own names: what the replacements below forward to.
void* __libc_malloc(std::size_t size);
void* __libc_calloc(std::size_t count, std::size_t size);
void* __libc_realloc(void* pointer, std::size_t size);
}

namespace {
// Zero-initialized and trivial: reading it never allocates (the executable's own TLS).
thread_local std::size_t thread_allocations = 0;
}  // namespace

extern "C" {

void* malloc(std::size_t size) {
  ++thread_allocations;
  return __libc_malloc(size);
}

void* calloc(std::size_t count, std::size_t size) {
  ++thread_allocations;
  return __libc_calloc(count, size);
}

void* realloc(void* pointer, std::size_t size) {
  ++thread_allocations;
  return __libc_realloc(pointer, size);
}

}  // extern "C"

namespace concord::testing {
bool counting_allocations() { return true; }
std::size_t allocations() { return thread_allocations; }
}  // namespace concord::testing

#else

namespace concord::testing {
bool counting_allocations() { return false; }
std::size_t allocations() { return 0; }
}  // namespace concord::testing

#endif

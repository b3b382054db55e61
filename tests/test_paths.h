#pragma once
// Where the tests find the source tree and the daemon they start (set by tests/CMakeLists.txt),
// and whether this build runs under a sanitizer.

#include <filesystem>

namespace concord::testing {

inline const std::filesystem::path kSource = CONCORD_SOURCE_DIR;
inline const std::filesystem::path kDaemon = CONCORD_DAEMON_PATH;

/// Whether this build runs under a sanitizer (ASan, TSan or UBSan): some tests skip or relax
/// what only a Release build can show (the package, memory figures), and the longest runs are
/// shortened there (the sanitizers check memory and threads; Release runs the full lengths).
#if defined(__SANITIZE_ADDRESS__) || defined(__SANITIZE_THREAD__)
constexpr bool kSanitized = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer) || __has_feature(thread_sanitizer) || \
    __has_feature(undefined_behavior_sanitizer)
constexpr bool kSanitized = true;
#else
constexpr bool kSanitized = false;
#endif
#else
constexpr bool kSanitized = false;
#endif

}  // namespace concord::testing

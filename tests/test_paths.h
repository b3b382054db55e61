#pragma once
// Where the tests find the source tree and the daemon they start (set by tests/CMakeLists.txt).

#include <filesystem>

namespace concord::testing {

inline const std::filesystem::path kSource = CONCORD_SOURCE_DIR;
inline const std::filesystem::path kDaemon = CONCORD_DAEMON_PATH;

}  // namespace concord::testing

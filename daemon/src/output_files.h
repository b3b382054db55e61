#pragma once
/// \file
/// The daemon's output folder: atomic replacement of each file (temporary file, optional fsync,
/// rename, fsync of the folder), removal of temporary files left by a killed process, and the
/// start-up check that the folder is writable.

#include <filesystem>
#include <string>

namespace concord::daemon {

/// Writes `content` to `file` atomically: a temporary file in the same folder is written (and,
/// if `durable`, fsync'ed), renamed over `file`, and (if `durable`) the folder is fsync'ed so
/// the rename survives a power loss. Throws std::runtime_error naming the file.
void write_output_file(const std::filesystem::path& file, const std::string& content, bool durable);

/// Creates `folder` if needed and proves it is writable (creates, fsyncs and removes a probe
/// file). Throws std::runtime_error naming the folder and the reason.
void check_output_folder(const std::filesystem::path& folder);

/// Removes temporary files of earlier runs (".NAME.tmp.*", as this writer and
/// dataset::write_file_atomically name them). Returns how many were removed.
int remove_stale_temporaries(const std::filesystem::path& folder);

}  // namespace concord::daemon

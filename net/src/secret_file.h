#pragma once
// Reading and writing the small secret files of a robot (the team key, its identity key): owner
// access only, read in one bounded piece, written exclusively and synced.
#include <filesystem>
#include <string>

namespace concord::net::detail {

/// The text of the secret file at `path`. Throws TeamKeyError with `name` (e.g. "team key
/// /etc/concord/team.key") if it is missing, not a regular file, readable or writable by group or
/// others (mode must be 0600 or 0400), or unreadable. The caller wipes the returned text.
std::string read_secret_file(const std::filesystem::path& path, const std::string& name);

/// Creates `path` with mode 0600 (never overwriting a file) holding `text`, synced. Throws
/// TeamKeyError with `name` on failure, leaving no partial file.
void write_secret_file(const std::filesystem::path& path, const std::string& name,
                       const std::string& text);

}  // namespace concord::net::detail

#pragma once
// Reading and writing the small secret files of a robot (the team key, its identity key): owner
// access only, read in one bounded piece, written exclusively and synced, the text wiped after
// use; and the hex form the keys are written in.
#include <cstddef>
#include <filesystem>
#include <string>
#include <string_view>

namespace concord::net::detail {

/// Overwrites `text` with zero bytes (sodium_memzero: not optimized away).
void wipe(std::string& text);

/// Wipes a string when it goes out of scope, however the scope is left.
struct WipeOnExit {
  std::string& text;
  ~WipeOnExit() { wipe(text); }
};

/// The text of the secret file at `path`. Throws TeamKeyError with `name` (e.g. "team key
/// /etc/concord/team.key") if it is missing, not a regular file, readable or writable by group or
/// others (mode must be 0600 or 0400), or unreadable. The caller wipes the returned text.
std::string read_secret_file(const std::filesystem::path& path, const std::string& name);

/// What `parse(text)` makes of the secret file's text; the text is wiped whether or not it
/// parses.
template <typename Parse>
auto parse_secret_file(const std::filesystem::path& path, const std::string& name, Parse parse) {
  std::string text = read_secret_file(path, name);
  const WipeOnExit wipe_text{text};
  return parse(text);
}

/// Creates `path` with mode 0600 (never overwriting a file) holding `text`, synced, and wipes
/// `text` whatever happens. Throws TeamKeyError with `name` on failure, leaving no partial file.
void write_secret_file(const std::filesystem::path& path, const std::string& name,
                       std::string& text);

/// Decodes exactly `size` bytes from `hex` (trailing spaces and line ends allowed); false
/// otherwise.
bool decode_hex(std::string_view hex, unsigned char* out, std::size_t size);
/// Lowercase hex digits of `size` bytes.
std::string encode_hex(const unsigned char* bytes, std::size_t size);

}  // namespace concord::net::detail

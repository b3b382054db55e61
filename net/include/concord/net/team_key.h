#pragma once
/// \file
/// The team's pre-shared key: 32 random bytes in a file that only the daemon's user may read
/// (`concord keygen` writes one). Every peer connection proves possession of it before anything
/// about the team is sent (secure_channel.h). The key bytes are never logged or printed; memory
/// holding them is wiped on destruction.

#include <array>
#include <cstddef>
#include <filesystem>
#include <stdexcept>
#include <string>

namespace concord::net {

/// A problem with a key file: missing, readable by others, malformed. The message names the path.
class TeamKeyError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

/// Initializes libsodium (once; later calls are cheap). Throws TeamKeyError if it cannot.
void ensure_sodium();

/// 32 secret bytes shared by the team.
class TeamKey {
 public:
  static constexpr std::size_t kBytes = 32;

  /// A key of all zero bytes (only for tests that need some key; never for a team).
  TeamKey();
  ~TeamKey();
  TeamKey(const TeamKey& other);
  TeamKey& operator=(const TeamKey& other);

  /// A fresh key from the operating system's random source (libsodium randombytes).
  [[nodiscard]] static TeamKey generate();
  /// The key of `text` in the key file format (see format()); throws TeamKeyError.
  [[nodiscard]] static TeamKey parse(const std::string& text, const std::string& source_name);
  /// A key derived from a passphrase-like seed, deterministic (tests only).
  [[nodiscard]] static TeamKey from_seed_for_tests(const std::string& seed);

  /// The key file text: "concord-team-key-v1 <64 hex digits>\n".
  [[nodiscard]] std::string format() const;

  const unsigned char* data() const { return bytes_.data(); }

 private:
  std::array<unsigned char, kBytes> bytes_{};
};

/// Reads a key file. Throws TeamKeyError naming `path` if it is missing, not a regular file,
/// readable or writable by group or others (mode must be 0600 or 0400), or malformed.
[[nodiscard]] TeamKey load_team_key(const std::filesystem::path& path);

/// Writes a new key file with mode 0600 (created exclusively: an existing file is never
/// overwritten). Throws TeamKeyError naming the path.
void write_team_key(const std::filesystem::path& path, const TeamKey& key);

}  // namespace concord::net

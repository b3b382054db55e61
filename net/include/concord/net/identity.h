#pragma once
/// \file
/// Per-robot identities: an Ed25519 signing key per robot (libsodium `crypto_sign`), the team's
/// public keys in every robot's config. The team key (team_key.h) says "a member of this team";
/// an identity says "robot 3". A connection's Hello is signed over the channel's transcript, so a
/// key holder cannot take another member's id on a connection, and an owner's association record
/// is signed by its owner, so it cannot be forged by the robots that relay it
/// (docs/network.md, "Identities").
///
/// Identity key file: "concord-identity-key-v1 <64 hex digits>\n" (the 32-byte seed), mode 0600,
/// written by `concord keygen --identity`; its public key is 64 hex digits.

#include <array>
#include <cstddef>
#include <filesystem>
#include <map>
#include <string>
#include <string_view>

#include "concord/net/team_key.h"

namespace concord::net {

/// Bytes of a signature.
inline constexpr std::size_t kSignatureBytes = 64;

/// A robot's public key (Ed25519).
class PublicKey {
 public:
  static constexpr std::size_t kBytes = 32;

  /// The key of 64 hex digits; throws TeamKeyError naming `source_name` otherwise.
  [[nodiscard]] static PublicKey parse(std::string_view hex, const std::string& source_name);
  /// 64 lowercase hex digits.
  [[nodiscard]] std::string hex() const;
  /// True if `signature` (kSignatureBytes) is this key's signature of `message`.
  [[nodiscard]] bool verify(std::string_view message, std::string_view signature) const;

  bool operator==(const PublicKey& other) const = default;

  std::array<unsigned char, kBytes> bytes{};
};

/// The members' public keys, by robot id.
using MemberKeys = std::map<int, PublicKey>;

/// A robot's signing key. The secret bytes are never logged or printed, and wiped on destruction.
class RobotIdentity {
 public:
  RobotIdentity();  ///< no key (sign() throws)
  ~RobotIdentity();
  RobotIdentity(const RobotIdentity& other);
  RobotIdentity& operator=(const RobotIdentity& other);

  /// A fresh key from the operating system's random source.
  [[nodiscard]] static RobotIdentity generate();
  /// The key of `text` in the key file format; throws TeamKeyError naming `source_name`.
  [[nodiscard]] static RobotIdentity parse(const std::string& text, const std::string& source_name);
  /// A key derived from a seed string, deterministic (tests only).
  [[nodiscard]] static RobotIdentity from_seed_for_tests(const std::string& seed);

  /// The key file text: "concord-identity-key-v1 <64 hex digits>\n".
  [[nodiscard]] std::string format() const;
  [[nodiscard]] const PublicKey& public_key() const { return public_key_; }
  /// The signature (kSignatureBytes) of `message`.
  [[nodiscard]] std::string sign(std::string_view message) const;

 private:
  void from_seed(const unsigned char* seed);
  std::array<unsigned char, 32> seed_{};
  std::array<unsigned char, 64> secret_{};  // libsodium's secret key: seed and public key
  PublicKey public_key_;
  bool valid_ = false;
};

/// Reads an identity key file (same rules as load_team_key: owner-only mode, bounded size).
[[nodiscard]] RobotIdentity load_identity(const std::filesystem::path& path);
/// Writes a new identity key file with mode 0600 (never overwriting one).
void write_identity(const std::filesystem::path& path, const RobotIdentity& identity);

/// What a robot signs in its Hello: a domain tag, the channel's binding
/// (SecureChannel::binding()), the signer's role in the channel (0 dialer, 1 acceptor) and its
/// robot id. Bound to this connection's fresh keys: it cannot be replayed on another connection.
[[nodiscard]] std::string hello_signing_bytes(std::string_view binding, bool signer_dialed,
                                              int robot);

}  // namespace concord::net

#pragma once
/// \file
/// The authenticated, encrypted channel every peer connection (and a non-loopback ingest port)
/// runs in, from libsodium's high-level APIs only: `crypto_kx` (X25519 ephemeral key exchange),
/// `crypto_auth` (HMAC-SHA-512-256 proof of the team key), `crypto_kdf` / `crypto_generichash`
/// (key derivation) and `crypto_secretstream_xchacha20poly1305` (one stream per direction:
/// authenticated encryption, nonces managed by libsodium, reordering, replay and truncation
/// detected). Pure: no sockets, so it is unit-tested and fuzzed alone. docs/network.md gives the
/// message layout.
///
///   both sides:  ChannelHello  = magic "CNCD" | protocol version (u32 BE) | ephemeral public key
///                                (32) | random nonce (32)                       -- 72 bytes
///   both sides:  ChannelProof  = HMAC(auth key, transcript | role) (32) | secretstream header (24)
///   then every frame's payload = secretstream ciphertext of one serialized Envelope
///
/// The transcript is both ChannelHellos (initiator's first), so a proof is bound to this
/// connection's fresh keys and nonces and cannot be replayed or reflected (the role is in it).
/// Nothing about the team (name, robot id, addresses) is sent before the peer's proof is
/// verified: the first Envelope goes out encrypted, after accept_proof() succeeded.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>

#include "concord/net/team_key.h"

namespace concord::net {

/// Wire protocol version: 2 = the concord.v1 schema inside this authenticated channel.
inline constexpr std::uint32_t kChannelProtocolVersion = 2;
/// Size of a ChannelHello payload.
inline constexpr std::size_t kChannelHelloBytes = 72;
/// Size of a ChannelProof payload.
inline constexpr std::size_t kChannelProofBytes = 56;
/// Bytes a sealed message adds to its plaintext.
inline constexpr std::size_t kChannelOverheadBytes = 17;

/// One side of one connection's channel.
class SecureChannel {
 public:
  enum class Role { kInitiator, kResponder };  ///< the dialer initiates
  enum class Stage { kAwaitingHello, kAwaitingProof, kEstablished, kFailed };

  /// Draws this connection's ephemeral key pair and nonce.
  SecureChannel(const TeamKey& key, Role role);
  ~SecureChannel();
  SecureChannel(const SecureChannel&) = delete;
  SecureChannel& operator=(const SecureChannel&) = delete;

  /// Our ChannelHello: send it first.
  [[nodiscard]] const std::string& hello() const { return hello_; }

  /// The peer's ChannelHello. Returns our ChannelProof to send next, or std::nullopt with
  /// `error` set (wrong size, magic or version, a weak public key); the channel then fails.
  [[nodiscard]] std::optional<std::string> accept_hello(std::string_view peer_hello,
                                                        std::string& error);
  /// The peer's ChannelProof. True once the peer proved the team key: the channel is
  /// established. False with `error` set otherwise (the channel fails).
  [[nodiscard]] bool accept_proof(std::string_view peer_proof, std::string& error);

  /// Encrypts one message (established only).
  [[nodiscard]] std::string seal(std::string_view plaintext);
  /// Encrypts one message into `ciphertext`, which must be exactly plaintext.size() +
  /// kChannelOverheadBytes long and must not overlap it (established only; std::logic_error
  /// otherwise): a sender seals straight into its write buffer (append_raw_frame_space).
  void seal(std::string_view plaintext, std::span<char> ciphertext);
  /// Decrypts one message; std::nullopt with `error` set if it was forged, replayed, reordered
  /// or corrupted (the channel then fails).
  [[nodiscard]] std::optional<std::string> open(std::string_view ciphertext, std::string& error);
  /// The same into `plaintext` (its storage kept from message to message); false with `error`
  /// set, and `plaintext` unspecified, where the other form returns std::nullopt.
  [[nodiscard]] bool open(std::string_view ciphertext, std::string& plaintext, std::string& error);

  /// 32 bytes that only the two ends of this connection can compute (a hash of both hellos and
  /// both session keys), once the peer's hello was accepted (std::logic_error before): a robot's
  /// identity signs it in its Hello (identity.h), which binds the signature to this connection.
  [[nodiscard]] std::string binding() const;

  Stage stage() const { return stage_; }
  bool established() const { return stage_ == Stage::kEstablished; }
  Role role() const { return role_; }

 private:
  struct Secrets;
  Role role_;
  Stage stage_ = Stage::kAwaitingHello;
  std::string hello_;
  std::string peer_hello_;
  std::unique_ptr<Secrets> secrets_;  // key material, wiped on destruction
};

/// Encrypts a discovery beacon with a key derived from the team key (crypto_secretbox, random
/// 24-byte nonce per beacon): a beacon tells an outsider nothing about the team.
[[nodiscard]] std::string seal_beacon(const TeamKey& key, std::string_view plaintext);
/// Decrypts a beacon; std::nullopt if it was not sealed with this team's key.
[[nodiscard]] std::optional<std::string> open_beacon(const TeamKey& key,
                                                     std::string_view ciphertext);

}  // namespace concord::net

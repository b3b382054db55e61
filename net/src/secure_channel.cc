#include "concord/net/secure_channel.h"

#include <sodium.h>

#include <array>
#include <cstring>
#include <stdexcept>

namespace concord::net {

namespace {

constexpr unsigned char kMagic[4] = {'C', 'N', 'C', 'D'};
constexpr char kKdfContext[crypto_kdf_CONTEXTBYTES + 1] = "concord2";  // 8 bytes
constexpr std::uint64_t kAuthKeyId = 1;
constexpr std::uint64_t kStreamKeyId = 2;
constexpr std::uint64_t kBeaconKeyId = 3;

static_assert(kChannelHelloBytes == 8 + crypto_kx_PUBLICKEYBYTES + 32);
static_assert(kChannelProofBytes ==
              crypto_auth_BYTES + crypto_secretstream_xchacha20poly1305_HEADERBYTES);
static_assert(kChannelOverheadBytes == crypto_secretstream_xchacha20poly1305_ABYTES);
static_assert(TeamKey::kBytes == crypto_kdf_KEYBYTES);

using Key = std::array<unsigned char, 32>;

Key derive(const TeamKey& team, std::uint64_t id) {
  Key key{};
  crypto_kdf_derive_from_key(key.data(), key.size(), id, kKdfContext, team.data());
  return key;
}

const unsigned char* bytes(std::string_view text) {
  return reinterpret_cast<const unsigned char*>(text.data());
}

}  // namespace

struct SecureChannel::Secrets {
  Key auth_key{};
  Key stream_key{};
  std::array<unsigned char, crypto_kx_PUBLICKEYBYTES> public_key{};
  std::array<unsigned char, crypto_kx_SECRETKEYBYTES> secret_key{};
  crypto_secretstream_xchacha20poly1305_state push{};
  crypto_secretstream_xchacha20poly1305_state pull{};
  Key peer_rx{};  // kx receive key until the peer's header arrives
  std::string transcript;
  Key binding{};  // channel binding (binding()), set with the transcript

  ~Secrets() {
    sodium_memzero(binding.data(), binding.size());
    sodium_memzero(auth_key.data(), auth_key.size());
    sodium_memzero(stream_key.data(), stream_key.size());
    sodium_memzero(secret_key.data(), secret_key.size());
    sodium_memzero(&push, sizeof push);
    sodium_memzero(&pull, sizeof pull);
    sodium_memzero(peer_rx.data(), peer_rx.size());
  }
};

SecureChannel::SecureChannel(const TeamKey& key, Role role)
    : role_(role), secrets_(std::make_unique<Secrets>()) {
  ensure_sodium();
  secrets_->auth_key = derive(key, kAuthKeyId);
  secrets_->stream_key = derive(key, kStreamKeyId);
  crypto_kx_keypair(secrets_->public_key.data(), secrets_->secret_key.data());
  hello_.resize(kChannelHelloBytes);
  auto* out = reinterpret_cast<unsigned char*>(hello_.data());
  std::memcpy(out, kMagic, 4);
  out[4] = static_cast<unsigned char>(kChannelProtocolVersion >> 24);
  out[5] = static_cast<unsigned char>(kChannelProtocolVersion >> 16);
  out[6] = static_cast<unsigned char>(kChannelProtocolVersion >> 8);
  out[7] = static_cast<unsigned char>(kChannelProtocolVersion);
  std::memcpy(out + 8, secrets_->public_key.data(), crypto_kx_PUBLICKEYBYTES);
  randombytes_buf(out + 8 + crypto_kx_PUBLICKEYBYTES, 32);
}

SecureChannel::~SecureChannel() = default;

std::optional<std::string> SecureChannel::accept_hello(std::string_view peer_hello,
                                                       std::string& error) {
  auto fail = [&](std::string reason) -> std::optional<std::string> {
    stage_ = Stage::kFailed;
    error = std::move(reason);
    return std::nullopt;
  };
  if (stage_ != Stage::kAwaitingHello) return fail("unexpected channel hello");
  if (peer_hello.size() != kChannelHelloBytes)
    return fail("channel hello of " + std::to_string(peer_hello.size()) + " bytes, expected " +
                std::to_string(kChannelHelloBytes) + " (not a Concord v2 peer?)");
  const unsigned char* in = bytes(peer_hello);
  if (std::memcmp(in, kMagic, 4) != 0) return fail("channel hello without the Concord magic");
  const std::uint32_t version = (std::uint32_t{in[4]} << 24) | (std::uint32_t{in[5]} << 16) |
                                (std::uint32_t{in[6]} << 8) | std::uint32_t{in[7]};
  if (version != kChannelProtocolVersion)
    return fail("protocol version " + std::to_string(version) + ", expected " +
                std::to_string(kChannelProtocolVersion));
  if (peer_hello == hello_) return fail("channel hello reflected back");
  peer_hello_.assign(peer_hello);
  const unsigned char* peer_public = in + 8;

  // 1. Ephemeral key exchange: the dialer is the kx client.
  Key rx{}, tx{};
  const int kx =
      role_ == Role::kInitiator
          ? crypto_kx_client_session_keys(rx.data(), tx.data(), secrets_->public_key.data(),
                                          secrets_->secret_key.data(), peer_public)
          : crypto_kx_server_session_keys(rx.data(), tx.data(), secrets_->public_key.data(),
                                          secrets_->secret_key.data(), peer_public);
  sodium_memzero(secrets_->secret_key.data(), secrets_->secret_key.size());
  if (kx != 0) return fail("weak public key in the channel hello");

  // 2. Transcript: both hellos, initiator's first.
  secrets_->transcript = role_ == Role::kInitiator ? hello_ + peer_hello_ : peer_hello_ + hello_;

  // 3. Direction keys bound to the team key and the transcript:
  //    key = BLAKE2b(key = stream key, kx session key | transcript).
  auto direction_key = [&](const Key& session) {
    Key out{};
    crypto_generichash_state state;
    crypto_generichash_init(&state, secrets_->stream_key.data(), secrets_->stream_key.size(),
                            out.size());
    crypto_generichash_update(&state, session.data(), session.size());
    crypto_generichash_update(&state, bytes(secrets_->transcript), secrets_->transcript.size());
    crypto_generichash_final(&state, out.data(), out.size());
    sodium_memzero(&state, sizeof state);
    return out;
  };
  // The channel binding a robot's identity signs (identity.h): the transcript and both session
  // keys, so only the two ends of this connection can compute it.
  {
    const Key& dialer_to_acceptor = role_ == Role::kInitiator ? tx : rx;
    const Key& acceptor_to_dialer = role_ == Role::kInitiator ? rx : tx;
    static constexpr std::string_view kBindingTag = "concord-channel-binding-v1";
    crypto_generichash_state state;
    crypto_generichash_init(&state, nullptr, 0, secrets_->binding.size());
    crypto_generichash_update(&state, bytes(kBindingTag), kBindingTag.size());
    crypto_generichash_update(&state, dialer_to_acceptor.data(), dialer_to_acceptor.size());
    crypto_generichash_update(&state, acceptor_to_dialer.data(), acceptor_to_dialer.size());
    crypto_generichash_update(&state, bytes(secrets_->transcript), secrets_->transcript.size());
    crypto_generichash_final(&state, secrets_->binding.data(), secrets_->binding.size());
    sodium_memzero(&state, sizeof state);
  }
  Key push_key = direction_key(tx);
  secrets_->peer_rx = direction_key(rx);
  sodium_memzero(rx.data(), rx.size());
  sodium_memzero(tx.data(), tx.size());

  // 4. Our proof (HMAC over transcript and our role) and our stream header.
  std::string proof(kChannelProofBytes, '\0');
  auto* out = reinterpret_cast<unsigned char*>(proof.data());
  const std::string message = secrets_->transcript + (role_ == Role::kInitiator ? "I" : "R");
  crypto_auth(out, bytes(message), message.size(), secrets_->auth_key.data());
  crypto_secretstream_xchacha20poly1305_init_push(&secrets_->push, out + crypto_auth_BYTES,
                                                  push_key.data());
  sodium_memzero(push_key.data(), push_key.size());
  stage_ = Stage::kAwaitingProof;
  return proof;
}

bool SecureChannel::accept_proof(std::string_view peer_proof, std::string& error) {
  auto fail = [&](std::string reason) {
    stage_ = Stage::kFailed;
    error = std::move(reason);
    return false;
  };
  if (stage_ != Stage::kAwaitingProof) return fail("unexpected channel proof");
  if (peer_proof.size() != kChannelProofBytes)
    return fail("channel proof of " + std::to_string(peer_proof.size()) + " bytes, expected " +
                std::to_string(kChannelProofBytes));
  const std::string message = secrets_->transcript + (role_ == Role::kInitiator ? "R" : "I");
  if (crypto_auth_verify(bytes(peer_proof), bytes(message), message.size(),
                         secrets_->auth_key.data()) != 0)
    return fail("the peer did not prove the team key");
  if (crypto_secretstream_xchacha20poly1305_init_pull(
          &secrets_->pull, bytes(peer_proof) + crypto_auth_BYTES, secrets_->peer_rx.data()) != 0)
    return fail("invalid stream header");
  sodium_memzero(secrets_->peer_rx.data(), secrets_->peer_rx.size());
  sodium_memzero(secrets_->auth_key.data(), secrets_->auth_key.size());
  stage_ = Stage::kEstablished;
  return true;
}

std::string SecureChannel::seal(std::string_view plaintext) {
  std::string out(plaintext.size() + kChannelOverheadBytes, '\0');
  seal(plaintext, out);
  return out;
}

void SecureChannel::seal(std::string_view plaintext, std::span<char> ciphertext) {
  if (stage_ != Stage::kEstablished)
    throw std::logic_error("SecureChannel::seal before established");
  if (ciphertext.size() != plaintext.size() + kChannelOverheadBytes)
    throw std::logic_error("SecureChannel::seal: ciphertext of " +
                           std::to_string(ciphertext.size()) + " bytes for a plaintext of " +
                           std::to_string(plaintext.size()));
  unsigned long long length = 0;
  crypto_secretstream_xchacha20poly1305_push(&secrets_->push,
                                             reinterpret_cast<unsigned char*>(ciphertext.data()),
                                             &length, bytes(plaintext), plaintext.size(), nullptr,
                                             0, crypto_secretstream_xchacha20poly1305_TAG_MESSAGE);
}

std::optional<std::string> SecureChannel::open(std::string_view ciphertext, std::string& error) {
  std::string out;
  if (!open(ciphertext, out, error)) return std::nullopt;
  return out;
}

bool SecureChannel::open(std::string_view ciphertext, std::string& plaintext, std::string& error) {
  if (stage_ != Stage::kEstablished) {
    error = "encrypted message before the channel is established";
    stage_ = Stage::kFailed;
    return false;
  }
  if (ciphertext.size() < kChannelOverheadBytes) {
    error = "encrypted message of " + std::to_string(ciphertext.size()) + " bytes is too short";
    stage_ = Stage::kFailed;
    return false;
  }
  plaintext.resize(ciphertext.size() - kChannelOverheadBytes);
  unsigned long long length = 0;
  unsigned char tag = 0;
  if (crypto_secretstream_xchacha20poly1305_pull(
          &secrets_->pull, reinterpret_cast<unsigned char*>(plaintext.data()), &length, &tag,
          bytes(ciphertext), ciphertext.size(), nullptr, 0) != 0 ||
      tag != crypto_secretstream_xchacha20poly1305_TAG_MESSAGE) {
    error = "message failed authentication (forged, replayed, reordered or corrupted)";
    stage_ = Stage::kFailed;
    return false;
  }
  plaintext.resize(static_cast<std::size_t>(length));
  return true;
}

std::string SecureChannel::binding() const {
  if (stage_ != Stage::kAwaitingProof && stage_ != Stage::kEstablished)
    throw std::logic_error("SecureChannel::binding: the peer's hello has not been accepted");
  return {reinterpret_cast<const char*>(secrets_->binding.data()), secrets_->binding.size()};
}

std::string seal_beacon(const TeamKey& key, std::string_view plaintext) {
  ensure_sodium();
  Key beacon_key = derive(key, kBeaconKeyId);
  std::string out(crypto_secretbox_NONCEBYTES + crypto_secretbox_MACBYTES + plaintext.size(), '\0');
  auto* nonce = reinterpret_cast<unsigned char*>(out.data());
  randombytes_buf(nonce, crypto_secretbox_NONCEBYTES);
  crypto_secretbox_easy(nonce + crypto_secretbox_NONCEBYTES, bytes(plaintext), plaintext.size(),
                        nonce, beacon_key.data());
  sodium_memzero(beacon_key.data(), beacon_key.size());
  return out;
}

std::optional<std::string> open_beacon(const TeamKey& key, std::string_view ciphertext) {
  ensure_sodium();
  if (ciphertext.size() < crypto_secretbox_NONCEBYTES + crypto_secretbox_MACBYTES)
    return std::nullopt;
  Key beacon_key = derive(key, kBeaconKeyId);
  const unsigned char* nonce = bytes(ciphertext);
  const std::size_t sealed = ciphertext.size() - crypto_secretbox_NONCEBYTES;
  std::string out(sealed - crypto_secretbox_MACBYTES, '\0');
  const int result = crypto_secretbox_open_easy(reinterpret_cast<unsigned char*>(out.data()),
                                                nonce + crypto_secretbox_NONCEBYTES, sealed, nonce,
                                                beacon_key.data());
  sodium_memzero(beacon_key.data(), beacon_key.size());
  if (result != 0) return std::nullopt;
  return out;
}

}  // namespace concord::net

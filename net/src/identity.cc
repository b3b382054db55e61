#include "concord/net/identity.h"

#include <sodium.h>

#include <stdexcept>

#include "secret_file.h"

namespace concord::net {

namespace {

constexpr std::string_view kHeader = "concord-identity-key-v1 ";
constexpr std::string_view kHelloTag = "concord-hello-identity-v1";

}  // namespace

PublicKey PublicKey::parse(std::string_view hex, const std::string& source_name) {
  ensure_sodium();
  PublicKey key;
  if (!detail::decode_hex(hex, key.bytes.data(), kBytes))
    throw TeamKeyError(source_name + ": malformed public key (expected " +
                       std::to_string(2 * kBytes) + " hex digits)");
  return key;
}

std::string PublicKey::hex() const { return detail::encode_hex(bytes.data(), bytes.size()); }

bool PublicKey::verify(std::string_view message, std::string_view signature) const {
  if (signature.size() != kSignatureBytes) return false;
  return crypto_sign_verify_detached(reinterpret_cast<const unsigned char*>(signature.data()),
                                     reinterpret_cast<const unsigned char*>(message.data()),
                                     message.size(), bytes.data()) == 0;
}

RobotIdentity::RobotIdentity() = default;
RobotIdentity::~RobotIdentity() {
  sodium_memzero(seed_.data(), seed_.size());
  sodium_memzero(secret_.data(), secret_.size());
}
RobotIdentity::RobotIdentity(const RobotIdentity& other) = default;
RobotIdentity& RobotIdentity::operator=(const RobotIdentity& other) = default;

void RobotIdentity::from_seed(const unsigned char* seed) {
  std::copy(seed, seed + seed_.size(), seed_.begin());
  if (crypto_sign_seed_keypair(public_key_.bytes.data(), secret_.data(), seed_.data()) != 0)
    throw TeamKeyError("libsodium could not derive a signing key");
  valid_ = true;
}

RobotIdentity RobotIdentity::generate() {
  ensure_sodium();
  std::array<unsigned char, 32> seed{};
  randombytes_buf(seed.data(), seed.size());
  RobotIdentity identity;
  identity.from_seed(seed.data());
  sodium_memzero(seed.data(), seed.size());
  return identity;
}

RobotIdentity RobotIdentity::from_seed_for_tests(const std::string& seed) {
  ensure_sodium();
  std::array<unsigned char, 32> bytes{};
  crypto_generichash(bytes.data(), bytes.size(),
                     reinterpret_cast<const unsigned char*>(seed.data()), seed.size(), nullptr, 0);
  RobotIdentity identity;
  identity.from_seed(bytes.data());
  return identity;
}

RobotIdentity RobotIdentity::parse(const std::string& text, const std::string& source_name) {
  ensure_sodium();
  const std::string_view view(text);
  if (view.substr(0, kHeader.size()) != kHeader)
    throw TeamKeyError(source_name +
                       ": not a Concord identity key (expected a line starting with '" +
                       std::string(kHeader) + "')");
  std::array<unsigned char, 32> seed{};
  if (!detail::decode_hex(view.substr(kHeader.size()), seed.data(), seed.size())) {
    sodium_memzero(seed.data(), seed.size());
    throw TeamKeyError(source_name + ": malformed identity key (expected 64 hex digits)");
  }
  RobotIdentity identity;
  identity.from_seed(seed.data());
  sodium_memzero(seed.data(), seed.size());
  return identity;
}

std::string RobotIdentity::format() const {
  if (!valid_) throw std::logic_error("RobotIdentity::format: no key");
  std::string hex = detail::encode_hex(seed_.data(), seed_.size());
  std::string text = std::string(kHeader) + hex + "\n";
  detail::wipe(hex);
  return text;
}

std::string RobotIdentity::sign(std::string_view message) const {
  if (!valid_) throw std::logic_error("RobotIdentity::sign: no key");
  std::string signature(kSignatureBytes, '\0');
  crypto_sign_detached(reinterpret_cast<unsigned char*>(signature.data()), nullptr,
                       reinterpret_cast<const unsigned char*>(message.data()), message.size(),
                       secret_.data());
  return signature;
}

RobotIdentity load_identity(const std::filesystem::path& path) {
  const std::string name = "identity key " + path.string();
  return detail::parse_secret_file(
      path, name, [&](const std::string& text) { return RobotIdentity::parse(text, name); });
}

void write_identity(const std::filesystem::path& path, const RobotIdentity& identity) {
  std::string text = identity.format();
  detail::write_secret_file(path, "identity key " + path.string(), text);
}

std::string hello_signing_bytes(std::string_view binding, bool signer_dialed, int robot) {
  std::string bytes(kHelloTag);
  bytes.append(binding);
  bytes.push_back(signer_dialed ? '\0' : '\1');
  const auto id = static_cast<std::uint32_t>(robot);
  for (int shift = 24; shift >= 0; shift -= 8)
    bytes.push_back(static_cast<char>((id >> shift) & 0xff));
  return bytes;
}

}  // namespace concord::net

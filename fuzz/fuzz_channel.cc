// libFuzzer target: the authenticated channel's handshake and message parsing on arbitrary
// bytes (a peer without the key, or a broken one): accept_hello, accept_proof and open must
// reject cleanly and never establish a channel with bytes that did not prove the key. Also the
// envelope parser on the decrypted payload position.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "concord/net/frame_codec.h"
#include "concord/net/secure_channel.h"
#include "concord/v1/concord.pb.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const concord::net::TeamKey key = concord::net::TeamKey::from_seed_for_tests("fuzz");
  const std::string_view bytes(reinterpret_cast<const char*>(data), size);
  const std::size_t split = size > 0 ? data[0] % (size + 1) : 0;
  std::string error;
  {
    // Responder: the fuzz input plays the dialer.
    concord::net::SecureChannel channel(key, concord::net::SecureChannel::Role::kResponder);
    const auto proof =
        channel.accept_hello(bytes.substr(0, std::min<std::size_t>(size, 72)), error);
    if (proof && channel.accept_proof(bytes.substr(std::min(split, size)), error)) std::abort();
    (void)channel.open(bytes, error);
  }
  {
    // A message on an established channel of the team: the fuzz input as ciphertext.
    concord::net::SecureChannel a(key, concord::net::SecureChannel::Role::kInitiator);
    concord::net::SecureChannel b(key, concord::net::SecureChannel::Role::kResponder);
    const auto proof_a = a.accept_hello(b.hello(), error);
    const auto proof_b = b.accept_hello(a.hello(), error);
    if (!proof_a || !proof_b || !b.accept_proof(*proof_a, error) ||
        !a.accept_proof(*proof_b, error))
      std::abort();
    if (b.open(bytes, error)) std::abort();  // forged without the stream key: never opens
  }
  concord::v1::Envelope envelope;
  (void)concord::net::parse_envelope(bytes, std::string("team"), envelope);
  (void)concord::net::open_beacon(key, bytes);
  return 0;
}

#pragma once
/// \file
/// The negotiated association on the wire: association::NegotiationMessage to and from
/// concord.v1.Negotiation (carried in a LandmarkSet), and the relabelling of a Marginal. Decoding
/// treats every byte as hostile: counts are bounded, every number checked (finite values,
/// positive definite covariances, rotations, ids and robots in range, objects sorted), and the
/// first problem is named. Encoding is exact (doubles bit for bit), so daemons reproduce concord
/// replay.

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "concord/association/negotiation.h"
#include "concord/daemon/config.h"
#include "concord/net/identity.h"

namespace concord::v1 {
class MapDescription;
class Negotiation;
}  // namespace concord::v1

namespace concord::daemon {

/// The bytes an owner signs of its record: a domain tag, then every field (owner, version, each
/// link, each frame edge with its corrections), integers big-endian and doubles as their IEEE
/// bits, in the order the wire carries them. The wire carries every double bit for bit, so a
/// receiver computes the same bytes from the record it read.
[[nodiscard]] std::string record_signing_bytes(const association::OwnerRecord& record);

/// Owner-record signatures with per-robot identities (docs/network.md, "Identities"): this
/// robot's own records are signed as they go out (each version once), and every record that
/// comes in must carry its owner's signature. Thread-safe.
class RecordSigner {
 public:
  RecordSigner(int robot, std::shared_ptr<const net::RobotIdentity> identity,
               net::MemberKeys member_keys);

  /// The signature `record` travels with: its own if it has one (relayed), this robot's for its
  /// own records, else empty.
  [[nodiscard]] std::string signature_of(const association::OwnerRecord& record) const;
  /// True if `record` carries a signature of its owner's key.
  [[nodiscard]] bool verifies(const association::OwnerRecord& record) const;

 private:
  int robot_;
  std::shared_ptr<const net::RobotIdentity> identity_;
  net::MemberKeys member_keys_;
  mutable std::mutex mutex_;
  mutable std::map<int, std::string> own_signatures_;  // by version, the newest few
};

/// Writes `message` (its sender is the envelope's) into `out`; with `signer`, every record goes
/// with its signature (RecordSigner::signature_of).
void to_wire(const association::NegotiationMessage& message, v1::Negotiation& out,
             const RecordSigner* signer = nullptr);
/// The same with the message's map description already written into `map` (to_wire below):
/// a round's description goes to every neighbour, and is written once.
void to_wire(const association::NegotiationMessage& message, const v1::MapDescription& map,
             v1::Negotiation& out, const RecordSigner* signer = nullptr);
/// Writes a map description into `out` (cleared first).
void to_wire(const association::MapDescription& map, v1::MapDescription& out);

/// The NegotiationMessage that `sender`'s Negotiation carries, or std::nullopt with `error`
/// naming the first problem. With `signer`, a record its owner did not sign (RecordSigner::
/// verifies) is left out of the message and counted in `*records_unsigned`.
[[nodiscard]] std::optional<association::NegotiationMessage> from_wire(
    const v1::Negotiation& message, int sender, const NegotiationLimits& limits, std::string& error,
    const RecordSigner* signer = nullptr, std::uint64_t* records_unsigned = nullptr);

}  // namespace concord::daemon

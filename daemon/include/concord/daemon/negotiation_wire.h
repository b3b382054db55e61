#pragma once
/// \file
/// The negotiated association on the wire: association::NegotiationMessage to and from
/// concord.v1.Negotiation (carried in a LandmarkSet), and the relabelling of a Marginal. Decoding
/// treats every byte as hostile: counts are bounded, every number checked (finite values,
/// positive definite covariances, rotations, ids and robots in range, objects sorted), and the
/// first problem is named. Encoding is exact (doubles bit for bit), so daemons reproduce concord
/// replay.

#include <optional>
#include <string>

#include "concord/association/negotiation.h"
#include "concord/daemon/config.h"

namespace concord::v1 {
class MapDescription;
class Negotiation;
}  // namespace concord::v1

namespace concord::daemon {

/// Writes `message` (its sender is the envelope's) into `out`.
void to_wire(const association::NegotiationMessage& message, v1::Negotiation& out);
/// The same with the message's map description already written into `map` (to_wire below):
/// a round's description goes to every neighbour, and is written once.
void to_wire(const association::NegotiationMessage& message, const v1::MapDescription& map,
             v1::Negotiation& out);
/// Writes a map description into `out` (cleared first).
void to_wire(const association::MapDescription& map, v1::MapDescription& out);

/// The NegotiationMessage that `sender`'s Negotiation carries, or std::nullopt with `error`
/// naming the first problem.
[[nodiscard]] std::optional<association::NegotiationMessage> from_wire(
    const v1::Negotiation& message, int sender, const NegotiationLimits& limits,
    std::string& error);

}  // namespace concord::daemon

#pragma once
/// \file
/// "host:port" addresses as written in configs and logs.

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace concord::net {

/// A host (name or IP literal) and a TCP/UDP port.
struct HostPort {
  std::string host;
  std::uint16_t port = 0;
  /// "host:port", IPv6 literals in brackets.
  std::string to_string() const;
  bool operator==(const HostPort&) const = default;
};

/// Parses "host:port" or "[ipv6]:port"; std::nullopt if malformed or the port is not 1-65535.
std::optional<HostPort> parse_host_port(std::string_view text);

}  // namespace concord::net

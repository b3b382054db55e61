#pragma once
/// \file
/// Framing of the Concord wire protocol, without sockets: every TCP frame (and every discovery
/// datagram) is a 4-byte big-endian payload length followed by one serialized concord.v1.Envelope.
///
/// `FrameDecoder` is a pure streaming parser in the spirit of Asio's HTTP `request_parser`: feed it
/// byte chunks of any size, pull complete envelopes out; it says "frame", "need more bytes" or
/// "error (with a reason)". A length above the maximum is rejected as soon as the 4 header bytes
/// are in, before any payload is buffered, so a peer can never make us allocate more than the
/// maximum. After an error the decoder stays failed: the connection it belongs to is closed.

#include <cstddef>
#include <cstdint>
#include <optional>
#include <span>
#include <string>
#include <string_view>

namespace concord::v1 {
class Envelope;
}  // namespace concord::v1

namespace concord::net {

/// `Envelope.protocol_version`, receivers reject any other value. 2: peer connections run in
/// the authenticated channel of secure_channel.h; 3: a Marginal's double covariance blocks travel
/// in its flat fields (block_landmarks, packed_upper), which a version-2 daemon does not read.
inline constexpr std::uint32_t kProtocolVersion = 3;
/// Size of the big-endian length prefix.
inline constexpr std::size_t kFrameHeaderBytes = 4;
/// Default hard maximum of one frame's payload.
inline constexpr std::size_t kDefaultMaxFrameBytes = std::size_t{16} << 20;
/// Bytes a session reads from its socket per call (frames larger than this take several reads).
inline constexpr std::size_t kReadChunkBytes = 64 * 1024;

/// Why a frame was rejected.
enum class FrameErrorKind {
  kNone,
  kZeroLength,       ///< length prefix 0 (an Envelope with protocol_version set is never empty)
  kOversized,        ///< length prefix above the maximum
  kGarbage,          ///< payload is not a parsable Envelope
  kWrongVersion,     ///< Envelope.protocol_version differs from kProtocolVersion
  kWrongTeam,        ///< Envelope.team differs from the expected team
  kUnauthenticated,  ///< the channel handshake failed or a message failed authentication
};

/// Short stable name of an error kind ("oversized", "garbage", ...), for logs and counters.
std::string_view to_string(FrameErrorKind kind);

/// A rejected frame: the kind and a one-line human-readable reason.
struct FrameError {
  FrameErrorKind kind = FrameErrorKind::kNone;
  std::string reason;
};

/// Serializes `envelope` as one frame (length prefix + payload).
std::string encode_frame(const v1::Envelope& envelope);

/// Appends one frame for `envelope` to `out` (lets a writer batch several frames in one buffer).
void append_frame(const v1::Envelope& envelope, std::string& out);

/// Checks the header fields every receiver checks: protocol version and, if `expected_team` is
/// set, the team. Returns kNone when the envelope is acceptable.
FrameError check_envelope(const v1::Envelope& envelope,
                          const std::optional<std::string>& expected_team);

/// Parses one frame payload as an Envelope and checks it like check_envelope(); kNone on success.
[[nodiscard]] FrameError parse_envelope(std::string_view payload,
                                        const std::optional<std::string>& expected_team,
                                        v1::Envelope& envelope);

/// Appends one frame holding `payload` as it is (handshake messages, ciphertext).
void append_raw_frame(std::string_view payload, std::string& out);
/// Appends the header of a frame of `payload_bytes` and room for its payload; returns that room
/// (valid until `out` changes again) for the caller to fill, e.g. SecureChannel::seal.
std::span<char> append_raw_frame_space(std::size_t payload_bytes, std::string& out);

/// What a decoder accepts.
struct FrameDecoderOptions {
  /// Largest accepted payload in bytes (the length prefix excluded).
  std::size_t max_frame_bytes = kDefaultMaxFrameBytes;
  /// Team every envelope must carry; std::nullopt accepts any team.
  std::optional<std::string> team;
};

/// Streaming decoder of length-prefixed Envelope frames.
class FrameDecoder {
 public:
  enum class Status {
    kFrame,     ///< `next` filled its argument with one complete, valid envelope
    kNeedMore,  ///< no complete frame buffered yet; feed more bytes
    kError,     ///< the stream is invalid (see error()); it stays failed
  };

  explicit FrameDecoder(FrameDecoderOptions options = {});

  /// Appends received bytes. Bytes fed after an error are ignored.
  void feed(std::string_view bytes);

  /// Extracts the next complete frame into `envelope` (call until it stops returning kFrame).
  [[nodiscard]] Status next(v1::Envelope& envelope);

  /// Extracts the next complete frame's payload without parsing it (for channel messages and
  /// ciphertext); the length checks are the same as next()'s.
  [[nodiscard]] Status next_payload(std::string& payload);

  /// Marks the stream failed with `kind` (a layer above found the payload invalid).
  void fail_with(FrameErrorKind kind, std::string reason) { fail(kind, std::move(reason)); }

  /// The reason of the first error (kind kNone while the stream is valid).
  const FrameError& error() const { return error_; }
  bool failed() const { return error_.kind != FrameErrorKind::kNone; }

  /// Bytes received but not yet returned as frames.
  std::size_t buffered_bytes() const { return buffer_.size() - read_offset_; }

  const FrameDecoderOptions& options() const { return options_; }

 private:
  Status fail(FrameErrorKind kind, std::string reason);
  /// Length-checks the next frame; kFrame with its payload length when complete.
  Status peek(std::uint32_t& length);

  FrameDecoderOptions options_;
  std::string buffer_;
  std::size_t read_offset_ = 0;  // start of the unconsumed bytes in buffer_
  FrameError error_;
};

}  // namespace concord::net

#include "concord/net/frame_codec.h"

#include <algorithm>
#include <cassert>
#include <limits>
#include <stdexcept>
#include <utility>

#include "concord/v1/concord.pb.h"

namespace concord::net {

std::string_view to_string(FrameErrorKind kind) {
  switch (kind) {
    case FrameErrorKind::kNone:
      return "none";
    case FrameErrorKind::kZeroLength:
      return "zero-length";
    case FrameErrorKind::kOversized:
      return "oversized";
    case FrameErrorKind::kGarbage:
      return "garbage";
    case FrameErrorKind::kWrongVersion:
      return "wrong-version";
    case FrameErrorKind::kWrongTeam:
      return "wrong-team";
    case FrameErrorKind::kUnauthenticated:
      return "unauthenticated";
  }
  return "unknown";
}

void append_frame(const v1::Envelope& envelope, std::string& out) {
  const std::size_t payload_bytes = envelope.ByteSizeLong();
  // A 4-byte prefix cannot describe more; protobuf itself refuses messages above 2 GiB.
  assert(payload_bytes <= std::numeric_limits<std::uint32_t>::max());
  const auto length = static_cast<std::uint32_t>(payload_bytes);
  const std::size_t start = out.size();
  out.resize(start + kFrameHeaderBytes + payload_bytes);
  auto* header = reinterpret_cast<unsigned char*>(out.data() + start);
  header[0] = static_cast<unsigned char>(length >> 24);
  header[1] = static_cast<unsigned char>(length >> 16);
  header[2] = static_cast<unsigned char>(length >> 8);
  header[3] = static_cast<unsigned char>(length);
  envelope.SerializeWithCachedSizesToArray(header + kFrameHeaderBytes);
}

void append_raw_frame(std::string_view payload, std::string& out) {
  const std::span<char> room = append_raw_frame_space(payload.size(), out);
  std::copy(payload.begin(), payload.end(), room.begin());
}

std::span<char> append_raw_frame_space(std::size_t payload_bytes, std::string& out) {
  if (payload_bytes > std::numeric_limits<std::uint32_t>::max())
    throw std::length_error("frame payload above 4 GiB");
  const auto length = static_cast<std::uint32_t>(payload_bytes);
  out.push_back(static_cast<char>(length >> 24));
  out.push_back(static_cast<char>(length >> 16));
  out.push_back(static_cast<char>(length >> 8));
  out.push_back(static_cast<char>(length));
  const std::size_t start = out.size();
  out.resize(start + payload_bytes);
  return {out.data() + start, payload_bytes};
}

std::string encode_frame(const v1::Envelope& envelope) {
  std::string out;
  append_frame(envelope, out);
  return out;
}

FrameError check_envelope(const v1::Envelope& envelope,
                          const std::optional<std::string>& expected_team) {
  if (envelope.protocol_version() != kProtocolVersion)
    return {FrameErrorKind::kWrongVersion, "protocol version " +
                                               std::to_string(envelope.protocol_version()) +
                                               ", expected " + std::to_string(kProtocolVersion)};
  if (expected_team && envelope.team() != *expected_team)
    return {FrameErrorKind::kWrongTeam,
            "team '" + envelope.team() + "', expected '" + *expected_team + "'"};
  return {};
}

FrameError parse_envelope(std::string_view payload, const std::optional<std::string>& expected_team,
                          v1::Envelope& envelope) {
  envelope.Clear();
  if (payload.size() > static_cast<std::size_t>(std::numeric_limits<int>::max()) ||
      !envelope.ParseFromArray(payload.data(), static_cast<int>(payload.size())))
    return {FrameErrorKind::kGarbage,
            "payload of " + std::to_string(payload.size()) + " bytes is not a valid Envelope"};
  return check_envelope(envelope, expected_team);
}

FrameDecoder::FrameDecoder(FrameDecoderOptions options) : options_(std::move(options)) {}

void FrameDecoder::feed(std::string_view bytes) {
  if (failed()) return;
  // Drop consumed bytes before growing, so the buffer stays within one frame plus one chunk.
  if (read_offset_ == buffer_.size()) {
    buffer_.clear();
    read_offset_ = 0;
  } else if (read_offset_ > 0 && read_offset_ >= buffer_.size() / 2) {
    buffer_.erase(0, read_offset_);
    read_offset_ = 0;
  }
  buffer_.append(bytes);
}

FrameDecoder::Status FrameDecoder::fail(FrameErrorKind kind, std::string reason) {
  error_ = {kind, std::move(reason)};
  buffer_.clear();
  buffer_.shrink_to_fit();
  read_offset_ = 0;
  return Status::kError;
}

FrameDecoder::Status FrameDecoder::peek(std::uint32_t& length) {
  if (failed()) return Status::kError;
  const std::size_t available = buffer_.size() - read_offset_;
  if (available < kFrameHeaderBytes) return Status::kNeedMore;

  // 1. Length prefix: checked before any payload is waited for.
  const auto* header = reinterpret_cast<const unsigned char*>(buffer_.data() + read_offset_);
  length = (std::uint32_t{header[0]} << 24) | (std::uint32_t{header[1]} << 16) |
           (std::uint32_t{header[2]} << 8) | std::uint32_t{header[3]};
  if (length == 0) return fail(FrameErrorKind::kZeroLength, "zero-length frame");
  if (length > options_.max_frame_bytes ||
      length > static_cast<std::uint32_t>(std::numeric_limits<int>::max()))
    return fail(FrameErrorKind::kOversized, "frame of " + std::to_string(length) +
                                                " bytes exceeds the maximum of " +
                                                std::to_string(options_.max_frame_bytes));
  if (available - kFrameHeaderBytes < length) return Status::kNeedMore;
  return Status::kFrame;
}

FrameDecoder::Status FrameDecoder::next_payload(std::string& payload) {
  std::uint32_t length = 0;
  const Status status = peek(length);
  if (status != Status::kFrame) return status;
  payload.assign(buffer_.data() + read_offset_ + kFrameHeaderBytes, length);
  read_offset_ += kFrameHeaderBytes + length;
  return Status::kFrame;
}

FrameDecoder::Status FrameDecoder::next(v1::Envelope& envelope) {
  std::uint32_t length = 0;
  const Status status = peek(length);
  if (status != Status::kFrame) return status;

  // 2. Payload: one Envelope, then the checks every receiver makes.
  const std::string_view payload(buffer_.data() + read_offset_ + kFrameHeaderBytes, length);
  FrameError check = parse_envelope(payload, options_.team, envelope);
  if (check.kind != FrameErrorKind::kNone) return fail(check.kind, std::move(check.reason));
  read_offset_ += kFrameHeaderBytes + length;
  return Status::kFrame;
}

}  // namespace concord::net

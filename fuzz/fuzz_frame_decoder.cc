// libFuzzer target: the frame decoder on arbitrary bytes, fed in arbitrary chunks. It must never
// crash, never buffer more than one maximum frame plus one chunk, and stay failed after an error.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "concord/net/frame_codec.h"
#include "concord/v1/concord.pb.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size == 0) return 0;
  concord::net::FrameDecoderOptions options;
  options.max_frame_bytes = 4096;
  options.team = (data[0] & 1) ? std::optional<std::string>("team") : std::nullopt;
  concord::net::FrameDecoder decoder(options);
  const std::size_t chunk = 1 + data[0] % 64;
  concord::v1::Envelope envelope;
  for (std::size_t offset = 1; offset < size; offset += chunk) {
    const std::size_t length = std::min(chunk, size - offset);
    decoder.feed(std::string_view(reinterpret_cast<const char*>(data + offset), length));
    while (true) {
      const auto status = decoder.next(envelope);
      if (status != concord::net::FrameDecoder::Status::kFrame) break;
    }
    if (decoder.buffered_bytes() > options.max_frame_bytes + 4 + chunk) std::abort();
    if (decoder.failed() && decoder.next(envelope) != concord::net::FrameDecoder::Status::kError)
      std::abort();
  }
  return 0;
}

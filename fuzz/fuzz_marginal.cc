// libFuzzer target: the validators of what peers and sensors send, on arbitrary protobuf bytes:
// Marginal -> from_wire (sizes, blocks, finiteness) and SensorFrame -> from_wire. Never crash,
// and an accepted marginal is well formed.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "concord/daemon/wire.h"
#include "concord/v1/concord.pb.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > (1 << 16)) return 0;
  std::string error;
  concord::v1::Marginal marginal;
  if (marginal.ParseFromArray(data, static_cast<int>(size))) {
    const auto parsed = concord::daemon::from_wire(marginal, error);
    if (parsed && !parsed->well_formed()) std::abort();
  }
  concord::v1::SensorFrame frame;
  if (frame.ParseFromArray(data, static_cast<int>(size))) {
    const auto parsed = concord::daemon::from_wire(frame, error);
    if (parsed && parsed->frame < 0) std::abort();
  }
  return 0;
}

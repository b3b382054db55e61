// libFuzzer target: the validators of what peers and sensors send, on arbitrary protobuf bytes:
// Marginal -> from_wire (sizes, blocks, finiteness), SensorFrame -> from_wire and Negotiation ->
// from_wire (the negotiated association's descriptions and owner records). Never crash, and what
// is accepted is well formed; a Marginal read into storage that held another one is the same as
// one read afresh.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "concord/daemon/negotiation_wire.h"
#include "concord/daemon/wire.h"
#include "concord/v1/concord.pb.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size > (1 << 16)) return 0;
  std::string error;
  concord::v1::Marginal marginal;
  if (marginal.ParseFromArray(data, static_cast<int>(size))) {
    const auto parsed = concord::daemon::from_wire(marginal, error);
    if (parsed && !parsed->well_formed()) std::abort();
    // Read into storage that held another marginal (as a daemon reads into the last round's):
    // the same verdict and, when accepted, the same marginal, nothing left over.
    concord::Marginal reused;
    reused.ids = {1, 2, 3};
    reused.mean = Eigen::VectorXd::Constant(9, 7.0);
    reused.blocks = {Eigen::MatrixXd::Identity(6, 6), Eigen::MatrixXd::Identity(3, 3)};
    const bool read = concord::daemon::from_wire(marginal, error, reused);
    if (read != parsed.has_value()) std::abort();
    if (read) {
      if (reused.ids != parsed->ids || reused.mean.size() != parsed->mean.size() ||
          reused.mean != parsed->mean || reused.blocks.size() != parsed->blocks.size())
        std::abort();
      for (std::size_t b = 0; b < reused.blocks.size(); ++b) {
        if (reused.blocks[b].rows() != parsed->blocks[b].rows() ||
            reused.blocks[b].cols() != parsed->blocks[b].cols() ||
            reused.blocks[b] != parsed->blocks[b])
          std::abort();
      }
    }
  }
  concord::v1::SensorFrame frame;
  if (frame.ParseFromArray(data, static_cast<int>(size))) {
    const auto parsed = concord::daemon::from_wire(frame, error);
    if (parsed && parsed->frame < 0) std::abort();
  }
  concord::v1::Negotiation negotiation;
  if (negotiation.ParseFromArray(data, static_cast<int>(size))) {
    const auto parsed =
        concord::daemon::from_wire(negotiation, 1, concord::daemon::NegotiationLimits{}, error);
    if (parsed && parsed->map) {
      for (std::size_t n = 0; n < parsed->map->objects.size(); ++n) {
        const auto& object = parsed->map->objects[n];
        if (!object.position.allFinite() || !object.covariance.allFinite() ||
            (n > 0 && parsed->map->objects[n - 1].id >= object.id))
          std::abort();
      }
    }
  }
  return 0;
}

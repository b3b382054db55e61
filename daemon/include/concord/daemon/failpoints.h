#pragma once
/// \file
/// Failpoints: named points in the daemon that a fault-injection test switches on with
/// `concordd --failpoint NAME[=ARG]` (a testing aid, in the spirit of etcd's gofail), so that a
/// fault test is deterministic and needs no sleeps.
///
///   marginal.silence        heartbeats and LandmarkSets go on, Marginals are never sent
///   marginal.garbage        Marginals are sent malformed (one mean value too many)
///   estimator.hang=SECONDS  the estimator thread hangs that long before its second frame
///                           (heartbeats go on: the network thread is not affected)
///   output.fail             every output write fails (as on a full or read-only disk)
///   exit.linger=SECONDS     after the outputs are written and the services stopped, the
///                           process waits that long before it exits (a stop signal then must
///                           not turn the clean exit into death by signal)

#include <string>

namespace concord::daemon {

struct Failpoints {
  bool marginal_silence = false;
  bool marginal_garbage = false;
  double estimator_hang_seconds = 0.0;
  bool output_fail = false;
  double exit_linger_seconds = 0.0;

  bool any() const {
    return marginal_silence || marginal_garbage || estimator_hang_seconds > 0.0 || output_fail ||
           exit_linger_seconds > 0.0;
  }
};

/// Switches on the failpoint `text` ("NAME" or "NAME=ARG"); returns "" or what is wrong.
[[nodiscard]] std::string enable_failpoint(const std::string& text, Failpoints& failpoints);

}  // namespace concord::daemon

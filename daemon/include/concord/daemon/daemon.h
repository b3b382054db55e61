#pragma once
/// \file
/// concordd: one robot's long-lived daemon (docs/daemon.md). A frame source (replay of one robot
/// folder, or live SensorFrame ingest over TCP) feeds a bounded queue; the estimator thread
/// processes each frame and runs its consensus round with the peers (ConsensusExchange over a
/// PeerNetwork); an HTTP endpoint serves the state as JSON; outputs are rewritten atomically
/// while running and at shutdown. Networking, HTTP and signals share one Asio io_context thread.

#include <memory>

#include "concord/daemon/config.h"

namespace concord::daemon {

/// Process exit codes of concordd (docs/daemon.md).
inline constexpr int kExitOk = 0;            ///< normal end, or after SIGTERM/SIGINT
inline constexpr int kExitCannotStart = 2;   ///< bad config or command line, key, data, output
                                             ///< directory, port in use
inline constexpr int kExitOutputFailed = 3;  ///< ran, but the final outputs could not be written

class Daemon {
 public:
  explicit Daemon(DaemonConfig config);
  ~Daemon();
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  /// Runs until the source is exhausted or a stop is requested (SIGINT/SIGTERM or
  /// request_stop()), writes the outputs and returns the process exit code: kExitOk,
  /// kExitCannotStart (the reason is logged) or kExitOutputFailed.
  [[nodiscard]] int run();

  /// Asks run() to finish the frame in progress, write the outputs and return. Any thread.
  void request_stop();

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace concord::daemon

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

class Daemon {
 public:
  explicit Daemon(DaemonConfig config);
  ~Daemon();
  Daemon(const Daemon&) = delete;
  Daemon& operator=(const Daemon&) = delete;

  /// Runs until the source is exhausted or a stop is requested (SIGINT/SIGTERM or
  /// request_stop()), writes the outputs and returns the process exit code: 0 on a normal end,
  /// 2 if the daemon could not start (bad data, port in use; the reason is logged).
  int run();

  /// Asks run() to finish the frame in progress, write the outputs and return. Any thread.
  void request_stop();

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace concord::daemon

#include "concord/daemon/daemon.h"

#include <spdlog/spdlog.h>
#include <sys/resource.h>

#include <algorithm>
#include <atomic>
#include <boost/asio/io_context.hpp>
#include <boost/asio/signal_set.hpp>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <sstream>
#include <thread>

#include "bounded_queue.h"
#include "concord/daemon/consensus_exchange.h"
#include "concord/daemon/wire.h"
#include "concord/dataset/dataset.h"
#include "concord/dataset/result_io.h"
#include "concord/estimator/estimator.h"
#include "concord/frontend/frontend.h"
#include "concord/frontend/frontend_options_file.h"
#include "concord/net/frame_listener.h"
#include "concord/net/peer_network.h"
#include "concord/v1/concord.pb.h"
#include "concord/web/http_server.h"
#include "concord/web/json_response.h"
#include "metrics_text.h"

namespace concord::daemon {

namespace {

using Clock = std::chrono::steady_clock;
using nlohmann::json;

double seconds_between(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

/// A frame waiting for the estimator, with when it arrived.
struct QueuedFrame {
  FrameInput input;
  double timestamp = 0.0;
  Clock::time_point arrival;
};

/// Percentile (nearest rank on a sorted copy) of a sample; 0 for an empty one.
template <typename T>
double percentile(std::vector<T> values, double p) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const auto rank = static_cast<std::size_t>(std::ceil(p / 100.0 * values.size()));
  return static_cast<double>(values[std::clamp<std::size_t>(rank, 1, values.size()) - 1]);
}

json pose_json(const Eigen::Isometry3d& pose) {
  const Eigen::Quaterniond q(pose.rotation());
  return {{"position", {pose.translation().x(), pose.translation().y(), pose.translation().z()}},
          {"quaternion", {{"w", q.w()}, {"x", q.x()}, {"y", q.y()}, {"z", q.z()}}}};
}

json matrix_json(const Eigen::MatrixXd& matrix) {
  json rows = json::array();
  for (Eigen::Index r = 0; r < matrix.rows(); ++r) {
    json row = json::array();
    for (Eigen::Index c = 0; c < matrix.cols(); ++c) row.push_back(matrix(r, c));
    rows.push_back(std::move(row));
  }
  return rows;
}

double seconds_ago(Clock::time_point then, Clock::time_point now) {
  if (then == Clock::time_point{}) return -1.0;
  return seconds_between(then, now);
}

}  // namespace

/// Everything the HTTP handlers and the output writer read, guarded by one mutex. The estimator
/// thread appends after each frame.
struct LiveState {
  mutable std::mutex mutex;
  std::string phase = "starting";
  std::vector<int> frames;
  std::vector<double> timestamps;
  std::vector<Eigen::Isometry3d> poses;
  /// The online covariance of every pose (right perturbation), with its frame.
  std::vector<dataset::PoseCovariance> pose_covariances;
  Eigen::Matrix<double, 6, 6> pose_covariance = Eigen::Matrix<double, 6, 6>::Zero();
  std::vector<ObjectEstimate> objects;
  std::uint64_t frames_rejected = 0;
  std::uint64_t frames_dropped = 0;
  std::uint64_t rounds = 0;
  std::uint64_t marginals_fused = 0;
  std::uint64_t landmarks_fused = 0;
  std::uint64_t objects_initialized = 0;
  double update_seconds = 0.0;
  double consensus_seconds = 0.0;  ///< whole rounds, waiting included
  double wait_seconds = 0.0;
  std::vector<double> latencies_ms;  ///< per frame: popped -> estimate published
  std::vector<std::uint64_t> bytes_per_round;
};

class Daemon::Impl {
 public:
  explicit Impl(DaemonConfig config) : config_(std::move(config)), queue_(config_.queue_capacity) {}

  int run();
  void request_stop();

 private:
  bool load_source();
  bool start_services();
  void register_routes();
  void replay_frames();
  void image_frames();
  void on_ingest(const v1::Envelope& envelope);
  void estimator_loop();
  bool process(QueuedFrame& item);
  void write_outputs(bool final);
  json stats_json() const;
  void shutdown_services();

  DaemonConfig config_;
  BoundedQueue<QueuedFrame> queue_;
  std::atomic<bool> stop_requested_{false};
  Clock::time_point started_ = Clock::now();

  // Source data (replay; images through the front-end).
  std::optional<dataset::RobotData> robot_;
  std::unique_ptr<frontend::StereoFrontend> frontend_;
  StereoCamera camera_;
  Eigen::Isometry3d start_pose_ = Eigen::Isometry3d::Identity();
  std::optional<Estimator> estimator_;

  boost::asio::io_context io_;
  std::unique_ptr<net::PeerNetwork> network_;
  std::unique_ptr<ConsensusExchange> exchange_;
  std::unique_ptr<web::HttpServer> http_;
  std::unique_ptr<net::FrameListener> ingest_;
  std::unique_ptr<boost::asio::signal_set> signals_;
  std::thread io_thread_;
  std::thread source_thread_;

  LiveState live_;
  Clock::time_point last_write_ = Clock::now();
  std::int64_t last_ingest_frame_ = -1;
};

bool Daemon::Impl::load_source() {
  try {
    if (config_.source.kind == SourceKind::kReplay) {
      dataset::ReadOptions options;
      options.only_robot = config_.source.robot;
      options.load_features = config_.source.point_features && config_.estimator.use_point_features;
      if (config_.source.max_frames > 0) options.max_frames = config_.source.max_frames;
      dataset::Dataset data = dataset::read_dataset(config_.source.dataset, options);
      camera_ = data.camera;
      robot_ = std::move(data.robots.front());
      start_pose_ = robot_->groundtruth.front();
      spdlog::info("source: replay of {} robot {} ({} frames{})", config_.source.dataset.string(),
                   config_.source.robot, robot_->num_frames(),
                   robot_->has_features ? ", point features" : "");
    } else if (config_.source.kind == SourceKind::kImages) {
      const SourceConfig& source = config_.source;
      frontend::SequenceReadOptions read_options;
      if (source.max_frames > 0) read_options.max_frames = source.max_frames;
      frontend::StereoSequence sequence =
          frontend::read_stereo_sequence(source.images, read_options);
      const frontend::FrontendOptions options =
          source.frontend.empty() ? frontend::FrontendOptions{}
                                  : frontend::load_frontend_options(source.frontend);
      const std::filesystem::path detections_file =
          source.detections.empty() ? source.images / "detections.csv" : source.detections;
      std::vector<std::vector<frontend::Detection>> detections;
      if (!source.detections.empty() || std::filesystem::exists(detections_file)) {
        detections = frontend::read_detections(detections_file, sequence.num_frames(),
                                               source.max_frames > 0);
      }
      if (sequence.groundtruth) {
        start_pose_ = sequence.groundtruth->front();
      } else {
        const auto& p = source.start_pose;
        start_pose_.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
        start_pose_.linear() =
            Eigen::Quaterniond(p[3], p[4], p[5], p[6]).normalized().toRotationMatrix();
      }
      const int frames = sequence.num_frames();
      frontend_ = std::make_unique<frontend::StereoFrontend>(std::move(sequence), options,
                                                             std::move(detections));
      camera_ = frontend_->camera();
      spdlog::info("source: images of {} through the front-end ({} frames{})",
                   source.images.string(), frames, detections.empty() ? "" : ", with detections");
    } else {
      camera_ = dataset::read_camera(config_.source.camera);
      const auto& p = config_.source.start_pose;
      start_pose_.translation() = Eigen::Vector3d(p[0], p[1], p[2]);
      start_pose_.linear() = Eigen::Quaterniond(p[3], p[4], p[5], p[6]).normalized().toRotationMatrix();
    }
  } catch (const std::exception& error) {
    spdlog::error("source: {}", error.what());
    return false;
  }
  return true;
}

bool Daemon::Impl::start_services() {
  try {
    if (config_.consensus.mode != ConsensusMode::kOff) {
      net::PeerNetworkOptions options;
      options.team = config_.team;
      options.robot_id = config_.robot_id;
      options.listen_address = config_.network.listen_address;
      options.listen_port = config_.network.listen_port;
      options.peers = config_.network.peers;
      options.max_frame_bytes = config_.network.max_frame_bytes;
      options.send_queue_limit = config_.network.send_queue_limit;
      options.heartbeat_interval = config_.network.heartbeat_interval;
      options.heartbeat_timeout = config_.network.heartbeat_timeout;
      options.capabilities = {"consensus." + to_string(config_.consensus.mode)};
      options.discovery.enabled = config_.network.discovery;
      options.discovery.address = config_.network.discovery_address;
      options.discovery.port = config_.network.discovery_port;
      network_ = std::make_unique<net::PeerNetwork>(io_, options);
      exchange_ = std::make_unique<ConsensusExchange>(
          config_.consensus, [this](int robot, const v1::Envelope& envelope) {
            return network_->send(robot, envelope);
          });
      network_->set_message_handler([this](int robot, const v1::Envelope& envelope) {
        exchange_->on_message(robot, envelope);
      });
      network_->set_peer_handler([this](int robot, bool up) {
        spdlog::info("peer: robot {} {}", robot, up ? "up" : "down");
        exchange_->on_peer(robot, up);
      });
      network_->start();
      spdlog::info("network: robot {} of team '{}' listening on {}:{}, {} static peers, mode {}",
                   config_.robot_id, config_.team, config_.network.listen_address,
                   network_->listen_port(), config_.network.peers.size(),
                   to_string(config_.consensus.mode));
    }
    if (config_.source.kind == SourceKind::kIngest) {
      net::FrameListenerOptions options;
      options.listen_address = config_.source.ingest_address;
      options.port = config_.source.ingest_port;
      options.max_frame_bytes = config_.network.max_frame_bytes;
      options.team = config_.team;
      ingest_ = std::make_unique<net::FrameListener>(io_, options);
      ingest_->set_envelope_handler(
          [this](std::uint64_t, const v1::Envelope& envelope) { on_ingest(envelope); });
      ingest_->start();
      spdlog::info("source: ingest of SensorFrame envelopes on {}:{}",
                   config_.source.ingest_address, ingest_->port());
    }
    if (config_.http.enabled) {
      web::ServerOptions options;
      options.address = config_.http.address;
      options.port = config_.http.port;
      http_ = std::make_unique<web::HttpServer>(io_, options);
      register_routes();
      http_->start();
      spdlog::info("http: serving on {}:{}", config_.http.address, http_->port());
    }
  } catch (const std::exception& error) {
    spdlog::error("start: {}", error.what());
    return false;
  }
  signals_ = std::make_unique<boost::asio::signal_set>(io_, SIGINT, SIGTERM);
  signals_->async_wait([this](const boost::system::error_code& error, int signal) {
    if (error) return;
    spdlog::info("signal {}: finishing the current frame and writing outputs", signal);
    request_stop();
  });
  return true;
}

void Daemon::Impl::request_stop() {
  stop_requested_ = true;
  if (exchange_) exchange_->stop();
  const std::size_t dropped = queue_.close_and_clear();
  if (dropped > 0) spdlog::info("stop: {} queued frames not processed", dropped);
}

void Daemon::Impl::replay_frames() {
  const auto period = config_.source.rate_hz > 0.0
                          ? std::chrono::duration_cast<Clock::duration>(
                                std::chrono::duration<double>(1.0 / config_.source.rate_hz))
                          : Clock::duration::zero();
  auto next = Clock::now();
  for (int k = 0; k < robot_->num_frames() && !stop_requested_; ++k) {
    if (period > Clock::duration::zero()) {
      // Pacing a replay at the sensor rate (not synchronisation).
      std::this_thread::sleep_until(next);
      next += period;
    }
    QueuedFrame item{robot_->frame_input(k), static_cast<double>(k), Clock::now()};
    if (!queue_.push(std::move(item))) return;
  }
  queue_.close();
}

/// The image source: the front-end processes frame after frame on this thread (at the camera rate
/// when rate_hz is set) and queues what the estimator takes. An unreadable image ends the source.
void Daemon::Impl::image_frames() {
  const auto period = config_.source.rate_hz > 0.0
                          ? std::chrono::duration_cast<Clock::duration>(
                                std::chrono::duration<double>(1.0 / config_.source.rate_hz))
                          : Clock::duration::zero();
  auto next = Clock::now();
  while (!frontend_->done() && !stop_requested_) {
    if (period > Clock::duration::zero()) {
      // Pacing at the camera rate (not synchronisation).
      std::this_thread::sleep_until(next);
      next += period;
    }
    frontend::FrontendFrame frame;
    try {
      frame = frontend_->process_next();
    } catch (const std::exception& error) {
      spdlog::error("source: front-end stopped at frame {}: {}", frontend_->next_frame(),
                    error.what());
      break;
    }
    if (frame.input.frame > 0 && !frame.motion.valid) {
      spdlog::warn("source: no visual odometry at frame {} (the previous motion is repeated)",
                   frame.input.frame);
    }
    QueuedFrame item{std::move(frame.input), frame.timestamp, Clock::now()};
    if (!queue_.push(std::move(item))) return;
  }
  queue_.close();
}

void Daemon::Impl::on_ingest(const v1::Envelope& envelope) {
  if (envelope.body_case() != v1::Envelope::kSensorFrame) {
    spdlog::warn("ingest: ignored a non-SensorFrame envelope from robot {}", envelope.sender());
    return;
  }
  const v1::SensorFrame& message = envelope.sensor_frame();
  std::string error;
  auto frame = from_wire(message, error);
  if (!frame) {
    std::lock_guard lock(live_.mutex);
    ++live_.frames_rejected;
    spdlog::warn("ingest: rejected: {}", error);
    return;
  }
  if (last_ingest_frame_ >= 0 && frame->frame != last_ingest_frame_ + 1) {
    std::lock_guard lock(live_.mutex);
    ++live_.frames_rejected;
    spdlog::warn("ingest: rejected frame {}: expected frame {}", frame->frame,
                 last_ingest_frame_ + 1);
    return;
  }
  const bool last = message.last();
  if (!queue_.try_push(QueuedFrame{std::move(*frame), message.timestamp(), Clock::now()})) {
    std::lock_guard lock(live_.mutex);
    ++live_.frames_dropped;
    spdlog::error("ingest: frame queue full ({} frames): frame {} dropped; the estimator cannot "
                  "keep up with the sensor rate", queue_.capacity(), message.frame());
    return;
  }
  last_ingest_frame_ = message.frame();
  if (last) {
    spdlog::info("ingest: last frame {} received", message.frame());
    queue_.close();
  }
}

bool Daemon::Impl::process(QueuedFrame& item) {
  const auto popped = Clock::now();
  if (!estimator_) {
    if (item.input.T_previous_current && config_.source.kind == SourceKind::kIngest) {
      item.input.T_previous_current.reset();  // the first frame is the known start
    }
    estimator_.emplace(config_.estimator, camera_, start_pose_, item.input.frame);
  }
  FrameReport report;
  try {
    report = estimator_->process(item.input);
  } catch (const std::invalid_argument& error) {
    std::lock_guard lock(live_.mutex);
    ++live_.frames_rejected;
    spdlog::warn("frame {} rejected: {}", item.input.frame, error.what());
    return false;
  }
  const auto updated = Clock::now();
  RoundReport round;
  std::uint64_t bytes = 0;
  if (exchange_) {
    const std::uint64_t before = network_->totals().bytes_out;
    round = exchange_->run_round(static_cast<std::uint64_t>(item.input.frame), *estimator_);
    bytes = network_->totals().bytes_out - before;
  }
  const auto done = Clock::now();
  {
    std::lock_guard lock(live_.mutex);
    live_.phase = "running";
    live_.frames.push_back(item.input.frame);
    live_.timestamps.push_back(item.timestamp);
    live_.poses.push_back(estimator_->current_pose());
    live_.pose_covariance = estimator_->current_pose_covariance();
    live_.pose_covariances.push_back({item.input.frame, live_.pose_covariance});
    live_.objects = estimator_->objects();
    live_.objects_initialized += static_cast<std::uint64_t>(report.objects.initialized);
    live_.update_seconds += seconds_between(popped, updated);
    if (exchange_) {
      ++live_.rounds;
      live_.marginals_fused += static_cast<std::uint64_t>(round.fused);
      live_.landmarks_fused += static_cast<std::uint64_t>(round.consensus.landmarks_fused);
      live_.consensus_seconds += seconds_between(updated, done);
      live_.wait_seconds += round.wait_seconds;
      live_.bytes_per_round.push_back(bytes);
    }
    live_.latencies_ms.push_back(1e3 * seconds_between(popped, done));
  }
  return true;
}

void Daemon::Impl::estimator_loop() {
  if (exchange_ && config_.consensus.wait_for_peers > 0) {
    {
      std::lock_guard lock(live_.mutex);
      live_.phase = "waiting_for_peers";
    }
    spdlog::info("waiting up to {} ms for {} peers", config_.consensus.startup_timeout.count(),
                 config_.consensus.wait_for_peers);
    const int live = exchange_->wait_for_peers(config_.consensus.wait_for_peers,
                                               config_.consensus.startup_timeout);
    if (live < config_.consensus.wait_for_peers && !stop_requested_) {
      spdlog::warn("starting with {} of {} peers live", live, config_.consensus.wait_for_peers);
    }
  }
  while (auto item = queue_.pop()) {
    if (stop_requested_) break;
    process(*item);
    if (config_.output.write_interval.count() > 0 &&
        Clock::now() - last_write_ >= config_.output.write_interval) {
      write_outputs(false);
    }
  }
}

void Daemon::Impl::write_outputs(bool final) {
  last_write_ = Clock::now();
  std::vector<Eigen::Isometry3d> poses;
  std::vector<dataset::PoseCovariance> pose_covariances;
  std::vector<ObjectEstimate> objects;
  {
    std::lock_guard lock(live_.mutex);
    poses = live_.poses;
    pose_covariances = live_.pose_covariances;
    objects = live_.objects;
  }
  try {
    std::filesystem::create_directories(config_.output.directory);
    dataset::write_trajectory_kitti(config_.output.directory / "trajectory.kitti", poses);
    dataset::write_pose_covariances_csv(config_.output.directory / "pose_covariance.csv",
                                        pose_covariances);
    dataset::write_objects_csv(config_.output.directory / "objects.csv", objects);
    if (final) {
      dataset::write_file_atomically(config_.output.directory / "stats.json",
                                     stats_json().dump(2) + "\n");
    }
  } catch (const std::exception& error) {
    spdlog::error("output: {}", error.what());
  }
}

json Daemon::Impl::stats_json() const {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  auto seconds = [](const timeval& t) { return t.tv_sec + 1e-6 * t.tv_usec; };
  std::lock_guard lock(live_.mutex);
  json stats = {
      {"robot_id", config_.robot_id},
      {"mode", to_string(config_.consensus.mode)},
      {"frames", live_.frames.size()},
      {"frames_rejected", live_.frames_rejected},
      {"frames_dropped", live_.frames_dropped},
      {"rounds", live_.rounds},
      {"marginals_fused", live_.marginals_fused},
      {"wall_seconds", seconds_between(started_, Clock::now())},
      {"cpu_user_seconds", seconds(usage.ru_utime)},
      {"cpu_system_seconds", seconds(usage.ru_stime)},
      {"update_seconds", live_.update_seconds},
      {"consensus_seconds", live_.consensus_seconds},
      {"wait_seconds", live_.wait_seconds},
      {"latency_ms", {{"p50", percentile(live_.latencies_ms, 50)},
                      {"p99", percentile(live_.latencies_ms, 99)},
                      {"max", percentile(live_.latencies_ms, 100)}}},
      {"bytes_sent_per_round", {{"median", percentile(live_.bytes_per_round, 50)},
                                {"max", percentile(live_.bytes_per_round, 100)}}},
  };
  if (network_) {
    const auto totals = network_->totals();
    stats["network"] = {{"bytes_out", totals.bytes_out},   {"bytes_in", totals.bytes_in},
                        {"messages_out", totals.messages_out}, {"messages_in", totals.messages_in},
                        {"send_drops", totals.send_drops},
                        {"rejected_oversized", totals.rejected_oversized},
                        {"rejected_garbage", totals.rejected_garbage},
                        {"rejected_handshake", totals.rejected_handshake}};
  }
  return stats;
}

void Daemon::Impl::register_routes() {
  http_->get("/healthz", [](const web::Request&) {
    return web::json_response(200, {{"status", "ok"}});
  });
  http_->get("/status", [this](const web::Request&) {
    json body = {{"robot_id", config_.robot_id},
                 {"team", config_.team},
                 {"mode", to_string(config_.consensus.mode)},
                 {"source", config_.source.kind == SourceKind::kReplay   ? "replay"
                            : config_.source.kind == SourceKind::kImages ? "images"
                                                                         : "ingest"},
                 {"uptime_seconds", seconds_between(started_, Clock::now())},
                 {"queue", queue_.size()}};
    body["live_peers"] = exchange_ ? exchange_->live_peers() : std::vector<int>{};
    std::lock_guard lock(live_.mutex);
    body["phase"] = live_.phase;
    body["frame"] = live_.frames.empty() ? json(nullptr) : json(live_.frames.back());
    body["frames_processed"] = live_.frames.size();
    body["rounds"] = live_.rounds;
    return web::json_response(200, body);
  });
  http_->get("/pose", [this](const web::Request&) {
    std::lock_guard lock(live_.mutex);
    if (live_.poses.empty()) return web::error_response(503, "no frame processed yet");
    json body = pose_json(live_.poses.back());
    body["frame"] = live_.frames.back();
    body["covariance"] = matrix_json(live_.pose_covariance);
    body["covariance_order"] = "rho_x rho_y rho_z phi_x phi_y phi_z (right perturbation)";
    return web::json_response(200, body);
  });
  http_->get("/trajectory", [this](const web::Request& request) {
    const auto it = request.query.find("format");
    const std::string format = it == request.query.end() ? "json" : it->second;
    std::lock_guard lock(live_.mutex);
    if (format == "json") {
      json poses = json::array();
      for (std::size_t i = 0; i < live_.poses.size(); ++i) {
        json entry = pose_json(live_.poses[i]);
        entry["frame"] = live_.frames[i];
        poses.push_back(std::move(entry));
      }
      return web::json_response(200, {{"robot_id", config_.robot_id}, {"poses", poses}});
    }
    if (format == "kitti") {
      return web::Response{200, "text/plain; charset=utf-8",
                           dataset::format_trajectory_kitti(live_.poses), {}};
    }
    if (format == "tum") {
      std::string text;
      char line[256];
      for (std::size_t i = 0; i < live_.poses.size(); ++i) {
        const Eigen::Isometry3d& T = live_.poses[i];
        const Eigen::Quaterniond q(T.rotation());
        std::snprintf(line, sizeof line, "%.9f %.9g %.9g %.9g %.9g %.9g %.9g %.9g\n",
                      live_.timestamps[i], T.translation().x(), T.translation().y(),
                      T.translation().z(), q.x(), q.y(), q.z(), q.w());
        text += line;
      }
      return web::Response{200, "text/plain; charset=utf-8", std::move(text), {}};
    }
    return web::error_response(400, "format: expected json, kitti or tum, got '" + format + "'");
  });
  http_->get("/objects", [this](const web::Request&) {
    std::lock_guard lock(live_.mutex);
    json objects = json::array();
    for (const ObjectEstimate& object : live_.objects) {
      objects.push_back({{"id", object.id},
                         {"position", {object.p_world.x(), object.p_world.y(), object.p_world.z()}},
                         {"covariance", matrix_json(object.covariance)}});
    }
    return web::json_response(200, {{"robot_id", config_.robot_id}, {"objects", objects}});
  });
  http_->get("/peers", [this](const web::Request&) {
    json peers = json::array();
    if (network_) {
      const auto now = Clock::now();
      for (const net::PeerStats& peer : network_->peers()) {
        peers.push_back({{"robot", peer.robot},
                         {"address", peer.address},
                         {"up", peer.up},
                         {"connected_for_seconds", peer.up ? seconds_ago(peer.connected_since, now) : -1.0},
                         {"last_seen_seconds_ago", seconds_ago(peer.last_seen, now)},
                         {"bytes_in", peer.bytes_in},
                         {"bytes_out", peer.bytes_out},
                         {"messages_in", peer.messages_in},
                         {"messages_out", peer.messages_out},
                         {"drops", peer.drops},
                         {"rtt_ms", 1e-6 * static_cast<double>(peer.rtt_last.count())},
                         {"rtt_mean_ms", 1e-6 * static_cast<double>(peer.rtt_mean.count())},
                         {"reconnects", peer.reconnects},
                         {"protocol_errors", peer.protocol_errors},
                         {"degree", peer.degree}});
      }
    }
    return web::json_response(200, {{"robot_id", config_.robot_id}, {"peers", peers}});
  });
  http_->get("/metrics", [this](const web::Request&) {
    MetricsText text;
    const std::string robot = "robot=\"" + std::to_string(config_.robot_id) + "\"";
    {
      std::lock_guard lock(live_.mutex);
      text.counter("concord_frames_processed_total", "Frames processed by the estimator",
                   robot, static_cast<double>(live_.frames.size()));
      text.counter("concord_frames_rejected_total", "Frames rejected (malformed or out of order)",
                   robot, static_cast<double>(live_.frames_rejected));
      text.counter("concord_frames_dropped_total", "Ingest frames dropped on a full queue", robot,
                   static_cast<double>(live_.frames_dropped));
      text.counter("concord_update_seconds_total", "Time in the estimator update", robot,
                   live_.update_seconds);
      text.counter("concord_consensus_seconds_total",
                   "Time in consensus rounds, waiting included", robot, live_.consensus_seconds);
      text.counter("concord_consensus_wait_seconds_total",
                   "Time waiting for neighbours in consensus rounds", robot, live_.wait_seconds);
      text.counter("concord_consensus_rounds_total", "Consensus rounds", robot,
                   static_cast<double>(live_.rounds));
      text.counter("concord_marginals_fused_total", "Neighbour marginals fused", robot,
                   static_cast<double>(live_.marginals_fused));
      text.gauge("concord_objects", "Objects in the map", robot,
                 static_cast<double>(live_.objects.size()));
      text.gauge("concord_frame_latency_p50_seconds", "Median frame latency (update + round)",
                 robot, 1e-3 * percentile(live_.latencies_ms, 50));
      text.gauge("concord_frame_latency_p99_seconds", "99th percentile frame latency", robot,
                 1e-3 * percentile(live_.latencies_ms, 99));
    }
    text.gauge("concord_frame_queue_depth", "Frames waiting for the estimator", robot,
               static_cast<double>(queue_.size()));
    if (exchange_) {
      const ExchangeCounters c = exchange_->counters();
      text.counter("concord_consensus_deadline_misses_total",
                   "Neighbours given up on at a round deadline", robot,
                   static_cast<double>(c.deadline_misses));
      text.counter("concord_consensus_malformed_total", "Unusable consensus messages", robot,
                   static_cast<double>(c.malformed));
    }
    if (network_) {
      const auto totals = network_->totals();
      text.gauge("concord_live_peers", "Peers up", robot,
                 static_cast<double>(network_->live_peers().size()));
      text.counter("concord_network_bytes_sent_total", "Bytes sent to peers", robot,
                   static_cast<double>(totals.bytes_out));
      text.counter("concord_network_bytes_received_total", "Bytes received from peers", robot,
                   static_cast<double>(totals.bytes_in));
      text.counter("concord_network_messages_sent_total", "Envelopes sent", robot,
                   static_cast<double>(totals.messages_out));
      text.counter("concord_network_messages_received_total", "Envelopes received", robot,
                   static_cast<double>(totals.messages_in));
      text.counter("concord_network_send_drops_total", "Messages not sent", robot,
                   static_cast<double>(totals.send_drops));
      text.counter("concord_network_frames_rejected_total",
                   "Connections closed for oversized, garbage or handshake violations", robot,
                   static_cast<double>(totals.rejected_oversized + totals.rejected_garbage +
                                       totals.rejected_handshake));
      for (const net::PeerStats& peer : network_->peers()) {
        const std::string labels = robot + ",peer=\"" + std::to_string(peer.robot) + "\"";
        text.gauge("concord_peer_up", "Whether a peer is up", labels, peer.up ? 1.0 : 0.0);
        text.counter("concord_peer_bytes_sent_total", "Bytes sent to a peer", labels,
                     static_cast<double>(peer.bytes_out));
        text.counter("concord_peer_bytes_received_total", "Bytes received from a peer", labels,
                     static_cast<double>(peer.bytes_in));
        text.counter("concord_peer_drops_total", "Messages to a peer dropped", labels,
                     static_cast<double>(peer.drops));
        text.gauge("concord_peer_rtt_seconds", "Last heartbeat round trip", labels,
                   1e-9 * static_cast<double>(peer.rtt_last.count()));
      }
    }
    const auto http = http_->counters();
    text.counter("concord_http_requests_total", "HTTP requests routed", robot,
                 static_cast<double>(http.requests));
    text.counter("concord_http_requests_rejected_total", "Malformed or oversized HTTP requests",
                 robot, static_cast<double>(http.requests_rejected));
    return web::Response{200, "text/plain; version=0.0.4; charset=utf-8", text.str(), {}};
  });
}

void Daemon::Impl::shutdown_services() {
  const std::uint64_t last_round = [&] {
    std::lock_guard lock(live_.mutex);
    return live_.frames.empty() ? std::uint64_t{0} : static_cast<std::uint64_t>(live_.frames.back());
  }();
  if (exchange_) exchange_->stop();
  if (network_) network_->stop(stop_requested_ ? "stopped" : "finished", last_round);
  if (ingest_) ingest_->stop();
  if (http_) http_->stop();
  if (signals_) {
    boost::system::error_code ignored;
    signals_->cancel(ignored);
  }
}

int Daemon::Impl::run() {
  if (!load_source()) return 2;
  if (!start_services()) {
    shutdown_services();
    io_.run();
    return 2;
  }
  io_thread_ = std::thread([this] {
    try {
      io_.run();
    } catch (const std::exception& error) {
      spdlog::critical("network thread: {}", error.what());
      request_stop();
    }
  });
  if (robot_) source_thread_ = std::thread([this] { replay_frames(); });
  if (frontend_) source_thread_ = std::thread([this] { image_frames(); });

  estimator_loop();

  {
    std::lock_guard lock(live_.mutex);
    live_.phase = stop_requested_ ? "stopped" : "finished";
  }
  write_outputs(true);
  {
    std::lock_guard lock(live_.mutex);
    spdlog::info("{}: {} frames, {} rounds; outputs in {}", live_.phase, live_.frames.size(),
                 live_.rounds, config_.output.directory.string());
  }
  queue_.close_and_clear();
  if (source_thread_.joinable()) source_thread_.join();
  shutdown_services();
  io_thread_.join();
  return 0;
}

Daemon::Daemon(DaemonConfig config) : impl_(std::make_unique<Impl>(std::move(config))) {}
Daemon::~Daemon() = default;
int Daemon::run() { return impl_->run(); }
void Daemon::request_stop() { impl_->request_stop(); }

}  // namespace concord::daemon

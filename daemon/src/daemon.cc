#include "concord/daemon/daemon.h"

#include <spdlog/spdlog.h>
#include <sys/resource.h>

#include <algorithm>
#include <atomic>
#include <boost/asio/io_context.hpp>
#include <boost/asio/signal_set.hpp>
#include <charconv>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <random>
#include <sstream>
#include <thread>

#include "bounded_queue.h"
#include "checkpoint.h"
#include "concord/config/options_file.h"
#include "concord/daemon/association_session.h"
#include "concord/daemon/consensus_exchange.h"
#include "concord/daemon/negotiation_wire.h"
#include "concord/daemon/wire.h"
#include "concord/dataset/dataset.h"
#include "concord/dataset/radio.h"
#include "concord/dataset/result_io.h"
#include "concord/estimator/estimator.h"
#include "concord/frontend/frontend.h"
#include "concord/frontend/frontend_options_file.h"
#include "concord/frontend/track_statistics.h"
#include "concord/net/frame_listener.h"
#include "concord/net/identity.h"
#include "concord/net/log_limiter.h"
#include "concord/net/peer_network.h"
#include "concord/net/team_key.h"
#include "concord/v1/concord.pb.h"
#include "concord/web/http_server.h"
#include "concord/web/json_response.h"
#include "concord/web/live_map.h"
#include "metrics_text.h"
#include "output_files.h"
#include "service_notifier.h"
#include "steady_time.h"
#include "trajectory_history.h"

namespace concord::daemon {

namespace {

using Clock = std::chrono::steady_clock;
using nlohmann::json;

/// A frame waiting for the estimator, with when it arrived.
struct QueuedFrame {
  FrameInput input;  ///< input.frame is the source's frame index (the consensus round)
  double timestamp = 0.0;
  Clock::time_point arrival;
  /// The detector's class of each object observation (parallel to input.objects), or empty.
  std::vector<int> object_classes;
};

/// Samples kept for percentiles: the latest ones only (a daemon runs for days).
constexpr std::size_t kMaxSamples = 8192;

template <typename T>
void push_bounded(std::vector<T>& samples, T value) {
  if (samples.size() >= kMaxSamples)
    samples.erase(samples.begin(), samples.begin() + kMaxSamples / 2);
  samples.push_back(value);
}

/// Rotation angle of a rotation matrix, radians.
/// The covariance of one frame's motion when it is unknown: uniform within the ingest
/// plausibility limits on each axis (sigma = limit / sqrt(3)).
Eigen::Matrix<double, 6, 6> unknown_motion_noise(const SourceConfig& source) {
  Eigen::Matrix<double, 6, 6> noise = Eigen::Matrix<double, 6, 6>::Zero();
  noise.diagonal().head<3>().setConstant(source.max_translation_m * source.max_translation_m / 3.0);
  noise.diagonal().tail<3>().setConstant(source.max_rotation_rad * source.max_rotation_rad / 3.0);
  return noise;
}

double rotation_angle(const Eigen::Matrix3d& R) {
  return std::acos(std::clamp((R.trace() - 1.0) / 2.0, -1.0, 1.0));
}

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

double unix_seconds_now() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
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
  TrajectoryHistory trajectory;  ///< processed frames (snapshots are cheap; see its header)
  Eigen::Matrix<double, 6, 6> pose_covariance = Eigen::Matrix<double, 6, 6>::Zero();
  std::vector<ObjectEstimate> objects;
  /// The estimated disparity offset and its sigma (image units), with a calibration state.
  std::optional<std::pair<double, double>> disparity_offset;
  /// The world up axis's tilt from the start's level axis and its largest standard deviation
  /// (radians), with the level prior on.
  std::optional<std::pair<double, double>> world_up_tilt;
  /// Team id of each object (parallel to objects): the object's id when ids are given, -1 while
  /// unshared when they are negotiated.
  std::vector<LandmarkId> team_ids;
  /// The detector's class of each object (negotiated association; association::kUnknownClass when
  /// its detections carried none), else empty.
  std::vector<int> object_classes;
  /// Where the estimates are (alignment.json), and the frame of each stretch of the trajectory:
  /// (first trajectory entry, frame robot or nullopt for the world).
  AlignmentState alignment;
  std::vector<std::pair<int, std::optional<int>>> segments;
  association::NegotiationCounters negotiation;
  std::uint64_t frames_rejected = 0;
  std::uint64_t frames_dropped = 0;
  std::uint64_t frames_gap = 0;          ///< frames never processed: rejected, missing, skipped
  std::uint64_t motion_unknown = 0;      ///< gaps bridged without odometry (assumed no motion)
  /// The image source's front-end (source.kind images): detections, the object observations made
  /// from them, detections refused for an ambiguous or left-right inconsistent stereo match, and
  /// frames without visual odometry.
  std::uint64_t frontend_detections = 0;
  std::uint64_t frontend_objects_observed = 0;
  std::uint64_t frontend_objects_refused = 0;
  std::uint64_t frontend_odometry_failures = 0;
  std::uint64_t output_failures = 0;     ///< output writes that failed
  std::int64_t resumed_from_round = -1;  ///< checkpoint round resumed from (-1: fresh start)
  std::uint64_t rounds = 0;
  std::uint64_t marginals_fused = 0;
  std::uint64_t landmarks_fused = 0;
  std::uint64_t landmarks_settled = 0;  ///< left out by consensus.fuse_kl_threshold
  std::uint64_t objects_initialized = 0;
  /// The estimator's refusals: object observations rejected by its gates, new objects whose
  /// initialization failed its chi-square test, point-feature tracks rejected, and Kalman updates
  /// refused (innovation not positive definite).
  std::uint64_t object_observations_rejected = 0;
  std::uint64_t object_initializations_gated = 0;
  /// Archived objects whose old marginal disagreed with their fresh estimate (not fused back).
  std::uint64_t object_rejoins_refused = 0;
  std::uint64_t feature_tracks_rejected = 0;
  std::uint64_t update_failures = 0;
  double update_seconds = 0.0;
  double consensus_seconds = 0.0;  ///< whole rounds, waiting included
  double wait_seconds = 0.0;
  double send_cpu_seconds = 0.0;  ///< the consensus step's CPU (RoundReport)
  double fuse_cpu_seconds = 0.0;
  std::vector<double> latencies_ms;  ///< per frame: popped -> estimate published
  /// System clock (seconds since the epoch) when the first frame was popped and the last frame's
  /// estimate published; 0 before the first frame.
  double first_frame_unix = 0.0;
  double last_frame_unix = 0.0;
  std::vector<std::uint64_t> bytes_per_round;
};

class Daemon::Impl {
 public:
  Impl(DaemonConfig config, DaemonHooks hooks)
      : config_(std::move(config)),
        hooks_(std::move(hooks)),
        queue_(config_.queue_capacity),
        odometry_noise_(Propagator(config_.estimator).odometry_noise()),
        unknown_motion_noise_(unknown_motion_noise(config_.source)),
        notifier_(std::make_unique<ServiceNotifier>(io_)) {}

  int run();
  void request_stop();

 private:
  bool load_source();
  bool start_services();
  /// consensus.radio: the exchange's links each round from the members' ground truth.
  void set_up_radio(const RadioConfig& radio);
  void register_routes();
  void replay_frames();
  void image_frames();
  bool on_ingest(const v1::Envelope& envelope);
  void estimator_loop();
  bool process(QueuedFrame& item);
  [[nodiscard]] bool write_outputs(bool final);
  void load_checkpoint();
  [[nodiscard]] bool wait_or_stop(Clock::duration duration);
  json stats_json() const;
  void shutdown_services();
  void arm_reload();
  void reload();
  std::string status_line() const;
  /// The longest a frame's processing may legitimately take: its consensus round's two waits.
  Clock::duration frame_budget() const;

  DaemonConfig config_;
  DaemonHooks hooks_;
  BoundedQueue<QueuedFrame> queue_;
  std::atomic<bool> stop_requested_{false};
  Clock::time_point started_ = Clock::now();

  // Source data (replay; images through the front-end).
  std::optional<dataset::RobotData> robot_;
  std::unique_ptr<frontend::StereoFrontend> frontend_;
  /// The image source's noise per observation (source.observation_noise).
  std::optional<frontend::RunningObservationNoise> observation_noise_;
  /// The image source's numbering of its detections' class names, when it passes classes.
  std::optional<frontend::ClassNumbering> class_numbering_;
  /// The detections have class names that are not passed (no source.classes; not numbers).
  bool unnumbered_classes_ = false;
  StereoCamera camera_;
  // The configured per-frame odometry noise, and that of a frame whose motion is unknown: any
  // motion within the plausibility limits (uniform: sigma = limit / sqrt(3) per axis).
  Eigen::Matrix<double, 6, 6> odometry_noise_;
  Eigen::Matrix<double, 6, 6> unknown_motion_noise_;
  Eigen::Isometry3d start_pose_ = Eigen::Isometry3d::Identity();
  /// Whether the start pose is known (else the filter starts at the identity of its own frame),
  /// and whether the association is negotiated (resolved from consensus.association).
  bool start_known_ = true;
  bool negotiated_ = false;
  std::optional<Estimator> estimator_;
  std::unique_ptr<AssociationSession> association_;

  boost::asio::io_context io_;
  boost::asio::io_context http_io_;  // HTTP on its own thread: a flood never delays the peers
  std::thread http_thread_;
  std::shared_ptr<const net::TeamKey> team_key_;
  std::unique_ptr<net::PeerNetwork> network_;
  std::unique_ptr<ConsensusExchange> exchange_;
  std::unique_ptr<web::HttpServer> http_;
  std::unique_ptr<net::FrameListener> ingest_;
  std::unique_ptr<boost::asio::signal_set> signals_;
  std::unique_ptr<boost::asio::signal_set> reload_signals_;  // SIGHUP
  std::unique_ptr<ServiceNotifier> notifier_;                // after io_: its timer runs there
  std::atomic<std::uint64_t> reloads_{0};
  std::thread io_thread_;
  std::thread source_thread_;

  LiveState live_;
  Clock::time_point last_write_ = Clock::now();
  Clock::time_point last_fsync_ = Clock::now();

  // Stop-aware waits (replay pacing, the estimator.hang failpoint).
  std::mutex stop_mutex_;
  std::condition_variable stop_changed_;

  // Ingest stream state (io thread only).
  net::LogLimiter ingest_limiter_;
  std::int64_t last_ingest_frame_ = -1;
  double last_ingest_timestamp_ = -std::numeric_limits<double>::infinity();
  ComposedMotion carried_;  // over rejected frames, not yet given to the estimator
  bool ingest_started_ = false;
  bool ingest_ended_ = false;

  // Resume (replay): the checkpoint read at start, and the first frame to replay.
  std::optional<Checkpoint> checkpoint_;
  int first_replay_frame_ = 0;
  bool hang_done_ = false;
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
      // What the robot may use: its start pose only when the dataset says it is known.
      start_known_ = data.start_poses == dataset::StartPoses::kKnown;
      start_pose_ = start_known_ ? robot_->groundtruth.front() : Eigen::Isometry3d::Identity();
      negotiated_ = config_.consensus.association == AssociationMode::kNegotiated ||
                    (config_.consensus.association == AssociationMode::kAuto &&
                     (data.object_ids == dataset::ObjectIds::kPrivate || !start_known_));
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
      class_numbering_ =
          frontend::robot_class_numbering(detections, source.classes, detections_file);
      unnumbered_classes_ =
          !class_numbering_ && std::any_of(detections.begin(), detections.end(),
                                           [](const auto& frame) { return !frame.empty(); });
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
      if (source.observation_noise) {
        // The mean level: the left image's per-coordinate standard deviation under the
        // configured feature_noise (common-mode plus half the disparity, both axes).
        const StereoNoise& noise = config_.estimator.feature_noise;
        const double variance =
            0.5 * (noise.horizontal * noise.horizontal + 0.25 * noise.disparity * noise.disparity +
                   noise.vertical * noise.vertical +
                   0.25 * noise.vertical_disparity * noise.vertical_disparity);
        observation_noise_.emplace(std::sqrt(variance));
      }
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
  if (config_.source.kind != SourceKind::kReplay) {
    start_known_ = !config_.source.unknown_start;
    if (!start_known_) start_pose_ = Eigen::Isometry3d::Identity();
    negotiated_ = config_.consensus.association == AssociationMode::kNegotiated ||
                  (config_.consensus.association == AssociationMode::kAuto &&
                   (!start_known_ || config_.source.private_ids));
  }
  if (config_.consensus.mode == ConsensusMode::kOff) negotiated_ = false;
  if (negotiated_ && config_.consensus.mode != ConsensusMode::kLockstep) {
    spdlog::error("consensus.association: the negotiated association needs consensus.mode "
                  "lockstep");
    return false;
  }
  if (!negotiated_ && !start_known_ && config_.consensus.mode != ConsensusMode::kOff) {
    spdlog::error("consensus.association given: the start pose is unknown, so the robots' frames "
                  "differ; use the negotiated association");
    return false;
  }
  if (negotiated_ && unnumbered_classes_) {
    spdlog::warn("source: the detections' class names are not passed to the negotiated "
                 "association, which then links objects whatever their class: set "
                 "source.classes to the team's class names (the same list on every robot)");
  }
  if (negotiated_) {
    try {
      association_ = std::make_unique<AssociationSession>(
          config_.robot_id, start_known_ ? association::kWorldFrame : config_.robot_id,
          config_.negotiation, config_.members);
    } catch (const std::invalid_argument& error) {
      spdlog::error("association: {}", error.what());
      return false;
    }
  }
  {
    std::lock_guard lock(live_.mutex);
    live_.alignment.frame = start_known_ ? association::kWorldFrame : config_.robot_id;
  }
  spdlog::info("association: {}, start pose {}{}", negotiated_ ? "negotiated" : "given",
               start_known_ ? "known" : "unknown (the robot's own frame)",
               negotiated_ ? "\n" + config::to_yaml(config_.negotiation) : std::string());
  return true;
}

bool Daemon::Impl::start_services() {
  try {
    // HTTP first: its port is announced in Hello. Nothing is served before run() starts the
    // HTTP thread, when every service below exists.
    if (config_.http.enabled) {
      web::ServerOptions options;
      options.address = config_.http.address;
      options.port = config_.http.port;
      options.max_connections = config_.http.max_connections;
      options.max_connections_per_client = config_.http.max_connections_per_client;
      http_ = std::make_unique<web::HttpServer>(http_io_, options);
      register_routes();
      http_->start();
      spdlog::info("http: serving on {}:{}", config_.http.address, http_->port());
    }
    const bool needs_key =
        config_.consensus.mode != ConsensusMode::kOff ||
        (config_.source.kind == SourceKind::kIngest && config_.source.ingest_authenticated);
    if (needs_key) {
      team_key_ = std::make_shared<const net::TeamKey>(net::load_team_key(config_.team_key_file));
      spdlog::info("team key read from {}", config_.team_key_file.string());  // never the key
    }
    if (config_.consensus.mode != ConsensusMode::kOff) {
      net::PeerNetworkOptions options;
      options.team_key = team_key_;
      options.members = config_.members;
      std::shared_ptr<RecordSigner> record_signer;
      if (!config_.member_keys.empty()) {
        options.identity = std::make_shared<const net::RobotIdentity>(
            net::load_identity(config_.identity_key_file));
        for (const auto& [robot, hex] : config_.member_keys)
          options.member_keys.emplace(
              robot, net::PublicKey::parse(hex, "member_keys of robot " + std::to_string(robot)));
        record_signer =
            std::make_shared<RecordSigner>(config_.robot_id, options.identity, options.member_keys);
        spdlog::info("identity key read from {} (public key {}); {} member keys",
                     config_.identity_key_file.string(), options.identity->public_key().hex(),
                     options.member_keys.size());
      }
      options.max_pending_handshakes = config_.network.max_pending_handshakes;
      options.receive_bytes_per_second = config_.network.receive_bytes_per_second;
      options.receive_messages_per_second = config_.network.receive_messages_per_second;
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
      if (http_) {
        options.http_address = config_.http.address;
        options.http_port = http_->port();
      }
      options.discovery.enabled = config_.network.discovery;
      options.discovery.address = config_.network.discovery_address;
      options.discovery.port = config_.network.discovery_port;
      network_ = std::make_unique<net::PeerNetwork>(io_, options);
      ConsensusConfig exchange_config = config_.consensus;
      exchange_config.share_kl_threshold = config_.estimator.consensus.share_kl_threshold;
      exchange_config.share_float32 = config_.estimator.consensus.share_float32;
      exchange_config.share_block_landmarks = config_.estimator.consensus.share_block_landmarks;
      exchange_config.share_max_landmarks = config_.estimator.consensus.share_max_landmarks;
      exchange_ = std::make_unique<ConsensusExchange>(
          std::move(exchange_config),
          [this](int robot, v1::Envelope&& envelope) {
            return network_->send(robot, std::move(envelope));
          },
          ExchangeFailpoints{config_.failpoints.marginal_silence,
                             config_.failpoints.marginal_garbage});
      if (association_) exchange_->set_association(association_.get());
      if (record_signer) exchange_->set_record_signer(std::move(record_signer));
      if (config_.consensus.graph == ConsensusGraph::kRing)
        exchange_->restrict_to(ring_neighbours(config_.robot_id, config_.members));
      if (const RadioConfig& radio = config_.consensus.radio; radio.any()) set_up_radio(radio);
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
      if (config_.source.ingest_authenticated) options.team_key = team_key_;
      ingest_ = std::make_unique<net::FrameListener>(io_, options);
      ingest_->set_envelope_handler(
          [this](std::uint64_t, const v1::Envelope& envelope) { return on_ingest(envelope); });
      ingest_->start();
      spdlog::info("source: ingest of SensorFrame envelopes on {}:{} ({})",
                   config_.source.ingest_address, ingest_->port(),
                   config_.source.ingest_authenticated ? "authenticated with the team key"
                                                       : "plaintext, loopback only");
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
  reload_signals_ = std::make_unique<boost::asio::signal_set>(io_, SIGHUP);
  arm_reload();
  return true;
}

void Daemon::Impl::set_up_radio(const RadioConfig& radio) {
  std::vector<int> members = config_.members;
  std::sort(members.begin(), members.end());
  members.erase(std::unique(members.begin(), members.end()), members.end());
  const std::filesystem::path truth = radio.truth.empty() ? config_.source.dataset : radio.truth;
  const int max_frames =
      config_.source.kind == SourceKind::kReplay ? config_.source.max_frames : 0;
  auto graph = std::make_shared<const RadioGraph>(members, config_.consensus.graph, radio,
                                                  dataset::read_true_positions(truth, members),
                                                  max_frames);
  exchange_->set_radio([graph, robot = config_.robot_id](std::uint64_t round) {
    return graph->neighbours(robot, round);
  });
  spdlog::warn(
      "consensus: a simulated radio decides the links each round (range {} m, nearest {}, max "
      "degree {}; 0 = no limit) from the ground truth in {}",
      radio.range_m, radio.nearest, radio.max_degree, truth.string());
}

void Daemon::Impl::arm_reload() {
  reload_signals_->async_wait([this](const boost::system::error_code& error, int) {
    if (error) return;
    reload();
    arm_reload();
  });
}

/// SIGHUP (network thread): reopen the log file, re-read the static peer list. A bad config file
/// changes nothing (logged); the daemon goes on either way.
void Daemon::Impl::reload() {
  notifier_->reloading();
  ++reloads_;
  if (hooks_.reopen_logs) {
    const std::string problem = hooks_.reopen_logs();
    if (problem.empty())
      spdlog::info("SIGHUP: log file reopened");
    else
      spdlog::error("SIGHUP: {} (logging goes on to the old file)", problem);
  }
  if (hooks_.reload_peers && network_) {
    try {
      std::vector<net::HostPort> addresses;
      for (const std::string& text : hooks_.reload_peers()) {
        const auto address = net::parse_host_port(text);
        if (!address)
          throw std::runtime_error("network.peers: '" + text + "' is not host:port");
        addresses.push_back(*address);
      }
      spdlog::info("SIGHUP: peer list re-read ({} static peers)", addresses.size());
      network_->set_static_peers(std::move(addresses));
    } catch (const std::exception& error) {
      std::string reason = error.what();  // one event per line
      std::replace(reason.begin(), reason.end(), '\n', ' ');
      spdlog::error("SIGHUP: peer list unchanged: {}", reason);
    }
  }
  notifier_->reloaded(status_line());
}

std::string Daemon::Impl::status_line() const {
  std::string line = "robot " + std::to_string(config_.robot_id) + " of team '" + config_.team + "'";
  if (network_) line += ", peers on port " + std::to_string(network_->listen_port());
  if (ingest_) line += ", ingest on port " + std::to_string(ingest_->port());
  if (http_) line += ", http on port " + std::to_string(http_->port());
  return line;
}

Clock::duration Daemon::Impl::frame_budget() const {
  if (!exchange_ || config_.consensus.mode != ConsensusMode::kLockstep) return Clock::duration::zero();
  return 2 * config_.consensus.round_deadline;  // landmark sets, then marginals
}

void Daemon::Impl::request_stop() {
  {
    std::lock_guard lock(stop_mutex_);
    stop_requested_ = true;
  }
  stop_changed_.notify_all();
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
  for (int k = first_replay_frame_; k < robot_->num_frames() && !stop_requested_; ++k) {
    if (period > Clock::duration::zero()) {
      // Pacing a replay at the sensor rate (not synchronisation); a stop ends the wait at once.
      if (!wait_or_stop(next - Clock::now())) return;
      next += period;
    }
    QueuedFrame item{robot_->frame_input(k), k * config_.source.frame_period_s, Clock::now(),
                     robot_->has_object_classes ? robot_->object_classes[k] : std::vector<int>{}};
    if (k == first_replay_frame_ && first_replay_frame_ > 0) {
      // Resumed: the motion from the checkpoint's frame to this one, composed from the
      // odometry of the frames skipped (reported as a gap), with its covariance.
      ComposedMotion composed;
      for (int j = static_cast<int>(checkpoint_->round) + 1; j <= k; ++j) {
        const FrameInput skipped = robot_->frame_input(j);
        if (skipped.T_previous_current) {
          composed.then(*skipped.T_previous_current,
                        skipped.odometry_covariance.value_or(odometry_noise_));
        } else {
          composed.then(Eigen::Isometry3d::Identity(), unknown_motion_noise_);
        }
      }
      item.input.T_previous_current = composed.motion;
      item.input.odometry_covariance = composed.covariance;
    }
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
      // Pacing at the camera rate (not synchronisation); a stop ends the wait at once.
      if (!wait_or_stop(next - Clock::now())) break;
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
    const bool odometry_failed = frame.input.frame > 0 && !frame.motion.valid;
    if (odometry_failed) {
      spdlog::warn("source: no visual odometry at frame {} (the previous motion is repeated)",
                   frame.input.frame);
    }
    {
      std::lock_guard lock(live_.mutex);
      live_.frontend_detections += static_cast<std::uint64_t>(frame.detections);
      live_.frontend_objects_observed += static_cast<std::uint64_t>(frame.objects_observed);
      live_.frontend_objects_refused +=
          static_cast<std::uint64_t>(frame.objects_ambiguous + frame.objects_inconsistent);
      live_.frontend_odometry_failures += odometry_failed ? 1 : 0;
    }
    if (observation_noise_)
      observation_noise_->apply(frame.input.features, frame.alignment_variances);
    std::vector<int> object_classes;
    if (class_numbering_) {
      for (const std::string& name : frame.object_class_names)
        object_classes.push_back(*class_numbering_->number(name));
    }
    QueuedFrame item{std::move(frame.input), frame.timestamp, Clock::now(),
                     std::move(object_classes)};
    if (!queue_.push(std::move(item))) return;
  }
  queue_.close();
}

bool Daemon::Impl::wait_or_stop(Clock::duration duration) {
  std::unique_lock lock(stop_mutex_);
  stop_changed_.wait_for(lock, duration, [&] { return stop_requested_.load(); });
  return !stop_requested_;
}

bool Daemon::Impl::on_ingest(const v1::Envelope& envelope) {
  // Runs on the network thread. Returns false only when the queue is full: the listener then
  // stops reading that connection and offers the frame again (backpressure to the sender).
  auto limited = [&](const char* kind, const std::string& message) {
    std::uint64_t suppressed = 0;
    if (ingest_limiter_.allow(kind, suppressed))
      spdlog::warn("ingest: {}{}", message, net::suppressed_note(suppressed));
  };
  if (ingest_ended_) return true;
  if (envelope.body_case() != v1::Envelope::kSensorFrame) {
    limited("other",
            fmt::format("ignored a non-SensorFrame envelope from sender {}", envelope.sender()));
    return true;
  }
  const v1::SensorFrame& message = envelope.sensor_frame();
  std::string error;
  std::vector<int> object_classes;
  std::optional<FrameInput> frame = from_wire(message, error, &object_classes);
  const std::int64_t index = message.frame();
  auto end_if_last = [&] {
    if (!message.last()) return;
    ingest_ended_ = true;
    spdlog::info("ingest: last frame {} received", index);
    queue_.close();
  };
  // 1. Old or repeated frames: rejected, the stream goes on.
  if (index <= last_ingest_frame_) {
    {
      std::lock_guard lock(live_.mutex);
      ++live_.frames_rejected;
    }
    limited("order",
            fmt::format("rejected frame {}: not after frame {}", index, last_ingest_frame_));
    end_if_last();
    return true;
  }
  // 2. Plausibility: finite, increasing time stamps; bounded motion per frame.
  if (frame) {
    const double t = message.timestamp();
    if (!std::isfinite(t) || t <= last_ingest_timestamp_) {
      error = "time stamp " + std::to_string(t) + " is not finite and after the previous one";
      frame.reset();
    } else if (frame->T_previous_current) {
      const double translation = frame->T_previous_current->translation().norm();
      const double rotation = rotation_angle(frame->T_previous_current->linear());
      if (translation > config_.source.max_translation_m ||
          rotation > config_.source.max_rotation_rad) {
        error = "odometry of " + std::to_string(translation) + " m and " +
                std::to_string(rotation) + " rad exceeds source.max_translation_m / " +
                "max_rotation_rad";
        frame.reset();
      }
    }
  }
  // 3. Frames missing before this one: a gap, whose motion is unknown.
  const std::int64_t missing = last_ingest_frame_ >= 0 ? index - last_ingest_frame_ - 1 : 0;
  if (!frame) {
    // A rejected frame never blocks the stream: the next usable frame goes on from here. Its
    // motion is composed if its odometry was readable, else unknown (assumed none).
    std::lock_guard lock(live_.mutex);
    ++live_.frames_rejected;
    live_.frames_gap += static_cast<std::uint64_t>(1 + missing);
  }
  if (!frame) {
    limited("rejected", fmt::format("rejected frame {}: {}", index, error));
    std::string pose_error;
    std::optional<Eigen::Isometry3d> pose;
    if (message.has_odometry() && missing == 0) {
      pose = from_wire(message.odometry(), pose_error);
      if (pose && (pose->translation().norm() > config_.source.max_translation_m ||
                   rotation_angle(pose->linear()) > config_.source.max_rotation_rad))
        pose.reset();
    }
    if (pose) {
      carried_.then(*pose, odometry_noise_);
    } else if (ingest_started_) {
      // Its motion (and that of the frames missing before it) is unknown: within the
      // plausibility limits, with the covariance that says so.
      carried_.then(Eigen::Isometry3d::Identity(),
                    static_cast<double>(1 + missing) * unknown_motion_noise_);
      std::lock_guard lock(live_.mutex);
      ++live_.motion_unknown;
    }
    last_ingest_frame_ = index;
    if (std::isfinite(message.timestamp()))
      last_ingest_timestamp_ = std::max(last_ingest_timestamp_, message.timestamp());
    end_if_last();
    return true;
  }
  // 4. A usable frame: bridge what was skipped.
  QueuedFrame item{std::move(*frame), message.timestamp(), Clock::now(),
                   std::move(object_classes)};
  if (ingest_started_) {
    if (missing > 0 || !item.input.T_previous_current) {
      limited("gap", fmt::format("frames {}..{} missing or without odometry: motion over the gap "
                                 "unknown (none, with the covariance of the plausibility limits)",
                                 last_ingest_frame_ + 1, index));
    }
    if (carried_.steps > 0 || missing > 0 || !item.input.T_previous_current) {
      // Composed on a copy: a full queue refuses this frame, which is then offered again.
      ComposedMotion composed = carried_;
      if (missing > 0) {
        composed.then(Eigen::Isometry3d::Identity(),
                      static_cast<double>(missing) * unknown_motion_noise_);
      }
      if (item.input.T_previous_current) {
        composed.then(*item.input.T_previous_current,
                      item.input.odometry_covariance.value_or(odometry_noise_));
      } else {
        composed.then(Eigen::Isometry3d::Identity(), unknown_motion_noise_);
      }
      item.input.T_previous_current = composed.motion;
      item.input.odometry_covariance = composed.covariance;
    }
  }
  if (!queue_.try_push(std::move(item))) {
    if (queue_.closed()) return true;
    return false;  // full: backpressure
  }
  {
    std::lock_guard lock(live_.mutex);
    live_.frames_gap += static_cast<std::uint64_t>(std::max<std::int64_t>(missing, 0));
    if (ingest_started_ && (missing > 0 || !message.has_odometry())) ++live_.motion_unknown;
  }
  ingest_started_ = true;
  carried_ = ComposedMotion{};
  last_ingest_frame_ = index;
  last_ingest_timestamp_ = message.timestamp();
  end_if_last();
  return true;
}

bool Daemon::Impl::process(QueuedFrame& item) {
  if (config_.failpoints.estimator_hang_seconds > 0.0 && !hang_done_ && estimator_) {
    // Failpoint estimator.hang: the estimator thread hangs (stop still ends it at once).
    hang_done_ = true;
    spdlog::warn("failpoint estimator.hang: hanging for {} s",
                 config_.failpoints.estimator_hang_seconds);
    if (!wait_or_stop(std::chrono::duration_cast<Clock::duration>(
            std::chrono::duration<double>(config_.failpoints.estimator_hang_seconds))))
      return false;
  }
  const auto popped = Clock::now();
  if (!estimator_ && checkpoint_ && item.input.T_previous_current) {
    // Resume: the filter continues from the checkpoint's state (poses, objects and their
    // covariance); the first frame's odometry spans the frames skipped.
    try {
      estimator_.emplace(config_.estimator, camera_, checkpoint_->state, checkpoint_->pending);
      spdlog::info("resume: filter state restored ({} poses, {} objects)",
                   checkpoint_->state.num_poses(), estimator_->objects().size());
    } catch (const std::invalid_argument& error) {
      spdlog::warn("resume: the checkpoint's filter state is unusable ({}); restarting the filter "
                   "at its newest pose",
                   error.what());
    }
  }
  if (!estimator_) {
    // The first frame is the known start (after a resume without a usable state: the
    // checkpoint's pose moved by the odometry of the frames skipped).
    Eigen::Isometry3d start = start_pose_;
    if (checkpoint_) start = checkpoint_->state.newest_pose().T_world_body;
    if (item.input.T_previous_current &&
        (config_.source.kind == SourceKind::kIngest || checkpoint_)) {
      if (checkpoint_) start = start * *item.input.T_previous_current;
      item.input.T_previous_current.reset();
    }
    estimator_.emplace(config_.estimator, camera_, start, item.input.frame);
  }
  FrameReport report;
  try {
    // The estimator numbers frames consecutively; the source's index (with gaps) is the round.
    FrameInput input = item.input;
    if (estimator_->state().num_poses() > 0 && input.T_previous_current)
      input.frame = estimator_->frame() + 1;
    report = estimator_->process(input);
  } catch (const std::invalid_argument& error) {
    std::lock_guard lock(live_.mutex);
    ++live_.frames_rejected;
    ++live_.frames_gap;
    spdlog::warn("frame {} rejected: {}", item.input.frame, error.what());
    return false;
  }
  if (association_) association_->observe(item.input.objects, item.object_classes, *estimator_);
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
    live_.trajectory.push({item.input.frame, item.timestamp, estimator_->current_pose(),
                           estimator_->current_pose_covariance()});
    live_.pose_covariance = estimator_->current_pose_covariance();
    live_.objects = estimator_->objects();
    if (const State& state = estimator_->state(); state.has_disparity_offset) {
      const int index = state.disparity_offset_index();
      const double variance = state.covariance(index, index);
      live_.disparity_offset = {state.disparity_offset, std::sqrt(std::max(variance, 0.0))};
    }
    if (const State& state = estimator_->state(); state.has_world_up) {
      const int index = state.world_up_index();
      // The larger eigenvalue of the symmetric 2x2 [a b; b c].
      const double a = state.covariance(index, index), c = state.covariance(index + 1, index + 1);
      const double b = state.covariance(index, index + 1);
      const double largest = 0.5 * (a + c) + std::hypot(0.5 * (a - c), b);
      const double angle = std::acos(
          std::clamp(state.world_up.direction().dot(state.world_up.reference), -1.0, 1.0));
      live_.world_up_tilt = {angle, std::sqrt(std::max(largest, 0.0))};
    }
    if (association_) {
      live_.team_ids = association_->team_ids(live_.objects);
      live_.object_classes = association_->object_classes(live_.objects);
      live_.alignment = association_->alignment();
      live_.negotiation = association_->counters();
    } else {
      live_.team_ids.clear();
      for (const ObjectEstimate& object : live_.objects) live_.team_ids.push_back(object.id);
      live_.object_classes.clear();
    }
    const int frame = live_.alignment.frame;
    const std::optional<int> frame_robot =
        frame == association::kWorldFrame ? std::nullopt : std::optional<int>(frame);
    if (live_.segments.empty() || live_.segments.back().second != frame_robot)
      live_.segments.emplace_back(static_cast<int>(live_.trajectory.size()) - 1, frame_robot);
    live_.objects_initialized += static_cast<std::uint64_t>(report.objects.initialized);
    live_.object_observations_rejected += static_cast<std::uint64_t>(report.objects.rejected);
    live_.object_initializations_gated += static_cast<std::uint64_t>(report.objects.init_gated);
    live_.object_rejoins_refused += static_cast<std::uint64_t>(report.objects.rejoins_refused);
    live_.feature_tracks_rejected += static_cast<std::uint64_t>(report.features.tracks_rejected);
    live_.update_failures += static_cast<std::uint64_t>(report.objects.update_failures +
                                                        report.features.update_failures +
                                                        (report.level_failed ? 1 : 0));
    live_.update_seconds += seconds_between(popped, updated);
    if (exchange_) {
      ++live_.rounds;
      live_.marginals_fused += static_cast<std::uint64_t>(round.fused);
      live_.landmarks_fused += static_cast<std::uint64_t>(round.consensus.landmarks_fused);
      live_.landmarks_settled += static_cast<std::uint64_t>(round.consensus.landmarks_settled);
      live_.consensus_seconds += seconds_between(updated, done);
      live_.wait_seconds += round.wait_seconds;
      live_.send_cpu_seconds += round.send_cpu_seconds;
      live_.fuse_cpu_seconds += round.fuse_cpu_seconds;
      push_bounded(live_.bytes_per_round, bytes);
    }
    push_bounded(live_.latencies_ms, 1e3 * seconds_between(popped, done));
    // Wall-clock times (comparable between the robots of one machine) of the first frame's
    // start and the last frame's end: the team's pace over its frames, startup left out.
    const double now_unix = unix_seconds_now();
    if (live_.first_frame_unix == 0.0)
      live_.first_frame_unix = now_unix - seconds_between(popped, done);
    live_.last_frame_unix = now_unix;
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
    notifier_->check_in(config_.consensus.startup_timeout);
    const int live = exchange_->wait_for_peers(config_.consensus.wait_for_peers,
                                               config_.consensus.startup_timeout);
    if (live < config_.consensus.wait_for_peers && !stop_requested_) {
      spdlog::warn("starting with {} of {} peers live", live, config_.consensus.wait_for_peers);
    }
  }
  if (robot_) {
    if (checkpoint_) {
      // Resume: rejoin at the team's current round (the frames in between are a gap).
      std::int64_t team_round = -1;
      if (exchange_ && config_.consensus.mode == ConsensusMode::kLockstep) {
        notifier_->check_in(config_.consensus.round_deadline);
        team_round = exchange_->wait_for_team_round(config_.consensus.round_deadline);
      }
      const auto after_checkpoint = static_cast<std::int64_t>(checkpoint_->round) + 1;
      first_replay_frame_ = static_cast<int>(
          std::min<std::int64_t>(std::max(after_checkpoint, team_round), robot_->num_frames()));
      const std::int64_t skipped = first_replay_frame_ - after_checkpoint;
      {
        std::lock_guard lock(live_.mutex);
        live_.frames_gap += static_cast<std::uint64_t>(std::max<std::int64_t>(skipped, 0));
      }
      spdlog::info(
          "resume: checkpoint at round {}, team at round {}: continuing at frame {} ({} "
          "frames skipped, reported as a gap)",
          checkpoint_->round, team_round, first_replay_frame_, skipped);
      if (exchange_ && first_replay_frame_ > 0)
        exchange_->resume_at(static_cast<std::uint64_t>(first_replay_frame_ - 1));
    }
    source_thread_ = std::thread([this] { replay_frames(); });
  }
  if (frontend_) source_thread_ = std::thread([this] { image_frames(); });
  // The watchdog is fed while this thread checks in: between waits for a frame (at least every
  // half interval), and before each frame with the bound of its consensus round.
  const auto idle_wait = notifier_->watchdog_enabled()
                             ? std::chrono::duration_cast<Clock::duration>(
                                   notifier_->watchdog_interval() / 2)
                             : Clock::duration(std::chrono::seconds(1));
  while (true) {
    notifier_->check_in();
    bool closed = false;
    auto item = queue_.pop_for(idle_wait, closed);
    if (closed) break;
    if (!item) continue;
    if (stop_requested_) break;
    notifier_->check_in(frame_budget());
    process(*item);
    if (config_.output.write_interval.count() > 0 &&
        Clock::now() - last_write_ >= config_.output.write_interval) {
      (void)write_outputs(false);  // a failure is logged and counted; the final write decides
    }
  }
}

void Daemon::Impl::load_checkpoint() {
  const std::filesystem::path file = config_.output.directory / "checkpoint.bin";
  if (!config_.output.checkpoint || !robot_ || !std::filesystem::exists(file)) return;
  if (negotiated_) {
    // The negotiation's state (pairs, records, team frame) is not checkpointed: a restarted robot
    // negotiates afresh from frame 0 rather than resume a state in a frame it no longer knows.
    spdlog::warn("resume: ignoring {}: the negotiated association does not resume",
                 file.string());
    return;
  }
  std::ifstream stream(file, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(stream)), std::istreambuf_iterator<char>());
  std::string error;
  std::optional<Checkpoint> checkpoint = parse_checkpoint(bytes, error);
  if (!checkpoint || checkpoint->robot_id != config_.robot_id) {
    spdlog::warn("resume: ignoring {}: {}", file.string(),
                 checkpoint ? "written by robot " + std::to_string(checkpoint->robot_id) : error);
    return;
  }
  if (checkpoint->round + 1 >= static_cast<std::uint64_t>(robot_->num_frames())) {
    spdlog::info("resume: {} is at the last frame; starting from frame 0", file.string());
    return;
  }
  std::lock_guard lock(live_.mutex);
  for (std::size_t i = 0; i < checkpoint->frames.size(); ++i)
    live_.trajectory.push(
        {checkpoint->frames[i], checkpoint->timestamps[i], checkpoint->poses[i],
         Eigen::Matrix<double, 6, 6>::Zero()});
  live_.resumed_from_round = static_cast<std::int64_t>(checkpoint->round);
  spdlog::info("resume: checkpoint {} at round {} ({} frames processed before)", file.string(),
               checkpoint->round, checkpoint->frames.size());
  checkpoint_ = std::move(checkpoint);
}

bool Daemon::Impl::write_outputs(bool final) {
  const auto now = Clock::now();
  last_write_ = now;
  const bool durable = final || (config_.output.fsync_interval.count() > 0 &&
                                 now - last_fsync_ >= config_.output.fsync_interval);
  if (durable) last_fsync_ = now;
  Checkpoint checkpoint;
  std::vector<ObjectEstimate> objects;
  std::vector<LandmarkId> team_ids;
  dataset::AlignmentRecord alignment;
  TrajectoryHistory::Snapshot trajectory;
  {
    std::lock_guard lock(live_.mutex);
    trajectory = live_.trajectory.snapshot();
    objects = live_.objects;
    team_ids = live_.team_ids;
    const AlignmentState& state = live_.alignment;
    if (state.frame != association::kWorldFrame) alignment.team_frame_robot = state.frame;
    alignment.aligned_at_frame = static_cast<int>(state.aligned_at_round);
    alignment.moved = state.moved;
    alignment.T_team_own = state.T_frame_start;
    alignment.covariance = state.covariance;
    alignment.segments = live_.segments;
    if (alignment.segments.empty()) alignment.segments.emplace_back(0, alignment.team_frame_robot);
  }
  checkpoint.frames = trajectory.frames();
  checkpoint.timestamps = trajectory.timestamps();
  checkpoint.poses = trajectory.poses();
  try {
    if (config_.failpoints.output_fail)
      throw std::runtime_error("failpoint output.fail: writes to " +
                               config_.output.directory.string() + " fail");
    const std::filesystem::path& folder = config_.output.directory;
    write_output_file(folder / "trajectory.kitti",
                      dataset::format_trajectory_kitti(checkpoint.poses), durable);
    write_output_file(folder / "pose_covariance.csv",
                      dataset::format_pose_covariances_csv(trajectory.pose_covariances()), durable);
    const std::filesystem::path objects_file = folder / "objects.csv";
    if (team_ids.size() == objects.size())
      dataset::write_objects_csv(objects_file, objects, team_ids);
    else
      dataset::write_objects_csv(objects_file, objects);
    dataset::write_alignment_json(folder / "alignment.json", alignment);
    if (config_.output.checkpoint && estimator_ && !checkpoint.frames.empty()) {
      checkpoint.robot_id = config_.robot_id;
      checkpoint.round = static_cast<std::uint64_t>(checkpoint.frames.back());
      checkpoint.state = estimator_->state();
      checkpoint.pending = estimator_->pending_objects();
      write_output_file(folder / "checkpoint.bin", serialize_checkpoint(checkpoint), durable);
    }
    if (final) write_output_file(folder / "stats.json", stats_json().dump(2) + "\n", true);
    return true;
  } catch (const std::exception& error) {
    std::uint64_t failures = 0;
    {
      std::lock_guard lock(live_.mutex);
      failures = ++live_.output_failures;
    }
    std::uint64_t suppressed = 0;
    if (final || ingest_limiter_.allow("output", suppressed))
      spdlog::error("output: {} ({} failed writes so far){}", error.what(), failures,
                    net::suppressed_note(suppressed));
    return false;
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
      {"frames", live_.trajectory.size()},
      {"frames_rejected", live_.frames_rejected},
      {"frames_dropped", live_.frames_dropped},
      {"frames_gap", live_.frames_gap},
      {"motion_unknown", live_.motion_unknown},
      {"frontend",
       {{"detections", live_.frontend_detections},
        {"objects_observed", live_.frontend_objects_observed},
        {"objects_refused", live_.frontend_objects_refused},
        {"odometry_failures", live_.frontend_odometry_failures}}},
      {"output_failures", live_.output_failures},
      {"resumed_from_round", live_.resumed_from_round},
      {"rounds", live_.rounds},
      {"marginals_fused", live_.marginals_fused},
      {"landmarks_fused", live_.landmarks_fused},
      {"landmarks_settled", live_.landmarks_settled},
      {"wall_seconds", seconds_between(started_, Clock::now())},
      {"cpu_user_seconds", seconds(usage.ru_utime)},
      {"cpu_system_seconds", seconds(usage.ru_stime)},
      {"update_seconds", live_.update_seconds},
      {"consensus_seconds", live_.consensus_seconds},
      {"wait_seconds", live_.wait_seconds},
      {"consensus_send_cpu_seconds", live_.send_cpu_seconds},
      {"consensus_fuse_cpu_seconds", live_.fuse_cpu_seconds},
      {"first_frame_unix", live_.first_frame_unix},
      {"last_frame_unix", live_.last_frame_unix},
      {"latency_ms",
       {{"p50", percentile(live_.latencies_ms, 50)},
        {"p99", percentile(live_.latencies_ms, 99)},
        {"max", percentile(live_.latencies_ms, 100)}}},
      {"bytes_sent_per_round",
       {{"median", percentile(live_.bytes_per_round, 50)},
        {"max", percentile(live_.bytes_per_round, 100)}}},
  };
  stats["association"] = negotiated_ ? "negotiated" : "given";
  if (negotiated_) {
    const association::NegotiationCounters& n = live_.negotiation;
    const ExchangeCounters c = exchange_->counters();
    stats["negotiation"] = {{"searches", n.searches},
                            {"aligned", n.aligned},
                            {"ambiguous", n.ambiguous},
                            {"tilted", n.tilted},
                            {"frame_edges", n.frame_edges},
                            {"revisits", n.revisits},
                            {"revisits_ambiguous", n.revisits_ambiguous},
                            {"in_frame_searches", n.in_frame_searches},
                            {"in_frame_aligned", n.in_frame_aligned},
                            {"records_redundant", n.records_redundant},
                            {"records_refused", n.records_refused},
                            {"records_not_owned", n.records_not_owned},
                            {"frame_corrections", n.frame_corrections},
                            {"reanchorings", n.reanchorings},
                            {"links_accepted", n.links_accepted},
                            {"links_split", n.links_split},
                            {"link_conflicts", n.link_conflicts},
                            {"team_id_conflicts", n.team_id_conflicts},
                            {"messages", n.messages},
                            {"bytes_sent", c.negotiation_bytes},
                            {"seconds", c.negotiation_seconds},
                            {"seconds_by_part",
                             {{"encode", c.negotiation_encode_seconds},
                              {"decode", c.negotiation_decode_seconds},
                              {"decide", c.negotiation_decide_seconds},
                              {"relabel", c.negotiation_relabel_seconds}}},
                            {"negotiations_refused", c.negotiations_refused},
                            {"relabellings_refused", c.relabellings_refused},
                            {"records_unsigned", c.records_unsigned},
                            {"frame", live_.alignment.frame}};
  }
  if (exchange_) {
    const ExchangeCounters c = exchange_->counters();
    stats["consensus"] = {{"deadline_misses", c.deadline_misses},
                          {"exclusions", c.exclusions},
                          {"future_dropped", c.future_dropped},
                          {"malformed", c.malformed},
                          {"landmarks_refused", c.landmarks_refused},
                          {"quarantines", c.quarantines},
                          {"quarantined_dropped", c.quarantined_dropped},
                          {"quarantined_refused", c.quarantined_refused},
                          {"bytes_sent", c.bytes_sent},
                          {"budget_marginals_trimmed", c.budget_marginals_trimmed},
                          {"budget_marginals_empty", c.budget_marginals_empty},
                          {"budget_landmarks_dropped", c.budget_landmarks_dropped}};
  }
  if (network_) {
    const auto totals = network_->totals();
    stats["network"] = {{"bytes_out", totals.bytes_out},
                        {"bytes_in", totals.bytes_in},
                        {"messages_out", totals.messages_out},
                        {"messages_in", totals.messages_in},
                        {"send_drops", totals.send_drops},
                        {"rejected_oversized", totals.rejected_oversized},
                        {"rejected_garbage", totals.rejected_garbage},
                        {"rejected_handshake", totals.rejected_handshake},
                        {"rejected_unauthenticated", totals.rejected_unauthenticated},
                        {"rejected_identity", totals.rejected_identity},
                        {"rejected_admission", totals.rejected_admission}};
    std::uint64_t reconnects = 0;
    for (const net::PeerStats& peer : network_->peers()) reconnects += peer.reconnects;
    stats["network"]["reconnects"] = reconnects;
  }
  return stats;
}

void Daemon::Impl::register_routes() {
  http_->get("/", [](const web::Request&) {
    // The live map: inline script and style only, data from this robot and its neighbours.
    return web::Response{200,
                         "text/html; charset=utf-8",
                         std::string(web::live_map_page()),
                         {{"Cache-Control", "no-cache"},
                          {"Content-Security-Policy",
                           "default-src 'none'; script-src 'unsafe-inline'; style-src "
                           "'unsafe-inline'; connect-src *; img-src 'self'"},
                          {"X-Content-Type-Options", "nosniff"}}};
  });
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
    body["frame"] = live_.trajectory.empty() ? json(nullptr) : json(live_.trajectory.back().frame);
    body["frames_processed"] = live_.trajectory.size();
    body["rounds"] = live_.rounds;
    body["resumed_from_round"] = live_.resumed_from_round;  // -1: a fresh start
    return web::json_response(200, body);
  });
  http_->get("/pose", [this](const web::Request&) {
    std::lock_guard lock(live_.mutex);
    if (live_.trajectory.empty()) return web::error_response(503, "no frame processed yet");
    json body = pose_json(live_.trajectory.back().pose);
    body["frame"] = live_.trajectory.back().frame;
    body["covariance"] = matrix_json(live_.pose_covariance);
    body["covariance_order"] = "rho_x rho_y rho_z phi_x phi_y phi_z (right perturbation)";
    return web::json_response(200, body);
  });
  http_->get("/trajectory", [this](const web::Request& request) {
    const auto it = request.query.find("format");
    const std::string format = it == request.query.end() ? "json" : it->second;
    if (format != "json" && format != "kitti" && format != "tum")
      return web::error_response(400, "format: expected json, kitti or tum, got '" + format + "'");
    // since=F (json only): the frames after F, for a client that keeps what it has (the live map).
    std::optional<long long> since;
    if (const auto found = request.query.find("since"); found != request.query.end()) {
      long long value = 0;
      const std::string& text = found->second;
      const auto [end, error] = std::from_chars(text.data(), text.data() + text.size(), value);
      if (error != std::errc() || end != text.data() + text.size() || value < -1)
        return web::error_response(400, "since: expected a frame number >= -1, got '" + text + "'");
      if (format != "json") return web::error_response(400, "since: only with format=json");
      since = value;
    }
    TrajectoryHistory::Snapshot trajectory;
    {
      // Only the snapshot under the estimator's lock; formatting happens outside it.
      std::lock_guard lock(live_.mutex);
      trajectory = live_.trajectory.snapshot();
    }
    if (format == "kitti")
      return web::Response{200,
                           "text/plain; charset=utf-8",
                           dataset::format_trajectory_kitti(trajectory.poses()),
                           {}};
    if (format == "tum")
      return web::Response{
          200,
          "text/plain; charset=utf-8",
          dataset::format_trajectory_tum(trajectory.timestamps(), trajectory.poses()),
          {}};
    json poses = json::array();
    trajectory.for_each([&](const TrajectoryPoint& point) {
      if (since && point.frame <= *since) return;
      json entry = pose_json(point.pose);
      entry["frame"] = point.frame;
      poses.push_back(std::move(entry));
    });
    return web::json_response(200, {{"robot_id", config_.robot_id}, {"poses", poses}});
  });
  http_->get("/objects", [this](const web::Request&) {
    std::lock_guard lock(live_.mutex);
    json objects = json::array();
    for (std::size_t n = 0; n < live_.objects.size(); ++n) {
      const ObjectEstimate& object = live_.objects[n];
      objects.push_back({{"id", object.id},
                         {"team_id", n < live_.team_ids.size() ? live_.team_ids[n] : -1},
                         {"class", n < live_.object_classes.size() ? live_.object_classes[n]
                                                                   : association::kUnknownClass},
                         {"position", {object.p_world.x(), object.p_world.y(), object.p_world.z()}},
                         {"covariance", matrix_json(object.covariance)}});
    }
    return web::json_response(200, {{"robot_id", config_.robot_id}, {"objects", objects}});
  });
  http_->get("/peers", [this](const web::Request&) {
    json peers = json::array();
    if (network_) {
      const auto now = Clock::now();
      const std::map<int, PeerTrust> trust =
          exchange_ ? exchange_->peer_trust() : std::map<int, PeerTrust>{};
      for (const net::PeerStats& peer : network_->peers()) {
        const auto found = trust.find(peer.robot);
        const PeerTrust peer_trust = found != trust.end() ? found->second : PeerTrust{};
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
                         {"landmarks_refused", peer_trust.landmarks_refused},
                         {"landmarks_tested", peer_trust.landmarks_tested},
                         {"quarantines", peer_trust.quarantines},
                         {"quarantined", peer_trust.quarantined},
                         {"degree", peer.degree},
                         {"http", peer.http_endpoint.empty() ? json(nullptr)
                                                             : json(peer.http_endpoint)}});
      }
    }
    return web::json_response(200, {{"robot_id", config_.robot_id}, {"peers", peers}});
  });
  http_->get("/metrics", [this](const web::Request&) {
    MetricsText text;
    const std::string robot = "robot=\"" + std::to_string(config_.robot_id) + "\"";
    std::uint64_t suppressed = ingest_limiter_.suppressed_total();
    {
      std::lock_guard lock(live_.mutex);
      text.counter("concord_frames_processed_total", "Frames processed by the estimator", robot,
                   static_cast<double>(live_.trajectory.size()));
      text.counter("concord_frames_rejected_total", "Frames rejected (malformed or out of order)",
                   robot, static_cast<double>(live_.frames_rejected));
      text.counter("concord_frames_dropped_total", "Ingest frames dropped on a full queue", robot,
                   static_cast<double>(live_.frames_dropped));
      text.counter("concord_frames_gap_total",
                   "Frames never processed: rejected, missing from the stream, skipped on resume",
                   robot, static_cast<double>(live_.frames_gap));
      text.counter("concord_ingest_motion_unknown_total",
                   "Ingest gaps bridged without odometry (no motion assumed)", robot,
                   static_cast<double>(live_.motion_unknown));
      if (config_.source.kind == SourceKind::kImages) {
        text.counter("concord_frontend_detections_total", "Detections read by the front-end",
                     robot, static_cast<double>(live_.frontend_detections));
        text.counter("concord_frontend_objects_observed_total",
                     "Detections the front-end turned into stereo object observations", robot,
                     static_cast<double>(live_.frontend_objects_observed));
        text.counter("concord_frontend_objects_refused_total",
                     "Detections refused for an ambiguous or left-right inconsistent match",
                     robot, static_cast<double>(live_.frontend_objects_refused));
        text.counter("concord_frontend_odometry_failures_total",
                     "Frames without visual odometry (the previous motion repeated)", robot,
                     static_cast<double>(live_.frontend_odometry_failures));
      }
      text.counter("concord_output_failures_total", "Output writes that failed", robot,
                   static_cast<double>(live_.output_failures));
      text.counter("concord_update_seconds_total", "Time in the estimator update", robot,
                   live_.update_seconds);
      text.counter("concord_consensus_seconds_total",
                   "Time in consensus rounds, waiting included", robot, live_.consensus_seconds);
      text.counter("concord_consensus_wait_seconds_total",
                   "Time waiting for neighbours in consensus rounds", robot, live_.wait_seconds);
      text.counter("concord_consensus_send_cpu_seconds_total",
                   "CPU building the marginal and each neighbour's message in consensus rounds",
                   robot, live_.send_cpu_seconds);
      text.counter("concord_consensus_fuse_cpu_seconds_total",
                   "CPU fusing neighbours' marginals in consensus rounds", robot,
                   live_.fuse_cpu_seconds);
      text.counter("concord_consensus_rounds_total", "Consensus rounds", robot,
                   static_cast<double>(live_.rounds));
      text.counter("concord_marginals_fused_total", "Neighbour marginals fused", robot,
                   static_cast<double>(live_.marginals_fused));
      text.counter("concord_landmarks_fused_total", "Landmarks replaced by a consensus average",
                   robot, static_cast<double>(live_.landmarks_fused));
      text.counter("concord_landmarks_settled_total",
                   "Landmarks left out of a round by consensus.fuse_kl_threshold", robot,
                   static_cast<double>(live_.landmarks_settled));
      text.gauge("concord_objects", "Objects in the map", robot,
                 static_cast<double>(live_.objects.size()));
      if (live_.disparity_offset) {
        text.gauge("concord_disparity_offset", "Estimated stereo disparity offset (image units)",
                   robot, live_.disparity_offset->first);
        text.gauge("concord_disparity_offset_sigma",
                   "Standard deviation of the disparity offset estimate", robot,
                   live_.disparity_offset->second);
      }
      if (live_.world_up_tilt) {
        text.gauge("concord_world_up_tilt",
                   "Estimated tilt of the world's up axis from the start's level axis (rad)", robot,
                   live_.world_up_tilt->first);
        text.gauge("concord_world_up_tilt_sigma",
                   "Largest standard deviation of the world up axis's tilt (rad)", robot,
                   live_.world_up_tilt->second);
      }
      text.counter("concord_object_observations_rejected_total",
                   "Object observations rejected by the chi-square gate", robot,
                   static_cast<double>(live_.object_observations_rejected));
      text.counter("concord_object_initializations_gated_total",
                   "New objects whose initialization failed the chi-square test", robot,
                   static_cast<double>(live_.object_initializations_gated));
      text.counter("concord_object_rejoins_refused_total",
                   "Archived objects seen again whose old marginal failed the chi-square test",
                   robot, static_cast<double>(live_.object_rejoins_refused));
      text.counter("concord_feature_tracks_rejected_total",
                   "Point-feature tracks rejected (triangulation, depth or chi-square)", robot,
                   static_cast<double>(live_.feature_tracks_rejected));
      text.counter("concord_update_failures_total",
                   "Kalman updates refused (innovation covariance not positive definite)", robot,
                   static_cast<double>(live_.update_failures));
      text.counter("concord_association_links_accepted_total",
                   "Object correspondences accepted as the owner of a pair", robot,
                   static_cast<double>(live_.negotiation.links_accepted));
      text.counter("concord_association_links_split_total",
                   "Accepted correspondences undone (a wrong merge split)", robot,
                   static_cast<double>(live_.negotiation.links_split));
      text.counter("concord_association_reanchorings_total",
                   "Moves of the state into a team frame, or within it by a correction", robot,
                   static_cast<double>(live_.negotiation.reanchorings));
      text.counter("concord_association_frame_corrections_total",
                   "Accepted frame edges corrected as the owner of a pair", robot,
                   static_cast<double>(live_.negotiation.frame_corrections));
      text.counter("concord_association_records_refused_total",
                   "Peers' owner records of robots outside the membership list, dropped", robot,
                   static_cast<double>(live_.negotiation.records_refused));
      text.counter("concord_association_records_not_owned_total",
                   "Members' owner records deciding pairs their owner does not own, dropped", robot,
                   static_cast<double>(live_.negotiation.records_not_owned));
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
      text.counter("concord_consensus_future_dropped_total",
                   "Consensus messages beyond the future-round window, dropped", robot,
                   static_cast<double>(c.future_dropped));
      text.counter("concord_consensus_exclusions_total",
                   "Times a peer left the lockstep waits after missing rounds", robot,
                   static_cast<double>(c.exclusions));
      text.gauge("concord_consensus_excluded_peers", "Peers out of the lockstep waits", robot,
                 static_cast<double>(c.excluded_peers));
      text.counter("concord_consensus_landmarks_refused_total",
                   "Neighbours' landmarks refused by the chi-square test against this robot's",
                   robot, static_cast<double>(c.landmarks_refused));
      text.counter("concord_consensus_quarantines_total",
                   "Times a peer was quarantined for repeatedly refused marginals", robot,
                   static_cast<double>(c.quarantines));
      text.counter("concord_consensus_quarantined_dropped_total",
                   "Marginals not fused because their sender was in quarantine", robot,
                   static_cast<double>(c.quarantined_dropped));
      text.counter("concord_consensus_quarantined_refused_total",
                   "Claims of a quarantined sender refused against its own earlier claims "
                   "(tested, not fused)",
                   robot, static_cast<double>(c.quarantined_refused));
      text.gauge("concord_consensus_quarantined_peers", "Peers in quarantine", robot,
                 static_cast<double>(c.quarantined_peers));
      text.counter("concord_consensus_bytes_sent_total",
                   "Bytes of landmark sets and marginals sent (framing and encryption included)",
                   robot, static_cast<double>(c.bytes_sent));
      text.gauge("concord_consensus_link_budget_bytes_per_second",
                 "consensus.link_budget_bytes_per_second (0: unlimited)", robot,
                 config_.consensus.link_budget_bytes_per_second);
      text.counter("concord_consensus_budget_marginals_trimmed_total",
                   "Marginals trimmed to fit the link budget (least valuable landmarks left out)",
                   robot, static_cast<double>(c.budget_marginals_trimmed));
      text.counter("concord_consensus_budget_marginals_empty_total",
                   "Marginals sent empty: no landmark fitted the link budget", robot,
                   static_cast<double>(c.budget_marginals_empty));
      text.counter("concord_consensus_budget_landmarks_dropped_total",
                   "Landmarks left out of marginals by the link budget", robot,
                   static_cast<double>(c.budget_landmarks_dropped));
      text.counter("concord_association_negotiations_refused_total",
                   "Peers' negotiation messages refused (malformed or over the bounds)", robot,
                   static_cast<double>(c.negotiations_refused));
      text.counter("concord_association_records_unsigned_total",
                   "Owner records left out because their owner did not sign them", robot,
                   static_cast<double>(c.records_unsigned));
      text.counter("concord_association_relabellings_refused_total",
                   "Peers' marginals without usable receiver ids (negotiated association)", robot,
                   static_cast<double>(c.relabellings_refused));
      text.counter("concord_association_bytes_sent_total",
                   "Bytes of this robot's negotiation messages", robot,
                   static_cast<double>(c.negotiation_bytes));
      text.counter("concord_association_seconds_total",
                   "CPU time in the negotiated association (messages in and out, decisions, moves)",
                   robot, c.negotiation_seconds);
      suppressed += c.log_lines_suppressed;
    }
    if (ingest_) {
      const auto c = ingest_->counters();
      text.counter("concord_ingest_busy_pauses_total",
                   "Times ingest reading paused on a full frame queue (backpressure)", robot,
                   static_cast<double>(c.busy_pauses));
      text.counter("concord_ingest_rejected_connections_total",
                   "Ingest connections closed for a bad frame or failed authentication", robot,
                   static_cast<double>(c.rejected_oversized + c.rejected_garbage +
                                       c.rejected_unauthenticated));
      suppressed += c.log_lines_suppressed;
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
      text.counter("concord_network_unauthenticated_total",
                   "Connections that failed the team-key handshake or message authentication",
                   robot, static_cast<double>(totals.rejected_unauthenticated));
      text.counter("concord_network_identity_refused_total",
                   "Connections whose Hello was not signed by the robot it claims to be", robot,
                   static_cast<double>(totals.rejected_identity));
      text.counter("concord_network_admission_refused_total",
                   "Connections refused by the admission cap", robot,
                   static_cast<double>(totals.rejected_admission));
      text.counter("concord_network_budget_pauses_total",
                   "Times a connection over its receive budget paused", robot,
                   static_cast<double>(totals.budget_pauses));
      suppressed += totals.log_lines_suppressed;
      // Each family contiguous (the text format requires it): one loop per family.
      const std::vector<net::PeerStats> peers = network_->peers();
      auto per_peer = [&](auto&& emit) {
        for (const net::PeerStats& peer : peers)
          emit(peer, robot + ",peer=\"" + std::to_string(peer.robot) + "\"");
      };
      per_peer([&](const net::PeerStats& peer, const std::string& labels) {
        text.gauge("concord_peer_up", "Whether a peer is up", labels, peer.up ? 1.0 : 0.0);
      });
      per_peer([&](const net::PeerStats& peer, const std::string& labels) {
        text.counter("concord_peer_bytes_sent_total", "Bytes sent to a peer", labels,
                     static_cast<double>(peer.bytes_out));
      });
      per_peer([&](const net::PeerStats& peer, const std::string& labels) {
        text.counter("concord_peer_bytes_received_total", "Bytes received from a peer", labels,
                     static_cast<double>(peer.bytes_in));
      });
      per_peer([&](const net::PeerStats& peer, const std::string& labels) {
        text.counter("concord_peer_drops_total", "Messages to a peer dropped", labels,
                     static_cast<double>(peer.drops));
      });
      per_peer([&](const net::PeerStats& peer, const std::string& labels) {
        text.counter("concord_peer_protocol_errors_total",
                     "Connections of a peer closed for a "
                     "protocol violation",
                     labels, static_cast<double>(peer.protocol_errors));
      });
      per_peer([&](const net::PeerStats& peer, const std::string& labels) {
        text.gauge("concord_peer_rtt_seconds", "Last heartbeat round trip", labels,
                   1e-9 * static_cast<double>(peer.rtt_last.count()));
      });
      if (exchange_) {
        const std::map<int, PeerTrust> trust = exchange_->peer_trust();
        auto trust_of = [&](int robot_id) {
          const auto found = trust.find(robot_id);
          return found != trust.end() ? found->second : PeerTrust{};
        };
        per_peer([&](const net::PeerStats& peer, const std::string& labels) {
          text.counter("concord_peer_landmarks_refused_total",
                       "A peer's landmarks refused by the chi-square test", labels,
                       static_cast<double>(trust_of(peer.robot).landmarks_refused));
        });
        per_peer([&](const net::PeerStats& peer, const std::string& labels) {
          text.gauge("concord_peer_quarantined", "Whether a peer is in quarantine", labels,
                     trust_of(peer.robot).quarantined ? 1.0 : 0.0);
        });
      }
    }
    text.counter("concord_watchdog_pings_total", "WATCHDOG=1 messages sent to the service manager",
                 robot, static_cast<double>(notifier_->pings_sent()));
    text.counter("concord_watchdog_stalls_total",
                 "Times the estimator thread missed its watchdog check-in (pings stopped)", robot,
                 static_cast<double>(notifier_->stalls()));
    text.counter("concord_reloads_total", "SIGHUP reloads (log file, peer list)", robot,
                 static_cast<double>(reloads_.load()));
    text.counter("concord_log_lines_suppressed_total",
                 "Log lines about peers and clients held back by the rate limit", robot,
                 static_cast<double>(suppressed));
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
    return live_.trajectory.empty() ? std::uint64_t{0}
                                    : static_cast<std::uint64_t>(live_.trajectory.back().frame);
  }();
  if (exchange_) exchange_->stop();
  if (network_) network_->stop(stop_requested_ ? "stopped" : "finished", last_round);
  if (ingest_) ingest_->stop();
  if (http_) http_->stop();
  if (signals_) {
    boost::system::error_code ignored;
    signals_->cancel(ignored);
  }
  if (reload_signals_) {
    boost::system::error_code ignored;
    reload_signals_->cancel(ignored);
  }
  notifier_->stop_watchdog();
}

int Daemon::Impl::run() {
  // Start-up errors exit with kExitCannotStart, naming what is wrong.
  try {
    check_output_folder(config_.output.directory);
    if (const int removed = remove_stale_temporaries(config_.output.directory); removed > 0)
      spdlog::info("output: removed {} temporary files left by an earlier run", removed);
  } catch (const std::exception& error) {
    spdlog::error("start: {}", error.what());
    return kExitCannotStart;
  }
  if (!load_source()) return kExitCannotStart;
  load_checkpoint();
  if (!start_services()) {
    shutdown_services();
    io_.run();
    http_io_.run();
    return kExitCannotStart;
  }
  // Listening (peers, ingest, HTTP): ready for the service manager.
  notifier_->ready(status_line());
  notifier_->start_watchdog();
  auto run_context = [this](boost::asio::io_context& context, const char* name) {
    try {
      context.run();
    } catch (const std::exception& error) {
      spdlog::critical("{} thread: {}", name, error.what());
      request_stop();
    }
  };
  io_thread_ = std::thread([&] { run_context(io_, "network"); });
  http_thread_ = std::thread([&] { run_context(http_io_, "HTTP"); });

  estimator_loop();

  {
    std::lock_guard lock(live_.mutex);
    live_.phase = stop_requested_ ? "stopped" : "finished";
  }
  notifier_->stopping();
  notifier_->stop_watchdog();
  const bool written = write_outputs(true);
  {
    std::lock_guard lock(live_.mutex);
    if (written)
      spdlog::info("{}: {} frames, {} rounds; outputs in {}", live_.phase, live_.trajectory.size(),
                   live_.rounds, config_.output.directory.string());
    else
      spdlog::error("{}: {} frames, {} rounds; the outputs could NOT be written to {}", live_.phase,
                    live_.trajectory.size(), live_.rounds, config_.output.directory.string());
  }
  queue_.close_and_clear();
  {
    std::lock_guard lock(stop_mutex_);
    stop_requested_ = true;  // ends a replay pacing wait
  }
  stop_changed_.notify_all();
  if (source_thread_.joinable()) source_thread_.join();
  shutdown_services();
  io_thread_.join();
  http_thread_.join();
  // Destroying a signal_set restores the default action (a stop signal would now kill the
  // process with 128+signal while it exits normally); the caller ignores them from here on:
  // see concordd_main.cc.
  signals_.reset();
  reload_signals_.reset();
  return written ? kExitOk : kExitOutputFailed;
}

Daemon::Daemon(DaemonConfig config, DaemonHooks hooks)
    : impl_(std::make_unique<Impl>(std::move(config), std::move(hooks))) {}
Daemon::~Daemon() = default;
int Daemon::run() { return impl_->run(); }
void Daemon::request_stop() { impl_->request_stop(); }

}  // namespace concord::daemon

#pragma once
/// \file
/// concordd's configuration: one YAML file per robot (configs/team-kitti00/robot_00.yaml is a
/// documented example), a few keys overridable on the command line. Relative paths in the file
/// are relative to the file's folder. Unknown keys are errors (typo protection); every problem is
/// reported at once in a config::ConfigError naming the file, the key and the bad value.

#include <chrono>
#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "concord/association/options.h"
#include "concord/daemon/failpoints.h"
#include "concord/estimator/options.h"

namespace concord::daemon {

enum class ConsensusMode {
  kOff,       ///< no consensus (the paper's "separate" runs)
  kLockstep,  ///< round k waits for every live neighbour's round-k marginal (reproducible)
  kAsync,     ///< fuse the freshest marginal of each neighbour, if not too old (live robots)
};

/// Parses "off", "lockstep" or "async"; std::nullopt otherwise.
std::optional<ConsensusMode> parse_consensus_mode(const std::string& text);
std::string to_string(ConsensusMode mode);

/// consensus.graph: whom a robot runs consensus with among its live peers.
enum class ConsensusGraph {
  kComplete,  ///< every live peer
  kRing,      ///< the two members next to it in the sorted `members` list (as `concord replay --graph ring`)
};

std::optional<ConsensusGraph> parse_consensus_graph(const std::string& text);
std::string to_string(ConsensusGraph graph);

enum class SourceKind {
  kReplay,  ///< frames of one robot folder of a dataset
  kIngest,  ///< SensorFrame envelopes received on a TCP port
  kImages,  ///< a stereo image sequence through the front-end (frontend/, docs/frontend.md)
};

struct SourceConfig {
  SourceKind kind = SourceKind::kReplay;
  /// Replay: the dataset folder and which robot_NN to replay.
  std::filesystem::path dataset;
  int robot = 0;
  /// Replay and images: frames per second; 0 = as fast as the consensus mode allows.
  double rate_hz = 0.0;
  /// Replay and images: only the first max_frames frames (0 = all).
  int max_frames = 0;
  /// Images: the sequence folder (EuRoC or KITTI layout), the robot's detections (default:
  /// <images>/detections.csv if present) and front-end options (a YAML file; "" = defaults).
  /// The start pose is the sequence's first ground-truth pose, or start_pose without one.
  std::filesystem::path images;
  std::filesystem::path detections;
  std::filesystem::path frontend;
  /// Images (source.observation_noise): each point observation's own noise from the front-end's
  /// alignments (frontend::RunningObservationNoise, at the mean level of the estimator's
  /// feature_noise); false: feature_noise for every observation.
  bool observation_noise = true;
  /// Replay: read features.csv (point features) where present.
  bool point_features = true;
  /// Replay (source.frame_period_s): seconds between frames of the dataset, for the time stamps
  /// of a replayed frame (TUM output); KITTI's 10 Hz by default.
  double frame_period_s = 0.1;
  /// Ingest: where SensorFrame envelopes are accepted.
  std::string ingest_address = "127.0.0.1";
  std::uint16_t ingest_port = 7600;
  /// Ingest: the camera (a dataset.json whose "camera" object describes it).
  std::filesystem::path camera;
  /// Ingest (and images without ground truth): the known start pose T_world_body:
  /// x y z qw qx qy qz.
  std::vector<double> start_pose{0, 0, 0, 1, 0, 0, 0};
  /// Ingest and images (source.unknown_start): the start pose is not known; the filter starts at
  /// the identity of the robot's own frame (negotiated association). Replay reads dataset.json.
  bool unknown_start = false;
  /// Ingest and images (source.private_ids): the object ids are the robot's own (its detector's
  /// track ids), not shared with the team; association auto then negotiates them. Replay reads
  /// dataset.json.
  bool private_ids = false;
  /// Images (source.classes): the team's detector class names, the same list on every robot (in
  /// any order). Each detection's class is numbered by its place in the sorted list
  /// (frontend::ClassNumbering, as `concord frontend` numbers objects.csv's class column) and
  /// passed to the negotiated association, which links only objects of one class. A detection of
  /// a class not in the list stops the source. Empty: class names that are numbers are passed
  /// as those numbers; others are not passed (a warning says so).
  std::vector<std::string> classes;
  /// Ingest (source.ingest_authenticated): senders must run the authenticated channel with the
  /// team key. Required when ingest_address is not a loopback address.
  bool ingest_authenticated = false;
  /// Ingest plausibility limits (source.max_translation_m, source.max_rotation_rad): a frame
  /// whose odometry moves further or turns more than this is rejected (and counted as a gap).
  double max_translation_m = 20.0;
  double max_rotation_rad = 1.5;
};

struct NetworkConfig {
  std::string listen_address = "127.0.0.1";
  std::uint16_t listen_port = 7100;
  std::vector<std::string> peers;  ///< "host:port" of neighbours to dial
  std::chrono::milliseconds heartbeat_interval{1000};
  std::chrono::milliseconds heartbeat_timeout{5000};
  std::size_t max_frame_bytes = 16u << 20;
  std::size_t send_queue_limit = 256;
  bool discovery = false;
  std::string discovery_address = "239.255.76.1";
  std::uint16_t discovery_port = 47600;
  /// network.max_pending_handshakes: connections not yet authenticated, at most.
  std::size_t max_pending_handshakes = 16;
  /// network.receive_bytes_per_second / receive_messages_per_second: per-connection budgets.
  std::size_t receive_bytes_per_second = std::size_t{32} << 20;
  std::size_t receive_messages_per_second = 4000;
};

/// Which objects robots share (docs/association.md).
enum class AssociationMode {
  kAuto,        ///< replay: as concord replay (negotiated when the dataset's object ids are
                ///< private or its start poses unknown, else given); ingest and images: given
  kGiven,       ///< object ids are global and the start pose known: share equal ids
  kNegotiated,  ///< association::Negotiator with the neighbours (lockstep only)
};

/// Parses "auto", "given" or "negotiated"; std::nullopt otherwise.
std::optional<AssociationMode> parse_association_mode(const std::string& text);
std::string to_string(AssociationMode mode);

/// Bounds on a peer's negotiation messages (consensus.max_description_objects, ...): larger ones
/// are refused and counted.
struct NegotiationLimits {
  /// consensus.max_description_objects: objects in one map description.
  int max_description_objects = 2000;
  /// consensus.max_owner_records: owner records in one message.
  int max_records = 64;
  /// consensus.max_record_links: links in one owner record.
  int max_links_per_record = 20000;
  /// consensus.max_record_frame_edges: frame edges in one owner record.
  int max_frame_edges_per_record = 256;
};

/// consensus.radio: a simulated radio for tests and benchmarks on a dataset with ground truth
/// (concord/dataset/radio.h, as `concord replay --range/--nearest/--max-degree`). Each round a
/// robot runs consensus only with the peers the rule links it to at that frame, from every
/// member's true position: both ends decide alike, so the graph stays symmetric. Robot ids must
/// be the dataset's robot indices. The filter never sees the positions.
struct RadioConfig {
  double range_m = 0.0;  ///< consensus.radio.range_m (0: no limit)
  int nearest = 0;       ///< consensus.radio.nearest (0: no limit)
  int max_degree = 0;    ///< consensus.radio.max_degree (0: no limit)
  /// consensus.radio.truth: the dataset whose robot_NN/groundtruth.kitti give the positions
  /// ("" = source.dataset).
  std::filesystem::path truth;
  bool any() const { return range_m > 0.0 || nearest > 0 || max_degree > 0; }
};

struct ConsensusConfig {
  ConsensusMode mode = ConsensusMode::kLockstep;
  /// consensus.graph: complete or ring. Both ends of a link decide alike (from `members`), so the
  /// graph stays symmetric and the Metropolis weights over it doubly stochastic.
  ConsensusGraph graph = ConsensusGraph::kComplete;
  /// consensus.radio: limits on each round's graph (off unless a limit is set).
  RadioConfig radio;
  /// Lockstep: how long round k waits for a live neighbour's messages before going on without it.
  std::chrono::milliseconds round_deadline{5000};
  /// Async: a neighbour's marginal older than this many rounds is not fused.
  int staleness_rounds = 5;
  /// Before the first frame, wait until this many peers are live (0: do not wait)...
  int wait_for_peers = 0;
  /// ... for at most this long.
  std::chrono::milliseconds startup_timeout{30000};
  /// consensus.future_rounds: messages for rounds further ahead of the robot's own round than
  /// this are dropped on arrival (counted): memory stays bounded whatever a peer sends.
  int future_rounds = 4;
  /// consensus.miss_limit: a peer that misses the deadline this many rounds in a row leaves the
  /// lockstep waits (it still takes part when its messages are there in time) until it answers
  /// in time again. A hung peer costs at most miss_limit deadlines in total.
  int miss_limit = 1;
  /// consensus.max_marginal_landmarks: larger marginals and landmark sets are rejected.
  int max_marginal_landmarks = 5000;
  /// consensus.suspicious_refusal_fraction: a round in which the estimator refuses more than
  /// this fraction (and at least 2) of the landmarks a peer's marginal offered (they disagree
  /// with the robot's own beyond the chi-square bound, estimator.consensus.
  /// neighbour_chi2_probability) counts against the peer. An honest peer with consistent
  /// covariances has about 0.1 % refused.
  double suspicious_refusal_fraction = 0.2;
  /// consensus.quarantine_after: that many suspicious rounds in a row quarantine the peer: its
  /// marginals are not fused (counted) for consensus.quarantine_rounds of the robot's rounds.
  int quarantine_after = 3;
  int quarantine_rounds = 50;
  /// consensus.quarantine_doublings: each further quarantine of the same peer lasts twice as
  /// long as the one before, up to 2^this times quarantine_rounds (0: every quarantine lasts
  /// quarantine_rounds). A member whose lie is caught only now and then (a slow drift, see
  /// docs/results-reliability.md) is kept out for longer after each time.
  int quarantine_doublings = 4;
  /// consensus.link_budget_bytes_per_second: what consensus may send per second over all links
  /// together (0: unlimited). Set it below this robot's share of the radio: marginals that do
  /// not fit are trimmed on purpose (least valuable landmarks first) instead of queueing
  /// (docs/field.md). Counted in /metrics (concord_consensus_budget_*).
  double link_budget_bytes_per_second = 0.0;
  /// consensus.association: auto, given or negotiated (AssociationMode).
  AssociationMode association = AssociationMode::kAuto;
  NegotiationLimits negotiation_limits;
  /// Compact, event-triggered sharing (given association): copied from the estimator config's
  /// consensus.share_kl_threshold, share_float32, share_max_landmarks and share_block_landmarks
  /// (marginal_sharing.h), so that the daemons send what `concord replay` models. Negotiated
  /// marginals go whole.
  double share_kl_threshold = 0.0;
  bool share_float32 = false;
  int share_max_landmarks = 0;
  int share_block_landmarks = 0;
};

struct HttpConfig {
  bool enabled = true;
  std::string address = "127.0.0.1";
  std::uint16_t port = 8080;
  /// http.max_connections: connections served at once.
  std::size_t max_connections = 64;
  /// http.max_connections_per_client: connections served at once per client address.
  std::size_t max_connections_per_client = 8;
};

struct OutputConfig {
  /// trajectory.kitti, objects.csv and stats.json are written here.
  std::filesystem::path directory = "out";
  /// Period of the atomic rewrite of the outputs while running (0: only at shutdown).
  std::chrono::milliseconds write_interval{5000};
  /// output.fsync_interval_ms: outputs written while running are also fsync'ed at most this
  /// often (0: only the final outputs, which are always fsync'ed).
  std::chrono::milliseconds fsync_interval{0};
  /// output.checkpoint: write checkpoint.bin (filter state and round) with the outputs, and
  /// resume from it at start.
  bool checkpoint = true;
};

struct DaemonConfig {
  int robot_id = 0;
  std::string team = "concord";
  /// team_key_file: the team's key (`concord keygen`); mode 0600. Required unless consensus is
  /// off and ingest is unauthenticated.
  std::filesystem::path team_key_file;
  /// members: robot ids of the team (the membership list). Required when consensus is on.
  std::vector<int> members;
  /// Per-robot identities (docs/network.md, "Identities"), both or neither:
  /// identity_key_file: this robot's signing key (`concord keygen --identity`); mode 0600.
  std::filesystem::path identity_key_file;
  /// member_keys: every member's public key (64 hex digits), by robot id. With them a peer must
  /// sign its Hello and its owner records with the key of the id it claims.
  std::map<int, std::string> member_keys;
  /// Estimator options (a file in the format of configs/sensors/*.yaml, or inline keys).
  EstimatorOptions estimator;
  std::filesystem::path estimator_file;  ///< where they came from ("" = inline/defaults)
  /// The negotiation's options: the `association:` section of the estimator file (or of the
  /// inline estimator map), as concord replay reads it.
  association::NegotiationOptions negotiation;
  SourceConfig source;
  NetworkConfig network;
  ConsensusConfig consensus;
  HttpConfig http;
  OutputConfig output;
  /// Capacity of the frame queue between the source and the estimator thread.
  std::size_t queue_capacity = 64;
  /// spdlog level: trace, debug, info, warn, error, critical, off.
  std::string log_level = "info";
  /// log_file: append the log to this file instead of stderr; SIGHUP reopens it (logrotate).
  /// "" = stderr (journald keeps it under systemd).
  std::filesystem::path log_file;
  /// Fault injection (command line only: --failpoint).
  Failpoints failpoints;

  /// Problems (cross-field checks), one per line; empty if the config is usable.
  [[nodiscard]] std::vector<std::string> validate() const;
};

/// Reads a daemon config file. Throws config::ConfigError on any problem.
[[nodiscard]] DaemonConfig load_daemon_config(const std::filesystem::path& file);
/// As load_daemon_config, from YAML text; relative paths are resolved against base_directory.
[[nodiscard]] DaemonConfig parse_daemon_config(const std::string& yaml_text,
                                               const std::string& source_name,
                                               const std::filesystem::path& base_directory);

/// `concordd --check-config`: the problems with what a valid config names, without starting
/// anything: the team key (present, well-formed, not readable by group or others), the source's
/// data (the dataset's robot folder, the image sequence folder and its detections and front-end
/// options, the ingest camera), the output folder and the log file (writable, or creatable by
/// this user). Each problem names the key and the path. Reads, never creates or writes.
[[nodiscard]] std::vector<std::string> check_config_files(const DaemonConfig& config);

/// One line saying what a config runs (robot, team, mode, source, peers, discovery, ports).
[[nodiscard]] std::string describe(const DaemonConfig& config);

}  // namespace concord::daemon

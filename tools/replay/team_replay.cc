#include "replay/team_replay.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <numeric>
#include <random>
#include <stdexcept>

#include "concord/association/relabelling.h"
#include "concord/estimator/estimator.h"
#include "concord/estimator/marginal_sharing.h"

namespace concord::replay {

namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

std::vector<LandmarkId> intersection(const std::vector<LandmarkId>& a,
                                     const std::vector<LandmarkId>& b) {
  std::vector<LandmarkId> out;
  std::set_intersection(a.begin(), a.end(), b.begin(), b.end(), std::back_inserter(out));
  return out;
}

}  // namespace

GraphKind parse_graph_kind(const std::string& text) {
  if (text == "complete") return GraphKind::kComplete;
  if (text == "ring") return GraphKind::kRing;
  if (text == "random") return GraphKind::kRandom;
  throw std::invalid_argument("graph: expected complete, ring or random, got '" + text + "'");
}

std::string to_string(GraphKind kind) {
  switch (kind) {
    case GraphKind::kComplete:
      return "complete";
    case GraphKind::kRing:
      return "ring";
    case GraphKind::kRandom:
      return "random";
  }
  return "unknown";
}

std::vector<std::vector<int>> make_graph(GraphKind kind, int robots, std::uint64_t seed) {
  std::vector<std::vector<bool>> edge(robots, std::vector<bool>(robots, false));
  auto connect = [&](int i, int j) {
    if (i != j) edge[i][j] = edge[j][i] = true;
  };
  switch (kind) {
    case GraphKind::kComplete:
      for (int i = 0; i < robots; ++i)
        for (int j = i + 1; j < robots; ++j) connect(i, j);
      break;
    case GraphKind::kRing:
      for (int i = 0; robots > 1 && i < robots; ++i) connect(i, (i + 1) % robots);
      break;
    case GraphKind::kRandom: {
      std::mt19937_64 random(seed);
      std::vector<int> order(robots);
      std::iota(order.begin(), order.end(), 0);
      std::shuffle(order.begin(), order.end(), random);
      for (int k = 1; k < robots; ++k) {
        std::uniform_int_distribution<int> pick(0, k - 1);
        connect(order[k], order[pick(random)]);
      }
      std::bernoulli_distribution extra(0.3);
      for (int i = 0; i < robots; ++i)
        for (int j = i + 1; j < robots; ++j)
          if (extra(random)) connect(i, j);
      break;
    }
  }
  std::vector<std::vector<int>> adjacency(robots);
  for (int i = 0; i < robots; ++i)
    for (int j = 0; j < robots; ++j)
      if (edge[i][j]) adjacency[i].push_back(j);
  return adjacency;
}

ReplayResult run_team(const dataset::Dataset& dataset, const EstimatorOptions& estimator_options,
                      const ReplayOptions& options, const ProgressCallback& progress) {
  if (options.radio.any() && options.radio.true_positions.empty()) {
    ReplayOptions with_positions = options;
    with_positions.radio.true_positions = RadioLimits::positions_of(dataset);
    return run_team(dataset::sensor_inputs(dataset), estimator_options, with_positions, progress);
  }
  return run_team(dataset::sensor_inputs(dataset), estimator_options, options, progress);
}

namespace {

/// Bytes of a marginal in a fixed-width encoding (ids and numbers 8 bytes each, blocks as upper
/// triangles).
/// Bytes of a landmark in a marginal's double form: its id and mean.
long long landmark_bytes(long long landmarks) { return 8 * 4 * landmarks; }
/// Bytes of a covariance block of that many landmarks: its upper triangle.
long long block_bytes(long long landmarks) { return 8 * (3 * landmarks) * (3 * landmarks + 1) / 2; }

long long marginal_bytes(const Marginal& marginal) {
  long long bytes = landmark_bytes(static_cast<long long>(marginal.ids.size()));
  for (const Eigen::MatrixXd& block : marginal.blocks) bytes += block_bytes(block.rows() / 3);
  return bytes;
}

/// Marginal of robot j's objects that robot i (the receiver) shares with it, relabelled with i's
/// ids: only pairs both robots' views agree on (what a daemon receiving j's marginal keeps), as
/// the daemons do it (AssociationSession::shared_cut, accept_marginal), cut out of `held`, j's
/// marginal of all it holds. The cut is what a run with given ids does too; the rest (which ids to
/// cut and j's labels for i, the pairs i's view agrees with, the relabelling) is there because the
/// ids are private, so its time is added to `relabel_seconds`, which the run counts as negotiation.
Marginal relabelled_marginal(const Marginal& held, const association::Negotiator& sender_view,
                             const association::Negotiator& receiver_view,
                             double& relabel_seconds) {
  auto start = Clock::now();
  const association::SharedCut shared =
      association::shared_cut(sender_view.shared_objects(receiver_view.robot()), held.ids);
  relabel_seconds += seconds_since(start);
  Marginal cut;
  Consensus::select(held, shared.ids, cut);
  start = Clock::now();
  Marginal relabelled = association::relabel_agreed(std::move(cut), shared.receiver_ids,
                                                    receiver_view.shared_view(sender_view.robot()));
  relabel_seconds += seconds_since(start);
  return relabelled;
}

}  // namespace

AssociationMode parse_association_mode(const std::string& text) {
  if (text == "given") return AssociationMode::kGiven;
  if (text == "negotiated") return AssociationMode::kNegotiated;
  throw std::invalid_argument("association: expected given or negotiated, got '" + text + "'");
}

std::string to_string(AssociationMode mode) {
  return mode == AssociationMode::kGiven ? "given" : "negotiated";
}

ReplayResult run_team(const dataset::TeamInputs& dataset, const EstimatorOptions& estimator_options,
                      const ReplayOptions& options, const ProgressCallback& progress) {
  if (!(options.link_loss >= 0.0 && options.link_loss <= 1.0)) {
    throw std::invalid_argument("loss: expected a probability in [0, 1], got " +
                                std::to_string(options.link_loss));
  }
  const AssociationMode mode =
      options.association.value_or(dataset.object_ids == dataset::ObjectIds::kGlobal &&
                                           dataset.start_poses == dataset::StartPoses::kKnown
                                       ? AssociationMode::kGiven
                                       : AssociationMode::kNegotiated);
  const bool negotiated = mode == AssociationMode::kNegotiated && options.consensus;
  if (mode == AssociationMode::kGiven && dataset.start_poses == dataset::StartPoses::kUnknown &&
      options.consensus && dataset.robots.size() > 1) {
    throw std::invalid_argument(
        "association given: the robots' start poses are unknown, so their frames differ; use "
        "the negotiated association");
  }
  // The sigmas themselves are checked where every start sigma is (EstimatorOptions::validate).
  if (options.unanchored_start_sigma && dataset.start_poses != dataset::StartPoses::kKnown) {
    throw std::invalid_argument(
        "unanchored start sigma: the robots' start poses are unknown (each starts in its own "
        "frame), so there is no given start to be uncertain about");
  }
  const auto run_start = Clock::now();
  const int robots = static_cast<int>(dataset.robots.size());
  std::vector<Estimator> estimators;
  std::vector<association::Negotiator> negotiators;
  std::vector<association::ObservationTally> tallies(robots);
  estimators.reserve(robots);
  int steps = 0;
  for (const auto& robot : dataset.robots) {
    if (robot.num_frames() == 0) throw std::invalid_argument("robot without frames");
    EstimatorOptions robot_options = estimator_options;
    if (options.unanchored_start_sigma && robot.index != 0) {
      robot_options.initial_position_sigma = options.unanchored_start_sigma->first;
      robot_options.initial_rotation_sigma = options.unanchored_start_sigma->second;
    }
    estimators.emplace_back(robot_options, dataset.camera,
                            robot.T_world_body_start.value_or(Eigen::Isometry3d::Identity()), 0);
    const int start_frame = robot.T_world_body_start ? association::kWorldFrame : robot.index;
    if (negotiated) {
      negotiators.emplace_back(robot.index, start_frame, options.negotiation);
      if (options.search_listener) negotiators.back().set_search_listener(options.search_listener);
    }
    steps = std::max(steps, robot.num_frames());
  }
  // Event-triggered, compact sharing (consensus.share_*): one sender and one receiver state per
  // directed link (from, to), as the daemons keep them per peer connection.
  const ConsensusOptions& sharing = estimator_options.consensus;
  const bool compact_sharing = sharing.share_kl_threshold > 0.0 || sharing.share_float32 ||
                               sharing.share_max_landmarks > 0 || sharing.share_block_landmarks > 0;
  std::map<std::pair<int, int>, MarginalSender> senders;
  std::map<std::pair<int, int>, MarginalReceiver> receivers;
  const auto graph = make_graph(options.graph, robots, options.seed);
  if (options.radio.any()) {
    const auto& positions = options.radio.true_positions;
    bool enough = static_cast<int>(positions.size()) == robots;
    for (int i = 0; enough && i < robots; ++i)
      enough = static_cast<int>(positions[i].size()) >= dataset.robots[i].num_frames();
    if (!enough)
      throw std::invalid_argument(
          "radio limits (range, nearest, max degree) need the true position of every robot at "
          "every frame (RadioLimits::true_positions)");
  }
  std::mt19937_64 loss_random(options.seed ^ 0x9e3779b97f4a7c15ULL);
  std::bernoulli_distribution drop(options.link_loss);

  ReplayResult result;
  result.association = mode;
  result.robots.resize(robots);
  ReplayStatistics& statistics = result.statistics;
  statistics.steps = steps;
  std::vector<int> frame_of(robots);
  for (int i = 0; i < robots; ++i) {
    frame_of[i] = dataset.robots[i].T_world_body_start ? association::kWorldFrame : i;
  }

  // Each robot's inbox keeps its marginals' storage from round to round: a marginal is built
  // into the one of the previous round at its place (Consensus::marginal reuses it).
  std::vector<std::vector<WeightedMarginal>> inbox(robots);
  std::vector<std::size_t> inbox_size(robots, 0);
  // With given ids: a round's marginal of all a robot holds (storage kept), which each of its
  // neighbours fuses the common part of.
  std::vector<SharedMarginal> held(robots);
  std::vector<WeightedShare> given_shares;    // with given ids, each robot's in turn
  std::vector<WeightedMarginal> given_inbox;  // the same, cut and sent in compact form
  std::vector<int> common_per_block;
  const auto next_in = [&](int i) -> WeightedMarginal& {
    auto& box = inbox[static_cast<std::size_t>(i)];
    std::size_t& size = inbox_size[static_cast<std::size_t>(i)];
    if (size == box.size()) box.emplace_back();
    return box[size++];
  };
  for (int step = 0; step < steps; ++step) {
    std::vector<bool> active(robots);
    for (int i = 0; i < robots; ++i) active[i] = step < dataset.robots[i].num_frames();

    // 1. Every robot processes its frame.
    auto phase_start = Clock::now();
    for (int i = 0; i < robots; ++i) {
      if (!active[i]) continue;
      const FrameReport report = estimators[i].process(dataset.robots[i].frame_input(step));
      ++statistics.robot_steps;
      statistics.objects_initialized += report.objects.initialized;
      statistics.object_observations_rejected += report.objects.rejected;
      statistics.feature_tracks_used += report.features.tracks_used;
      statistics.feature_tracks_rejected += report.features.tracks_rejected;
      statistics.object_initializations_gated += report.objects.init_gated;
      statistics.object_rejoins_refused += report.objects.rejoins_refused;
      statistics.objects_reactivated += report.objects.reactivated;
      statistics.update_failures += report.objects.update_failures + report.features.update_failures +
                                    (report.level_failed ? 1 : 0);
    }
    statistics.update_seconds += seconds_since(phase_start);

    if (options.consensus) {
      // This round's graph: live robots, each edge dropped with probability link_loss. The
      // random draws happen for every edge of the base graph in a fixed order.
      std::vector<std::vector<int>> round_neighbours(robots);
      for (int i = 0; i < robots; ++i) {
        for (int j : graph[i]) {
          if (j <= i) continue;
          const bool dropped = drop(loss_random);
          if (dropped || !active[i] || !active[j]) continue;
          round_neighbours[i].push_back(j);
          round_neighbours[j].push_back(i);
        }
      }
      if (options.radio.any()) {
        std::vector<Eigen::Vector3d> positions(robots, Eigen::Vector3d::Zero());
        for (int i = 0; i < robots; ++i)
          if (active[i]) positions[i] = options.radio.true_positions[i][step];
        round_neighbours = limit_graph(round_neighbours, positions, options.radio);
      }
      statistics.edge_rounds += [&] {
        long long edges = 0;
        for (const auto& neighbours : round_neighbours) edges += static_cast<long long>(neighbours.size());
        return edges / 2;
      }();

      // 2. Negotiation: descriptions, messages, decisions, moves into the team frame.
      if (negotiated) {
        phase_start = Clock::now();
        for (int i = 0; i < robots; ++i) {
          if (!active[i]) continue;
          tallies[i].add(dataset.robots[i].objects[step], dataset.robots[i].object_classes[step],
                         estimators[i].state(), estimators[i].camera());
          if (negotiators[i].describes(step)) {
            negotiators[i].set_own_map(
                association::describe_map(estimators[i].state(), i, negotiators[i].frame(),
                                          tallies[i],
                                          options.negotiation.association.min_observations,
                                          options.negotiation.association.min_detection_ratio),
                step);
          }
        }
        std::vector<std::vector<association::NegotiationMessage>> messages(robots);
        for (int i = 0; i < robots; ++i) {
          for (int j : round_neighbours[i])
            messages[j].push_back(negotiators[i].message_for(j, step));
        }
        for (int i = 0; i < robots; ++i) {
          if (!active[i]) continue;
          ++statistics.negotiation_robot_rounds;
          for (const auto& message : messages[i]) negotiators[i].receive(message, step);
          const std::size_t corrections = negotiators[i].corrections_seen();
          const auto move = negotiators[i].finish_round(step);
          // A correction moved some robots within the team frame: their claims jump.
          if (negotiators[i].corrections_seen() != corrections) estimators[i].forget_claims();
          if (move) {
            estimators[i].reanchor(move->T_new_old, move->covariance, move->pose_frame,
                                   move->independent);
            // The first frame in the final frame: a correction (a move within it) keeps it.
            if (move->from_frame != move->to_frame) result.robots[i].aligned_at_frame = step;
            result.robots[i].moved = true;
          }
          frame_of[i] = negotiators[i].frame();
        }
        statistics.negotiation_seconds += seconds_since(phase_start);
      }

      phase_start = Clock::now();
      double relabel_seconds = 0.0;  // negotiation work within this phase (relabelled_marginal)
      // 3. All marginals are taken before anyone fuses.
      std::fill(inbox_size.begin(), inbox_size.end(), 0);
      std::vector<long long> sent_bytes(robots, 0);  // by sender, this round
      const auto count_bytes = [&](int sender, long long bytes) {
        statistics.marginal_bytes += bytes;
        sent_bytes[sender] += bytes;
      };
      if (negotiated) {
        // Each robot's marginal of all it holds, built once for the neighbours in its frame.
        std::vector<bool> sends(robots, false);
        for (int i = 0; i < robots; ++i) {
          for (int j : round_neighbours[i]) sends[j] = sends[j] || frame_of[i] == frame_of[j];
        }
        for (int j = 0; j < robots; ++j) {
          if (sends[j]) estimators[j].marginal(estimators[j].object_ids(), held[j].marginal());
        }
        for (int i = 0; i < robots; ++i) {
          for (int j : round_neighbours[i]) {
            if (frame_of[i] != frame_of[j]) continue;  // not aligned yet: separate
            Marginal marginal = relabelled_marginal(held[j].marginal(), negotiators[j],
                                                    negotiators[i], relabel_seconds);
            if (marginal.ids.empty()) continue;
            count_bytes(j, marginal_bytes(marginal));
            const double weight =
                Consensus::metropolis_weight(static_cast<int>(round_neighbours[i].size()),
                                             static_cast<int>(round_neighbours[j].size()));
            next_in(i) = {weight, std::move(marginal), j};
          }
        }
      }
      // Given ids: every robot's marginal of all it holds is taken here, before anyone fuses,
      // and indexed once. A neighbour fuses the part of it that it holds too: the marginal of
      // their common objects, which a daemon would send it (counted as such), without a copy.
      // In compact form what a neighbour is sent is cut out of it just before that neighbour
      // fuses, into one inbox all robots use in turn.
      std::vector<std::vector<LandmarkId>> ids(negotiated ? 0 : robots);
      if (!negotiated) {
        for (int i = 0; i < robots; ++i)
          if (active[i]) ids[i] = estimators[i].object_ids();
        for (int j = 0; j < robots; ++j) {
          if (ids[j].empty()) continue;
          estimators[j].marginal(ids[j], held[j].marginal());
          held[j].index();
        }
      }
      // What robot i receives from its neighbours this round (given ids, in full), into
      // given_shares.
      const auto share_given = [&](int i) {
        given_shares.clear();
        for (int j : round_neighbours[i]) {
          if (ids[i].empty() || ids[j].empty()) continue;
          const double weight =
              Consensus::metropolis_weight(static_cast<int>(round_neighbours[i].size()),
                                           static_cast<int>(round_neighbours[j].size()));
          if (!held[j].usable()) {  // left out by fuse, and counted there
            given_shares.push_back({weight, &held[j], j});
            continue;
          }
          held[j].count_common(ids[i], common_per_block);
          long long common = 0, bytes = 0;  // marginal_bytes of the cut
          for (const int kept : common_per_block) {
            common += kept;
            bytes += block_bytes(kept);
          }
          if (common == 0) continue;
          count_bytes(j, landmark_bytes(common) + bytes);
          given_shares.push_back({weight, &held[j], j});
        }
      };
      // What robot i receives from its neighbours this round (given ids, compact), into `box`;
      // returns how many marginals.
      const auto receive_given = [&](int i, std::vector<WeightedMarginal>& box) {
        std::size_t size = 0;
        const auto next = [&]() -> WeightedMarginal& {
          if (size == box.size()) box.emplace_back();
          return box[size++];
        };
        for (int j : round_neighbours[i]) {
          const auto common = intersection(ids[i], ids[j]);
          if (common.empty()) continue;
          const double weight =
              Consensus::metropolis_weight(static_cast<int>(round_neighbours[i].size()),
                                           static_cast<int>(round_neighbours[j].size()));
          // What j sends i (the changed landmarks, in float32 if asked), then what i fuses.
          MarginalSender& sender = senders[{j, i}];
          Marginal cut;
          Consensus::select(held[j].marginal(), common, cut);
          Marginal sent =
              sender.select(cut, sharing.share_kl_threshold,
                            link_landmark_cap(sharing.share_max_landmarks,
                                              static_cast<int>(round_neighbours[j].size())));
          sent = split_blocks(sent, sharing.share_block_landmarks);
          if (sharing.share_float32) {
            const CompactMarginal wire = compact(sent);
            count_bytes(j, wire.bytes());
            sent = expand(wire);
          } else {
            count_bytes(j, marginal_bytes(sent));
          }
          sender.delivered(sent);
          Marginal fused = receivers[{i, j}].complete(sent, common);
          if (!fused.ids.empty()) next() = {weight, std::move(fused), j};
        }
        return size;
      };
      // 4. Every robot fuses.
      for (int i = 0; i < robots; ++i) {
        const ConsensusReport* fused = nullptr;
        if (!negotiated && !compact_sharing) {
          share_given(i);
          if (given_shares.empty()) continue;
          fused = &estimators[i].fuse(std::span<const WeightedShare>(given_shares));
        } else {
          std::vector<WeightedMarginal>& box = negotiated ? inbox[i] : given_inbox;
          box.resize(negotiated ? inbox_size[i] : receive_given(i, given_inbox));
          if (box.empty()) continue;
          fused = &estimators[i].fuse(box);
        }
        const ConsensusReport& report = *fused;
        ++statistics.consensus_robot_steps;
        statistics.landmarks_fused += report.landmarks_fused;
        statistics.landmarks_settled += report.landmarks_settled;
        statistics.neighbours_skipped += report.neighbours_skipped;
        statistics.landmarks_refused += report.landmarks_refused;
        statistics.claims_refused += report.claims_refused;
      }
      for (int i = 0; i < robots; ++i) {
        if (active[i] && !round_neighbours[i].empty())
          statistics.marginal_bytes_per_robot_round.push_back(sent_bytes[i]);
      }
      statistics.consensus_seconds += seconds_since(phase_start) - relabel_seconds;
      statistics.negotiation_seconds += relabel_seconds;
    }

    // 5. Record the online estimate of frame `step`.
    for (int i = 0; i < robots; ++i) {
      if (!active[i]) continue;
      result.robots[i].trajectory.push_back(estimators[i].current_pose());
      result.robots[i].pose_covariances.push_back(estimators[i].current_pose_covariance());
      result.robots[i].trajectory_frames.push_back(frame_of[i]);
    }
    if (progress) progress(step + 1, steps);
  }
  for (int i = 0; i < robots; ++i) {
    RobotOutput& output = result.robots[i];
    output.objects = estimators[i].objects();
    if (const State& state = estimators[i].state(); state.has_disparity_offset) {
      const int index = state.disparity_offset_index();
      output.disparity_offset = {state.disparity_offset,
                                 std::sqrt(std::max(state.covariance(index, index), 0.0))};
    }
    for (const ObjectEstimate& object : output.objects) {
      output.team_ids.push_back(negotiated ? negotiators[i].team_id(object.id) : object.id);
    }
    if (negotiated) {
      output.T_team_own = negotiators[i].T_frame_start();
      output.alignment_covariance = negotiators[i].covariance_frame_start();
      const auto& counters = negotiators[i].counters();
      statistics.negotiation_messages += counters.messages;
      statistics.negotiation_bytes += counters.bytes_sent;
      statistics.description_bytes += counters.description_bytes;
      statistics.searches += counters.searches;
      statistics.in_frame_searches += counters.in_frame_searches;
      statistics.in_frame_aligned += counters.in_frame_aligned;
      statistics.ambiguous += counters.ambiguous;
      statistics.tilted += counters.tilted;
      statistics.frame_edges += counters.frame_edges;
      statistics.revisits += counters.revisits;
      statistics.revisits_ambiguous += counters.revisits_ambiguous;
      statistics.records_redundant += counters.records_redundant;
      statistics.records_not_owned += counters.records_not_owned;
      statistics.frame_corrections += counters.frame_corrections;
      statistics.reanchorings += counters.reanchorings;
      statistics.links_accepted += counters.links_accepted;
      statistics.links_split += counters.links_split;
      statistics.link_conflicts += counters.link_conflicts;
      statistics.team_id_conflicts =
          std::max<long long>(statistics.team_id_conflicts, counters.team_id_conflicts);
    }
  }
  statistics.total_seconds = seconds_since(run_start);
  return result;
}

}  // namespace concord::replay

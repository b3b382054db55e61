// Consensus under a link budget (issue 14): the token bucket, the estimated marginal size
// against the real encoding, and which landmarks a trimmed marginal keeps (pure functions of
// daemon/src/link_budget.h; the daemons on rate-limited links are in field_netns_test.cc).
#include <gtest/gtest.h>

#include "concord/daemon/wire.h"
#include "concord/net/frame_codec.h"
#include "concord/v1/concord.pb.h"
#include "link_budget.h"

namespace concord::daemon {
namespace {

using namespace std::chrono_literals;

TEST(LinkBudget, TokenBucketRefillsAtItsRateUpToOneSecondAndSharesEqually) {
  const auto t0 = LinkBudget::Clock::time_point{} + 100s;
  LinkBudget budget(10000.0, t0);
  EXPECT_DOUBLE_EQ(budget.share(4), 2500.0);
  budget.spend(9000);
  budget.refill(t0 + 100ms);
  EXPECT_NEAR(budget.tokens(), 2000.0, 1e-6);
  budget.spend(5000);  // control messages may overdraw
  EXPECT_DOUBLE_EQ(budget.share(2), 0.0);
  budget.refill(t0 + 10s);  // capped at one second's worth
  EXPECT_DOUBLE_EQ(budget.tokens(), 10000.0);
  EXPECT_TRUE(LinkBudget(0.0).unlimited());
  EXPECT_GT(LinkBudget(0.0).share(10), 1e12);
}

/// A marginal as the estimator makes it: one dense block over `in_state`, then 3x3 blocks.
Marginal make_marginal(int in_state, int archived) {
  Marginal marginal;
  const int n = in_state + archived;
  for (int i = 0; i < n; ++i) marginal.ids.push_back(1000 + 37 * i);
  marginal.mean = Eigen::VectorXd::Constant(3 * n, 12.5);
  if (in_state > 0)
    marginal.blocks.push_back(Eigen::MatrixXd::Identity(3 * in_state, 3 * in_state));
  for (int i = 0; i < archived; ++i) marginal.blocks.push_back(Eigen::Matrix3d::Identity());
  return marginal;
}

TEST(LinkBudget, EstimatedSizeBoundsTheEncodedMarginal) {
  for (const auto& [in_state, archived] :
       std::vector<std::pair<int, int>>{{0, 1}, {1, 0}, {5, 0}, {0, 40}, {12, 30}, {40, 200}}) {
    v1::Envelope envelope;
    envelope.set_round(123456);
    envelope.set_team("a-team-name");
    envelope.set_sender(7);
    envelope.set_protocol_version(net::kProtocolVersion);
    to_wire(make_marginal(in_state, archived), *envelope.mutable_marginal());
    envelope.mutable_marginal()->set_round(123456);
    envelope.mutable_marginal()->set_degree(9);
    const std::size_t actual = envelope.ByteSizeLong() + 21;
    const std::size_t estimate = estimated_marginal_bytes(in_state, archived);
    EXPECT_GE(estimate, actual) << in_state << " + " << archived;
    EXPECT_LE(estimate, actual + actual / 5 + 64) << in_state << " + " << archived;
  }
}

TEST(LinkBudget, TrimmedMarginalsKeepTheJointStateFirstAndRotateTheRest) {
  // Ids 1-4 in the joint state, 10-19 archived.
  std::vector<std::pair<LandmarkId, bool>> candidates;
  for (LandmarkId id = 1; id <= 4; ++id) candidates.emplace_back(id, true);
  for (LandmarkId id = 10; id <= 19; ++id) candidates.emplace_back(id, false);
  std::map<LandmarkId, std::uint64_t> sent;
  // Everything fits: everything goes.
  EXPECT_EQ(choose_within_budget(candidates, sent, 1e9).size(), candidates.size());
  // Nothing fits: an empty marginal.
  EXPECT_TRUE(choose_within_budget(candidates, sent, 10.0).empty());
  // Room for the joint state and 3 archived landmarks.
  const double allowance = static_cast<double>(estimated_marginal_bytes(4, 3));
  std::set<LandmarkId> archived_seen;
  for (std::uint64_t round = 0; round < 4; ++round) {
    const std::vector<LandmarkId> chosen = choose_within_budget(candidates, sent, allowance);
    ASSERT_EQ(chosen.size(), 7u);
    EXPECT_TRUE(std::is_sorted(chosen.begin(), chosen.end()));
    for (LandmarkId id = 1; id <= 4; ++id)
      EXPECT_TRUE(std::binary_search(chosen.begin(), chosen.end(), id)) << "joint-state id " << id;
    for (const LandmarkId id : chosen) {
      if (id >= 10) archived_seen.insert(id);
      sent[id] = round;
    }
  }
  // Least recently sent first: in 4 rounds of 3, all 10 archived landmarks went out.
  EXPECT_EQ(archived_seen.size(), 10u);
  // When the joint state itself does not fit, archived landmarks still can.
  const std::vector<LandmarkId> small =
      choose_within_budget(candidates, {}, static_cast<double>(estimated_marginal_bytes(0, 2)));
  EXPECT_EQ(small.size(), 2u);
}

}  // namespace
}  // namespace concord::daemon

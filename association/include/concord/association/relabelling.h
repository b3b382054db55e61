#pragma once
/// \file
/// Consensus over team ids: which of a sender's objects a receiver fuses, and under which of its
/// own ids. The sender's view (its shared objects with the receiver) and the receiver's may differ
/// for a round (an owner's new decision reaches the other robot a round later): only the pairs
/// both views hold are fused. One function for concord replay and the daemons.

#include <utility>
#include <vector>

#include "concord/estimator/types.h"

namespace concord::association {

/// (sender id, receiver id) pairs, ascending by sender id, one a sender id.
using Labels = std::vector<std::pair<LandmarkId, LandmarkId>>;

/// Sender id -> receiver id for the pairs both views agree on. `sent`: the sender's shared objects
/// with the receiver, (sender id, receiver id), in any order; `received`: the receiver's with the
/// sender, (receiver id, sender id) (of two entries for one sender id, the later counts).
Labels agreed_labels(
    const std::vector<std::pair<LandmarkId, LandmarkId>>& sent,
    const std::vector<std::pair<LandmarkId, LandmarkId>>& received);

/// The receiver's view of `received` (as agreed_labels takes it) by sender id: sender id ->
/// receiver id, ascending, one a sender id (of two entries for one sender id, the later in
/// `received` counts). A receiver keeps it from one change of its shared objects to the next.
Labels receiver_view(const std::vector<std::pair<LandmarkId, LandmarkId>>& received);

/// The cut of a sender's marginal for one receiver. `shared`: the sender's shared objects with
/// it, (sender id, receiver id), ascending; `held_ids`: the ids of the marginal it is cut out of.
/// `ids`: the sender ids to cut, ascending (Consensus::select's); `receiver_ids`: the receiver's id
/// of each landmark that cut keeps, in its order (held's). Of two entries for one sender id, the
/// first counts.
struct SharedCut {
  std::vector<LandmarkId> ids;
  std::vector<LandmarkId> receiver_ids;
};
SharedCut shared_cut(const std::vector<std::pair<LandmarkId, LandmarkId>>& shared,
                     const std::vector<LandmarkId>& held_ids);

/// What a receiver fuses of a sender's marginal: the landmarks whose sender id and receiver id
/// (`receiver_ids`, parallel to the marginal's ids, as the sender wrote them) the receiver's
/// view (receiver_view of its shared objects with the sender) holds too, relabelled with the
/// receiver's ids; order and covariance entries kept exactly. For a marginal of distinct ids the
/// same as relabel_marginal(marginal, agreed_labels(sent, received)), with view =
/// receiver_view(received) and sent the marginal's (id, receiver id) pairs, in one pass; when every
/// landmark is agreed only the ids change. Needs receiver_ids.size() == marginal.ids.size().
Marginal relabel_agreed(Marginal&& marginal, const std::vector<LandmarkId>& receiver_ids,
                        const Labels& view);

/// The part of `marginal` (the sender's ids) whose ids `labels` holds, relabelled with the
/// receiver's ids; order and covariance entries kept exactly (a marginal of a subset is the
/// submatrix of the marginal of a superset), blocks left empty dropped.
Marginal relabel_marginal(const Marginal& marginal, const Labels& labels);

}  // namespace concord::association

#!/usr/bin/env python3
"""Writes the seed corpora of fuzz_negotiation and fuzz_consensus (protoc --encode of text-format
messages): robot 2's Negotiations to robot 0 (with robot 1's records, relayed), whose own map
fuzz_negotiation.cc fixes, and a
neighbour's Marginals of the objects fuzz_consensus.cc gives the robot (100-103 in its joint
state, 104-105 archived). Run from the repository root."""
import math
import subprocess

# Robot 0's map (fuzz_negotiation.cc), moved into robot 2's frame by a turn of 30 degrees about z
# and a shift: the search of the pair (owned by robot 0) finds it.
XYZ = [(4.9, -4.2, 2.0), (1.1, 0.4, 1.1), (0.9, 0.1, 0.1), (6.5, -5.2, 0.3), (6.4, 3.9, 0.4),
       (3.3, 1.5, 2.8), (8.7, -1.2, 2.9), (0.7, 4.3, 0.9), (2.2, -4.6, 0.9), (12.2, -3.8, 1.7),
       (9.6, -1.5, 1.6), (0.9, -5.3, 0.6)]
ANGLE, SHIFT = math.radians(30.0), (3.0, -2.0, 0.0)
C, S = math.cos(ANGLE), math.sin(ANGLE)
ROBOT1, ROBOT2 = 1 << 40, 2 << 40  # object keys: robot * 2^40 + private id


def in_frame_2(p):
    return (C * p[0] - S * p[1] + SHIFT[0], S * p[0] + C * p[1] + SHIFT[1], p[2] + SHIFT[2])


def numbers(values):
    return "[" + ", ".join(repr(v) for v in values) + "]"


COV3 = "covariance: [0.01, 0, 0, 0.01, 0, 0.01] local_covariance: [0.01, 0, 0, 0.01, 0, 0.01]"
COV6 = numbers([0.01 if r == c else 0.0 for r in range(6) for c in range(r, 6)])
# frame 2 -> frame 0 (T_a_b with a = 0, b = 2): the inverse of the move above, 3x4 row by row.
R_INV = [[C, S, 0.0], [-S, C, 0.0], [0.0, 0.0, 1.0]]
T_INV = [-sum(R_INV[r][k] * SHIFT[k] for k in range(3)) for r in range(3)]
T_0_2 = numbers([v for r in range(3) for v in (*R_INV[r], T_INV[r])])

MAP = "map { frame: 2 " + " ".join(
    f"objects {{ id: {200 + i} object_class: {i % 2} observations: 20 "
    f"position: {numbers(in_frame_2(p))} {COV3} }}" for i, p in enumerate(XYZ)) + " }"
def links(robot_key):
    return " ".join(f"links {{ a: {100 + i} b: {robot_key + 200 + i} mahalanobis_squared: 0.5 }}"
                    for i in range(len(XYZ)))


NEGOTIATION_SEEDS = {
    # A description only: robot 0's searches and confirmations.
    "seed_map": f"frame: 2 {MAP}",
    # Robot 1's record, relayed by robot 2 (robot 1 owns its pair with robot 0): links of robot
    # 0's objects with robot 1's and an edge between their frames.
    "seed_record": f"frame: 2 {MAP} records {{ owner: 1 version: 1 {links(ROBOT1)} frame_edges {{ "
                   f"frame_a: 0 frame_b: 1 T_a_b: {T_0_2} covariance: {COV6} round: 5 owner: 1 "
                   "robot_b: 0 } } held { owner: 1 version: 1 }",
    # Robot 2's own record deciding the pair robot 0 owns (refused whole, records_not_owned).
    "seed_record_not_owned": f"frame: 2 {MAP} records {{ owner: 2 version: 1 {links(ROBOT2)} "
                             f"frame_edges {{ frame_a: 0 frame_b: 2 T_a_b: {T_0_2} covariance: "
                             f"{COV6} round: 5 owner: 2 }} }} held {{ owner: 2 version: 1 }}",
    # Robot 1's edge between robot 0's frame and the world frame, corrected once: robot 0 moves.
    "seed_world_edge": f"frame: 2 records {{ owner: 1 version: 3 frame_edges {{ frame_a: -1 frame_b: 0 "
                       f"T_a_b: {T_0_2} covariance: {COV6} round: 10 owner: 1 robot_b: 0 "
                       f"corrections {{ frame: -1 moves_b_side: true T: {T_0_2} covariance: {COV6} "
                       "round: 15 } } } held { owner: 1 version: 3 }",
}

CONSENSUS_XYZ = {100: (4.0, 1.0, 0.5), 101: (5.5, -2.0, 1.0), 102: (7.0, 0.5, 0.2),
                 103: (6.0, 3.0, 1.5),
                 104: (2.0, -4.0, 0.3), 105: (9.0, 2.5, 0.8)}


def upper(n, diagonal, off=0.0):
    return [diagonal if r == c else off for r in range(n) for c in range(r, n)]


def marginal(ids, blocks, shift=None):
    shift = shift or {}
    mean = []
    for i in ids:
        position = CONSENSUS_XYZ.get(i, (1.0, 1.0, 1.0))
        mean += [v + d for v, d in zip(position, shift.get(i, (0.0, 0.0, 0.0)))]
    packed = []
    for landmarks, diagonal, off in blocks:
        packed += upper(3 * landmarks, diagonal, off)
    return (f"round: 3 landmark_ids: {ids} mean: {mean} degree: 1 "
            f"block_landmarks: {[b[0] for b in blocks]} packed_upper: {packed}")


CONSENSUS_SEEDS = {
    # The four joint objects in one correlated block, a little off the robot's estimates.
    "seed_joint": marginal([100, 101, 102, 103], [(4, 0.02, 0.002)],
                           {100: (0.1, 0.0, 0.0), 102: (0.0, -0.1, 0.05)}),
    # Two archived objects, a block each, and one the robot does not hold.
    "seed_archived": marginal([104, 105, 200], [(1, 0.03, 0.0), (1, 0.03, 0.0), (1, 0.5, 0.0)]),
    # One object 10 m away from the robot's estimate (refused), one close.
    "seed_outlier": marginal([101, 103], [(1, 0.02, 0.0), (1, 0.02, 0.0)], {101: (10.0, 0.0, 0.0)}),
}


def write(message, folder, seeds):
    for name, text in seeds.items():
        encoded = subprocess.run(["protoc", "--proto_path=proto", f"--encode=concord.v1.{message}",
                                  "concord/v1/concord.proto"], input=text.encode(), check=True,
                                 capture_output=True).stdout
        with open(f"fuzz/corpus/{folder}/{name}", "wb") as seed:
            seed.write(encoded)


write("Negotiation", "negotiation", NEGOTIATION_SEEDS)
write("Marginal", "consensus", CONSENSUS_SEEDS)

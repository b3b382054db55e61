#!/usr/bin/env python3
"""Writes fuzz_consensus's seeds (protoc --encode of text-format Marginals): a neighbour's marginals
of the objects fuzz_consensus.cc gives the robot (100-103 in its joint state, 104-105 archived).
Run from the repository root."""
import subprocess

XYZ = {100: (4.0, 1.0, 0.5), 101: (5.5, -2.0, 1.0), 102: (7.0, 0.5, 0.2), 103: (6.0, 3.0, 1.5),
       104: (2.0, -4.0, 0.3), 105: (9.0, 2.5, 0.8)}


def upper(n, diagonal, off=0.0):
    return [diagonal if r == c else off for r in range(n) for c in range(r, n)]


def marginal(ids, blocks, shift=None):
    shift = shift or {}
    mean = []
    for i in ids:
        mean += [v + d for v, d in zip(XYZ.get(i, (1.0, 1.0, 1.0)), shift.get(i, (0.0, 0.0, 0.0)))]
    packed = []
    for landmarks, diagonal, off in blocks:
        packed += upper(3 * landmarks, diagonal, off)
    return (f"round: 3 landmark_ids: {ids} mean: {mean} degree: 1 "
            f"block_landmarks: {[b[0] for b in blocks]} packed_upper: {packed}")


SEEDS = {
    # The four joint objects in one correlated block, a little off the robot's estimates.
    "seed_joint": marginal([100, 101, 102, 103], [(4, 0.02, 0.002)],
                           {100: (0.1, 0.0, 0.0), 102: (0.0, -0.1, 0.05)}),
    # Two archived objects, a block each, and one the robot does not hold.
    "seed_archived": marginal([104, 105, 200], [(1, 0.03, 0.0), (1, 0.03, 0.0), (1, 0.5, 0.0)]),
    # One object 10 m away from the robot's estimate (refused), one close.
    "seed_outlier": marginal([101, 103], [(1, 0.02, 0.0), (1, 0.02, 0.0)], {101: (10.0, 0.0, 0.0)}),
}
for name, text in SEEDS.items():
    encoded = subprocess.run(["protoc", "--proto_path=proto", "--encode=concord.v1.Marginal",
                              "concord/v1/concord.proto"], input=text.encode(), check=True,
                             capture_output=True).stdout
    with open(f"fuzz/corpus/consensus/{name}", "wb") as seed:
        seed.write(encoded)

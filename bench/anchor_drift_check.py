#!/usr/bin/env python3
"""Diagnosis (issue 11): how the negotiated team's accuracy compares with its anchor robot alone.

With unknown starts the team frame is robot 0's start frame (the lowest robot of the team), and
nothing else in the team knows where that frame is: robot 0's own map is the team's only anchor.
A given run has every robot's start pose, one anchor a robot. This script measures what that
means on the sim cases of bench/association_bench.sh (bench/out/association): for every case it
replays the given set once more with every robot alone (`--separate`, known start, written to
BENCH_OUT/separate-CASE; skipped when present) and prints, next to each other:
  - robot 0 alone: its trajectory RMSE, and its position error at the team's first alignment
    frame, at the end, and on average from that frame on;
  - robot 0 in the negotiated team (its trajectory is in its own start frame, the team frame;
    the truth is taken into that frame): the same three errors;
  - the given run's robot 0, the same;
  - the team's RMSE (mean over robots, from each robot's alignment frame on) negotiated and
    given, and their ratios to robot 0 alone.
Then what one anchor costs by itself: every case replayed given (global ids, every start right)
with `--unanchored-start SIGMA_M SIGMA_RAD` (every robot but robot 0 starts with that uncertainty
about its start, written to BENCH_OUT/unanchored-SIGMA_M-CASE), for uncertainties from far below
to about the size of a negotiated alignment's error, against the given run: no association and no
alignment error, only robot 0's start as the team's anchor.
Nothing in the filter or the negotiation changes; it reads the bench's outputs and runs
`concord replay` only.

Usage: bench/anchor_drift_check.py [BENCH_OUT] [CONCORD] [CONFIG] > docs/results-anchor.md
       (defaults bench/out/association, build/tools/concord, configs/sensors/sim.yaml)
"""
import json
import math
import os
import statistics
import subprocess
import sys


def poses(path):
    """A KITTI pose file as a list of (R rows, t)."""
    out = []
    with open(path) as f:
        for line in f:
            v = [float(x) for x in line.split()]
            if len(v) == 12:
                out.append(([v[0:3], v[4:7], v[8:11]], [v[3], v[7], v[11]]))
    return out


def in_start_frame(start, pose):
    """The position of `pose` in the frame of `start` (both in the world): R0^T (t - t0)."""
    R, t = start
    d = [pose[1][i] - t[i] for i in range(3)]
    return [sum(R[r][i] * d[r] for r in range(3)) for i in range(3)]


def errors(estimate, truth, own_frame):
    """Per-frame position error of robot 0; own_frame: the estimate is in its start frame."""
    return [math.dist(e[1], in_start_frame(truth[0], g) if own_frame else g[1])
            for e, g in zip(estimate, truth)]


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "bench/out/association"
    concord = sys.argv[2] if len(sys.argv) > 2 else "build/tools/concord"
    config = sys.argv[3] if len(sys.argv) > 3 else "configs/sensors/sim.yaml"
    cases = sorted(d[len("sim-"):-len("-negotiated")] for d in os.listdir(out)
                   if d.startswith("sim-") and d.endswith("-negotiated"))
    print("# What one anchor costs: negotiated and given teams against robot 0 alone (issue 11)\n")
    print("Written by `bench/anchor_drift_check.py` from the outputs of "
          "`bench/association_bench.sh` (see the script's header and docs/association.md, "
          "Limits, \"The gap taken apart\"). Errors in metres; robot 0's errors are positions "
          "at the team's first alignment frame, at the end, and the mean from that frame on.\n")
    print("| case | first alignment | robot 0 alone: RMSE / at alignment / end / mean after | "
          "robot 0 negotiated | robot 0 given | team RMSE negotiated / given | "
          "negotiated / robot 0 alone | given / robot 0 alone |")
    print("|---|---|---|---|---|---|---|---|")
    ratios_alone, ratios_given_alone, grew = [], [], 0
    for case in cases:
        data = os.path.join(out, "data-" + case)
        separate = os.path.join(out, "separate-" + case)
        if not os.path.exists(os.path.join(separate, "metrics.json")):
            subprocess.run([concord, "replay", "--dataset", data, "--out", separate, "--config",
                            config, "--separate", "--association", "given"],
                           check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        negotiated = json.load(open(os.path.join(out, f"sim-{case}-negotiated", "metrics.json")))
        given = json.load(
            open(os.path.join(out, f"sim-{case}-given-from-alignment", "metrics.json")))
        alone = json.load(open(os.path.join(separate, "metrics.json")))
        moved = [r["aligned_at_frame"] for r in negotiated["robots"] if r["aligned_at_frame"] > 0]
        if not moved:
            continue
        first = min(moved)
        truth = poses(os.path.join(data, "robot_00", "groundtruth.kitti"))
        cells = []
        for folder, own in ((separate, False), (os.path.join(out, f"sim-{case}-negotiated"), True),
                            (os.path.join(out, f"sim-{case}-given"), False)):
            e = errors(poses(os.path.join(folder, "robot_00", "trajectory.kitti")), truth, own)
            after = e[first:]
            cells.append((e[first], e[-1], sum(after) / len(after)))
        alone_rmse = alone["robots"][0]["trajectory_rmse"]
        team_negotiated = negotiated["average"]["trajectory_rmse"]
        team_given = given["average"]["trajectory_rmse"]
        ratios_alone.append(team_negotiated / alone_rmse)
        ratios_given_alone.append(team_given / alone_rmse)
        grew += cells[1][2] > 1.5 * cells[1][0]
        fmt = lambda c: "%.2f / %.2f / %.2f" % c
        print(f"| {case} | {first} | {alone_rmse:.2f} / {fmt(cells[0])} | {fmt(cells[1])} | "
              f"{fmt(cells[2])} | {team_negotiated:.3f} / {team_given:.3f} | "
              f"{team_negotiated / alone_rmse:.2f} | {team_given / alone_rmse:.2f} |")
    if ratios_alone:
        print(f"\n{len(ratios_alone)} cases. Team RMSE over robot 0 alone: negotiated median "
              f"{statistics.median(ratios_alone):.2f} "
              f"({min(ratios_alone):.2f}-{max(ratios_alone):.2f}), given median "
              f"{statistics.median(ratios_given_alone):.2f} "
              f"({min(ratios_given_alone):.2f}-{max(ratios_given_alone):.2f}). Negotiated robot "
              f"0's mean error after the first alignment above 1.5 times its error at it: "
              f"{grew} of {len(ratios_alone)}.")

    print("\n| unanchored start sigma | trajectory RMSE / given, median (range) | within 10 % | "
          "object error / given, median | pose NEES median | object NEES median |")
    print("|---|---|---|---|---|---|")
    for position, rotation in ((0.05, 0.005), (0.2, 0.02), (0.5, 0.05), (1.0, 0.1)):
        trajectory, objects, pose_nees, object_nees = [], [], [], []
        for case in cases:
            folder = os.path.join(out, f"unanchored-{position}-{case}")
            if not os.path.exists(os.path.join(folder, "metrics.json")):
                subprocess.run([concord, "replay", "--dataset", os.path.join(out, "data-" + case),
                                "--out", folder, "--config", config, "--association", "given",
                                "--unanchored-start", str(position), str(rotation)],
                               check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            run = json.load(open(os.path.join(folder, "metrics.json")))["average"]
            given = json.load(open(os.path.join(out, f"sim-{case}-given", "metrics.json")))["average"]
            trajectory.append(run["trajectory_rmse"] / given["trajectory_rmse"])
            objects.append(run["object_error"] / given["object_error"])
            pose_nees.append(run["pose_nees"]["mean"])
            object_nees.append(run["object_nees"]["mean"])
        print(f"| {position} m, {rotation} rad | {statistics.median(trajectory):.2f} "
              f"({min(trajectory):.2f}-{max(trajectory):.2f}) | "
              f"{sum(r <= 1.1 for r in trajectory)} of {len(trajectory)} | "
              f"{statistics.median(objects):.2f} | {statistics.median(pose_nees):.1f} | "
              f"{statistics.median(object_nees):.2f} |")


if __name__ == "__main__":
    main()

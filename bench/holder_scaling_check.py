#!/usr/bin/env python3
"""Diagnosis (issue 9): how far the consensus objects' covariances are from the team's information.

The weighted geometric mean of eq. (19) leaves each robot with about the average of the
holders' information about an object, where the centralized filter would have their sum
(docs/estimator.md, "Why the conservative covariance is worth keeping", worked out on a scalar
model). This script measures it on the full filter: for every consensus run of
bench/consistency_bench.sh (bench/out/consistency), the final object NEES (3-D) of every robot's
objects as written, and with each covariance divided by the number of robots holding the object
at the end (the holders of eq. 19 on the complete graph), next to the separate runs' object NEES
of the same sets. Nothing in the filter changes; it reads the bench's outputs only.

Usage: bench/holder_scaling_check.py [BENCH_OUT]   (default bench/out/consistency)
"""
import csv
import glob
import os
import statistics
import sys

CHI2_3_95 = 7.814727903251178  # chi-square 95 % quantile, 3 degrees of freedom


def solve3(c, d):
    """d^T c^-1 d for a symmetric 3x3 c (Cramer's rule; no numpy)."""
    a, b, e = c[0][0], c[0][1], c[0][2]
    f, g, i = c[1][1], c[1][2], c[2][2]
    det = a * (f * i - g * g) - b * (b * i - g * e) + e * (b * g - f * e)
    if det <= 0.0:
        return float("inf")
    inv = [
        [f * i - g * g, e * g - b * i, b * g - e * f],
        [e * g - b * i, a * i - e * e, b * e - a * g],
        [b * g - e * f, b * e - a * g, a * f - b * b],
    ]
    return sum(d[r] * inv[r][k] * d[k] for r in range(3) for k in range(3)) / det


def read_objects(path):
    objects = {}
    with open(path) as f:
        for row in csv.DictReader(f):
            p = [float(row[k]) for k in ("x", "y", "z")]
            cxx, cxy, cxz = float(row["cxx"]), float(row["cxy"]), float(row["cxz"])
            cyy, cyz, czz = float(row["cyy"]), float(row["cyz"]), float(row["czz"])
            objects[int(row["id"])] = (p, [[cxx, cxy, cxz], [cxy, cyy, cyz], [cxz, cyz, czz]])
    return objects


def run_nees(run, truth, divide_by_holders):
    robots = [read_objects(p) for p in sorted(glob.glob(os.path.join(run, "robot_*", "objects.csv")))]
    holders = {}
    for objects in robots:
        for object_id in objects:
            holders[object_id] = holders.get(object_id, 0) + 1
    values = []
    for objects in robots:
        for object_id, (p, c) in objects.items():
            if object_id not in truth:
                continue
            scale = holders[object_id] if divide_by_holders else 1
            d = [p[k] - truth[object_id][k] for k in range(3)]
            values.append(solve3([[x / scale for x in row] for row in c], d))
    return values


def main():
    out = sys.argv[1] if len(sys.argv) > 1 else "bench/out/consistency"
    rows = {}
    for run in sorted(glob.glob(os.path.join(out, "sim-n*-consensus"))):
        name = os.path.basename(run)[len("sim-"):-len("-consensus")]
        separate = os.path.join(out, "sim-" + name + "-separate")
        truth_path = os.path.join(out, "data-" + name, "objects_gt.csv")
        if not os.path.isdir(separate) or not os.path.isfile(truth_path):
            continue
        with open(truth_path) as f:
            truth = {int(r["id"]): [float(r[k]) for k in ("x", "y", "z")] for r in csv.DictReader(f)}
        size = int(name.split("-")[0][1:])
        as_written = run_nees(run, truth, False)
        scaled = run_nees(run, truth, True)
        alone = run_nees(separate, truth, False)
        inside = lambda v: sum(x <= CHI2_3_95 for x in v) / len(v)
        rows.setdefault(size, []).append(
            (statistics.mean(as_written), inside(as_written), statistics.mean(scaled), inside(scaled),
             statistics.mean(alone), inside(alone)))
    print("| robots | runs | consensus as written: object NEES (inside) | divided by the holders | separate |")
    print("|---|---|---|---|---|")
    for size in sorted(rows):
        r = rows[size]
        m = [statistics.mean(x[k] for x in r) for k in range(6)]
        print(f"| {size} | {len(r)} | {m[0]:.2f} ({100 * m[1]:.0f} %) | {m[2]:.2f} ({100 * m[3]:.0f} %) "
              f"| {m[4]:.2f} ({100 * m[5]:.0f} %) |")


if __name__ == "__main__":
    main()

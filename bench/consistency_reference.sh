#!/usr/bin/env bash
# What a consistent filter scores on issue 9's pose targets, run by run: each set of the
# consistency bench's simulation sweep replayed separate with odometry only (no objects, no
# point features), where the filter's model is exactly the simulator's (relative motions with
# independent Gaussian noise a frame, the config's sigmas set to the simulator's). Its pose NEES
# is that of a consistent estimator up to the rotation's nonlinearity, with the same robots,
# paths and samples a run as the filter's. Printed next to the filter's separate runs of the
# same sets: the share of runs meeting each target, and per team size the means.
# Needs bench/consistency_bench.sh's data and separate runs (bench/out/consistency/).
# Writes bench/out/consistency-reference/ (kept between runs) and prints the comparison.
# Usage: bench/consistency_reference.sh
set -euo pipefail
cd "$(dirname "$0")/.."
data=bench/out/consistency
out=bench/out/consistency-reference
[ -d "$data" ] || { echo "run bench/consistency_bench.sh first" >&2; exit 1; }
mkdir -p "$out"
source bench/replay_runs.sh

for set in "$data"/data-n*; do
  name=$(basename "$set")
  name=${name#data-}
  noise=${name##*-x}
  translation=$(python3 -c "print(0.015 * $noise)")
  rotation=$(python3 -c "print(0.01 * $noise)")
  run "$name" "$set" --separate --no-point-features --set object_min_observations=1000000 \
    --set "odometry_translation_sigma=$translation" --set "odometry_rotation_sigma=$rotation"
done

python3 - "$data" "$out" <<'PY'
import collections, json, os, statistics, sys
data, out = sys.argv[1], sys.argv[2]

def pose(path):
    p = json.load(open(path))["average"]["pose_nees"]
    return p["mean"], p["inside_95"], p["last_quarter_median"] / p["first_quarter_median"]

def meets(mean, inside, growth):
    return 3 <= mean <= 12 and inside >= 0.85 and growth <= 1.5

rows = []
for name in sorted(os.listdir(out)):
    reference = f"{out}/{name}/metrics.json"
    separate = f"{data}/sim-{name}-separate/metrics.json"
    if os.path.isfile(reference) and os.path.isfile(separate):
        rows.append((name, pose(reference), pose(separate)))
print(f"{len(rows)} sets (issue 9's pose targets: NEES mean in [3, 12], at least 85 % inside "
      "the 95 % bound, growth at most x1.5)\n")
print("| run | every pose target | mean in [3, 12] | inside >= 85 % | growth <= x1.5 |")
print("|---|---|---|---|---|")
for label, k in (("odometry only (exact model)", 1), ("the filter, separate", 2)):
    count = lambda test: sum(test(r[k]) for r in rows)
    print(f"| {label} | {count(lambda p: meets(*p))} | {count(lambda p: 3 <= p[0] <= 12)} | "
          f"{count(lambda p: p[1] >= 0.85)} | {count(lambda p: p[2] <= 1.5)} |")
print("\n| robots | odometry only: NEES mean / inside (lowest run) / growth median (largest) "
      "| the filter, separate: the same |")
print("|---|---|---|")
by_size = collections.defaultdict(list)
for row in rows:
    by_size[int(row[0].split("-")[0][1:])].append(row)
for size in sorted(by_size):
    cells = []
    for k in (1, 2):
        runs = [r[k] for r in by_size[size]]
        cells.append(f"{statistics.mean(p[0] for p in runs):.2f} / "
                     f"{statistics.mean(p[1] for p in runs):.2f} ({min(p[1] for p in runs):.2f}) / "
                     f"x{statistics.median(p[2] for p in runs):.2f} (x{max(p[2] for p in runs):.2f})")
    print(f"| {size} | {cells[0]} | {cells[1]} |")
PY

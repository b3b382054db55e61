#!/usr/bin/env bash
# Issue 13, compact marginals: bytes per robot per round against the event-triggering threshold
# (consensus.share_kl_threshold, with and without consensus.share_float32), and the accuracy and
# NEES each costs, on kitti00, sim15 and a 50-robot `concord sim` team (300 frames, seed 1), and
# at KL 0.01 in float32 the cap of landmarks a robot sends a round (consensus.share_max_landmarks,
# split over its links) and the covariance blocks cut into runs of at most 1, 4 or 8 landmarks
# (consensus.share_block_landmarks; blocks of 4 also at KL 0.003 and 0.001).
# Every run is `concord replay` (consensus, complete graph) with the set's sensor config; only
# the sharing keys change (--set). Writes docs/results-sharing.md; runs in bench/out/sharing/
# (kept between runs: delete the folder to start afresh). Two runs at a time.
# Usage: bench/sharing_bench.sh [THRESHOLDS [CAPS]]
#   (defaults "0.001 0.01 0.03 0.1 0.3" and "10 20 150 210 300")
set -euo pipefail
cd "$(dirname "$0")/.."
thresholds="${1:-0.001 0.01 0.03 0.1 0.3}"
caps="${2:-10 20 150 210 300}"
shared=../shared/datasets
out=bench/out/sharing
source bench/replay_runs.sh

sim50="$out/data-sim50"
[ -f "$sim50/dataset.json" ] || $concord sim --robots 50 --frames 300 --seed 1 --out "$sim50" >/dev/null

for set in kitti00 sim15 sim50; do
  case $set in
    sim50) data=$sim50 ;;
    *) data=$shared/$set ;;
  esac
  run "$set-whole" "$data" &
  run "$set-float32" "$data" --set consensus.share_float32=true &
  wait
  pending=0
  for threshold in $thresholds; do
    run "$set-kl$threshold-float32" "$data" --set consensus.share_kl_threshold="$threshold" \
      --set consensus.share_float32=true &
    pending=$((pending + 1))
    if [ $pending = 2 ]; then wait; pending=0; fi
  done
  wait
  run "$set-kl0.01-double" "$data" --set consensus.share_kl_threshold=0.01 &
  pending=1
  for blocks in 1 4 8; do
    run "$set-kl0.01-float32-blocks$blocks" "$data" --set consensus.share_kl_threshold=0.01 \
      --set consensus.share_float32=true --set consensus.share_block_landmarks="$blocks" &
    pending=$((pending + 1))
    if [ $pending = 2 ]; then wait; pending=0; fi
  done
  wait
  # Blocks of 4 under smaller thresholds: fresher marginals for a few more bytes.
  for threshold in 0.003 0.001; do
    run "$set-kl$threshold-float32-blocks4" "$data" --set consensus.share_kl_threshold="$threshold" \
      --set consensus.share_float32=true --set consensus.share_block_landmarks=4 &
  done
  wait
  pending=0
  for cap in $caps; do
    run "$set-kl0.01-float32-rcap$cap" "$data" --set consensus.share_kl_threshold=0.01 \
      --set consensus.share_float32=true --set consensus.share_max_landmarks="$cap" &
    pending=$((pending + 1))
    if [ $pending = 2 ]; then wait; pending=0; fi
  done
  wait
done

python3 - "$out" "$thresholds" "$caps" >docs/results-sharing.md <<'PY'
import json, sys
out, thresholds, caps = sys.argv[1], sys.argv[2].split(), sys.argv[3].split()
print("# Compact, event-triggered marginals: bytes against accuracy\n")
print("Written by `bench/sharing_bench.sh` (issue 13). `concord replay`, consensus on the complete")
print("graph, each set with its sensor config; only the sharing keys change:")
print("`consensus.share_kl_threshold` (a link sends a landmark again only when its marginal moved by")
print("more than this KL divergence, in nats, since it last carried it; the receiver fuses the last")
print("one it got), `consensus.share_float32` (float32 means and Cholesky factors) and")
print("`consensus.share_max_landmarks` (at most this many landmarks a robot sends a round, split")
print("evenly over its links: the never sent and the most moved first, the rest later) and")
print("`consensus.share_block_landmarks` (covariance blocks cut into runs of at most that many")
print("landmarks, the correlations between runs left out: bytes linear in the landmarks instead of")
print("quadratic). Bytes: what")
print("a robot sends its neighbours in a round (8 per id; mean and covariance numbers at 8 bytes in")
print("double, 4 in float32, plus a 24-byte origin), median and largest over robots and rounds. The")
print("daemons send the same marginals (tests/daemon_exchange_test.cc), plus their framing.\n")
summary = []
for name, title in (("kitti00", "kitti00 (3 robots)"), ("sim15", "sim15 (15 robots)"),
                    ("sim50", "`concord sim --robots 50 --frames 300 --seed 1`")):
    rows = [("whole, double", f"{name}-whole"), ("whole, float32", f"{name}-float32")]
    rows += [(f"KL {t}, float32", f"{name}-kl{t}-float32") for t in thresholds]
    rows += [("KL 0.01, double", f"{name}-kl0.01-double")]
    rows += [(f"KL 0.01, float32, blocks of {n}", f"{name}-kl0.01-float32-blocks{n}")
             for n in (1, 4, 8)]
    rows += [(f"KL {t}, float32, blocks of 4", f"{name}-kl{t}-float32-blocks4")
             for t in ("0.003", "0.001")]
    rows += [(f"KL 0.01, float32, cap {c}", f"{name}-kl0.01-float32-rcap{c}") for c in caps]
    base = None
    print(f"## {title}\n")
    print("| sharing | bytes median | bytes max | median vs whole | max vs whole | traj RMSE m | vs whole | object err m | vs whole | pose NEES | object NEES |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    meets = []
    for label, run in rows:
        try:
            m = json.load(open(f"{out}/{run}/metrics.json"))
        except FileNotFoundError:
            continue
        a, r = m["average"], m["run"]
        b = r["marginal_bytes_per_robot_round"]
        if base is None:
            base = (b["median"], b["max"], a["trajectory_rmse"], a["object_error"])
        median = b["median"] / base[0] if base[0] else 0.0
        largest = b["max"] / base[1] if base[1] else 0.0
        dt = 100.0 * (a["trajectory_rmse"] / base[2] - 1.0)
        do = 100.0 * (a["object_error"] / base[3] - 1.0)
        if dt <= 2.0 and do <= 2.0 and median <= 0.1 and largest <= 0.1:
            meets.append(label)
        print(f"| {label} | {b['median']} | {b['max']} | {median:.3f} | {largest:.3f} | "
              f"{a['trajectory_rmse']:.4f} | {dt:+.1f} % | {a['object_error']:.4f} | {do:+.1f} % | "
              f"{a['pose_nees']['mean']:.2f} | {a['object_nees']['mean']:.2f} |")
    print("\nMedian and largest round at most 0.1 of whole with trajectory and objects within 2 % "
          "of whole (or better): " + (", ".join(meets) if meets else "none") + ".\n")
    summary.append((title, meets))
print("## All three sets\n")
common = set(summary[0][1]).intersection(*(set(m) for _, m in summary[1:]))
print("Settings that meet it on every set: " + (", ".join(sorted(common)) if common else "none") + ".")
target = set(summary[0][1]).intersection(set(summary[2][1]))
print("\nOn kitti00 and the 50-robot team (issue 13's two sets): " +
      (", ".join(sorted(target)) if target else "none") + ".")
PY

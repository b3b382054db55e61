#!/usr/bin/env bash
# Issue 13, compact marginals: bytes per robot per round against the event-triggering threshold
# (consensus.share_kl_threshold, with and without consensus.share_float32), and the accuracy and
# NEES each costs, on kitti00, sim15 and a 50-robot `concord sim` team (300 frames, seed 1).
# Every run is `concord replay` (consensus, complete graph) with the set's sensor config; only
# the sharing keys change (--set). Writes docs/results-sharing.md; runs in bench/out/sharing/
# (kept between runs: delete the folder to start afresh). Two runs at a time.
# Usage: bench/sharing_bench.sh [THRESHOLDS]   (default "0.001 0.01 0.03 0.1 0.3")
set -euo pipefail
cd "$(dirname "$0")/.."
thresholds="${1:-0.001 0.01 0.03 0.1 0.3}"
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
  run "$set-kl0.01-double" "$data" --set consensus.share_kl_threshold=0.01
done

python3 - "$out" "$thresholds" >docs/results-sharing.md <<'PY'
import json, sys
out, thresholds = sys.argv[1], sys.argv[2].split()
print("# Compact, event-triggered marginals: bytes against accuracy\n")
print("Written by `bench/sharing_bench.sh` (issue 13). `concord replay`, consensus on the complete")
print("graph, each set with its sensor config; only `consensus.share_kl_threshold` (a link sends a")
print("landmark again only when its marginal moved by more than this KL divergence, in nats, since")
print("it last carried it; the receiver fuses the last one it got) and `consensus.share_float32`")
print("(float32 means and Cholesky factors) change. Bytes: what a robot sends its neighbours in a")
print("round (8 per id; mean and covariance numbers at 8 bytes in double, 4 in float32, plus a")
print("24-byte origin), median and largest over robots and rounds. The daemons send the same")
print("marginals (tests/daemon_exchange_test.cc), plus their framing.\n")
for name, title in (("kitti00", "kitti00 (3 robots)"), ("sim15", "sim15 (15 robots)"),
                    ("sim50", "`concord sim --robots 50 --frames 300 --seed 1`")):
    rows = [("whole, double", f"{name}-whole"), ("whole, float32", f"{name}-float32")]
    rows += [(f"KL {t}, float32", f"{name}-kl{t}-float32") for t in thresholds]
    rows += [("KL 0.01, double", f"{name}-kl0.01-double")]
    base = None
    base_max = None
    best = None
    print(f"## {title}\n")
    print("| sharing | bytes median | bytes max | median vs whole | traj RMSE m | vs whole | object err m | vs whole | pose NEES | object NEES |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for label, run in rows:
        try:
            m = json.load(open(f"{out}/{run}/metrics.json"))
        except FileNotFoundError:
            continue
        a, r = m["average"], m["run"]
        b = r["marginal_bytes_per_robot_round"]
        if base is None:
            base = (b["median"], a["trajectory_rmse"], a["object_error"])
            base_max = b["max"]
        ratio = b["median"] / base[0] if base[0] else 0.0
        dt = 100.0 * (a["trajectory_rmse"] / base[1] - 1.0)
        do = 100.0 * (a["object_error"] / base[2] - 1.0)
        if dt <= 2.0 and do <= 2.0 and (best is None or ratio < best[1]):
            best = (label, ratio, b["max"] / base_max if base_max else 0.0, dt, do)
        print(f"| {label} | {b['median']} | {b['max']} | {ratio:.3f} | {a['trajectory_rmse']:.4f} | "
              f"{dt:+.1f} % | {a['object_error']:.4f} | {do:+.1f} % | {a['pose_nees']['mean']:.2f} | "
              f"{a['object_nees']['mean']:.2f} |")
    if best:
        print(f"\nFewest bytes at equal accuracy (trajectory and objects within 2 % of whole, or "
              f"better): {best[0]}, median {best[1]:.3f} and largest {best[2]:.3f} of whole "
              f"(trajectory {best[3]:+.1f} %, objects {best[4]:+.1f} %).")
    print()
PY
cat docs/results-sharing.md

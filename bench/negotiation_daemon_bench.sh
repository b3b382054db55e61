#!/usr/bin/env bash
# Issue 11's time line on the daemons: what the negotiated association costs a concordd, in CPU,
# against the rest of its CPU (the estimator, consensus, the network, HTTP). bench/association_bench.sh
# measures the same line on `concord replay`, where nothing else runs; this is the deployed form.
#
# `concord sim` (300 frames, 4 detector classes, objects only, the association bench's sets) with
# private ids and unknown starts, then `concord launch --lockstep --rate 10` over the complete
# graph with configs/sensors/sim.yaml, one team at a time. Per daemon, from its stats.json:
# negotiation.seconds (CPU time of the threads doing the negotiation: messages in and out,
# decisions, moves) and the process's CPU (user + system); the share is negotiation / (CPU -
# negotiation). Wall-clock time is no use here: with more daemons than cores every section of code
# also waits for the other processes' turns.
# Writes docs/results-negotiation-daemons.md; runs in bench/out/negotiation-daemons (kept between
# runs: delete the folder to start afresh).
# Usage: bench/negotiation_daemon_bench.sh [SEEDS] [TEAM SIZES]   (default "1 2" "3 5 10 15")
set -euo pipefail
cd "$(dirname "$0")/.."
seeds="${1:-1 2}"
sizes="${2:-3 5 10 15}"
out=bench/out/negotiation-daemons
mkdir -p "$out"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 --target concord concordd >/dev/null
concord=./build/tools/concord

for n in $sizes; do
  for seed in $seeds; do
    data="$out/data-n$n-s$seed"
    private="$data-private"
    [ -f "$data/dataset.json" ] || $concord sim --robots "$n" --seed "$seed" --frames 300 \
      --classes 4 --points-per-frame 0 --out "$data" >/dev/null
    [ -f "$private/dataset.json" ] ||
      $concord convert --dataset "$data" --out "$private" --private-ids --unknown-start >/dev/null
    run="$out/n$n-s$seed"
    if [ ! -f "$run/metrics.json" ]; then
      rm -rf "$run"
      $concord launch --dataset "$private" --out "$run" --config configs/sensors/sim.yaml \
        --lockstep --rate 10 --base-port 25000 --http-base-port 26000 >"$run.log" 2>&1 ||
        { echo "bench: n$n-s$seed FAILED (see $run.log)" >&2; exit 1; }
    fi
    echo "bench: n$n-s$seed" >&2
  done
done

python3 - "$out" $sizes -- $seeds >docs/results-negotiation-daemons.md <<'PY'
import glob, json, os, statistics, sys
out = sys.argv[1]
split = sys.argv.index("--")
sizes, seeds = sys.argv[2:split], sys.argv[split + 1:]
print("# The negotiation's CPU on the daemons\n")
print("Written by `bench/negotiation_daemon_bench.sh` (issue 11: the negotiation adds at most 20 % to")
print("the per-frame time). `concord launch --lockstep --rate 10`, complete graph, `concord sim` sets")
print("(300 frames, 4 classes, objects only) with private ids and unknown starts. Per daemon:")
print("negotiation CPU (stats.json `negotiation.seconds`: messages in and out, decisions, moves, and")
print("since 2026-11-30 the relabelling of marginals between private ids) over")
print("the rest of its CPU (user + system); median and largest over the team's daemons. The replay's")
print("figure for the same data is in docs/results-association.md (there nothing but the filter,")
print("consensus and the negotiation runs, so the same work is a larger share).\n")
print("| robots | seed | negotiation CPU s (median) | daemon CPU s (median) | share, median | share, largest | traj RMSE m | object err m |")
print("|---|---|---|---|---|---|---|---|")
for n in sizes:
    for seed in seeds:
        run = os.path.join(out, f"n{n}-s{seed}")
        rows = []
        for path in sorted(glob.glob(os.path.join(run, "robot_*", "stats.json"))):
            with open(path) as f:
                stats = json.load(f)
            cpu = stats["cpu_user_seconds"] + stats["cpu_system_seconds"]
            negotiation = stats["negotiation"]["seconds"]
            rows.append((negotiation, cpu, negotiation / max(cpu - negotiation, 1e-9)))
        if not rows:
            continue
        with open(os.path.join(run, "metrics.json")) as f:
            metrics = json.load(f)
        average = metrics.get("average", {})
        shares = [r[2] for r in rows]
        print(f"| {n} | {seed} | {statistics.median(r[0] for r in rows):.3f} | "
              f"{statistics.median(r[1] for r in rows):.2f} | {statistics.median(shares):.3f} | "
              f"{max(shares):.3f} | {average.get('trajectory_rmse', float('nan')):.4f} | "
              f"{average.get('object_error', float('nan')):.4f} |")
PY
cat docs/results-negotiation-daemons.md

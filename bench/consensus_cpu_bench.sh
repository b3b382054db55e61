#!/usr/bin/env bash
# Issue 13's consensus CPU: milliseconds of the consensus phase (marginals out, eq. 19 and
# Proposition 2) per robot and step of `concord replay` on the shared 15-robot simulation, over a
# complete graph, each robot's 3 nearest and a ring, for this tree's `concord` and a BASELINE
# binary (a `concord` built from an older commit), alternating, REPS runs each (default 5), one
# at a time. Prints the medians, their ratio and the accuracy of both (equal when only speed
# changed); writes the table to bench/out/consensus-cpu/table.md. DATA overrides the dataset;
# BASELINE_CONFIG gives the baseline a sensor config of its time (a newer config has keys an older
# binary refuses), e.g. `git show 46ee365:configs/sensors/sim.yaml > /tmp/sim-old.yaml`. GRAPHS
# limits the graphs (default "complete nearest3 ring"; a binary older than 3feb9d9 knows only
# the complete graph: GRAPHS=complete).
# Usage: bench/consensus_cpu_bench.sh BASELINE_CONCORD [REPS]
set -euo pipefail
cd "$(dirname "$0")/.."
baseline="${1:?usage: bench/consensus_cpu_bench.sh BASELINE_CONCORD [REPS]}"
reps="${2:-5}"
data="${DATA:-../shared/datasets/sim15}"
out=bench/out/consensus-cpu
mkdir -p "$out"
cmake --build build --target concord >/dev/null
cp build/tools/concord "$out/concord"
cp "$baseline" "$out/baseline"
declare -A graphs=([complete]="" [nearest3]="--nearest 3" [ring]="--graph ring")
read -r -a graph_list <<< "${GRAPHS:-complete nearest3 ring}"
for graph in "${graph_list[@]}"; do
  for ((rep = 0; rep < reps; ++rep)); do
    for binary in baseline concord; do
      config=()
      if [ "$binary" = baseline ] && [ -n "${BASELINE_CONFIG:-}" ]; then
        config=(--config "$BASELINE_CONFIG")
      fi
      # shellcheck disable=SC2086  # the graph's options split into words
      "$out/$binary" replay --dataset "$data" --out "$out/$graph-$binary-$rep" ${graphs[$graph]} \
        "${config[@]}" >"$out/$graph-$binary-$rep.log" 2>&1
    done
  done
done
python3 - "$out" "$reps" "${graph_list[@]}" <<'PY' | tee "$out/table.md"
import json, statistics, sys
out, reps, graphs = sys.argv[1], int(sys.argv[2]), sys.argv[3:]
print("| graph | baseline ms | this tree ms | ratio | traj RMSE m (baseline / this) | object err m (baseline / this) |")
print("|---|---|---|---|---|---|")
for graph in graphs:
    ms, acc = {}, {}
    for binary in ["baseline", "concord"]:
        runs = [json.load(open(f"{out}/{graph}-{binary}-{r}/metrics.json")) for r in range(reps)]
        ms[binary] = statistics.median(m["run"]["consensus_ms_per_robot_step"] for m in runs)
        a = runs[0]["average"]
        acc[binary] = (a["trajectory_rmse"], a["object_error"])
    print(f"| {graph} | {ms['baseline']:.3f} | {ms['concord']:.3f} | {ms['concord'] / ms['baseline']:.2f} | "
          f"{acc['baseline'][0]:.4f} / {acc['concord'][0]:.4f} | {acc['baseline'][1]:.4f} / {acc['concord'][1]:.4f} |")
PY

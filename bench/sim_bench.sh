#!/usr/bin/env bash
# Issue 3's must-show on Concord's own simulation (concord sim, defaults, seed 1):
#  1. Table IV: 3, 5, 10, 15 robots, separate vs consensus (complete graph, point features);
#  2. Fig. 4: consensus at link-loss rates 0, 0.3, 0.6, 0.9 against separate;
#  3. beyond the paper: 30 and 50 robots, and the ring graph.
# Writes docs/results-sim.md and docs/fig4-{trajectory,objects}.png; runs in bench/out/sim-*.
# Runs one replay at a time so that the consensus timings are not shared with another run.
# Usage: bench/sim_bench.sh [TEAM SIZES]   (default "3 5 10 15 30 50")
set -euo pipefail
cd "$(dirname "$0")/.."
sizes="${1:-3 5 10 15 30 50}"
out=bench/out
mkdir -p "$out"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 --target concord >/dev/null
concord=./build/tools/concord

run() {  # name dataset args...
  local name=$1 dataset=$2
  shift 2
  [ -f "$out/$name/metrics.json" ] && return 0
  $concord replay --dataset "$dataset" --out "$out/$name" "$@" >"$out/$name.log" 2>&1
  echo "bench: $name" >&2
}

for n in $sizes; do
  data="$out/sim-data-$n"
  [ -f "$data/dataset.json" ] || $concord sim --robots "$n" --seed 1 --out "$data" >/dev/null
  run "sim-$n-separate" "$data" --separate
  run "sim-$n-consensus" "$data"
  run "sim-$n-ring" "$data" --graph ring
  if [ "$n" -le 15 ]; then
    for loss in 0.3 0.6 0.9; do run "sim-$n-loss$loss" "$data" --loss "$loss"; done
  fi
done

python3 bench/summarize_sim.py "$out" docs "$sizes" >docs/results-sim.md
for chart in trajectory objects; do
  $concord plot --input "$out/fig4-$chart.json" --out "docs/fig4-$chart.png" >/dev/null
done
cat docs/results-sim.md

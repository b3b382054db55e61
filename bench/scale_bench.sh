#!/usr/bin/env bash
# Issue 13's scale must-show: 50 concordd processes on this machine at 10 Hz (300 frames), in
# lockstep and async, over the complete graph and over a simulated radio (consensus.radio: links
# only within a range, from the dataset's ground truth). Per run: the team's frame span (first
# frame of any robot to the last frame of any robot, from stats.json: startup left out), the
# team's CPU, deadline misses, and the team's accuracy; lockstep radio rows are checked against
# `concord replay --range` of the same data. Writes docs/results-scale-daemons.md; runs in
# bench/out/scale-*.
# Usage: bench/scale_bench.sh [SEEDS]   (default "1 2"; seed 1 is the set of the earlier rows)
set -euo pipefail
cd "$(dirname "$0")/.."
seeds="${1:-1 2}"
out=bench/out
mkdir -p "$out"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 --target concord concordd >/dev/null
concord=./build/tools/concord
config=configs/sensors/sim.yaml

for seed in $seeds; do
  data="$out/scale-sim50-seed$seed"
  [ -d "$data" ] || "$concord" sim --robots 50 --frames 300 --seed "$seed" --out "$data" >/dev/null
  for range in 5 10; do
    rm -rf "$data-replay-range$range"
    "$concord" replay --dataset "$data" --config "$config" --range "$range" \
      --out "$data-replay-range$range" >"$data-replay-range$range.log" 2>&1
  done
  for run in "lockstep 0" "lockstep 5" "lockstep 10" "async 0" "async 5" "async 10"; do
    set -- $run
    name="$data-$1-range$2"
    rm -rf "$name"
    radio=()
    [ "$2" = 0 ] || radio=(--range "$2")
    /usr/bin/time -f "%e" -o "$name.time" "$concord" launch --dataset "$data" --out "$name" \
      --config "$config" --"$1" --rate 10 "${radio[@]}" --base-port 21000 \
      --http-base-port 22000 >"$name.log" 2>&1
    echo "bench: seed $seed $1 range $2 done" >&2
  done
done
python3 bench/summarize_scale.py "$out" $seeds >docs/results-scale-daemons.md
cat docs/results-scale-daemons.md

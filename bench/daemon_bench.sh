#!/usr/bin/env bash
# The daemon issue's must-show: teams of concordd processes in lockstep on loopback, against the
# in-process `concord replay` of the same data: 3 daemons on the full kitti00, 15 on sim15.
# Per daemon: bytes sent per round (median, max), frame latency p50/p99, CPU; team metrics as
# `concord eval` computes them. Writes docs/results-daemon.md; runs in bench/out/daemon-*.
# Usage: bench/daemon_bench.sh [DATASETS_DIR]   (default ../shared/datasets)
set -euo pipefail
cd "$(dirname "$0")/.."
datasets="${1:-../shared/datasets}"
out=bench/out
mkdir -p "$out"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 --target concord concordd >/dev/null

for dataset in kitti00 sim15; do
  rm -rf "$out/daemon-$dataset" "$out/daemon-$dataset-replay"
  ./build/tools/concord launch --dataset "$datasets/$dataset" --out "$out/daemon-$dataset" \
    --lockstep --base-port 17100 --http-base-port 18100 >"$out/daemon-$dataset.log" 2>&1
  echo "bench: daemons on $dataset done" >&2
  ./build/tools/concord replay --dataset "$datasets/$dataset" --out "$out/daemon-$dataset-replay" \
    >"$out/daemon-$dataset-replay.log" 2>&1
  echo "bench: replay of $dataset done" >&2
done

python3 bench/summarize_daemon.py "$out" >docs/results-daemon.md
cat docs/results-daemon.md

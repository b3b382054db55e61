#!/usr/bin/env bash
# Installs what is missing, builds, and runs the demo: a team of concordd daemons (one process
# per robot, consensus over TCP on loopback, state on http://127.0.0.1:8100+i) on the embedded
# default scenario, a 3-robot team from the simulator (`concord sim`, seed 1), or on the dataset
# folder given as the first argument, at the camera rate (RATE, default 10 Hz). Prints the live
# map's address and the curl lines to ask the robots for their state, shows a live status line,
# then the metrics table and where the trajectories, object maps, metrics.json and the plot went
# (default out/demo).
# Usage: scripts/demo.sh [DATASET_DIR [OUT_DIR]]
set -euo pipefail
cd "$(dirname "$0")/.."
dataset="${1:-}"
out="${2:-out/demo}"
./scripts/install-deps.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build build --parallel 2 --target concord concordd
if [ -z "$dataset" ]; then
  dataset="$out/scenario"
  ./build/tools/concord sim --robots 3 --seed 1 --out "$dataset"
fi
# The team runs at its camera rate (10 Hz: tens of seconds for the default scenario), so that the
# robots can be asked for their state while they run. RATE=0 runs as fast as possible.
rate="${RATE:-10}"
robots=$(ls -d "$dataset"/robot_* | wc -l)
echo "demo: $robots robots at ${rate} Hz; while they run, open the live map of robot 0 (it draws"
echo "  its neighbours too) in a browser:  http://127.0.0.1:8100/"
echo "  or ask them for their state:"
for ((robot = 0; robot < robots && robot < 3; ++robot)); do
  port=$((8100 + robot))
  echo "  curl -s http://127.0.0.1:$port/status   curl -s http://127.0.0.1:$port/pose   curl -s http://127.0.0.1:$port/objects"
done
echo "  curl -s http://127.0.0.1:8100/peers     curl -s http://127.0.0.1:8100/metrics"
./build/tools/concord launch --dataset "$dataset" --out "$out/team" --lockstep --rate "$rate"

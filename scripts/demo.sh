#!/usr/bin/env bash
# Installs what is missing, builds, and runs the demo: a team of concordd daemons (one process
# per robot, consensus over TCP on loopback, state on http://127.0.0.1:8100+i) on the embedded
# default scenario, a 3-robot team from the simulator (`concord sim`, seed 1), or on the dataset
# folder given as the first argument. Shows a live status line per robot, then the metrics table
# and where the trajectories, object maps, metrics.json and the plot went (default out/demo).
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
./build/tools/concord launch --dataset "$dataset" --out "$out/team" --lockstep

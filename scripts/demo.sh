#!/usr/bin/env bash
# Installs what is missing, builds, and runs the demo: a three-robot team on the embedded sim15
# slice (data/sim15-3x200), with consensus. Prints the metrics table and where the
# trajectories, object maps, metrics.json and the plot went (default out/demo).
set -euo pipefail
cd "$(dirname "$0")/.."
out="${1:-out/demo}"
./scripts/install-deps.sh
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release
cmake --build build --parallel 2 --target concord
./build/tools/concord replay --dataset data/sim15-3x200 --out "$out"

#!/usr/bin/env bash
# Reproduces the estimator issue's must-show table on the shared datasets: odometry-only,
# separate and consensus runs of kitti00 and sim15 (object-only: they carry no point features),
# and kitti00-vo77 with point features. Writes docs/results.md (the table) and keeps the run
# folders in bench/out/. Wall times are whole-process times of a single run on this machine.
# Usage: bench/estimator_bench.sh [DATASETS_DIR]   (default ../shared/datasets)
set -euo pipefail
cd "$(dirname "$0")/.."
datasets="${1:-../shared/datasets}"
out=bench/out
mkdir -p "$out"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 --target concord >/dev/null

run() {  # name dataset args...
  local name=$1 dataset=$2
  shift 2
  local start end
  start=$EPOCHREALTIME
  ./build/tools/concord replay --dataset "$datasets/$dataset" --out "$out/$name" "$@" \
    >"$out/$name.log" 2>&1
  end=$EPOCHREALTIME
  python3 -c "print($end - $start)" >"$out/$name.wall"
  echo "bench: $name done in $(cat "$out/$name.wall") s" >&2
}

run kitti00-separate kitti00 --separate
run kitti00-consensus kitti00
run sim15-separate sim15 --separate
run sim15-consensus sim15
run kitti00-vo77-features kitti00-vo77
run kitti00-vo77-objects-only kitti00-vo77 --no-point-features

python3 bench/summarize.py "$out" >docs/results.md
cat docs/results.md

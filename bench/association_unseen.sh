#!/usr/bin/env bash
# Issue 11's re-check on sets that no choice was measured on: the `concord sim` sets the sessions
# made after a change to judge it (never used to choose anything), remade from their seeds, each
# converted with `concord convert --private-ids --unknown-start` and replayed negotiated with
# configs/sensors/sim.yaml. Prints one markdown row a set: association precision and recall,
# trajectory RMSE, the team-fit trajectory, mean pose / object / alignment NEES and the pose and
# object fractions inside the 95 % bound. No given runs (bench/association_bench.sh has those).
# Runs in bench/out/association-unseen (kept between runs: delete a set's run to make it again).
# Usage: bench/association_unseen.sh [BINARY]   (default: the Release build of this checkout)
set -euo pipefail
cd "$(dirname "$0")/.."
out=bench/out/association-unseen
mkdir -p "$out"
if [ $# -ge 1 ]; then
  concord=$1
else
  cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
  cmake --build build --parallel 2 --target concord >/dev/null
  cp build/tools/concord "$out/concord"
  concord="$out/concord"
fi

# robots seed frames false-detection-rate: the sets of sessions 72-77 (docs/association.md,
# Results), 4 detector classes, objects only.
sets=(
  "4 98 300 0.05"
  "5 99 300 0.05"
  "6 63 300 0"
  "7 61 300 0.05"
  "8 97 400 0.05"
  "9 91 300 0.05"
  "11 97 300 0.05"
  "12 62 300 0.05"
  "13 93 300 0.05"
  "3 95 300 0.05"
)

echo "| robots, seed, frames, false det. | precision | recall | trajectory m | team fit m | pose NEES (inside) | object NEES (inside) | alignment NEES |"
echo "|---|---|---|---|---|---|---|---|"
for spec in "${sets[@]}"; do
  read -r robots seed frames rate <<<"$spec"
  name="n$robots-s$seed-f$rate"
  data="$out/data-$name"
  private="$data-private"
  [ -f "$data/dataset.json" ] || $concord sim --robots "$robots" --seed "$seed" --frames "$frames" \
    --classes 4 --points-per-frame 0 --false-detections "$rate" --out "$data" >"$data.log" 2>&1 ||
    { echo "bench: sim of $name FAILED (see $data.log)" >&2; exit 1; }
  [ -f "$private/dataset.json" ] ||
    $concord convert --dataset "$data" --out "$private" --private-ids --unknown-start \
      >"$private.log" 2>&1 || { echo "bench: convert of $name FAILED (see $private.log)" >&2; exit 1; }
  run="$out/$name"
  if [ ! -f "$run/metrics.json" ]; then
    rm -rf "$run"
    $concord replay --dataset "$private" --out "$run" --config configs/sensors/sim.yaml \
      >"$run.log" 2>&1 || { echo "bench: $name FAILED (see $run.log)" >&2; exit 1; }
    $concord eval --dataset "$private" --result "$run" >"$run.eval" 2>&1 ||
      { echo "bench: eval of $name FAILED (see $run.eval)" >&2; exit 1; }
  fi
  python3 - "$run/metrics.json" "$robots, $seed, $frames, $rate" <<'PY'
import json
import sys

m = json.load(open(sys.argv[1]))
a, s = m["average"], m["association"]
precision = s["precision"]
print("| %s | %s | %.3f | %.3f | %.3f | %.2f (%.0f %%) | %.2f (%.0f %%) | %.2f |" % (
    sys.argv[2], "-" if precision is None else "%.4f" % precision, s["recall"],
    a["trajectory_rmse"], m["team_aligned"]["trajectory_rmse"],
    a["pose_nees"]["mean"], 100 * a["pose_nees"]["inside_95"],
    a["object_nees"]["mean"], 100 * a["object_nees"]["inside_95"],
    a.get("alignment_nees") or 0.0))
PY
done

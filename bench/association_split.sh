#!/usr/bin/env bash
# Issue 11: which half of the negotiation costs the accuracy. Each case (a `concord sim` set as
# bench/association_bench.sh makes them: 300 frames, 4 classes, objects only) is replayed four
# ways on the same measurements, converted with `concord convert`:
#   given       global ids, known starts (`--association given`)
#   private     private ids, known starts (`--private-ids`: the association alone)
#   unknown     global ids, unknown starts (`--unknown-start`: the frames alone)
#   negotiated  private ids, unknown starts (both, as the association bench)
# and tabulated: team trajectory RMSE and object error (each robot from its first frame in the
# team frame on, as `concord eval` reports them), pose / object NEES, and robot 0's trajectory
# RMSE (its frame is the team frame: it never moves, so its loss is what the others' moves and
# matches do to it). One run at a time; the config is configs/sensors/sim.yaml as it is.
# Writes the table to stdout and to bench/out/association-split/table.md.
# Usage: bench/association_split.sh [CASES]   (default "5:1 5:2 10:1 10:2"; a case is
# ROBOTS:SEED[:FALSE_DETECTION_RATE], the rate 0 unless given)
set -euo pipefail
cd "$(dirname "$0")/.."
cases="${1:-5:1 5:2 10:1 10:2}"
out=bench/out/association-split
config=configs/sensors/sim.yaml
mkdir -p "$out"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 --target concord >/dev/null
cp build/tools/concord "$out/concord"
concord="$out/concord"

names=()
for case in $cases; do
  IFS=: read -r robots seed rate <<<"$case"
  rate=${rate:-0}
  name="n$robots-s$seed-f$rate"
  names+=("$name")
  data="$out/data-$name"
  [ -f "$data/dataset.json" ] || "$concord" sim --robots "$robots" --seed "$seed" --frames 300 \
    --classes 4 --false-detections "$rate" --points-per-frame 0 --out "$data" >/dev/null
  for variant in private unknown negotiated; do
    case $variant in
      private) flags=(--private-ids) ;;
      unknown) flags=(--unknown-start) ;;
      negotiated) flags=(--private-ids --unknown-start) ;;
    esac
    [ -f "$data-$variant/dataset.json" ] ||
      "$concord" convert --dataset "$data" --out "$data-$variant" "${flags[@]}" >/dev/null
  done
  for variant in given private unknown negotiated; do
    result="$out/$name-$variant"
    [ -f "$result/metrics.json" ] && continue
    if [ "$variant" = given ]; then
      "$concord" replay --dataset "$data" --out "$result" --config "$config" \
        --association given >"$result.log" 2>&1
    else
      "$concord" replay --dataset "$data-$variant" --out "$result" --config "$config" \
        >"$result.log" 2>&1
    fi
    echo "bench: $name $variant" >&2
  done
done

python3 - "$out" "${names[@]}" <<'PY' | tee "$out/table.md"
import json, sys
out, names = sys.argv[1], sys.argv[2:]
variants = ["given", "private", "unknown", "negotiated"]
print("| case | run | traj RMSE m | object err m | robot 0 traj m | pose NEES | object NEES |")
print("|---|---|---|---|---|---|---|")
for name in names:
    for variant in variants:
        m = json.load(open(f"{out}/{name}-{variant}/metrics.json"))
        a = m["average"]
        robot0 = next(r for r in m["robots"] if r["robot"] == 0)
        print(f"| {name} | {variant} | {a['trajectory_rmse']:.3f} | {a['object_error']:.3f} | "
              f"{robot0['trajectory_rmse']:.3f} | {a['pose_nees']['mean']:.2f} | "
              f"{a['object_nees']['mean']:.2f} |")
PY

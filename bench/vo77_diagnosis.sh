#!/usr/bin/env bash
# Why kitti00-vo77 with point features is overconfident (pose NEES about 270 where 6 is
# consistent; objects only: 7). Replays variants of the set's real tracks with
# configs/sensors/kitti-stereo.yaml and prints trajectory RMSE and NEES for each:
#   tracks as given; every 4th / 10th track only (fewer, equally good observations);
#   the right image's u shifted by +0.18 px / -0.18 px (a disparity offset of the size the
#   calibration measures: `concord calibrate` reports a +0.18 px disparity median on these tracks).
# Each variant runs with the disparity offset state off and as the config has it (0.5 px prior).
# A diagnosis, not a tuning: no config is changed by it. Runs in bench/out/vo77/.
# Usage: bench/vo77_diagnosis.sh
set -euo pipefail
cd "$(dirname "$0")/.."
source_set=../shared/datasets/kitti00-vo77
out=bench/out/vo77
mkdir -p "$out"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 --target concord >/dev/null

variant() {  # name python-filter (reads features.csv rows as lists, returns a row or None)
  local name=$1 filter=$2
  rm -rf "${out:?}/$name"
  cp -r "$source_set" "$out/$name"
  python3 - "$out/$name/robot_00/features.csv" "$filter" <<'PY'
import sys
path, rule = sys.argv[1], sys.argv[2]
lines = open(path).read().splitlines()
rows = [lines[0]]
for line in lines[1:]:
    row = line.split(",")
    row = eval(rule, {"row": row, "float": float, "int": int})
    if row is not None:
        rows.append(",".join(row))
open(path, "w").write("\n".join(rows) + "\n")
PY
}
variant given 'row'
variant every-4th 'row if int(row[1]) % 4 == 0 else None'
variant every-10th 'row if int(row[1]) % 10 == 0 else None'
variant right-u-plus-0.18 'row[:4] + [f"{float(row[4]) + 0.18:.4f}", row[5]]'
variant right-u-minus-0.18 'row[:4] + [f"{float(row[4]) - 0.18:.4f}", row[5]]'

printf '| tracks | disparity offset state | traj RMSE m | pose NEES mean | inside 95 %% | position NEES | orientation NEES | offset estimate px |\n'
printf '|---|---|---|---|---|---|---|---|\n'
for name in given every-4th every-10th right-u-plus-0.18 right-u-minus-0.18 objects-only; do
  for sigma in 0 0.5; do  # the offset state off, and as configs/sensors/kitti-stereo.yaml has it
    dataset="$out/$name"
    extra=(--set "disparity_offset_sigma=$sigma")
    if [ "$name" = objects-only ]; then dataset="$out/given"; extra+=(--no-point-features); fi
    ./build/tools/concord replay --dataset "$dataset" --config configs/sensors/kitti-stereo.yaml \
      --out "$out/run-$name-$sigma" "${extra[@]}" >"$out/run-$name-$sigma.log" 2>&1
    python3 - "$out/run-$name-$sigma/metrics.json" "$name" "$sigma" <<'PY'
import json, sys
metrics = json.load(open(sys.argv[1]))
m = metrics["average"]
offsets = metrics["run"].get("disparity_offset", [])
offset = f"{offsets[0]['estimate']:+.3f} +- {offsets[0]['sigma']:.3f}" if offsets else "-"
state = "off" if float(sys.argv[3]) == 0 else f"prior {sys.argv[3]} px"
print(f"| {sys.argv[2]} | {state} | {m['trajectory_rmse']:.3f} | {m['pose_nees']['mean']:.1f} | "
      f"{100 * m['pose_nees']['inside_95']:.0f} % | {m['position_nees']['mean']:.1f} | "
      f"{m['orientation_nees']['mean']:.1f} | {offset} |")
PY
  done
done

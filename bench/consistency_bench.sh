#!/usr/bin/env bash
# Issue 9's must-show: consistency (NEES) and accuracy of the filter with one config per sensor.
#  1. concord sim sweeps: 3, 5, 10, 15 robots x seeds 1-5 x with/without point features x
#     odometry noise x1/x2 (the config's odometry sigmas follow the simulator's setting, as a
#     sensor's specification would), separate and consensus, and a reference for each set:
#     odometry only, an exactly modelled (consistent) filter on the same paths;
#  2. sim15, separate and consensus;
#  3. kitti00: consensus and separate, the first 600 frames, object noise halved and doubled;
#     kitti00-vo77;
#  4. replay time of kitti00 and sim15 (median of 3 runs).
# Writes docs/results-consistency.md; runs in bench/out/consistency/ (kept between runs: delete
# the folder to start afresh). Two runs at a time (timings: 4. runs alone).
# Usage: bench/consistency_bench.sh [SEEDS] [TEAM SIZES]   (default "1 2 3 4 5" "3 5 10 15")
set -euo pipefail
cd "$(dirname "$0")/.."
seeds="${1:-1 2 3 4 5}"
sizes="${2:-3 5 10 15}"
shared=../shared/datasets
out=bench/out/consistency
source bench/replay_runs.sh

# 1. Simulation sweeps. Odometry x2 doubles both odometry sigmas of the simulator and the config.
jobs=()
for n in $sizes; do
  for seed in $seeds; do
    for features in 10 0; do
      for noise in 1 2; do
        data="$out/data-n$n-s$seed-p$features-x$noise"
        translation=$(python3 -c "print(0.015 * $noise)")
        rotation=$(python3 -c "print(0.01 * $noise)")
        [ -f "$data/dataset.json" ] || $concord sim --robots "$n" --seed "$seed" \
          --points-per-frame "$features" --odometry-translation-noise "$translation" \
          --odometry-rotation-noise "$rotation" --out "$data" >/dev/null
        set_noise=(--set "odometry_translation_sigma=$translation"
                   --set "odometry_rotation_sigma=$rotation")
        name="sim-n$n-s$seed-p$features-x$noise"
        run "$name-separate" "$data" --separate "${set_noise[@]}" &
        run "$name-consensus" "$data" "${set_noise[@]}" &
        wait
        # The reference: odometry only (no objects, no features), the model exactly the
        # simulator's: what a consistent estimator scores on the same robots and paths.
        run "$name-reference" "$data" --separate --no-point-features --set use_objects=false \
          "${set_noise[@]}"
      done
    done
  done
done

# 2. sim15.
run sim15-separate "$shared/sim15" --separate &
run sim15-consensus "$shared/sim15" &
wait

# 3. KITTI.
run kitti00-separate "$shared/kitti00" --separate &
run kitti00-consensus "$shared/kitti00" &
wait
run kitti00-600-consensus "$shared/kitti00" --frames 600 &
run kitti00-600-separate "$shared/kitti00" --frames 600 --separate &
wait
# The object noise halved and doubled, from the config's own values (so that the variants follow
# the config when it changes).
scaled_object_noise() {  # factor -> --set arguments
  python3 - "$1" <<'PY'
import sys, yaml
config = yaml.safe_load(open("configs/sensors/kitti-stereo.yaml"))
# Every part of the detection error model (independent, constant, persistent) scaled alike.
print(" ".join(f"--set {key}.{k}={v * float(sys.argv[1]):g}"
               for key in ("object_noise", "object_noise_constant", "object_noise_persistent")
               if key in config for k, v in config[key].items()))
PY
}
# shellcheck disable=SC2046  # the --set arguments split on purpose
run kitti00-objects-half "$shared/kitti00" $(scaled_object_noise 0.5) &
# shellcheck disable=SC2046
run kitti00-objects-double "$shared/kitti00" $(scaled_object_noise 2) &
wait
run kitti00-vo77 "$shared/kitti00-vo77"
run kitti00-vo77-objects-only "$shared/kitti00-vo77" --no-point-features

# 4. Replay time, each run alone, three times.
for set in kitti00 sim15; do
  for k in 1 2 3; do
    [ -f "$out/time-$set-$k/metrics.json" ] ||
      $concord replay --dataset "$shared/$set" --out "$out/time-$set-$k" >/dev/null 2>&1
  done
done

python3 bench/summarize_consistency.py "$out" "$seeds" "$sizes" >docs/results-consistency.md
cat docs/results-consistency.md

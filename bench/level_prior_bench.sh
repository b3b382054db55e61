#!/usr/bin/env bash
# The level prior of a ground vehicle (docs/estimator.md, "Level prior") on kitti00: how its
# result depends on the values `concord calibrate` gives it. Consensus runs of kitti00 with
# kitti-stereo.yaml and, over it:
#  1. the prior off;
#  2. level_sigma from the segment's RMS (0.0145), the config's unbiased spread (0.01763), the
#     earlier rule's RMS about the start frame's +z (0.023), 0.03 and the spread's 95 % upper
#     confidence bound (0.040), each every 32, 64 (the config) and 128 frames;
#  3. the config's sigma and spacing with the nominal +z instead of the calibrated level axis;
#  4. the config: separate, and the first 600 frames;
#  5. the prior as `concord calibrate` measures it on other 200-frame segments (robots 0-2,
#     frames 0 and 1000): how much the result depends on which segment calibrates it.
# Writes docs/results-level-prior.md; runs in bench/out/level-prior/ (kept between runs).
set -euo pipefail
cd "$(dirname "$0")/.."
shared=../shared/datasets
out=bench/out/level-prior
source bench/replay_runs.sh

run off "$shared/kitti00" --set level_sigma=0 &
run nominal-axis "$shared/kitti00" --set "level_up_axis=+z" &
wait
for sigma in 0.0145 0.01763 0.023 0.03 0.040; do
  for every in 32 64 128; do
    run "sigma$sigma-every$every" "$shared/kitti00" --set "level_sigma=$sigma" \
      --set "level_every_frames=$every" &
  done
  wait
done
run config-separate "$shared/kitti00" --separate &
run config-600 "$shared/kitti00" --frames 600 &
wait
run off-600 "$shared/kitti00" --frames 600 --set level_sigma=0

# 5. Other calibration segments: their suggested level keys (commented in calibrate's output).
for robot in 0 1 2; do
  for first in 0 1000; do
    name="segment-r$robot-f$first"
    $concord calibrate --dataset "$shared/kitti00" --robot "$robot" --first "$first" \
      --frames 200 >"$out/$name.yaml"
    sets=()
    for key in level_sigma level_every_frames level_up_axis; do
      sets+=(--set "$key=$(sed -n "s/^# $key: //p" "$out/$name.yaml")")
    done
    run "$name" "$shared/kitti00" "${sets[@]}"
  done
done

python3 bench/summarize_level_prior.py "$out" >docs/results-level-prior.md
cat docs/results-level-prior.md

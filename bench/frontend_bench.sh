#!/usr/bin/env bash
# Issue 12's must-show for the stereo front-end (docs/frontend.md), written to
# docs/results-frontend.md; runs in bench/out/frontend-*:
#  1. Rendered sequences (concord sim --render: 3 robots x 300 frames, 752x480, seed 1): the
#     front-end's visual odometry drift and track reprojection error against the exact ground
#     truth (concord frontend-eval); the team replayed from the front-end's own outputs
#     (separate, consensus, odometry only) and from the simulator's exact tracks; and four
#     other rendered teams (FRONTEND_TEAMS: seeds 2, 7, 17, 23 of 2-5 robots) through the same
#     front-end and detector model, separate and consensus.
#  2. The real EuRoC V1_01 frames (../shared/datasets/euroc-v101-static, 40 pairs): stereo tracks
#     a frame and odometry drift over the 40 frames.
#  3. Speed: milliseconds a frame on one core (OpenCV single-threaded), p50 and p99, on the
#     rendered 752x480 sequences (about 200 tracks; medians of SPEED_RUNS runs) and on EuRoC.
# Usage: bench/frontend_bench.sh [EUROC_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
euroc="${1:-../shared/datasets/euroc-v101-static}"
out=bench/out
mkdir -p "$out"
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 --target concord >/dev/null
concord=./build/tools/concord

# The exact team's noise is the front-end's: odometry 2 mm and 0.2 mrad per axis per frame (the
# visual odometry's per-axis errors are about 2 mm and 0.1 mrad; it reports about 3.3 mm and
# 0.2 mrad), 0.4 px on every image coordinate (the front-end's tracks deviate from the truth by
# about that much), 200 point tracks a frame of points on the rendered world's surfaces, lost at
# 2.5 % a frame besides leaving the view or being occluded (the front-end's tracks last about 10
# frames, and so do these). Pixel noise is in normalized units: 0.4 px / 537 px focal length.
translation_noise=0.002
rotation_noise=0.0002
pixel_noise=0.00075

render() {  # folder robots frames seed: a rendered team with the noise above, unless there
  local folder=$1
  [ -f "$folder/world.csv" ] && return 0
  rm -rf "$folder"
  $concord sim --render --robots "$2" --frames "$3" --seed "$4" --out "$folder" \
    --odometry-translation-noise $translation_noise --odometry-rotation-noise $rotation_noise \
    --pixel-noise $pixel_noise --points-per-frame 200 --point-track-loss 0.025 \
    >"$folder.log" 2>&1
  echo "bench: rendered $(basename "$folder")" >&2
}
rendered="$out/frontend-rendered"
render "$rendered" 3 300 1
frontend_of() {  # rendered-team output name [args]: the front-end on a rendered team, unless there
  [ -f "$2/frontend.json" ] && return 0
  rm -rf "$2"
  $concord frontend --threads 1 --input "$1" --out "$2" --up-axis -y --name "$3" "${@:4}" \
    >"$2.log" 2>&1
  echo "bench: front-end on $(basename "$1")" >&2
}

# The rendered robots' body is the left camera, looking forward on a level robot: up is -y
# (written to estimator.yaml for a negotiated association; the given-ids runs below ignore it).
frontend="$out/frontend-tracks"
if [ ! -f "$frontend/frontend_eval.json" ]; then
  rm -rf "$frontend"
  frontend_of "$rendered" "$frontend" sim-render-frontend
  $concord frontend-eval --dataset "$frontend" --world "$rendered/world.csv" \
    >>"$out/frontend-tracks.log" 2>&1
  echo "bench: front-end on the rendered team" >&2
fi

# The exact team's config: configs/sensors/sim.yaml with the simulator's noise of this run (and
# the sanity limits scaled with it, 5 sigma, as in sim.yaml), and the front-end's depth limit for
# point features (a disparity of 1 px: 537 px x 0.54 m), since both teams see the same surfaces.
exact_config="$out/frontend-exact.yaml"
python3 - "$exact_config" $translation_noise $rotation_noise $pixel_noise <<'PY'
import re, sys
path, translation, rotation, pixel = sys.argv[1], *map(float, sys.argv[2:])
values = {"odometry_translation_sigma": translation, "odometry_rotation_sigma": rotation,
          "object_noise": pixel, "feature_noise": pixel,
          "object_init_max_reprojection_error": 5 * pixel,
          "feature_max_distance": 537.0 * 0.54}
text = open("configs/sensors/sim.yaml").read()
for key, value in values.items():
    text = re.sub(rf"^{key}: .*$", f"{key}: {value:.6g}", text, flags=re.M)
open(path, "w").write("# Written by bench/frontend_bench.sh: sim.yaml with the exact team's noise.\n" + text)
PY

run() {  # name dataset args...: a replay, unless there and newer than the config it reads
  local name=$1 dataset=$2
  shift 2
  local config="$dataset/estimator.yaml" previous=""
  for argument in "$@"; do  # --config FILE replaces the dataset's
    [ "$previous" = --config ] && config=$argument
    previous=$argument
  done
  [ -f "$out/$name/metrics.json" ] && [ "$out/$name/metrics.json" -nt "$config" ] &&
    [ "$out/$name/metrics.json" -nt "$concord" ] && return 0
  $concord replay --dataset "$dataset" --out "$out/$name" "$@" >"$out/$name.log" 2>&1
  echo "bench: $name" >&2
}
run frontend-team-separate "$frontend" --separate
run frontend-team-consensus "$frontend"

# The detector's error model measured on a calibration rendering (another seed, one robot x 400
# frames; never the reported team): the front-end's object observations against the truth,
# fitted by `concord calibrate --detector-model` as a displacement in space per (robot, object)
# that walks, plus independent image noise (docs/estimator.md, "Detection displacements"), and
# the point tracks' drift measured on the same tracks (feature_drift_sigma; "Point-feature
# drift"). The front-end then runs on the team again with that model (--detector-model), which
# it writes into estimator.yaml: the team is replayed with the front-end's config alone, one
# config for camera, tracker and detector.
calibration="$out/frontend-calibration-rendered"
render "$calibration" 1 400 11
calibration_frontend="$out/frontend-calibration"
frontend_of "$calibration" "$calibration_frontend" sim-render-calibration
detection_model="$out/frontend-detection-model.yaml"
# Measured again with every build of concord; the file is replaced (and the teams' front-end
# outputs that read it redone) only when the model's text changed.
$concord calibrate --dataset "$calibration_frontend" --robot 0 --frames 400 --up-axis -y \
  --detector-model "$detection_model.new" >"$out/frontend-calibration.yaml" 2>/dev/null
if cmp -s "$detection_model.new" "$detection_model"; then
  rm "$detection_model.new"
else
  mv "$detection_model.new" "$detection_model"
fi
frontend_model="$out/frontend-model-tracks"
[ "$detection_model" -nt "$frontend_model/frontend.json" ] && rm -rf "$frontend_model"
frontend_of "$rendered" "$frontend_model" sim-render-frontend-model --detector-model "$detection_model"
run frontend-model-separate "$frontend_model" --separate
run frontend-model-consensus "$frontend_model"
run frontend-exact-separate "$rendered" --separate --config "$exact_config"
run frontend-exact-consensus "$rendered" --config "$exact_config"

# Inputs swapped between the two teams (a diagnosis of where the gap comes from): the front-end's
# tracks and odometry with the simulator's object observations (normalized -> pixels), and the
# simulator's tracks and odometry with the front-end's object observations (pixels -> normalized;
# the exact config with the front-end's stated object noise, 1.41 px a coordinate).
swap_tracks="$out/frontend-swap-fe-tracks"
swap_objects="$out/frontend-swap-fe-objects"
swap_config="$out/frontend-swap.yaml"
python3 - "$frontend" "$rendered" "$swap_tracks" "$swap_objects" "$exact_config" "$swap_config" <<'PY'
import csv, json, os, re, shutil, sys
frontend, rendered, swap_tracks, swap_objects, exact_config, swap_config = sys.argv[1:]
K = json.load(open(f"{frontend}/dataset.json"))["camera"]["K"]
fx, cx, fy, cy = K[0][0], K[0][2], K[1][1], K[1][2]
def convert(source, target, to_pixels):
    rows = list(csv.reader(open(source)))
    with open(target, "w") as out:
        out.write("frame,id,u_left,v_left,u_right,v_right\n")
        for row in rows[1:]:
            u, v, ur, vr = map(float, row[2:6])
            if to_pixels:
                values = (fx * u + cx, fy * v + cy, fx * ur + cx, fy * vr + cy)
            else:
                values = ((u - cx) / fx, (v - cy) / fy, (ur - cx) / fx, (vr - cy) / fy)
            out.write(",".join([row[0], row[1]] + [repr(x) for x in values]) + "\n")
for folder in (swap_tracks, swap_objects):
    shutil.rmtree(folder, ignore_errors=True)
shutil.copytree(frontend, swap_tracks)
os.makedirs(swap_objects)
for name in ("dataset.json", "objects_gt.csv"):
    shutil.copy(f"{rendered}/{name}", f"{swap_objects}/{name}")
robots = json.load(open(f"{rendered}/dataset.json"))["robots"]
for r in range(robots):
    robot = f"robot_{r:02d}"
    convert(f"{rendered}/{robot}/objects.csv", f"{swap_tracks}/{robot}/objects.csv", True)
    os.makedirs(f"{swap_objects}/{robot}")
    for name in ("features.csv", "groundtruth.kitti", "odometry.kitti"):
        shutil.copy(f"{rendered}/{robot}/{name}", f"{swap_objects}/{robot}/{name}")
    convert(f"{frontend}/{robot}/objects.csv", f"{swap_objects}/{robot}/objects.csv", False)
sigma = 2.0 / 2 ** 0.5 / fx  # objects.detection_sigma (2 px an edge) on a box centre
text = open(exact_config).read()
text = re.sub(r"^object_noise: .*$", f"object_noise: {sigma:.6g}", text, flags=re.M)
text = re.sub(r"^object_init_max_reprojection_error: .*$",
              f"object_init_max_reprojection_error: {5 * sigma:.6g}", text, flags=re.M)
open(swap_config, "w").write(text)
PY
run frontend-swap-fe-tracks-separate "$swap_tracks" --separate
run frontend-swap-fe-tracks-consensus "$swap_tracks"
run frontend-swap-fe-objects-separate "$swap_objects" --separate --config "$swap_config"
run frontend-swap-fe-objects-consensus "$swap_objects" --config "$swap_config"

euroc_out="$out/frontend-euroc"
if [ ! -f "$euroc_out/frontend_eval.json" ]; then
  rm -rf "$euroc_out"
  $concord frontend --threads 1 --input "$euroc" --out "$euroc_out" >"$out/frontend-euroc.log" 2>&1
  $concord frontend-eval --dataset "$euroc_out" >>"$out/frontend-euroc.log" 2>&1
  echo "bench: EuRoC" >&2
fi

# Other rendered teams (seeds, sizes and lengths used to build nothing; FRONTEND_TEAMS, a list
# of seed:robots:frames, "" for none): the front-end with the calibration rendering's detector
# model, replayed with the estimator.yaml it wrote alone, separate and consensus; and the same
# team on the simulator's exact tracks (the exact config), consensus.
for team in ${FRONTEND_TEAMS-2:3:300 7:2:300 17:5:150 23:4:100}; do
  IFS=: read -r seed robots frames <<<"$team"
  other_rendered="$out/frontend-rendered-s$seed"
  render "$other_rendered" "$robots" "$frames" "$seed"
  other="$out/frontend-model-tracks-s$seed"
  [ "$detection_model" -nt "$other/frontend.json" ] && rm -rf "$other"
  frontend_of "$other_rendered" "$other" "sim-render-s$seed" --detector-model "$detection_model"
  run "frontend-s$seed-separate" "$other" --separate
  run "frontend-s$seed-consensus" "$other"
  run "frontend-s$seed-exact-consensus" "$other_rendered" --config "$exact_config"
done

# Speed: each rendered robot's sequence again, alone, SPEED_RUNS times (default 3, robots
# alternating); the speed table quotes the median over the runs (the machine is shared: one run's
# p99 moves by several milliseconds).
speed="$out/frontend-speed"
rm -rf "$speed"
mkdir -p "$speed"
for run in $(seq "${SPEED_RUNS:-3}"); do
  for robot in "$rendered"/robot_*; do
    name=$(basename "$robot")
    $concord frontend --threads 1 --input "$robot" --out "$speed/$name-$run" \
      >"$speed/$name-$run.log" 2>&1
  done
done
echo "bench: speed" >&2

python3 bench/summarize_frontend.py "$out" >docs/results-frontend.md
cat docs/results-frontend.md

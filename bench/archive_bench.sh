#!/usr/bin/env bash
# Issue 9: what archiving an object that left the view costs and buys (docs/estimator.md,
# "Archiving"). Each MODE, separate and consensus:
#   marginal     object_archive_mode: marginal (the default config);
#   marginal-kl  the same with consensus.fuse_kl_threshold: 0.001 (event-triggered fusion);
#   consider     object_archive_mode: consider (Schmidt consider states);
#   consider-kl  consider with consensus.fuse_kl_threshold: 0.001.
# on `concord sim` 3 robots seeds 1-5 and 7 robots seed 9, each with 0 and 10 point features,
# and on sets not used while building it: 4 robots seed 11 (no point features), 5 robots seed 8
# (10 point features), sim15 and kitti00. The threshold acts on consensus only: a -kl mode's
# separate runs are its base mode's (shown as a check). Plain `consider` is slow under consensus
# (about a minute an n3 run, 2.5 min on kitti00) and left out unless asked for.
# Writes docs/results-archiving.md; runs in bench/out/archiving/ (kept between runs: delete it to
# start afresh). Two runs at a time: compare times within one run of the bench.
# Usage: bench/archive_bench.sh [MODES]   (default "marginal marginal-kl consider-kl")
set -euo pipefail
cd "$(dirname "$0")/.."
modes="${1:-marginal marginal-kl consider-kl}"
shared=../shared/datasets
out=bench/out/archiving
source bench/replay_runs.sh

declare -A mode_args=(
  [marginal]=""
  [marginal-kl]="--set consensus.fuse_kl_threshold=0.001"
  [consider]="--set object_archive_mode=consider"
  [consider-kl]="--set object_archive_mode=consider --set consensus.fuse_kl_threshold=0.001"
)

# name robots seed features
simulated=(
  "n3-s1-p0 3 1 0" "n3-s1-p10 3 1 10" "n3-s2-p0 3 2 0" "n3-s2-p10 3 2 10" "n3-s3-p0 3 3 0"
  "n3-s3-p10 3 3 10" "n3-s4-p0 3 4 0" "n3-s4-p10 3 4 10" "n3-s5-p0 3 5 0" "n3-s5-p10 3 5 10"
  "n7-s9-p0 7 9 0" "n7-s9-p10 7 9 10" "n4-s11-p0 4 11 0" "n5-s8-p10 5 8 10"
)
sets=()
for entry in "${simulated[@]}"; do
  read -r name robots seed features <<<"$entry"
  data="$out/data-$name"
  [ -f "$data/dataset.json" ] || $concord sim --robots "$robots" --seed "$seed" \
    --points-per-frame "$features" --out "$data" >/dev/null 2>&1
  sets+=("$name=$data")
done
sets+=("sim15=$shared/sim15" "kitti00=$shared/kitti00")

for mode in $modes; do
  [ -n "${mode_args[$mode]+set}" ] || { echo "bench: unknown mode $mode" >&2; exit 2; }
  for entry in "${sets[@]}"; do
    name=${entry%%=*}
    data=${entry#*=}
    # shellcheck disable=SC2086  # the --set arguments split on purpose
    run "$mode-$name-consensus" "$data" ${mode_args[$mode]} &
    # shellcheck disable=SC2086
    run "$mode-$name-separate" "$data" --separate ${mode_args[$mode]} &
    wait
  done
done

python3 bench/summarize_archiving.py "$out" "$modes" >docs/results-archiving.md
cat docs/results-archiving.md

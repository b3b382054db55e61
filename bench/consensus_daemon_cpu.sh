#!/usr/bin/env bash
# Issue 13's consensus step as a daemon pays it: one concordd per robot of each dataset on
# loopback (`concord launch`, lockstep, as fast as they go), then each daemon's own CPU in the
# step a round from its stats.json: `consensus_send_cpu_seconds` (its marginal and each
# neighbour's message, cut, encoded and handed to the network) and `consensus_fuse_cpu_seconds`
# (the fuse of what arrived), waiting and negotiation left out. Prints, per dataset, the median
# daemon and the range over the daemons, in ms a round; REPS launches each (default 1). Writes
# the table to bench/out/consensus-daemon-cpu/table.md. The replay's figure of the same step
# (estimator work only, no messages) is bench/consensus_cpu_bench.sh's.
# Usage: bench/consensus_daemon_cpu.sh [DATASET_DIR ...]   (default: the shared sim15)
set -euo pipefail
cd "$(dirname "$0")/.."
reps="${REPS:-1}"
if [ "$#" -eq 0 ]; then set -- ../shared/datasets/sim15; fi
out=bench/out/consensus-daemon-cpu
mkdir -p "$out"
cmake --build build --target concord concordd >/dev/null
runs=()
for data in "$@"; do
  name=$(basename "$data")
  for ((rep = 0; rep < reps; ++rep)); do
    run="$out/$name-$rep"
    rm -rf "$run"
    ./build/tools/concord launch --dataset "$data" --out "$run" --lockstep --rate 0 \
      >"$run.log" 2>&1 || { echo "bench: $name run $rep FAILED (see $run.log)" >&2; exit 1; }
    runs+=("$run")
  done
done
python3 - "${runs[@]}" <<'PY' | tee "$out/table.md"
import glob, json, os, statistics, sys
print("| run | daemons | rounds | messages ms | fuse ms | both ms |")
print("|---|---|---|---|---|---|")
for run in sys.argv[1:]:
    rows = []
    for path in sorted(glob.glob(os.path.join(run, "robot_*", "stats.json"))):
        stats = json.load(open(path))
        rounds = stats["rounds"]
        if rounds == 0:
            continue
        rows.append((1e3 * stats["consensus_send_cpu_seconds"] / rounds,
                     1e3 * stats["consensus_fuse_cpu_seconds"] / rounds, rounds))
    if not rows:
        print(f"| {os.path.basename(run)} | 0 | - | - | - | - |")
        continue
    def cell(values):
        return f"{statistics.median(values):.3f} ({min(values):.3f}-{max(values):.3f})"
    send = [r[0] for r in rows]
    fuse = [r[1] for r in rows]
    both = [r[0] + r[1] for r in rows]
    print(f"| {os.path.basename(run)} | {len(rows)} | {statistics.median(r[2] for r in rows):.0f} | "
          f"{cell(send)} | {cell(fuse)} | {cell(both)} |")
PY

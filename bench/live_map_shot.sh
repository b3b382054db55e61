#!/usr/bin/env bash
# The live map picture of docs/daemon.md: a 3-robot team of concordd daemons on the repository's
# kitti00-300 slice at its camera rate (10 Hz), robot 0's page at / taken with headless Chromium
# once every robot has processed FRAME frames (default 250), written to docs/live-map.png.
# Usage: bench/live_map_shot.sh [FRAME]
set -euo pipefail
cd "$(dirname "$0")/.."
frame="${1:-250}"
out=bench/out/live-map
rm -rf "$out"
mkdir -p "$out"
cmake --build build --target concord concordd >/dev/null
./build/tools/concord launch --dataset data/kitti00-300 --out "$out/team" --rate 10 \
  --base-port 7400 --http-base-port 8400 >"$out/launch.log" 2>&1 &
launch_pid=$!
trap 'kill "$launch_pid" 2>/dev/null || true' EXIT
deadline=$((SECONDS + 120))
for robot in 0 1 2; do
  until curl -s "http://127.0.0.1:$((8400 + robot))/status" |
        python3 -c "import json,sys; sys.exit(json.load(sys.stdin)['frames_processed'] < $frame)" \
        2>/dev/null; do
    [ "$SECONDS" -lt "$deadline" ] || { echo "robot $robot did not reach frame $frame" >&2; exit 1; }
    sleep 0.2
  done
done
chromium --headless=new --no-sandbox --disable-gpu --disable-dev-shm-usage --hide-scrollbars \
  --no-first-run --user-data-dir="$out/chromium" --window-size=1100,720 \
  --virtual-time-budget=5000 --screenshot=docs/live-map.png http://127.0.0.1:8400/ \
  >"$out/chromium.log" 2>&1
wait "$launch_pid"
trap - EXIT
echo "docs/live-map.png: robot 0's live map at frame $frame or later"

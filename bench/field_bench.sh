#!/usr/bin/env bash
# The field issue's must-show (issue 14): 10 concordd in 10 network namespaces on 1 Mbit/s links
# against the same team on loopback, and a 6-robot team partitioned 3 + 3 for 30 s, then healed.
# Needs root, iproute2 (ip, tc) and curl. Writes docs/results-field.md; runs in bench/out/field.
# Usage: sudo bench/field_bench.sh
set -euo pipefail
cd "$(dirname "$0")/.."
cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release >/dev/null
cmake --build build --parallel 2 --target concord concordd >/dev/null
python3 bench/field_bench.py >docs/results-field.md
cat docs/results-field.md

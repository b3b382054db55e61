"""Turns bench/out/daemon-* (concord launch) and daemon-*-replay into docs/results-daemon.md."""
import json
import statistics
import sys
from pathlib import Path

out = Path(sys.argv[1])


def read_kitti(path):
    return [[float(v) for v in line.split()] for line in path.read_text().splitlines() if line.strip()]


def max_difference(a, b):
    if len(a) != len(b):
        return float("inf")
    return max((abs(x - y) for ra, rb in zip(a, b) for x, y in zip(ra, rb)), default=0.0)


print("# concordd teams on loopback\n")
print("Written by `bench/daemon_bench.sh`. Every daemon is a process. They run in lockstep")
print("consensus over TCP on 127.0.0.1, on this 2-core machine, so a team of n daemons shares 2")
print("cores. The replay column is `concord replay` on the same data in one process.\n")
for dataset in ["kitti00", "sim15"]:
    team = out / f"daemon-{dataset}"
    replay = out / f"daemon-{dataset}-replay"
    if not (team / "metrics.json").exists():
        continue
    launched = json.loads((team / "metrics.json").read_text())
    replayed = json.loads((replay / "metrics.json").read_text())
    robots = sorted(p for p in team.glob("robot_*") if p.is_dir())
    print(f"## {dataset}: {len(robots)} daemons\n")
    print("| run | traj RMSE m | object err m | disagreement m | wall s |")
    print("|---|---|---|---|---|")
    a, b = launched["average"], replayed["average"]
    print(f"| daemons (lockstep) | {a['trajectory_rmse']:.3f} | {a['object_error']:.3f} | "
          f"{a['disagreement']:.3f} | {launched['run']['wall_seconds']:.1f} |")
    print(f"| replay (one process) | {b['trajectory_rmse']:.3f} | {b['object_error']:.3f} | "
          f"{b['disagreement']:.3f} | {replayed['run']['total_seconds']:.1f} |")
    differences = [max_difference(read_kitti(r / "trajectory.kitti"),
                                  read_kitti(replay / r.name / "trajectory.kitti")) for r in robots]
    print(f"\nLargest difference between a daemon's trajectory and the replay's: "
          f"{max(differences):.2e} (KITTI matrix entries, m for translations).\n")
    print("| robot | frames | bytes sent per round (median / max) | frame latency ms (p50 / p99) "
          "| CPU s (user + system) | wall s |")
    print("|---|---|---|---|---|---|")
    medians = []
    for robot in robots:
        s = json.loads((robot / "stats.json").read_text())
        medians.append(s["bytes_sent_per_round"]["median"])
        print(f"| {robot.name} | {s['frames']} | {s['bytes_sent_per_round']['median']:.0f} / "
              f"{s['bytes_sent_per_round']['max']:.0f} | {s['latency_ms']['p50']:.2f} / "
              f"{s['latency_ms']['p99']:.2f} | {s['cpu_user_seconds'] + s['cpu_system_seconds']:.2f} | "
              f"{s['wall_seconds']:.1f} |")
    print(f"\nMedian over daemons of the median bytes per round: {statistics.median(medians):.0f}.\n")

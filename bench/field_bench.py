"""Field bench (issue 14): concordd teams in network namespaces on rate-limited links.

1. Ten daemons in ten namespaces on 1 Mbit/s links (tc tbf), beacon discovery only, async
   consensus at 10 Hz with a link budget, against the same team on unlimited loopback
   (`concord launch --async`): frame rate, bytes per robot per second against the link and the
   budget, accuracy (`concord eval`).
2. Six robots partitioned 3 + 3 for 30 s (robots 3-5 moved to a second bridge), then healed:
   the disagreement between the halves before, during and after, and the rounds to agree again.

Needs root and iproute2; run through bench/field_bench.sh. Writes docs/results-field.md.
"""
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BUILD = ROOT / "build"
CONCORD = BUILD / "tools" / "concord"
CONCORDD = BUILD / "daemon" / "concordd"
OUT = ROOT / "bench" / "out" / "field"
PREFIX = "cf"  # namespaces cfN, bridges cfbrA / cfbrB, veths cfhN
LINK = "1mbit"
LINK_BYTES_PER_SECOND = 125000
BUDGET = 60000  # consensus bytes per second per robot (half the link: heartbeats, TCP, bursts)
RATE_HZ = 10


def sh(*args, check=True, capture=False):
    result = subprocess.run([str(a) for a in args], check=check, text=True,
                            stdout=subprocess.PIPE if capture else subprocess.DEVNULL,
                            stderr=subprocess.PIPE if capture else subprocess.DEVNULL)
    return result.stdout if capture else None


def cleanup(robots=16):
    for robot in range(robots):
        sh("ip", "netns", "del", f"{PREFIX}{robot}", check=False)
    for bridge in ("cfbrA", "cfbrB"):
        sh("ip", "link", "del", bridge, check=False)


def make_lab(robots):
    cleanup()
    for bridge in ("cfbrA", "cfbrB"):
        sh("ip", "link", "add", bridge, "type", "bridge")
        sh("ip", "link", "set", bridge, "type", "bridge", "mcast_snooping", "0")
        sh("ip", "link", "set", bridge, "up")
    for robot in range(robots):
        ns = f"{PREFIX}{robot}"
        sh("ip", "netns", "add", ns)
        sh("ip", "link", "add", f"cfh{robot}", "type", "veth", "peer", "name", "eth0", "netns", ns)
        sh("ip", "link", "set", f"cfh{robot}", "master", "cfbrA", "up")
        sh("ip", "-n", ns, "addr", "add", f"10.214.0.{robot + 1}/24", "dev", "eth0")
        sh("ip", "-n", ns, "link", "set", "eth0", "up")
        sh("ip", "-n", ns, "link", "set", "lo", "up")
        sh("ip", "-n", ns, "route", "add", "224.0.0.0/4", "dev", "eth0")
        sh("ip", "netns", "exec", ns, "tc", "qdisc", "replace", "dev", "eth0", "root", "tbf",
           "rate", LINK, "burst", "32kb", "latency", "400ms")


def http(robot, target):
    text = sh("ip", "netns", "exec", f"{PREFIX}{robot}", "curl", "-s", "--max-time", "1",
              f"http://127.0.0.1:8080{target}", check=False, capture=True)
    try:
        return json.loads(text)
    except (json.JSONDecodeError, TypeError):
        return None


def write_configs(dataset, out, robots, key, budget):
    configs = []
    for robot in range(robots):
        config = out / f"robot_{robot:02d}.yaml"
        config.write_text(f"""robot_id: {robot}
team: field
team_key_file: {key}
members: [{", ".join(str(r) for r in range(robots))}]
estimator: {ROOT / "configs/sensors/sim.yaml"}
source: {{kind: replay, dataset: {dataset}, robot: {robot}, rate_hz: {RATE_HZ}}}
network: {{listen_address: 0.0.0.0, listen_port: 7100, peers: [], discovery: true}}
consensus: {{mode: async, wait_for_peers: {robots - 1}, startup_timeout_ms: 30000,
             link_budget_bytes_per_second: {budget}}}
http: {{address: 127.0.0.1, port: 8080}}
output: {{directory: {out / f"robot_{robot:02d}"}, write_interval_ms: 0}}
""")
        configs.append(config)
    return configs


def start(configs):
    return [subprocess.Popen(["ip", "netns", "exec", f"{PREFIX}{robot}", str(CONCORDD), "--config",
                              str(config)],
                             stdout=open(config.with_suffix(".log"), "w"), stderr=subprocess.STDOUT)
            for robot, config in enumerate(configs)]


def discovery_seconds(log, peers):
    """Seconds from a daemon's first log line to its `peers`-th peer up (None if never)."""
    from datetime import datetime
    stamps, up = [], set()
    for line in log.read_text().splitlines():
        try:
            stamp = datetime.fromisoformat(line.split()[0])
        except (ValueError, IndexError):
            continue
        stamps.append(stamp)
        if ": peer: robot " in line and line.endswith(" up"):
            up.add(line.split(": peer: robot ")[1].split()[0])
            if len(up) == peers:
                return (stamp - stamps[0]).total_seconds()
    return None


def evaluate(dataset, result):
    sh(CONCORD, "eval", "--dataset", dataset, "--result", result)
    return json.loads((result / "metrics.json").read_text())["average"]


def cross_disagreement(snapshots, half):
    """Mean over objects held on both sides of the distance between the halves' mean estimates."""
    sides = [{}, {}]
    for robot, objects in snapshots.items():
        for obj in objects:
            sides[robot >= half].setdefault(obj["id"], []).append(obj["position"])
    distances = []
    for object_id in set(sides[0]) & set(sides[1]):
        means = [[statistics.fmean(c) for c in zip(*sides[s][object_id])] for s in (0, 1)]
        distances.append(sum((a - b) ** 2 for a, b in zip(*means)) ** 0.5)
    return (statistics.fmean(distances), len(distances)) if distances else (float("nan"), 0)


def run_ten(key):
    robots = 10
    dataset = OUT / "sim10"
    if not dataset.exists():
        sh(CONCORD, "sim", "--out", dataset, "--robots", robots, "--frames", 300, "--seed", 1)
    # Reference: the same team on unlimited loopback.
    loopback = OUT / "loopback10"
    shutil.rmtree(loopback, ignore_errors=True)
    sh(CONCORD, "launch", "--dataset", dataset, "--out", loopback, "--async", "--rate", RATE_HZ,
       "--base-port", 17300, "--http-base-port", 18300)
    reference = evaluate(dataset, loopback)
    # The namespaces.
    team = OUT / "netns10"
    shutil.rmtree(team, ignore_errors=True)
    team.mkdir(parents=True)
    make_lab(robots)
    try:
        daemons = start(write_configs(dataset, team, robots, key, BUDGET))
        for daemon in daemons:
            daemon.wait(timeout=240)
    finally:
        cleanup()
    result = evaluate(dataset, team)
    rows = []
    for robot in range(robots):
        stats = json.loads((team / f"robot_{robot:02d}" / "stats.json").read_text())
        wall = stats["wall_seconds"]
        rows.append({"robot": robot, "frames": stats["frames"], "fps": stats["frames"] / wall,
                     "bytes_out_per_s": stats["network"]["bytes_out"] / wall,
                     "consensus_per_s": stats["consensus"]["bytes_sent"] / wall,
                     "trimmed": stats["consensus"]["budget_marginals_trimmed"],
                     "empty": stats["consensus"]["budget_marginals_empty"],
                     "dropped": stats["consensus"]["budget_landmarks_dropped"],
                     "fused": stats["marginals_fused"], "rounds": stats["rounds"],
                     "latency_p99": stats["latency_ms"]["p99"],
                     "discovery_s": discovery_seconds(team / f"robot_{robot:02d}.log", robots - 1)})
    return reference, result, rows


def run_partition(key):
    robots, half = 6, 3
    dataset = OUT / "sim6"
    if not dataset.exists():
        sh(CONCORD, "sim", "--out", dataset, "--robots", robots, "--frames", 700, "--seed", 2)
    team = OUT / "partition6"
    shutil.rmtree(team, ignore_errors=True)
    team.mkdir(parents=True)
    make_lab(robots)
    timeline = []  # (seconds, phase, robot 0's frame, disagreement, objects compared)
    try:
        daemons = start(write_configs(dataset, team, robots, key, BUDGET))
        start_time = None
        phase = "before"
        while any(d.poll() is None for d in daemons):
            status = http(0, "/status")
            if status and status.get("frames_processed", 0) > 0 and start_time is None:
                start_time = time.monotonic()
            if start_time is not None:
                elapsed = time.monotonic() - start_time
                if phase == "before" and elapsed >= 15:
                    for robot in range(half, robots):
                        sh("ip", "link", "set", f"cfh{robot}", "master", "cfbrB")
                    phase = "during"
                elif phase == "during" and elapsed >= 45:
                    for robot in range(half, robots):
                        sh("ip", "link", "set", f"cfh{robot}", "master", "cfbrA")
                    phase = "after"
                snapshots = {}
                for robot in range(robots):
                    objects = http(robot, "/objects")
                    if objects:
                        snapshots[robot] = objects["objects"]
                frame = (status.get("frame") or -1) if status else -1
                value, count = cross_disagreement(snapshots, half)
                timeline.append((elapsed, phase, frame, value, count))
            time.sleep(0.5)  # sampling period of the bench, not synchronisation
    finally:
        for daemon in daemons:
            if daemon.poll() is None:
                daemon.kill()
        cleanup()
    return timeline


def main():
    if os.geteuid() != 0:
        sys.exit("field_bench: needs root (network namespaces)")
    OUT.mkdir(parents=True, exist_ok=True)
    key = OUT / "team.key"
    if not key.exists():
        sh(CONCORD, "keygen", "--out", key)
    reference, result, rows = run_ten(key)
    timeline = run_partition(key)
    save(reference, result, rows, timeline)


def save(reference, result, rows, timeline):
    (OUT / "field.json").write_text(json.dumps(
        {"reference": reference, "result": result, "rows": rows, "timeline": timeline}, indent=1))
    print(render(reference, result, rows, timeline))


def rerender():
    """--render: the page again from bench/out/field/field.json and the logs (no run)."""
    saved = json.loads((OUT / "field.json").read_text())
    for row in saved["rows"]:
        row["discovery_s"] = discovery_seconds(OUT / "netns10" / f"robot_{row['robot']:02d}.log",
                                               len(saved["rows"]) - 1)
    save(saved["reference"], saved["result"], saved["rows"], saved["timeline"])


def render(reference, result, rows, timeline):
    lines = ["# Field conditions: teams in network namespaces on rate-limited links", "",
             "Written by `bench/field_bench.sh` (root; docs/field.md). Each concordd runs in its own "
             "network namespace, on a veth pair to a bridge, its egress limited by a `tc` token "
             f"bucket ({LINK}); robots find each other by UDP beacons (no static peers); async "
             f"consensus at {RATE_HZ} Hz with `consensus.link_budget_bytes_per_second: {BUDGET}`. "
             "All daemons share this machine's 2 cores (with other work running).", "",
             "## 10 daemons on 1 Mbit/s links (concord sim, 10 robots, 300 frames)", "",
             "| run | traj RMSE m | object err m | disagreement m |", "|---|---|---|---|",
             f"| loopback, unlimited | {reference['trajectory_rmse']:.3f} | "
             f"{reference['object_error']:.3f} | {reference['disagreement']:.3f} |",
             f"| namespaces, {LINK} + budget | {result['trajectory_rmse']:.3f} | "
             f"{result['object_error']:.3f} | {result['disagreement']:.3f} |", "",
             "| robot | frames | frames/s | bytes out/s (link 125000) | consensus bytes/s (budget "
             f"{BUDGET}) | marginals trimmed | sent empty | landmarks left out | fused | latency p99 ms "
             "| all 9 peers up after s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['robot']} | {r['frames']} | {r['fps']:.2f} | {r['bytes_out_per_s']:.0f} | "
                     f"{r['consensus_per_s']:.0f} | {r['trimmed']} | {r['empty']} | {r['dropped']} | "
                     f"{r['fused']} | {r['latency_p99']:.1f} | "
                     f"{'-' if r.get('discovery_s') is None else format(r['discovery_s'], '.2f')} |")
    discovered = [r["discovery_s"] for r in rows if r.get("discovery_s") is not None]
    if len(discovered) == len(rows):
        lines += ["", f"Discovery with no static peers: every robot had its {len(rows) - 1} peers "
                  f"up within {max(discovered):.2f} s of its own start (median "
                  f"{statistics.median(discovered):.2f} s; beacons every second; the daemons were "
                  "started one after the other)."]
    lines += ["", "## 6 robots, partitioned 3 + 3 for 30 s, then healed (concord sim, 6 robots)", "",
              "Robots 3-5 are moved to a second bridge at 15 s and back at 45 s. Disagreement: over "
              "the objects both halves hold, the distance between the two halves' mean estimates "
              "(sampled every 0.5 s from /objects).", ""]
    phases = {}
    for _, phase, _, value, _ in timeline:
        if value == value:
            phases.setdefault(phase, []).append(value)
    lines += ["| phase | samples | disagreement mean m | max m |", "|---|---|---|---|"]
    for phase in ("before", "during", "after"):
        values = phases.get(phase, [])
        if values:
            lines.append(f"| {phase} | {len(values)} | {statistics.fmean(values):.4f} | {max(values):.4f} |")
    before = phases.get("before", [])
    heal = next((t for t in timeline if t[1] == "after"), None)
    if before and heal:
        level = 1.5 * statistics.fmean(before)
        agreed = next((t for t in timeline if t[1] == "after" and t[3] == t[3] and t[3] <= level), None)
        if agreed:
            lines += ["", f"Agreement again (disagreement within 1.5x its mean before the partition, "
                      f"{level:.4f} m): {agreed[2] - heal[2]} rounds (frames of robot 0) and "
                      f"{agreed[0] - heal[0]:.1f} s after the heal."]
        else:
            lines += ["", "The halves did not come back within 1.5x their earlier disagreement "
                      "before the run ended."]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    rerender() if sys.argv[1:] == ["--render"] else main()

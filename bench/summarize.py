"""Turns the bench run folders (metrics.json + wall time) into the markdown table of docs/results.md."""
import json
import sys
from pathlib import Path

out = Path(sys.argv[1])
reference = {  # the authors' Python code on the same folders, object-only, from the issue
    ("kitti00", "separate"): (78.00, 57.25, 89.51, "11.5 min"),
    ("kitti00", "consensus"): (76.10, 53.65, 85.09, "17.4 min"),
    ("sim15", "separate"): (4.54, 5.36, 8.50, "4.0 min"),
    ("sim15", "consensus"): (9.27, 38.57, 73.40, "11.0 min"),
}


def fmt(value, digits=3):
    return "-" if value is None else f"{value:.{digits}f}"


rows = []
for dataset, runs in [
    ("kitti00", ["kitti00-separate", "kitti00-consensus"]),
    ("sim15", ["sim15-separate", "sim15-consensus"]),
    ("kitti00-vo77", ["kitti00-vo77-objects-only", "kitti00-vo77-features"]),
]:
    odometry_shown = False
    for name in runs:
        folder = out / name
        metrics = json.loads((folder / "metrics.json").read_text())
        average = metrics["average"]
        wall = float((out / f"{name}.wall").read_text())
        if not odometry_shown:
            rows.append(f"| {dataset} | odometry only | {fmt(average['odometry_rmse'])} | | | |")
            odometry_shown = True
        mode = name[len(dataset) + 1:]
        key = (dataset, mode)
        if key in reference:
            r = reference[key]
            rows.append(f"| {dataset} | reference, {mode} | {r[0]:.2f} | {r[1]:.2f} | {r[2]:.2f} | {r[3]} |")
        rows.append(
            f"| {dataset} | **Concord, {mode}** | {fmt(average['trajectory_rmse'])} | "
            f"{fmt(average['object_error'])} | {fmt(average['disagreement'])} | {wall:.2f} s |")

print("# Estimator results on the shared datasets\n")
print("Produced by `bench/estimator_bench.sh` (one config per sensor, `configs/sensors/`).")
print("Averages over robots; trajectory RMSE without alignment; wall time of one whole")
print("`concord replay` process (reading, filtering, writing, plotting) on the 2-core machine.\n")
print("| data | run | traj RMSE m | object err m | disagreement m | wall time |")
print("|---|---|---|---|---|---|")
print("\n".join(rows))

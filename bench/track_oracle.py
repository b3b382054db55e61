#!/usr/bin/env python3
"""Oracle variants of a front-end's point tracks on a rendered team (diagnosis, not a result).

Usage: bench/track_oracle.py RENDERED FRONTEND OUT MODE   (beside bench/track_drift.py, whose ray cast it uses)

RENDERED is the `concord sim --render` team (its world.csv), FRONTEND the dataset `concord
frontend` wrote from it, OUT a copy of FRONTEND whose features.csv is rewritten. Each track's
true point is where the ray of its first left observation meets the world; its errors (all four
coordinates, against that point's projections in the true poses) are split into a straight line
over the track's frames and the rest, and put back according to MODE:
  drift          the line only (offset and slope)
  white          the rest only
  noconst        the errors less their mean over the track
  noslope        the errors less the line's slope part (offset and rest kept)
  nostereoconst  the right image's errors less the track's mean right-minus-left difference
Tracks whose ray misses the world, that leave the view, or with an error beyond 3 px keep their
observations. Replay OUT with `concord replay` to see what each part of the error does to the
filter (docs/frontend.md, "Found by oracle"). Needs numpy.
"""
import collections
import csv
import json
import os
import shutil
import sys

import numpy as np

from track_drift import load_poses, world_caster

KEYS = ("u_left", "v_left", "u_right", "v_right")
MODES = ("drift", "white", "noconst", "noslope", "nostereoconst")


def main():
    if len(sys.argv) != 5 or sys.argv[4] not in MODES:
        sys.exit(__doc__)
    rendered, frontend, out, mode = sys.argv[1:5]
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(frontend, out)
    camera = json.load(open(f"{frontend}/dataset.json"))["camera"]
    K = np.array(camera["K"])
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    baseline = camera["fx_times_baseline"] / fx
    cast = world_caster(f"{rendered}/world.csv")

    def project(q):
        x, y, z = q
        return np.array([fx * x / z + cx, fy * y / z + cy, fx * (x - baseline) / z + cx,
                         fy * y / z + cy])

    changed = 0
    for robot in sorted(d for d in os.listdir(frontend) if d.startswith("robot_")):
        poses = load_poses(f"{frontend}/{robot}/groundtruth.kitti")
        rows = list(csv.DictReader(open(f"{frontend}/{robot}/features.csv")))
        by_track = collections.defaultdict(list)
        for k, row in enumerate(rows):
            by_track[int(row["id"])].append(k)
        for indices in by_track.values():
            first = rows[indices[0]]
            pose = poses[int(first["frame"])]
            ray = pose[:3, :3] @ np.array([(float(first["u_left"]) - cx) / fx,
                                           (float(first["v_left"]) - cy) / fy, 1.0])
            point = cast(pose[:3, 3], ray / np.linalg.norm(ray))
            if point is None:
                continue
            predicted, observed = [], []
            for k in indices:
                inverse = np.linalg.inv(poses[int(rows[k]["frame"])])
                q = inverse[:3, :3] @ point + inverse[:3, 3]
                if q[2] < 0.1:
                    break
                predicted.append(project(q))
                observed.append([float(rows[k][key]) for key in KEYS])
            if len(predicted) != len(indices):
                continue
            predicted = np.array(predicted)
            errors = np.array(observed) - predicted
            if np.abs(errors).max() > 3.0:
                continue
            n = len(indices)
            if n >= 2:
                design = np.vstack([np.ones(n), np.arange(n)]).T
                coefficients, *_ = np.linalg.lstsq(design, errors, rcond=None)
                line = design @ coefficients
            else:
                line = errors.copy()
            if mode == "drift":
                new = line
            elif mode == "white":
                new = errors - line
            elif mode == "noconst":
                new = errors - errors.mean(0)
            elif mode == "noslope":
                new = errors - (line - line.mean(0))
            else:  # nostereoconst
                new = errors.copy()
                new[:, 2] -= (errors[:, 2] - errors[:, 0]).mean()
                new[:, 3] -= (errors[:, 3] - errors[:, 1]).mean()
            for j, k in enumerate(indices):
                for c, key in enumerate(KEYS):
                    rows[k][key] = repr(predicted[j, c] + new[j, c])
            changed += 1
        with open(f"{out}/{robot}/features.csv", "w", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(rows[0].keys()))
            writer.writeheader()
            writer.writerows(rows)
    print(f"{out}: {mode}, {changed} tracks rewritten")


if __name__ == "__main__":
    main()

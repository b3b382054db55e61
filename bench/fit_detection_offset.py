#!/usr/bin/env python3
"""Fits the estimator's detection-error model to a calibration dataset with ground truth.

usage: fit_detection_offset.py DATASET [--robot R] [--frames N] [--gap FRAMES] [--max-lag N]

DATASET is a dataset folder in pixels whose object observations came from a detector (e.g.
`concord frontend` on a rendered calibration team) and that holds the truth: objects_gt.csv and
each robot's groundtruth.kitti. Each observation's error against the true object centre is split
into its left x (du), y (dv) and disparity (dd) parts. Along each (robot, object) track the
errors are modelled as an offset that starts with standard deviation `sigma` and walks by
`walk` a frame, plus independent noise `independent`:

    var(e[k+n] - e[k]) = 2 independent^2 + n walk^2        (fitted over lags 1..max-lag)
    var(e at a track's first observation) = sigma^2 + independent^2

The vertical disparity (v_left - v_right) is taken as independent noise of its robust standard
deviation. Errors beyond 3 robust standard deviations (median absolute deviation) are left out (a wrong
match is the chi-square gate's business); the independent part gets a floor of 10 % of the
component's robust standard deviation (a fit to lags 1..max-lag says little about it), as
`concord calibrate` does for the persistent model. Prints the three estimator keys (object_noise,
object_offset_sigma, object_offset_walk; docs/estimator.md, "Detection offsets"). Only the
standard library: runs wherever the bench runs.
"""
import argparse
import csv
import json
import math
import statistics
import sys


def invert(pose):
    """Inverse of a 3x4 rigid transform given as 12 numbers, row-major."""
    r = [[pose[0], pose[1], pose[2]], [pose[4], pose[5], pose[6]], [pose[8], pose[9], pose[10]]]
    t = [pose[3], pose[7], pose[11]]
    rt = [[r[j][i] for j in range(3)] for i in range(3)]
    return rt, [-sum(rt[i][j] * t[j] for j in range(3)) for i in range(3)]


def robust_sigma(values):
    median = statistics.median(values)
    return 1.4826 * statistics.median(abs(v - median) for v in values)


def clipped(values):
    if len(values) < 5:
        return values
    median, sigma = statistics.median(values), robust_sigma(values)
    return [v for v in values if abs(v - median) <= 3.0 * sigma] if sigma > 0 else values


def mean_square(values):
    return sum(v * v for v in values) / len(values) if values else float("nan")


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("dataset")
    parser.add_argument("--gap", type=int, default=5,
                        help="frames without an observation that end a track (default 5)")
    parser.add_argument("--max-lag", type=int, default=10)
    parser.add_argument("--robot", type=int, help="only this robot (default: every robot)")
    parser.add_argument("--frames", type=int,
                        help="only each robot's first FRAMES frames (a calibration segment)")
    args = parser.parse_args()

    meta = json.load(open(f"{args.dataset}/dataset.json"))
    camera = meta["camera"]
    fx, cx = camera["K"][0][0], camera["K"][0][2]
    fy, cy = camera["K"][1][1], camera["K"][1][2]
    focal_baseline = camera["fx_times_baseline"]
    cam_body = camera["T_cam_body"]
    truth = {int(row["id"]): [float(row["x"]), float(row["y"]), float(row["z"])]
             for row in csv.DictReader(open(f"{args.dataset}/objects_gt.csv"))}

    tracks = []  # lists of (frame, [du, dv, dd])
    vertical_disparities = []  # v_left - v_right: independent noise only (no offset part)
    robots = range(meta["robots"]) if args.robot is None else [args.robot]
    for robot in robots:
        folder = f"{args.dataset}/robot_{robot:02d}"
        poses = [list(map(float, line.split())) for line in open(f"{folder}/groundtruth.kitti")
                 if line.strip()]
        by_object = {}
        for row in csv.DictReader(open(f"{folder}/objects.csv")):
            frame, object_id = int(row["frame"]), int(row["id"])
            if object_id not in truth or frame >= len(poses) or \
                    (args.frames is not None and frame >= args.frames):
                continue
            r, t = invert(poses[frame])  # world -> body
            p = truth[object_id]
            body = [sum(r[i][j] * p[j] for j in range(3)) + t[i] for i in range(3)]
            c = [sum(cam_body[i][j] * body[j] for j in range(3)) + cam_body[i][3] for i in range(3)]
            if c[2] <= 0:
                continue
            u_true, v_true = fx * c[0] / c[2] + cx, fy * c[1] / c[2] + cy
            u, v, u_right = float(row["u_left"]), float(row["v_left"]), float(row["u_right"])
            error = [u - u_true, v - v_true, (u - u_right) - focal_baseline / c[2]]
            vertical_disparities.append(v - float(row["v_right"]))
            by_object.setdefault(object_id, []).append((frame, error))
        for observations in by_object.values():
            observations.sort()
            track = [observations[0]]
            for previous, current in zip(observations, observations[1:]):
                if current[0] - previous[0] > args.gap:
                    tracks.append(track)
                    track = []
                track.append(current)
            tracks.append(track)

    names = ("horizontal", "vertical", "disparity")
    fitted = {}
    for component, name in enumerate(names):
        # Differences at each lag, clipped, as mean squares (the offsets' walk has zero mean).
        lags, variances = [], []
        for lag in range(1, args.max_lag + 1):
            differences = []
            for track in tracks:
                by_frame = {frame: error[component] for frame, error in track}
                differences += [by_frame[f + lag] - e for f, e in by_frame.items()
                                if f + lag in by_frame]
            differences = clipped(differences)
            if len(differences) >= 20:
                lags.append(lag)
                variances.append(mean_square(differences))
        if len(lags) < 2:
            sys.exit(f"fit_detection_offset: too few tracks for the {name} component")
        mean_lag, mean_variance = statistics.fmean(lags), statistics.fmean(variances)
        slope = sum((n - mean_lag) * (v - mean_variance) for n, v in zip(lags, variances)) / \
            sum((n - mean_lag) ** 2 for n in lags)
        intercept = mean_variance - slope * mean_lag
        starts = clipped([track[0][1][component] for track in tracks])
        start_variance = statistics.fmean(v * v for v in starts)
        independent = math.sqrt(max(intercept / 2.0, 0.0))
        everything = [error[component] for track in tracks for _, error in track]
        independent = max(independent, 0.1 * robust_sigma(everything))
        fitted[name] = {
            "independent": independent,
            "walk": math.sqrt(max(slope, 0.0)),
            "sigma": math.sqrt(max(start_variance - independent ** 2, 0.0)),
            "tracks": len(tracks),
        }

    h, v, d = (fitted[n] for n in names)
    # Vertical disparity (zero for a rectified pair's true point): independent noise, its robust
    # sigma, with the same floor (the front-end puts both centres on one row).
    floor = max(robust_sigma(clipped(vertical_disparities)), 0.1 * v["independent"])
    print(f"# fit_detection_offset.py on {args.dataset}: {h['tracks']} tracks, lags 1-{args.max_lag}")
    print(f"object_noise: {{horizontal: {h['independent']:.3g}, vertical: {v['independent']:.3g}, "
          f"disparity: {d['independent']:.3g}, vertical_disparity: {floor:.3g}}}")
    print(f"object_offset_sigma: {{horizontal: {h['sigma']:.3g}, vertical: {v['sigma']:.3g}, "
          f"disparity: {d['sigma']:.3g}, vertical_disparity: 0}}")
    print(f"object_offset_walk: {{horizontal: {h['walk']:.3g}, vertical: {v['walk']:.3g}, "
          f"disparity: {d['walk']:.3g}, vertical_disparity: 0}}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""How a front-end's point tracks err along a track, against the ground truth (diagnosis).

Usage: bench/track_drift.py DATASET [ROBOT] [--min-length N] [--world WORLD_CSV]

Each track of at least N observations (default 8) in DATASET/robot_NN/features.csv is
triangulated (Gauss-Newton on its stereo reprojections) in the true camera poses
(groundtruth.kitti, the left camera in the front-end's datasets), and its residuals are read by
position along the track. With --world (the world.csv of a `concord sim --render` team, in the
poses' frame) the point is instead the world's surface where the ray of the track's first left
observation meets it, and the errors are against that true point: nothing is absorbed by a
triangulation (the first left observation's error is zero by construction, and the right
image's first error is the stereo match's). Printed per image coordinate (u, v of the left and
right images):
- the residuals' autocorrelation at lags 1, 2, 3 and 5 within tracks;
- their RMS by position along the track (a U shape is a drift the triangulation half absorbs);
- the spread over tracks of each track's least-squares slope (pixels a frame): a track's drift.
White noise gives autocorrelations near 0, a flat RMS and slopes near 0. docs/frontend.md
("How the anchored tracks' errors hang together") reads them. Tracks with a residual beyond
2 px (a wrong match) are left out. Needs numpy.
"""
import argparse
import collections
import csv
import json

import numpy as np

COORDINATES = ("u_left", "v_left", "u_right", "v_right")


def load_poses(path):
    poses = []
    for line in open(path):
        if line.strip():
            pose = np.eye(4)
            pose[:3, :] = np.array(list(map(float, line.split()))).reshape(3, 4)
            poses.append(pose)
    return poses


def world_caster(world_csv):
    """A function (origin, unit direction) -> the nearest point where the ray meets one of the
    rendered world's faces (world.csv: corner, edge u, edge v), or None."""
    faces = np.array([[float(x) for x in row[1:10]] for row in list(csv.reader(open(world_csv)))[1:]])
    corner, edge_u, edge_v = faces[:, 0:3], faces[:, 3:6], faces[:, 6:9]
    normal = np.cross(edge_u, edge_v)
    uu, vv, uv = (edge_u**2).sum(1), (edge_v**2).sum(1), (edge_u * edge_v).sum(1)
    det = np.where(uu * vv - uv * uv == 0.0, 1.0, uu * vv - uv * uv)

    def cast(origin, direction):
        denominator = normal @ direction
        valid = np.abs(denominator) > 1e-12
        t = np.where(valid, ((corner - origin) * normal).sum(1) / np.where(valid, denominator, 1.0),
                     np.inf)
        w = origin + t[:, None] * direction - corner
        wu, wv = (w * edge_u).sum(1), (w * edge_v).sum(1)
        a, c = (wu * vv - wv * uv) / det, (wv * uu - wu * uv) / det
        hit = valid & (t > 0.05) & (a >= 0) & (a <= 1) & (c >= 0) & (c <= 1)
        return origin + np.min(np.where(hit, t, np.inf)) * direction if hit.any() else None

    return cast


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset")
    parser.add_argument("robot", nargs="?", type=int, default=0)
    parser.add_argument("--min-length", type=int, default=8)
    parser.add_argument("--world", help="world.csv of the rendered team (faces: corner, u, v)")
    args = parser.parse_args()
    camera = json.load(open(f"{args.dataset}/dataset.json"))["camera"]
    K = np.array(camera["K"])
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    baseline = camera["fx_times_baseline"] / fx
    folder = f"{args.dataset}/robot_{args.robot:02d}"
    world_camera = load_poses(f"{folder}/groundtruth.kitti")
    camera_world = [np.linalg.inv(pose) for pose in world_camera]
    tracks = collections.defaultdict(list)
    for row in csv.DictReader(open(f"{folder}/features.csv")):
        tracks[int(row["id"])].append(
            (int(row["frame"]), np.array([float(row[key]) for key in COORDINATES])))

    def project(q):
        x, y, z = q
        return np.array([fx * x / z + cx, fy * y / z + cy, fx * (x - baseline) / z + cx,
                         fy * y / z + cy])

    cast = world_caster(args.world) if args.world else None
    sequences = []
    for observations in tracks.values():
        if len(observations) < args.min_length:
            continue
        first_frame, uv = observations[0]
        if cast is not None:
            pose = world_camera[first_frame]
            ray = pose[:3, :3] @ np.array([(uv[0] - cx) / fx, (uv[1] - cy) / fy, 1.0])
            point = cast(pose[:3, 3], ray / np.linalg.norm(ray))
            if point is None:
                continue
            errors = []
            for frame, uv in observations:
                T = camera_world[frame]
                q = T[:3, :3] @ point + T[:3, 3]
                if q[2] < 0.1:
                    break
                errors.append(uv - project(q))
            errors = np.array(errors)
            if len(errors) >= args.min_length and np.abs(errors).max() <= 3.0:
                sequences.append(errors)
            continue
        disparity = uv[0] - uv[2]
        if disparity <= 0.5:
            continue
        depth = fx * baseline / disparity
        point = (world_camera[first_frame] @ np.array(
            [(uv[0] - cx) / fx * depth, (uv[1] - cy) / fy * depth, depth, 1.0]))[:3]
        usable = True
        for _ in range(6):
            normal, gradient = np.zeros((3, 3)), np.zeros(3)
            for frame, uv in observations:
                T = camera_world[frame]
                q = T[:3, :3] @ point + T[:3, 3]
                if q[2] < 1e-3:
                    usable = False
                    break
                x, y, z = q
                H = np.array([[fx / z, 0, -fx * x / z**2], [0, fy / z, -fy * y / z**2],
                              [fx / z, 0, -fx * (x - baseline) / z**2], [0, fy / z, -fy * y / z**2]])
                J = H @ T[:3, :3]
                normal += J.T @ J
                gradient += J.T @ (uv - project(q))
            if not usable:
                break
            point = point + np.linalg.solve(normal, gradient)
        if not usable:
            continue
        residuals = np.array([uv - project(camera_world[f][:3, :3] @ point + camera_world[f][:3, 3])
                              for f, uv in observations])
        if np.abs(residuals).max() <= 2.0:
            sequences.append(residuals)
    against = "the world's true points" if cast is not None else "their triangulation"
    print(f"{folder}: {len(sequences)} tracks of at least {args.min_length} observations, "
          f"against {against}")
    if not sequences:
        return
    longest = max(len(r) for r in sequences)
    for c, name in enumerate(COORDINATES):
        correlations = []
        for lag in (1, 2, 3, 5):
            numerator = denominator = 0.0
            for r in sequences:
                x = r[:, c] - r[:, c].mean()
                if len(x) > lag:
                    numerator += np.dot(x[:-lag], x[lag:]) / (len(x) - lag)
                denominator += np.dot(x, x) / len(x)
            correlations.append(numerator / denominator)
        by_position = [np.sqrt(np.mean([r[i, c] ** 2 for r in sequences if len(r) > i]))
                       for i in range(min(longest, 12))]
        slopes = np.array([np.polyfit(np.arange(len(r)), r[:, c], 1)[0] for r in sequences])
        print(f"  {name:8s} autocorrelation (lags 1 2 3 5) "
              + " ".join(f"{v:5.2f}" for v in correlations)
              + " | RMS by position px " + " ".join(f"{v:.3f}" for v in by_position)
              + f" | slope px a frame {slopes.mean():+.4f} +- {slopes.std():.4f}")


if __name__ == "__main__":
    main()

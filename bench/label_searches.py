#!/usr/bin/env python3
"""Judges a negotiated replay's searches against the truth.

Usage: bench/label_searches.py DATASET SEARCH_LOG [--wrong-degrees 10]

DATASET is the set the replay ran on (its robot_XX/groundtruth.kitti: the first line is each
robot's start pose in the world, whatever the set's start_poses says); SEARCH_LOG is what
`concord replay --search-log` wrote. For every aligned search it compares the transform found
(own frame <- the neighbour's frame, each frame a robot's start frame) with the true one, and
prints the wrong ones (rotation error above --wrong-degrees) with their clique size, the clique
fit's chi-square and its upper-tail probability under 3k - 6 degrees of freedom (k members: 3
coordinates each, 6 taken by the transform), then how many right ones fall below 0.001, 0.01
and 0.05. A diagnosis: nothing reads the truth during a run.
"""
import argparse
import glob
import math
import os
import re


def upper_gamma_regularized(a, x):
    """Q(a, x) by the series (x < a + 1) or the continued fraction (Numerical Recipes 6.2)."""
    if x <= 0:
        return 1.0
    log_front = -x + a * math.log(x) - math.lgamma(a)
    if x < a + 1:
        total = term = 1.0 / a
        n = a
        for _ in range(1000):
            n += 1
            term *= x / n
            total += term
            if abs(term) < abs(total) * 1e-15:
                break
        return max(0.0, 1.0 - total * math.exp(log_front))
    b = x + 1 - a
    c = 1e300
    d = 1 / b
    h = d
    for i in range(1, 1000):
        an = -i * (i - a)
        b += 2
        d = an * d + b
        d = 1 / d if d != 0 else 1e300
        c = b + an / c if c != 0 else 1e300
        h *= d * c
        if abs(d * c - 1) < 1e-15:
            break
    return math.exp(log_front) * h


def chi2_upper_tail(x, dof):
    return upper_gamma_regularized(dof / 2, x / 2)


def pose(numbers):
    return [numbers[0:4], numbers[4:8], numbers[8:12], [0.0, 0.0, 0.0, 1.0]]


def multiply(a, b):
    return [[sum(a[i][k] * b[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def inverse(t):
    r = [[t[j][i] for j in range(3)] for i in range(3)]
    shift = [-sum(r[i][k] * t[k][3] for k in range(3)) for i in range(3)]
    return [r[i] + [shift[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]


def rotation_degrees(t):
    cosine = (t[0][0] + t[1][1] + t[2][2] - 1) / 2
    return math.degrees(math.acos(max(-1.0, min(1.0, cosine))))


SEARCH = re.compile(r"round (\d+) pair (\d+)-(\d+): .* clique (\d+) rival (\d+) "
                    r"\(clique fit chi2 ([\d.]+), largest ([\d.]+)\): aligned$")
TRANSFORM = re.compile(r"\s+frames (-?\d+) <- (-?\d+), T_a_b:((?: \S+){12})$")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset")
    parser.add_argument("log")
    parser.add_argument("--wrong-degrees", type=float, default=10.0)
    args = parser.parse_args()
    starts = {}
    for path in glob.glob(os.path.join(args.dataset, "robot_*", "groundtruth.kitti")):
        robot = int(re.search(r"robot_(\d+)", path).group(1))
        with open(path) as f:
            starts[robot] = pose([float(x) for x in f.readline().split()])
    with open(args.log) as f:
        lines = f.read().splitlines()
    right, wrong = [], []
    for line, following in zip(lines, lines[1:]):
        search = SEARCH.match(line)
        transform = TRANSFORM.match(following)
        if not search or not transform:
            continue
        own_frame, their_frame = int(transform.group(1)), int(transform.group(2))
        found = pose([float(x) for x in transform.group(3).split()])
        truth = multiply(inverse(starts[own_frame]), starts[their_frame])
        error = multiply(inverse(truth), found)
        members = int(search.group(4))
        chi2 = float(search.group(6))
        entry = {
            "round": int(search.group(1)),
            "pair": f"{search.group(2)}-{search.group(3)}",
            "clique": members,
            "chi2": chi2,
            "p": chi2_upper_tail(chi2, 3 * members - 6),
            "degrees": rotation_degrees(error),
            "metres": math.sqrt(sum(error[i][3] ** 2 for i in range(3))),
        }
        (wrong if entry["degrees"] > args.wrong_degrees else right).append(entry)
    print(f"{len(right) + len(wrong)} aligned searches, {len(wrong)} wrong "
          f"(more than {args.wrong_degrees:g} degrees off)")
    for e in wrong:
        print(f"  wrong: round {e['round']} pair {e['pair']} clique {e['clique']} "
              f"chi2 {e['chi2']:.2f} p {e['p']:.2g}: {e['degrees']:.1f} deg, {e['metres']:.1f} m off")
    for bound in (0.001, 0.01, 0.05):
        below = sum(e["p"] < bound for e in right)
        print(f"  right searches with p < {bound:g}: {below} of {len(right)}")


if __name__ == "__main__":
    main()

#!/usr/bin/env python3
"""Why consensus objects are conservative, on the smallest model that shows it (issue 9).

N robots estimate one static scalar, each measuring it once a frame (noise variance R), and run
one consensus round a frame on the complete graph (weights 1/N). Three ways to fuse, each
measured over Monte-Carlo trials at the last frame: the error variance of the mean, the variance
the filter claims, and their ratio (NEES, 1 when consistent):

- centralized: one filter takes every robot's measurements (the reference);
- ci: the weighted geometric mean of eq. (19), i.e. covariance intersection of the members;
- sci: split covariance intersection, the members' own noise since the last round counted as
  independent (consistent whatever the correlation of the rest).

Usage: bench/consensus_scalar_check.py [FRAMES] [TRIALS]   (pure Python, no dependencies)
"""
import math
import random
import sys


def run(robots, mode, frames, trials, noise=1.0, prior=100.0):
    error = claimed = 0.0
    for trial in range(trials):
        rng = random.Random(1000003 * trial + robots)
        truth = rng.gauss(0.0, math.sqrt(prior))
        mean = [0.0] * robots
        variance = [prior] * robots
        independent = [0.0] * robots  # sci: the part of the variance from own noise since fusing
        for _ in range(frames):
            measurements = [truth + rng.gauss(0.0, math.sqrt(noise)) for _ in range(robots)]
            if mode == "centralized":
                for z in measurements:
                    gain = variance[0] / (variance[0] + noise)
                    mean[0] += gain * (z - mean[0])
                    variance[0] *= 1.0 - gain
                continue
            for i, z in enumerate(measurements):
                gain = variance[i] / (variance[i] + noise)
                mean[i] += gain * (z - mean[i])
                dependent = (1.0 - gain) ** 2 * (variance[i] - independent[i])
                independent[i] = (1.0 - gain) ** 2 * independent[i] + gain * gain * noise
                variance[i] = dependent + independent[i]
            if mode == "ci":
                shares = [1.0 / (robots * v) for v in variance]
            else:  # sci: (P_dependent / w + P_independent)^-1 with w = 1 / robots
                shares = [1.0 / (robots * (v - p) + p) for v, p in zip(variance, independent)]
            information = sum(shares)
            fused = sum(s * m for s, m in zip(shares, mean)) / information
            mean = [fused] * robots
            variance = [1.0 / information] * robots
            independent = [0.0] * robots  # after fusing, everything is shared
        error += (mean[0] - truth) ** 2 / trials
        claimed += variance[0] / trials
    return error, claimed


def main():
    frames = int(sys.argv[1]) if len(sys.argv) > 1 else 200
    trials = int(sys.argv[2]) if len(sys.argv) > 2 else 400
    print(f"{frames} frames, {trials} trials; variances x 1e4 at the last frame")
    print("| robots | fusion | error variance | claimed variance | NEES |")
    print("|---|---|---|---|---|")
    for robots in (3, 5, 15):
        for mode in ("centralized", "ci", "sci"):
            error, claimed = run(robots, mode, frames, trials)
            print(f"| {robots} | {mode} | {1e4 * error:.2f} | {1e4 * claimed:.2f} | "
                  f"{error / claimed:.2f} |")


if __name__ == "__main__":
    main()

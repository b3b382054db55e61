"""Summarizes bench/scale_bench.sh runs into docs/results-scale-daemons.md (markdown on stdout).

Usage: python3 bench/summarize_scale.py OUT_DIR SEED [SEED ...]
"""
import glob
import json
import os
import sys


def team(folder):
    stats = [json.load(open(f)) for f in sorted(glob.glob(os.path.join(folder, "robot_*", "stats.json")))]
    metrics = json.load(open(os.path.join(folder, "metrics.json")))
    span = max(s["last_frame_unix"] for s in stats) - min(s["first_frame_unix"] for s in stats)
    return {
        "robots": len(stats),
        "frames": min(s["frames"] for s in stats),
        "span": span,
        "user": sum(s["cpu_user_seconds"] for s in stats),
        "system": sum(s["cpu_system_seconds"] for s in stats),
        "misses": sum(s.get("consensus", {}).get("deadline_misses", 0) for s in stats),
        "trajectory": metrics["average"]["trajectory_rmse"],
        "objects": metrics["average"]["object_error"],
        "pose_nees": metrics["average"]["pose_nees"]["mean"],
        "object_nees": metrics["average"]["object_nees"]["mean"],
    }


def main():
    out, seeds = sys.argv[1], sys.argv[2:]
    print("# 50 daemons on one 2-core machine at 10 Hz\n")
    print("Written by `bench/scale_bench.sh`: `concord sim --robots 50 --frames 300 --seed S`, then "
          "`concord launch --rate 10` (lockstep or async) with `configs/sensors/sim.yaml`, over the "
          "complete graph or a simulated radio (`--range R`: consensus.radio, links only while two "
          "robots are within R metres, from the dataset's ground truth; the filters never see it). "
          "One run each, one after the other on this machine.\n")
    print("- **300 frames took**: from the first frame any robot started to the last frame any "
          "robot finished (stats.json `first_frame_unix`, `last_frame_unix`), startup left out; "
          "10 Hz means at most 33 s (the frames span 29.9 s).")
    print("- **team CPU**: user + system seconds of all 50 daemons, startup included.")
    print("- **NEES**: team means of the pose (6-D, consistent mean 6) and object (3-D, consistent "
          "mean 3) NEES from `concord eval`; objects are under-confident under consensus at many "
          "robots (issue 9).")
    print("- **links a round** and **as the replay**: from `concord replay --range R` of the same "
          "data; a lockstep radio row equals the replay when its trajectory and object figures are "
          "the replay's.\n")
    print("| seed | mode | graph | links a round | 300 frames took s | 10 Hz held | team CPU s (user + system) "
          "| deadline misses | traj RMSE m | object err m | pose / object NEES | replay traj / obj m |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for seed in seeds:
        base = os.path.join(out, f"scale-sim50-seed{seed}")
        for mode in ("lockstep", "async"):
            for rng in (0, 5, 10):
                folder = f"{base}-{mode}-range{rng}"
                if not os.path.exists(os.path.join(folder, "metrics.json")):
                    continue
                t = team(folder)
                links, reference = "1225", ""
                if rng:
                    replay = json.load(open(f"{base}-replay-range{rng}/metrics.json"))
                    links = f"{replay['run']['edges_per_round']:.0f}"
                    reference = (f"{replay['average']['trajectory_rmse']:.4f} / "
                                 f"{replay['average']['object_error']:.4f}")
                graph = f"within {rng} m" if rng else "complete"
                held = "yes" if t["frames"] == 300 and t["span"] <= 33.0 else "no"
                print(f"| {seed} | {mode} | {graph} | {links} | {t['span']:.1f} | {held} | "
                      f"{t['user']:.0f} + {t['system']:.0f} | {t['misses']} | {t['trajectory']:.4f} | "
                      f"{t['objects']:.4f} | {t['pose_nees']:.2f} / {t['object_nees']:.2f} | {reference} |")


if __name__ == "__main__":
    main()

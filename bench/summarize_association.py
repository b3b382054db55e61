#!/usr/bin/env python3
"""Summarizes bench/association_bench.sh's runs as docs/results-association.md (stdout)."""
import json
import os
import re
import statistics
import sys

out = sys.argv[1]


def load(name):
    path = os.path.join(out, name, "metrics.json")
    if not os.path.exists(path):
        return None
    with open(path) as f:
        return json.load(f)


def case(name):
    given = load(name + "-given")
    negotiated = load(name + "-negotiated")
    aligned = load(name + "-given-from-alignment")
    if not (given and negotiated and aligned):
        return None
    a = negotiated["association"]
    av, mx, run = negotiated["average"], negotiated["maximum"], negotiated["run"]
    robots = negotiated["robots"]
    moved = [r for r in robots if r.get("moved")]
    steps = run["steps"]
    row = {
        "name": name,
        "precision": a["precision"],
        "recall": a["recall"],
        "linked": a["linked_pairs"],
        "pairs": f'{a["pairs_in_one_frame"]}/{a["robot_pairs"]}',
        "all_pairs": a["pairs_in_one_frame"] == a["robot_pairs"],
        "moved": len(moved),
        "align_frame_max": max([r["aligned_at_frame"] for r in moved], default=None),
        "align_t": max([r["alignment_translation_error"] for r in moved], default=None),
        "align_r": max([r["alignment_rotation_error_degrees"] for r in moved], default=None),
        "rmse": av["trajectory_rmse_aligned"],
        "rmse_given": aligned["average"]["trajectory_rmse"],
        "team_fit": negotiated["team_aligned"]["trajectory_rmse"],
        "team_fit_given": aligned["team_aligned"]["trajectory_rmse"],
        "team_fit_object": negotiated["team_aligned"]["object_error"],
        "team_fit_object_given": aligned["team_aligned"]["object_error"],
        "alignment_nees": av.get("alignment_nees"),
        "object": av["object_error"],
        "object_given": given["average"]["object_error"],
        "pose_nees": av["pose_nees"]["mean"],
        "pose_nees_given": given["average"]["pose_nees"]["mean"],
        "object_nees": av["object_nees"]["mean"],
        "object_nees_given": given["average"]["object_nees"]["mean"],
        "time_ratio": run["total_seconds"] / given["run"]["total_seconds"],
        "negotiation_share": run["negotiation_seconds"] / run["total_seconds"],
        # The negotiation's own time over the rest of the negotiated run's time.
        "overhead": run["negotiation_seconds"] / (run["total_seconds"] - run["negotiation_seconds"]),
        "bytes": run["negotiation_bytes_per_robot_round"],
        "splits": run["links_split"],
        "conflicts": run["link_conflicts"],
        "tilted": run.get("tilted", 0),
    }
    row["rmse_ratio"] = row["rmse"] / row["rmse_given"]
    row["object_ratio"] = row["object"] / row["object_given"]
    row["team_fit_ratio"] = (row["team_fit"] / row["team_fit_given"]
                             if row["team_fit"] is not None and row["team_fit_given"] else None)
    return row


names = sorted({re.sub(r"-(given|negotiated|given-from-alignment)$", "", d)
                for d in os.listdir(out) if d.startswith(("sim-", "kitti00"))
                and os.path.isdir(os.path.join(out, d))})
rows = [r for r in (case(n) for n in names) if r]
sims = [r for r in rows if r["name"].startswith("sim-")]
kitti = [r for r in rows if r["name"].startswith("kitti00")]


def key(row):
    m = re.match(r"sim-n(\d+)-s(\d+)-f([\d.]+)", row["name"])
    return (int(m.group(1)), float(m.group(3)), int(m.group(2)))


sims.sort(key=key)


def fmt(value, digits=3):
    if value is None:
        return "-"
    return f"{value:.{digits}f}"


def median(values):
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


targets = [
    ("precision >= 99.5 %", lambda r: r["precision"] is not None and r["precision"] >= 0.995),
    ("recall >= 90 %", lambda r: r["recall"] is not None and r["recall"] >= 0.90),
    ("every robot pair aligned", lambda r: r["all_pairs"]),
    ("alignment error <= 0.5 m", lambda r: r["align_t"] is not None and r["align_t"] <= 0.5),
    ("alignment error <= 1 deg", lambda r: r["align_r"] is not None and r["align_r"] <= 1.0),
    ("traj RMSE within 10 % of given", lambda r: r["rmse_ratio"] <= 1.10),
    ("object error within 10 % of given", lambda r: r["object_ratio"] <= 1.10),
    ("negotiation time <= 20 % of the rest of the run", lambda r: r["overhead"] <= 0.20),
    ("total time <= 1.2 x the given run", lambda r: r["time_ratio"] <= 1.20),
]

print("# Negotiated association: results (issue 11)\n")
print("Measured with `bench/association_bench.sh` (summary by `bench/summarize_association.py`).")
print("Every case runs twice on the same measurements: **given** (global ids, known start poses,")
print("`concord replay --association given`) and **negotiated** (the set converted with `concord")
print("convert --private-ids --unknown-start`: each robot names its objects privately and starts at")
print("the identity of its own frame; the robots negotiate team ids and frames, docs/association.md).")
print("Sims: `concord sim`, 300 frames, 4 detector classes, objects only (no point features), with 0")
print("and 5 % false detections (phantom objects), seeds 1-5. Configs: `configs/sensors/sim.yaml` and")
print("`kitti-stereo.yaml` as they are; the association options are the in-class defaults but for")
print("the up axis each sensor config names (`start_up_axis`: `+z` for both bodies, x forward and z")
print("up; docs/association.md, \"The up axis\"). **Nothing was tuned on the")
print("reported runs**: the choices measured on this branch (dropping `confirmation_growth`; how the")
print("up axis refuses a tilted transform) used seeds 11-13.\n")
print("Definitions: precision = correct linked pairs / linked pairs (a pair of two robots' objects")
print("with one team id, judged by the truth files); recall = objects seen by both robots of a pair")
print("for at least 10 frames each that got one team id / all such objects; alignment error = error")
print("of each moved robot's T_team_own at the frame it moved (the worst robot); traj RMSE from each")
print("robot's alignment frame on (the given run evaluated over the same frames, `eval")
print("--first-frames-from`); object error of the final maps; time ratio = total replay time")
print("negotiated / given (the same process, one after the other: before alignment a negotiated")
print("robot runs separate, which is cheaper, so this ratio can be below 1); negotiation overhead =")
print("the negotiation's own time (descriptions, messages, searches, team ids, moves, and since")
print("2026-11-30 the relabelling of neighbours' marginals into the receiver's ids) / the rest of")
print("the negotiated run's time; bytes = negotiation bytes per")
print("robot and round (fixed-width encoding, `NegotiationMessage::wire_size`; marginals not")
print("included). Team fit: the team's trajectory (and objects) after one rigid transform fitted to")
print("the truth over all robots in robot 0's frame from their alignment frames on (`concord eval`,")
print("`team_aligned`): what is left once an error of the team frame as a whole is taken out; the")
print("targets are judged without it. Alignment NEES: each moved robot's T_team_own against the truth")
print("under its covariance (6-D, consistent about 6), the mean over moved robots.\n")

print("## Targets\n")
print("| target | sim cases meeting it | kitti00 |")
print("|---|---|---|")
for label, test in targets:
    met = sum(1 for r in sims if test(r))
    k = ("yes" if test(kitti[0]) else "no") if kitti else "-"
    print(f"| {label} | {met} of {len(sims)} | {k} |")
print()

print("## By team size and false-detection rate (medians over seeds)\n")
print("| robots | false det. | precision | recall | pairs aligned | align frame (max) | align err m / deg (worst robot) | alignment NEES | traj RMSE neg / given | team fit: traj neg / given | object err neg / given | team fit: objects neg / given | pose NEES neg / given | object NEES neg / given | time ratio | negotiation overhead | bytes / robot / round |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
groups = {}
for r in sims:
    n, f, _ = key(r)
    groups.setdefault((n, f), []).append(r)
for (n, f), group in sorted(groups.items()):
    m = lambda k: median([r[k] for r in group])
    aligned_all = sum(1 for r in group if r["all_pairs"])
    print(f"| {n} | {f:g} | {fmt(min(r['precision'] for r in group), 4)} (min) / {fmt(m('precision'), 4)} | "
          f"{fmt(m('recall'))} | {aligned_all} of {len(group)} runs all | {fmt(m('align_frame_max'), 0)} | "
          f"{fmt(m('align_t'), 2)} / {fmt(m('align_r'), 2)} | {fmt(m('alignment_nees'), 1)} | "
          f"{fmt(m('rmse'))} / {fmt(m('rmse_given'))} | {fmt(m('team_fit'))} / {fmt(m('team_fit_given'))} | "
          f"{fmt(m('object'))} / {fmt(m('object_given'))} | {fmt(m('team_fit_object'))} / {fmt(m('team_fit_object_given'))} | "
          f"{fmt(m('pose_nees'), 1)} / {fmt(m('pose_nees_given'), 1)} | "
          f"{fmt(m('object_nees'), 2)} / {fmt(m('object_nees_given'), 2)} | {fmt(m('time_ratio'), 2)} | "
          f"{fmt(m('overhead'), 2)} | {fmt(m('bytes'), 0)} |")
print()
if sims:
    print(f"Over all {len(sims)} sim runs: median time ratio {fmt(median([r['time_ratio'] for r in sims]), 2)}, "
          f"median negotiation overhead {fmt(median([r['overhead'] for r in sims]), 2)}, "
          f"median negotiation bytes per robot and round {fmt(median([r['bytes'] for r in sims]), 0)}, "
          f"median alignment NEES {fmt(median([r['alignment_nees'] for r in sims]), 1)} (largest "
          f"{fmt(max([r['alignment_nees'] for r in sims if r['alignment_nees'] is not None], default=None), 1)}), "
          f"median team-fit trajectory ratio negotiated / given {fmt(median([r['team_fit_ratio'] for r in sims]), 2)} "
          f"(without the fit {fmt(median([r['rmse_ratio'] for r in sims]), 2)}), "
          f"splits {sum(r['splits'] for r in sims)}, links refused as conflicts {sum(r['conflicts'] for r in sims)}, "
          f"searches refused as tilted {sum(r['tilted'] for r in sims)}.\n")

if kitti:
    r = kitti[0]
    print("## kitti00\n")
    print("| precision | recall | linked pairs | pairs aligned | robots moved | align frame | align err m / deg | traj RMSE neg / given | object err neg / given | pose NEES neg / given | object NEES neg / given | time ratio | bytes / robot / round |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    print(f"| {fmt(r['precision'], 4)} | {fmt(r['recall'])} | {r['linked']} | {r['pairs']} | {r['moved']} | "
          f"{fmt(r['align_frame_max'], 0)} | {fmt(r['align_t'], 2)} / {fmt(r['align_r'], 2)} | "
          f"{fmt(r['rmse'])} / {fmt(r['rmse_given'])} | {fmt(r['object'])} / {fmt(r['object_given'])} | "
          f"{fmt(r['pose_nees'], 1)} / {fmt(r['pose_nees_given'], 1)} | {fmt(r['object_nees'], 2)} / "
          f"{fmt(r['object_nees_given'], 2)} | {fmt(r['time_ratio'], 2)} | {fmt(r['bytes'], 0)} |")
    print()

print("## Every sim run\n")
print("| case | precision | recall | pairs | align frame | align err m / deg | alignment NEES | RMSE ratio | team-fit RMSE ratio | object ratio | time ratio |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for r in sims:
    print(f"| {r['name']} | {fmt(r['precision'], 4)} | {fmt(r['recall'])} | {r['pairs']} | {fmt(r['align_frame_max'], 0)} | "
          f"{fmt(r['align_t'], 2)} / {fmt(r['align_r'], 2)} | {fmt(r['alignment_nees'], 1)} | {fmt(r['rmse_ratio'], 2)} | "
          f"{fmt(r['team_fit_ratio'], 2)} | {fmt(r['object_ratio'], 2)} | {fmt(r['time_ratio'], 2)} |")

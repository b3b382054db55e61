"""bench/out/sim-* (concord replay runs on concord sim data) -> docs/results-sim.md and the
Fig. 4 chart descriptions bench/out/fig4-{trajectory,objects}.json (drawn by concord plot)."""
import json
import sys
from pathlib import Path

out, docs, sizes = Path(sys.argv[1]), Path(sys.argv[2]), [int(n) for n in sys.argv[3].split()]
paper = {  # Table IV of the paper: separate / consensus trajectory RMSE and object error (m)
    3: (1.318, 0.605, 1.402, 0.514),
    5: (1.452, 0.748, 1.604, 0.536),
    10: (1.464, 0.941, 1.605, 0.752),
    15: (1.385, 0.933, 1.573, 0.737),
}


def load(name):
    path = out / name / "metrics.json"
    return json.loads(path.read_text()) if path.exists() else None


def average(metrics, key):
    return metrics["average"][key]


def gain(separate, consensus):
    return f"{100.0 * (consensus - separate) / separate:+.0f} %"


print("# Concord on its own simulation: Table IV, Fig. 4 and beyond\n")
print("Written by `bench/sim_bench.sh`. The data comes from `concord sim --robots N --seed 1` with")
print("the defaults (420 frames, 210 objects, 10 point features a frame, see docs/simulator.md).")
print("The runs are `concord replay` with `configs/sensors/sim.yaml`, on the complete graph unless")
print("noted, with point features, one run at a time on the 2-core development machine. Errors are")
print("averages over robots. Consensus time is the consensus step's wall time (taking the")
print("marginals and fusing) per robot per step.\n")
print("## Table IV\n")
print("| N | run | traj RMSE m | object err m | disagreement m | consensus ms / robot / step "
      "| paper traj | paper object |")
print("|---|---|---|---|---|---|---|---|")
rows_ok = True
for n in sizes:
    separate, consensus = load(f"sim-{n}-separate"), load(f"sim-{n}-consensus")
    if not separate or not consensus:
        continue
    p = paper.get(n)
    s_t, s_o = average(separate, "trajectory_rmse"), average(separate, "object_error")
    c_t, c_o = average(consensus, "trajectory_rmse"), average(consensus, "object_error")
    print(f"| {n} | separate | {s_t:.3f} | {s_o:.3f} | {average(separate, 'disagreement'):.3f} | "
          f"| {p[0] if p else ''} | {p[2] if p else ''} |")
    print(f"| {n} | consensus | **{c_t:.3f}** ({gain(s_t, c_t)}) | **{c_o:.3f}** ({gain(s_o, c_o)}) | "
          f"{average(consensus, 'disagreement'):.3f} | "
          f"{consensus['run']['consensus_ms_per_robot_step']:.2f} | {p[1] if p else ''} | "
          f"{p[3] if p else ''} |")
    ring = load(f"sim-{n}-ring")
    if ring:
        r_t, r_o = average(ring, "trajectory_rmse"), average(ring, "object_error")
        print(f"| {n} | consensus, ring graph | {r_t:.3f} ({gain(s_t, r_t)}) | {r_o:.3f} "
              f"({gain(s_o, r_o)}) | {average(ring, 'disagreement'):.3f} | "
              f"{ring['run']['consensus_ms_per_robot_step']:.2f} | | |")
print("\nThe paper's relative improvements at 15 robots: trajectory -33 %, objects -53 %; its")
print("consensus averaging took 21-28 ms per robot per step (Python).\n")

print("## Fig. 4: link loss\n")
print("Each link of the complete graph is dropped independently per round with probability r")
print("(`concord replay --loss r`).\n")
print("| N | separate traj / object | r = 0 | r = 0.3 | r = 0.6 | r = 0.9 |")
print("|---|---|---|---|---|---|")
charts = {
    "trajectory": {"title": "Trajectory RMSE against link-loss rate (Fig. 4)",
                   "x_label": "link-loss rate r", "y_label": "trajectory RMSE [m]",
                   "x_ticks": [0, 0.3, 0.6, 0.9], "y_min": 0.0, "series": []},
    "objects": {"title": "Object error against link-loss rate",
                "x_label": "link-loss rate r", "y_label": "object error [m]",
                "x_ticks": [0, 0.3, 0.6, 0.9], "y_min": 0.0, "series": []},
}
losses = [0.0, 0.3, 0.6, 0.9]
for colour, n in enumerate([n for n in sizes if n <= 15]):
    separate = load(f"sim-{n}-separate")
    runs = [load(f"sim-{n}-consensus")] + [load(f"sim-{n}-loss{r}") for r in losses[1:]]
    if not separate or not all(runs):
        continue
    cells = [f"{average(m, 'trajectory_rmse'):.3f} / {average(m, 'object_error'):.3f}" for m in runs]
    print(f"| {n} | {average(separate, 'trajectory_rmse'):.3f} / "
          f"{average(separate, 'object_error'):.3f} | " + " | ".join(cells) + " |")
    for chart, key in [("trajectory", "trajectory_rmse"), ("objects", "object_error")]:
        charts[chart]["series"].append({"label": f"N={n} consensus", "x": losses,
                                        "y": [average(m, key) for m in runs], "colour": colour})
        charts[chart]["series"].append({"label": f"N={n} separate", "x": [0.0, 0.9],
                                        "y": [average(separate, key)] * 2, "dashed": True,
                                        "markers": False, "colour": colour})
# The acceptance checks, computed from the runs above.
beaten = []
for n in sizes:
    separate = load(f"sim-{n}-separate")
    names = [f"sim-{n}-consensus", f"sim-{n}-ring"] + [f"sim-{n}-loss{r}" for r in losses[1:]]
    for name in names:
        run = load(name)
        if separate and run:
            beaten.append(average(run, "trajectory_rmse") < average(separate, "trajectory_rmse") and
                          average(run, "object_error") < average(separate, "object_error"))
print(f"\nConsensus beats separate on trajectory RMSE and object error in {sum(beaten)} of "
      f"{len(beaten)} consensus runs (every team size, graph and loss rate above).")
s15, c15 = load("sim-15-separate"), load("sim-15-consensus")
if s15 and c15:
    print(f"At 15 robots the improvement is "
          f"{100 * (1 - average(c15, 'trajectory_rmse') / average(s15, 'trajectory_rmse')):.0f} % on "
          f"trajectories and {100 * (1 - average(c15, 'object_error') / average(s15, 'object_error')):.0f} %"
          f" on objects (paper: 33 % and 53 %), and the consensus step takes "
          f"{c15['run']['consensus_ms_per_robot_step']:.2f} ms per robot per step.")
for chart, description in charts.items():
    (out / f"fig4-{chart}.json").write_text(json.dumps(description, indent=1))
print("\n![Fig. 4, trajectory](fig4-trajectory.png)\n")
print("![Fig. 4, objects](fig4-objects.png)\n")

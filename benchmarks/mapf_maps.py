"""MAPF maps: the standard MovingAI benchmark under the NMPC with roadmap coordination.

For each map, fleet size and ``.scen`` file: the first ``K`` agents, cell ``--cell``
(0.5 m), robots of 0.3 m, v_max 1 m/s, acceleration bounds [-2, 2] m/s^2 and
[-10, 10] rad/s^2 (:func:`sqpmpc.problem.movingai.mapf_scenario`), run in one process
with the ``coordination`` plug-in (``--rules``, default ``coordination``), decentralized
(and centralized up to ``--centralized-max`` robots). Reported per run: the outcome
(every robot within 0.05 m of its goal at the end, or not), collisions between robots at
and between samples and with the map, the makespan and the sum of arrival times against
the roadmap plan's own (its steps times the cell at v_max; its steps count the turns in
place at omega_max, :func:`sqpmpc.coordination.mapf.plan_paths`), against the plan the
same planner makes when turns take no time, and against the straight-line lower bound,
the controllers' CPU time per robot-sample and the planning CPU time.

The maps are not shipped (the tests use ``tests/data/maze-12-8``); fetch them from
https://movingai.com/benchmarks/mapf.html (maps and "random" scenarios) into a folder::

    python -m benchmarks.mapf_maps --maps-dir DIR --out docs/mapf-maps.md
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from sqpmpc.control.settings import SolverSettings
from sqpmpc.coordination.mapf import plan_paths
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.movingai import mapf_scenario
from sqpmpc.rules.registry import select_rules
from sqpmpc.sim.simulation import ClosedLoopSimulation

from .maps import TOLERANCE, run_until_home

__all__ = ["main", "run_one"]

MAPS = ("warehouse-10-20-10-2-1", "room-32-32-4", "random-32-32-10", "maze-32-32-2")
V_MAX = 1.0


def run_one(map_path: Path, scen_path: Path | None, robots: int, scheme: str, cell: float,
            rules: list[str], t_end: float | None = None) -> dict:
    """One closed loop; the row of the report."""
    sc = mapf_scenario(map_path, robots, scen_path=scen_path, cell=cell, diameter=0.3,
                       v_max=V_MAX, acceleration=2.0, angular_acceleration=10.0)
    if t_end is not None:
        sc = sc.with_changes(t_end=round(t_end / sc.sample_time) * sc.sample_time)
    sim = ClosedLoopSimulation(sc, scheme, SolverSettings(rules=select_rules(rules)))
    coordination = sim.controllers[0].rule("coordination")
    plan = None if coordination is None else coordination.plan
    cpu0 = time.process_time()
    run_until_home(sim)  # stopped once every robot has stayed home for 10 s
    cpu = time.process_time() - cpu0
    record = sim.record()
    m = compute_metrics(record)
    goals = sc.reference_positions(0.0)
    err = np.hypot(*(record.states[:, :, :2] - goals[None]).transpose(2, 0, 1))
    inside = err <= TOLERANCE
    arrival = np.full(sc.n_robots, math.inf)
    for j in range(sc.n_robots):
        out = np.flatnonzero(~inside[:, j])
        arrival[j] = 0.0 if not out.size else (
            record.t[out[-1] + 1] if out[-1] < record.t.size - 1 else math.inf)
    straight = np.hypot(*(goals - sc.initial_states()[:, :2]).T) / V_MAX
    plan_makespan = math.nan if plan is None else plan.makespan_steps * cell / V_MAX
    untimed = math.nan
    if plan is not None:  # the same roadmap and starts, turns taking no time
        rm = plan.roadmap
        steps = plan_paths(rm, rm.starts[plan.robots], rm.goals[plan.robots]).shape[0] - 1
        untimed = steps * cell / V_MAX
    arrived = int(np.isfinite(arrival).sum())
    return {
        "map": map_path.stem, "scen": scen_path.stem if scen_path else "random",
        "robots": robots, "scheme": scheme, "arrived": arrived,
        "success": arrived == robots,
        "collisions": int(m["collisions"]), "between": int(m["intersample_collisions"]),
        "obstacle": int(m["obstacle_collisions"]),
        "makespan": float(arrival.max()) if arrived == robots else math.inf,
        "plan_makespan": plan_makespan,
        "untimed_plan_makespan": untimed,
        "straight_makespan": float(straight.max()),
        "flowtime": float(arrival.sum()) if arrived == robots else math.inf,
        "straight_flowtime": float(straight.sum()),
        "cpu_ms_per_robot_sample": 1e3 * cpu / (max(sim.k, 1) * sc.n_robots),
        "planning_s": math.nan if plan is None else plan.seconds,
        "stalls": 0 if coordination is None else int(
            sim.controllers[0].counters().get("coordination_stalls", 0)),
    }


def _row(r: dict) -> str:
    def ratio(a: float, b: float) -> str:
        return "-" if not (math.isfinite(a) and math.isfinite(b) and b > 0) else f"{a / b:.2f}"
    return (f"| {r['map']} | {r['scen']} | {r['robots']} | {r['scheme']} | "
            f"{r['arrived']}/{r['robots']} | {r['collisions']}/{r['between']}/{r['obstacle']} | "
            f"{ratio(r['makespan'], r['plan_makespan'])} | "
            f"{ratio(r['makespan'], r['untimed_plan_makespan'])} | "
            f"{ratio(r['makespan'], r['straight_makespan'])} | "
            f"{ratio(r['flowtime'], r['straight_flowtime'])} | "
            f"{r['cpu_ms_per_robot_sample']:.2f} | {r['planning_s']:.3f} |")


HEADER = ("| map | scen | robots | scheme | arrived | collisions robot/between/map | "
          "makespan / plan's | makespan / plan's without turns | makespan / straight | "
          "flowtime / straight | CPU ms per robot-sample | planning CPU s |\n"
          "|---|---|---|---|---|---|---|---|---|---|---|---|")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maps-dir", type=Path, required=True,
                        help="folder of MovingAI .map and -random-K.scen files")
    parser.add_argument("--maps", nargs="+", default=list(MAPS))
    parser.add_argument("--sizes", type=int, nargs="+", default=[8, 32, 64])
    parser.add_argument("--scens", type=int, default=5, help="scen files 1..S per map")
    parser.add_argument("--cell", type=float, default=0.5)
    parser.add_argument("--centralized-max", type=int, default=8)
    parser.add_argument("--rules", default="coordination")
    parser.add_argument("--t-end", type=float, default=None, help="cap on the run, s")
    parser.add_argument("--out", type=Path, default=None, help="write a Markdown report")
    args = parser.parse_args(argv)
    rows = []
    print(HEADER, flush=True)
    for name in args.maps:
        for size in args.sizes:
            for k in range(1, args.scens + 1):
                scen = args.maps_dir / f"{name}-random-{k}.scen"
                for scheme in ("decentralized", "centralized"):
                    if scheme == "centralized" and size > args.centralized_max:
                        continue
                    r = run_one(args.maps_dir / f"{name}.map", scen, size, scheme, args.cell,
                                args.rules.split(","), args.t_end)
                    rows.append(r)
                    print(_row(r), flush=True)
    ok = sum(r["success"] for r in rows)
    collided = sum(r["collisions"] + r["between"] + r["obstacle"] > 0 for r in rows)
    summary = f"{ok}/{len(rows)} runs with every robot arrived; {collided} runs with a collision"
    print(summary)
    if args.out is not None:
        args.out.write_text("# MAPF maps (MovingAI)\n\n" + (__doc__ or "") + "\n\n" + HEADER
                            + "\n" + "\n".join(map(_row, rows)) + "\n\n" + summary + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Fleets: antipodal swaps of 4 to 64 robots at one density, both schemes, in one process.

Usage (from the repository root)::

    python -m benchmarks.fleet                       # writes docs/fleet.md
    python -m benchmarks.fleet --sizes 4 8 16 --budget 60 --no-write

Every swap is :func:`sqpmpc.fleets.antipodal_swap` (radius ``3 sqrt(n/6)`` m:
the density of ``swap-6``; ``Ts = 0.5 s``, ``N = 8``; ``t_end`` three times the
straight trip at full speed), run centralized, decentralized with one collision
slot per other robot (the default), and decentralized with ``--slots``
neighbour slots (``SolverSettings.neighbour_slots``). Each run gets a wall-clock
budget (``--budget``
seconds); a run that exceeds it is stopped and reported with the sample it
reached: that is where a scheme stops fitting on this machine. Measured per
run: per-robot step time (median and p99 over every controller call; the
centralized controller is one "robot" that plans for all), the largest sample
(sum over controllers), QP iterations per QP, arrivals (robots within 0.05 m
of their goals at the last simulated sample), the smallest clearance at and
between samples, QP rescues and fallbacks. Then ``--crossings`` seeded random
crossings of ``--crossing-robots`` robots (decentralized, ``--slots`` slots).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from sqpmpc.fleets import antipodal_swap, random_crossings
from sqpmpc.metrics import compute_metrics
from sqpmpc.scenario import Scenario
from sqpmpc.settings import SolverSettings
from sqpmpc.simulation import ClosedLoopSimulation

from .compare_ipopt import machine_line
from .report import publish
from .rows import GOAL_TOLERANCE

__all__ = ["main", "run_swap"]

DOC_PATH = Path(__file__).resolve().parent.parent / "docs" / "fleet.md"
SIZES = (4, 8, 16, 32, 64)


def run_swap(n: int, scheme: str, budget: float, slots: int | None = None,
             scenario: Scenario | None = None) -> dict[str, object]:
    """One antipodal swap of ``n`` robots (or ``scenario``), stopped after ``budget`` s."""
    sc = antipodal_swap(n) if scenario is None else scenario
    sim = ClosedLoopSimulation(sc, scheme, SolverSettings(neighbour_slots=slots))
    t0 = time.perf_counter()
    while sim.k < sc.steps and time.perf_counter() - t0 < budget:
        sim.step()
    wall = time.perf_counter() - t0
    record = sim.record()
    m = compute_metrics(record)
    steps = record.solve_times  # (K, controllers)
    per_robot = steps.ravel()
    goals = sc.reference_positions(record.t[-1])
    final = record.states[-1, :, :2]
    arrived = int(np.count_nonzero(np.hypot(*(final - goals).T) <= GOAL_TOLERANCE))
    qps = int(sim.sqp_iterations[:sim.k].sum())
    return {
        "n": n, "scheme": scheme, "steps": sim.k, "of": sc.steps, "wall": wall,
        "median_ms": float(np.median(per_robot) * 1e3) if per_robot.size else float("nan"),
        "p99_ms": float(np.percentile(per_robot, 99) * 1e3) if per_robot.size else float("nan"),
        "sample_max_ms": float(steps.sum(axis=1).max() * 1e3) if steps.size else float("nan"),
        "qp_iterations": sim.qp_iterations / max(qps, 1), "arrived": arrived,
        "clearance": m["min_clearance"], "between": m["intersample_min_clearance"],
        "collisions": m["collisions"] + m["intersample_collisions"],
        "rescues": m["counters"].get("qp_rescues", 0), "fallbacks": m["solver_failures"],
    }


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.fleet",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES))
    parser.add_argument("--budget", type=float, default=120.0,
                        help="wall-clock seconds per run before it is stopped (default 120)")
    parser.add_argument("--slots", type=int, default=8,
                        help="neighbour slots of the third configuration (default 8)")
    parser.add_argument("--crossings", type=int, default=10,
                        help="seeds of random crossings to run (decentralized, --slots)")
    parser.add_argument("--crossing-robots", type=int, default=32)
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    head = ("| robots | scheme | samples run | per-robot step median ms | p99 ms | "
            "largest sample ms | QP iterations per QP | arrived | min clearance m "
            "(between samples) | collisions | rescues | fallbacks |")
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    configs = [("centralized", None), ("decentralized", None),
               ("decentralized", args.slots)]
    for n in args.sizes:
        for scheme, slots in configs:
            r = run_swap(n, scheme, args.budget, slots)
            stopped = "" if r["steps"] == r["of"] else f" (stopped after {r['wall']:.0f} s)"
            label = scheme if slots is None else f"{scheme}, {slots} neighbour slots"
            lines.append(
                f"| {n} | {label} | {r['steps']} of {r['of']}{stopped} | "
                f"{r['median_ms']:.2f} | {r['p99_ms']:.2f} | {r['sample_max_ms']:.1f} | "
                f"{r['qp_iterations']:.0f} | {r['arrived']}/{n} | {r['clearance']:.4f} "
                f"({r['between']:.4f}) | {r['collisions']} | {r['rescues']} | "
                f"{r['fallbacks']} |")
            print(lines[-1], file=sys.stderr)
    crossings = [head.replace("| robots |", "| seed |"), lines[1]]
    for seed in range(args.crossings):
        sc = random_crossings(args.crossing_robots, seed)
        r = run_swap(sc.n_robots, "decentralized", args.budget, args.slots, sc)
        stopped = "" if r["steps"] == r["of"] else f" (stopped after {r['wall']:.0f} s)"
        crossings.append(
            f"| {seed} | decentralized, {args.slots} neighbour slots | {r['steps']} of "
            f"{r['of']}{stopped} | {r['median_ms']:.2f} | {r['p99_ms']:.2f} | "
            f"{r['sample_max_ms']:.1f} | {r['qp_iterations']:.0f} | "
            f"{r['arrived']}/{sc.n_robots} | {r['clearance']:.4f} ({r['between']:.4f}) | "
            f"{r['collisions']} | {r['rescues']} | {r['fallbacks']} |")
        print(crossings[-1], file=sys.stderr)
    crossing_section = "" if not args.crossings else f"""
## Random crossings of {args.crossing_robots} robots (`sqpmpc generate crossings`)

{chr(10).join(crossings)}
"""
    report = f"""# Fleets: antipodal swaps of {args.sizes[0]} to {args.sizes[-1]} robots

Reproduce: `python -m benchmarks.fleet --sizes {' '.join(map(str, args.sizes))} --budget
{args.budget:g} --slots {args.slots}` (module docstring: what is measured). Swaps at the
density of `swap-6` (radius 3 sqrt(n/6) m), Ts 0.5 s, N 8, t_end three times the straight
trip; every run gets {args.budget:g} s of wall clock and is stopped there ("samples run").

{machine_line(t0)}

{chr(10).join(lines)}
{crossing_section}"""
    publish(report, None if args.no_write else DOC_PATH)
    return 0


if __name__ == "__main__":
    sys.exit(main())

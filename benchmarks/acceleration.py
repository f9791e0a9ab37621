"""Robots with acceleration limits: the second robot model on the built-in scenarios.

Every built-in scenario of up to 6 robots gets ``[bounds] acceleration = [-1, 1]`` and
``angular_acceleration = [-3, 3]`` (CONTRACT 1c), which makes the controllers plan with
the unicycle with velocity states and acceleration inputs
(:class:`sqpmpc.models.acceleration.AccelerationUnicycle`) and the plant change the
velocities within the limits. Both schemes run on the Euler plant and on the exact plant
(the controller predicts with Euler, the margins cover the difference:
:func:`sqpmpc.problem.plant.acceleration_path_deviation`). Reported per run: collisions
at and between samples (along the plant's true paths, velocities ramping), obstacle
collisions, input-bound violations, the largest acceleration the plant applied, the
fallbacks, the largest final error and whether every robot arrived (within 0.05 m of a
fixed goal; for paper-s2's moving references, within the tracking band of the run of the
paper's robot: the largest tracking error over its last tenth), and the closed-loop cost
against the paper's robot (no limits) on the same scheme.

Reproduce (writes ``docs/acceleration-limits.md``)::

    python -m benchmarks.acceleration
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.plant import PlantSpec
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import builtin_scenario_names, load_scenario
from sqpmpc.sim.simulation import ClosedLoopSimulation

from .compare_ipopt import machine_line
from .report import publish
from .rows import GOAL_TOLERANCE

__all__ = ["run_case", "with_limits"]

DOC_PATH = Path(__file__).resolve().parent.parent / "docs" / "acceleration-limits.md"
ACCELERATION = (-1.0, 1.0)
ANGULAR_ACCELERATION = (-3.0, 3.0)
MAX_ROBOTS = 6


def with_limits(scenario: Scenario, plant: str) -> Scenario:
    """``scenario`` with the benchmark's acceleration limits and plant model."""
    bounds = replace(scenario.bounds, acceleration=ACCELERATION,
                     angular_acceleration=ANGULAR_ACCELERATION)
    return scenario.with_changes(bounds=bounds, plant=PlantSpec(plant))


def _band(scenario: Scenario, record: Any) -> float:
    """Arrival tolerance: 0.05 m for fixed goals, the paper robot's tracking band else."""
    t_end = scenario.steps * scenario.sample_time
    moving = not np.allclose(scenario.reference_positions(t_end),
                             scenario.reference_positions(t_end - scenario.sample_time))
    if not moving:
        return GOAL_TOLERANCE
    err = np.linalg.norm(record.positions - record.references(), axis=-1)
    return max(GOAL_TOLERANCE, float(err[-max(1, err.shape[0] // 10):].max()))


def run_case(name: str, scheme: str, plant: str, paper: tuple[float, float]) -> dict:
    """One run with acceleration limits; ``paper`` = (cost, arrival band) of the paper robot."""
    scenario = with_limits(load_scenario(name), plant)
    t0 = time.perf_counter()
    sim = ClosedLoopSimulation(scenario, scheme)
    record = sim.run()
    m = compute_metrics(record)
    reached = record.plant_inputs
    change = np.diff(np.concatenate((np.zeros((1,) + reached.shape[1:]), reached)), axis=0)
    accel = np.abs(change).max(axis=(0, 1)) / scenario.sample_time
    counters = sim.counters()
    cost, band = paper
    return {
        "scenario": name, "scheme": scheme, "plant": plant,
        "collisions": int(m["collisions"]), "between": int(m["intersample_collisions"]),
        "obstacle": int(m.get("obstacle_collisions") or 0),
        "violations": int(m["input_bound_violations"]),
        "a": float(accel[0]), "alpha": float(accel[1]),
        "fallbacks": int(m["solver_failures"]), "brakes": int(counters["brake_fallbacks"]),
        "final": float(m["max_final_position_error"]),
        "arrived": bool(m["max_final_position_error"] <= band), "band": band,
        "cost": float(m["closed_loop_cost"]), "ratio": float(m["closed_loop_cost"]) / cost,
        "wall": time.perf_counter() - t0,
    }


def report(rows: list[dict], started: float) -> str:
    """The Markdown report."""
    lines = [
        "# Robots with acceleration limits",
        "",
        "`python -m benchmarks.acceleration`: every built-in scenario of up to "
        f"{MAX_ROBOTS} robots with `acceleration = [{ACCELERATION[0]:g}, {ACCELERATION[1]:g}]`"
        f" m/s^2 and `angular_acceleration = [{ANGULAR_ACCELERATION[0]:g}, "
        f"{ANGULAR_ACCELERATION[1]:g}]` rad/s^2 (the controllers plan with velocity states "
        "and acceleration inputs, the plant changes the velocities within the limits), both "
        "schemes, Euler controller on the Euler and on the exact plant. Collisions are "
        "counted at the samples and between them along the true paths (velocities "
        "ramping); `a`, `alpha` are the largest accelerations the plant applied; arrival: "
        "final error within 0.05 m of a fixed goal, or, for moving references (paper-s2), "
        "within the tracking band of the paper robot's run (largest error over its last "
        "tenth); cost: the closed-loop cost (the paper's objective on the applied "
        "velocities) over that of the paper's robot, same scheme.",
        "",
        "| scenario | scheme | plant | collisions (at / between) | obstacle | bound "
        "violations | max a, alpha | fallbacks (brakes) | max final error, m | arrived | "
        "cost / paper robot |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scenario']} | {r['scheme']} | {r['plant']} | {r['collisions']} / "
            f"{r['between']} | {r['obstacle']} | {r['violations']} | {r['a']:.2f}, "
            f"{r['alpha']:.2f} | {r['fallbacks']} ({r['brakes']}) | {r['final']:.3f} | "
            f"{'yes' if r['arrived'] else 'no'} (band {r['band']:.3f}) | {r['ratio']:.2f} |")
    safe = sum(r["collisions"] + r["between"] + r["obstacle"] + r["violations"] for r in rows)
    arrived = sum(r["arrived"] for r in rows)
    lines += ["", f"{len(rows)} runs: {safe} collisions or bound violations in all; "
              f"{arrived} of {len(rows)} with every robot arrived.", "",
              machine_line(started), ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    """Run the sweep and write the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DOC_PATH)
    parser.add_argument("--scenarios", nargs="*", default=None)
    args = parser.parse_args(argv)
    started = time.perf_counter()
    names = args.scenarios or [n for n in builtin_scenario_names()
                               if load_scenario(n).n_robots <= MAX_ROBOTS]
    rows = []
    for name in names:
        for scheme in ("centralized", "decentralized"):
            base = load_scenario(name)
            ideal = ClosedLoopSimulation(base, scheme).run()
            paper = (float(compute_metrics(ideal)["closed_loop_cost"]), _band(base, ideal))
            for plant in ("euler", "exact"):
                rows.append(run_case(name, scheme, plant, paper))
                print(rows[-1], flush=True)
    publish(report(rows, started), args.out)


if __name__ == "__main__":
    main()

"""Real plants: every built-in scenario on an exact-unicycle plant, input noise, obstacles.

For every built-in scenario and both schemes it runs

- the **matching model** (the default: Euler controller, Euler plant), the
  cost reference;
- an **exact plant under the default Euler controller**, whose rows keep the
  margin derived from the path-deviation bound (:mod:`sqpmpc.problem.plant`:
  :math:`v_{\\max}\\omega_{\\max}T_s^2` plus the 1 mm solver margin);
- an **exact plant under the exact controller** (the arcs' chord bound gives
  the same margin);

and reports collisions at and between samples (along the plant's true arcs),
robot-obstacle collisions, arrivals (final position within 0.05 m of the
reference), fallbacks and the closed-loop cost against the matching-model run.
Then moving obstacles: one robot of ``head-on`` against one obstacle (0.4 m)
that passes the middle of its straight path at t = 5 s, from 8 directions at
0.1, 0.3 and 0.45 m/s (t_end 45 s). Then input noise of 5 % of the bounds
(standard deviations 0.05 (v_max, omega_max), Gaussian truncated at 4 sigma) on
the exact plant, 5 seeds, on paper-s2 and swap-6, both schemes.

Reproduce (writes ``docs/real-plants.md``)::

    python -m benchmarks.real_plants
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sqpmpc.control.settings import SolverSettings
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.obstacles import Obstacle
from sqpmpc.problem.plant import PlantSpec, model_margin
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import builtin_scenario_names, load_scenario
from sqpmpc.sim.simulation import simulate

from .compare_ipopt import machine_line
from .report import publish
from .rows import GOAL_TOLERANCE

__all__ = ["run_case"]

DOC_PATH = Path(__file__).resolve().parent.parent / "docs" / "real-plants.md"
NOISE_FRACTION = 0.05
NOISE_SCENARIOS = ("paper-s2", "swap-6")
NOISE_SEEDS = (1, 2, 3, 4, 5)
CASES = (  # label, controller discretization, plant model
    ("matching model (Euler / Euler)", "euler", "euler"),
    ("exact plant, Euler controller", "euler", "exact"),
    ("exact plant, exact controller", "exact", "exact"),
)


def run_case(scenario: Scenario, scheme: str, discretization: str, plant: PlantSpec
             ) -> dict[str, Any]:
    """One closed loop; its metrics plus ``arrived``, ``margin`` and ``wall_s``."""
    scenario = scenario.with_changes(plant=plant)
    started = time.perf_counter()
    record = simulate(scenario, scheme, SolverSettings(discretization=discretization))
    m = compute_metrics(record)
    m["wall_s"] = time.perf_counter() - started
    errors = m["final_position_error"].values()
    m["arrived"] = sum(e is not None and e <= GOAL_TOLERANCE for e in errors)
    m["margin"] = m["collision_margin"] + model_margin(
        scenario.bounds.input_lower(), scenario.bounds.input_upper(), scenario.sample_time,
        discretization, plant)
    return m


def _clearance(m: dict[str, Any]) -> str:
    values = [v for v in (m["min_clearance"], m["intersample_min_clearance"]) if v is not None]
    return f"{min(values):.4f}" if values else "-"


def _obstacles(m: dict[str, Any]) -> str:
    if m["min_obstacle_clearance"] is None:
        return "-"
    return f"{m['obstacle_collisions']} ({m['min_obstacle_clearance']:.4f})"


def _row(name: str, scheme: str, label: str, m: dict[str, Any], ref: dict[str, Any],
         n: int) -> str:
    ratio = m["closed_loop_cost"] / ref["closed_loop_cost"] if ref["closed_loop_cost"] else 1
    return (f"| {name} | {scheme} | {label} | {m['margin']:.4f} | "
            f"{m['collisions']} / {m['intersample_collisions']} | {_clearance(m)} | "
            f"{_obstacles(m)} | {m['arrived']}/{n} | {m['solver_failures']} | "
            f"{m['closed_loop_cost']:.4g} | {ratio:.3f} | {m['wall_s']:.1f} |")


def _moving_obstacles(failures: list[str]) -> list[str]:
    """The moving-obstacle sweep's table."""
    base = load_scenario("head-on")
    robot = base.robots[0]
    middle = 0.5 * (np.asarray(robot.initial_state[:2]) + robot.reference.position(0.0))
    lines = ["", "## Moving obstacles: one robot, one obstacle across its path from 8 "
             "directions", "",
             "| scheme | obstacle speed m/s | runs | 0 collisions | arrived | "
             "min obstacle clearance m | fallbacks |", "|---|---|---|---|---|---|---|"]
    for scheme in ("centralized", "decentralized"):
        for speed in (0.1, 0.3, 0.45):
            safe = arrived = fallbacks = 0
            worst = np.inf
            for angle in np.linspace(0.0, 2 * np.pi, 8, endpoint=False):
                w = speed * np.array([np.cos(angle), np.sin(angle)])
                start = middle - 5.0 * w
                obstacle = Obstacle((float(start[0]), float(start[1])), 0.4,
                                    (float(w[0]), float(w[1])))
                sc = base.with_changes(robots=(robot,), obstacles=(obstacle,), t_end=45.0)
                m = compute_metrics(simulate(sc, scheme))
                safe += m["obstacle_collisions"] == 0
                arrived += m["max_final_position_error"] <= GOAL_TOLERANCE
                fallbacks += m["solver_failures"]
                worst = min(worst, m["min_obstacle_clearance"])
                if m["obstacle_collisions"]:
                    failures.append(f"moving obstacle {scheme} {speed} m/s {angle:.2f} rad")
            lines.append(f"| {scheme} | {speed} | 8 | {safe} | {arrived} | {worst:.4f} | "
                         f"{fallbacks} |")
            print(lines[-1], file=sys.stderr, flush=True)
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark and write the report (``--no-write``: print only)."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.real_plants")
    parser.add_argument("--scenarios", nargs="*", default=None,
                        help="built-in scenarios (default: all)")
    parser.add_argument("--no-write", action="store_true")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    names = args.scenarios or builtin_scenario_names()
    lines = [
        "# Real plants: an exact-unicycle plant, input noise and obstacles",
        "",
        "Generated by `python -m benchmarks.real_plants` (the module docstring says what "
        "runs). *margin*: what the rows add to every required distance between two robots, "
        "m (1 mm solver margin + the derived model margin, `sqpmpc/problem/plant.py`); "
        "*collisions*: "
        "(sample, pair) at / between samples, between samples along the plant's true arcs; "
        "*min clearance*: at and between samples, m; *obstacles*: robot-obstacle collisions "
        "(min clearance); *arrived*: final position within 0.05 m of the reference; "
        "*fallbacks*: samples that applied a fallback input; *cost ratio*: against the "
        "matching-model run of the same scheme.",
        "",
        "| scenario | scheme | plant / controller | margin m | collisions at / between | "
        "min clearance m | obstacles | arrived | fallbacks | cost | cost ratio | wall s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    failures = []
    for name in names:
        scenario = load_scenario(name)
        for scheme in ("centralized", "decentralized"):
            ref = None
            for label, discretization, plant in CASES:
                m = run_case(scenario, scheme, discretization, PlantSpec(plant))
                ref = ref or m
                lines.append(_row(name, scheme, label, m, ref, scenario.n_robots))
                print(lines[-1], file=sys.stderr, flush=True)
                if (m["collisions"] or m["intersample_collisions"] or m["obstacle_collisions"]
                        or m["arrived"] < scenario.n_robots):
                    failures.append(f"{name} {scheme} {label}")
    lines += _moving_obstacles(failures) if not args.scenarios else []
    lines += [
        "",
        f"## Input noise: {NOISE_FRACTION:.0%} of the bounds on the exact plant, Euler "
        "controller, seeds " + ", ".join(map(str, NOISE_SEEDS)),
        "",
        "| scenario | scheme | seed | margin m | collisions at / between | min clearance m | "
        "arrived | fallbacks | largest applied noise (v, omega) | cost | cost ratio | wall s |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name in NOISE_SCENARIOS:
        if args.scenarios and name not in args.scenarios:
            continue
        scenario = load_scenario(name)
        sigma = (NOISE_FRACTION * scenario.bounds.v[1], NOISE_FRACTION * scenario.bounds.omega[1])
        for scheme in ("centralized", "decentralized"):
            ref = run_case(scenario, scheme, "euler", PlantSpec("euler"))
            for seed in NOISE_SEEDS:
                m = run_case(scenario, scheme, "euler", PlantSpec("exact", sigma, seed))
                noise = m["plant"].get("applied_noise_max", [0.0, 0.0])
                ratio = m["closed_loop_cost"] / ref["closed_loop_cost"]
                lines.append(
                    f"| {name} | {scheme} | {seed} | {m['margin']:.4f} | {m['collisions']} / "
                    f"{m['intersample_collisions']} | {_clearance(m)} | "
                    f"{m['arrived']}/{scenario.n_robots} | {m['solver_failures']} | "
                    f"{noise[0]:.3f}, {noise[1]:.3f} | {m['closed_loop_cost']:.4g} | "
                    f"{ratio:.3f} | {m['wall_s']:.1f} |")
                print(lines[-1], file=sys.stderr, flush=True)
                if m["collisions"] or m["intersample_collisions"]:
                    failures.append(f"{name} {scheme} noise seed {seed}")
    lines += ["", "Runs with a collision or a robot that did not arrive: "
              + (", ".join(failures) if failures else "none") + ".", "",
              machine_line(started), ""]
    publish("\n".join(lines), None if args.no_write else DOC_PATH)
    return 0


if __name__ == "__main__":
    sys.exit(main())

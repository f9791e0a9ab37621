"""Random scenarios: is every closed loop safe, whatever the fleet, timing and references?

The built-in scenarios are a handful of hand-made encounters. This campaign
draws ``--count`` scenarios from seeded random numbers and runs each with both
schemes (the decentralized run loses 20 % of its plan messages in one run of
three): 2 to 6 robots of diameters 0.2-0.5 m at random non-overlapping
positions and headings in a 4 m square, goals at least 0.6 m apart, point or
waypoint references (the waypoints pass through the centre at 5 s),
``Ts`` in {0.1, 0.2, 0.5, 1.0} s, ``N`` in 5..15 and ``t_end`` three times
the longest straight trip at full speed plus 10 s.

It prints one line per run and a summary: safety violations (collisions at or
between samples, input bound violations; all must be 0), fallbacks, and how
many runs brought every robot within 0.05 m of its goal, by horizon length
(short horizons do not see past a neighbour: see the README's liveness
notes). Nothing is asserted; ``tests/test_random_scenarios.py`` runs a few
seeds and asserts safety.

Reproduce (writes ``docs/random-scenarios.md``)::

    python -m benchmarks.random_scenarios
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sqpmpc.control.settings import SolverSettings
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import parse_scenario
from sqpmpc.sim.simulation import SimulationOptions, simulate

from .compare_ipopt import machine_info
from .report import publish
from .rows import GOAL_TOLERANCE

__all__ = ["random_scenario", "run_random", "safety_violations"]

DOC_PATH = Path(__file__).resolve().parent.parent / "docs" / "random-scenarios.md"
V_MAX = 0.6


def _spread(rng: np.random.Generator, count: int, spacing: np.ndarray | float) -> list[np.ndarray]:
    """``count`` points in the 4 m square, pairwise farther apart than ``spacing[i, j]``."""
    spacing = np.broadcast_to(np.asarray(spacing, dtype=float), (count, count))
    points: list[np.ndarray] = []
    while len(points) < count:
        p = rng.uniform(-2.0, 2.0, 2)
        j = len(points)
        if all(np.hypot(*(p - q)) > spacing[j, i] for i, q in enumerate(points)):
            points.append(p)
    return points


def random_scenario(seed: int) -> Scenario:
    """The random scenario number ``seed`` (see the module notes)."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 7))
    sample_time = float(rng.choice([0.1, 0.2, 0.5, 1.0]))
    horizon = int(rng.integers(5, 16))
    diameters = rng.uniform(0.2, 0.5, n)
    starts = _spread(rng, n, 0.5 * (diameters[:, None] + diameters[None, :]) + 0.05)
    goals = _spread(rng, n, 0.6)
    waypoints = bool(rng.integers(0, 2))
    robots = []
    for j in range(n):
        start, goal = [float(v) for v in starts[j]], [float(v) for v in goals[j]]
        reference = ({"type": "waypoints", "times": [0.0, 5.0, 10.0],
                      "points": [start, [0.0, 0.0], goal]} if waypoints
                     else {"type": "point", "position": goal})
        robots.append({"id": j + 1, "diameter": float(diameters[j]), "reference": reference,
                       "initial_state": [*start, float(rng.uniform(-math.pi, math.pi))]})
    trip = max(float(np.hypot(*(g - s))) for g, s in zip(goals, starts, strict=True))
    return parse_scenario({
        "name": f"random-{seed}", "t_end": float(math.ceil(3.0 * trip / V_MAX + 10.0)),
        "sample_time": sample_time, "horizon": horizon,
        "weights": {"Q": [1.0, 1.0], "R": [0.5, 0.5]},
        "bounds": {"v": [-V_MAX, V_MAX], "omega": [-math.pi / 4, math.pi / 4]},
        "robots": robots,
    }, source=f"<random {seed}>")


def safety_violations(metrics: dict) -> int:
    """Collisions at and between samples plus input bound violations of one run."""
    return (int(metrics["collisions"]) + int(metrics["intersample_collisions"])
            + int(metrics["input_bound_violations"]))


def run_random(seed: int, scheme: str, t_end: float | None = None,
               settings: SolverSettings | None = None) -> dict:
    """Metrics of one closed loop of random scenario ``seed`` (``t_end`` overrides)."""
    scenario = random_scenario(seed)
    if t_end is not None:
        scenario = scenario.with_changes(t_end=t_end)
    drop = 0.2 if scheme == "decentralized" and seed % 3 == 0 else 0.0
    options = SimulationOptions(message_drop_probability=drop, seed=seed)
    metrics = compute_metrics(simulate(scenario, scheme, settings, options=options))
    metrics["message_drop_probability"] = drop
    return metrics


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.random_scenarios",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=60, help="random scenarios")
    parser.add_argument("--first", type=int, default=0, help="first seed")
    parser.add_argument("--no-write", action="store_true", help="print only")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    lines = ["| seed | scheme | robots | Ts s | N | horizon s | message loss | safety "
             "violations | min clearance m | fallbacks | max final error m |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    violations = runs = 0
    arrived: dict[bool, list[int]] = {True: [0, 0], False: [0, 0]}  # long horizon?
    for seed in range(args.first, args.first + args.count):
        scenario = random_scenario(seed)
        horizon_s = scenario.horizon * scenario.sample_time
        for scheme in ("centralized", "decentralized"):
            m = run_random(seed, scheme)
            bad = safety_violations(m)
            violations += bad
            runs += 1
            ok = m["max_final_position_error"] <= GOAL_TOLERANCE
            arrived[horizon_s >= 2.0][0] += ok
            arrived[horizon_s >= 2.0][1] += 1
            clearance = m["min_clearance"]
            line = (f"| {seed} | {scheme} | {scenario.n_robots} | {scenario.sample_time:g} | "
                    f"{scenario.horizon} | {horizon_s:.1f} | {m['message_drop_probability']:g} | "
                    f"{bad} | {'-' if clearance is None else f'{clearance:.4f}'} | "
                    f"{m['solver_failures']} | {m['max_final_position_error']:.3f} |")
            print(line, file=sys.stderr, flush=True)
            lines.append(line)
    info = machine_info()
    (long_ok, long_n), (short_ok, short_n) = arrived[True], arrived[False]
    report = f"""# Random scenarios

Reproduce: `python -m benchmarks.random_scenarios --count {args.count} --first {args.first}`

{__doc__.split(chr(10) + chr(10))[1]}

Machine: {info['CPU']}, {info['cores']}, Python {info['Python']}, OSQP {info['OSQP']};
{info['date']}; wall time {time.perf_counter() - t0:.0f} s.

## Summary

- runs: {runs} ({args.count} scenarios x 2 schemes)
- safety violations (collisions at or between samples, input bound violations): **{violations}**
- every robot within {GOAL_TOLERANCE} m of its goal at `t_end`: {long_ok} of {long_n} runs with a
  horizon of at least 2 s, {short_ok} of {short_n} runs with a shorter one. Random goals and
  starts make jams that a short horizon does not see coming; arrival here is a
  measurement, not a guarantee.

## Runs

{chr(10).join(lines)}
"""
    publish(report, None if args.no_write else DOC_PATH)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Check a simulated ROS 2 fleet's true poses: collisions at and between samples, arrival.

``python -m services.ros2.check DIR --scenario S [--tolerance M] [--dt S]``
reads ``DIR/poses.json`` (written by :mod:`services.ros2.simfleet`: every
command segment of every robot, exact unicycle arcs in between), evaluates
every robot's pose on a grid of ``--dt`` s over the whole run and measures,
per pair, the distance minus the required one (the sum of the radii). Two
robots move at most ``2 v_max`` apart, so between grid points the distance
changes by at most ``v_max dt``: the *certified* clearance (grid clearance
minus that) bounds the clearance at every instant. Arrival: the final
distance of each robot to its reference at the end of the run. For each robot
whose odometry was stopped: the time from the stop to the first zero command
and whether it moved again. Writes ``DIR/check.json``; exit status 0 when
there is no collision and every robot arrived, 1 otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from sqpmpc.cli.options import Parser, positive_float
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.io.atomic import atomic_path
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import load_scenario

__all__ = ["ARRIVAL_STEP", "FleetCheck", "check_fleet", "main", "poses_at"]

ARRIVAL_STEP = 0.05
"""Grid of :attr:`FleetCheck.arrival_times`, s."""


def poses_at(segments: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Poses ``(T, 3)`` at ``times`` from segments ``(S, 6)`` ``[t, x, y, psi, v, omega]``
    (exact arcs; before the first segment: its state)."""
    seg = segments[np.clip(np.searchsorted(segments[:, 0], times, side="right") - 1, 0,
                           len(segments) - 1)]
    dt = np.maximum(times - seg[:, 0], 0.0)
    x, y, psi, v, w = seg[:, 1], seg[:, 2], seg[:, 3], seg[:, 4], seg[:, 5]
    turn = w * dt
    straight = np.abs(turn) < 1e-9
    safe_w = np.where(straight, 1.0, w)
    r = v / safe_w
    mid = psi + 0.5 * turn
    xs = np.where(straight, x + v * dt * np.cos(mid), x + r * (np.sin(psi + turn) - np.sin(psi)))
    ys = np.where(straight, y + v * dt * np.sin(mid), y - r * (np.cos(psi + turn) - np.cos(psi)))
    return np.stack((xs, ys, psi + turn), axis=-1)


@dataclass(frozen=True)
class FleetCheck:
    """What :func:`check_fleet` measured (distances in m, times in s)."""

    robots: int
    duration: float
    grid_step: float
    collisions: int
    """Pairs whose grid clearance went below zero."""
    min_clearance: float
    """Smallest distance minus required distance over pairs and grid times."""
    certified_clearance: float
    """``min_clearance - v_max * grid_step``: a lower bound at every instant."""
    closest_pair: tuple[int, int]
    final_errors: dict[str, float]
    """Per robot: final distance to its reference."""
    arrived: int
    tolerance: float
    commands: int
    stop_to_zero: dict[str, float | None]
    """Per robot whose odometry stopped: seconds from the stop to its first zero command
    (under acceleration limits: until its velocities are zero, the log holds velocities)."""
    moved_after_zero: dict[str, bool]
    """Per such robot: whether a non-zero command came after that zero."""
    command_timeouts: dict[str, int] = field(default_factory=dict)
    """Per robot: times its base stopped on its command timeout (no command for the
    simulated fleet's ``--cmd-timeout``) while its command was not zero."""
    timed_out: dict[str, float] = field(default_factory=dict)
    """Per robot: seconds it stood on a command timeout."""
    lagged_timeouts: dict[str, int] = field(default_factory=dict)
    """Per robot: timeouts the simulated fleet judged on its own lag and took back (the next
    command had been sent within the timeout of the one before)."""
    arrival_times: dict[str, float | None] = field(default_factory=dict)
    """Per robot: the scenario time (s from the epoch) from which it stayed within
    ``tolerance`` of its reference to the end, on a grid of :data:`ARRIVAL_STEP`
    (``None``: not within at the end)."""

    @property
    def ok(self) -> bool:
        """No collision and every robot arrived."""
        return self.collisions == 0 and self.arrived == self.robots


def check_fleet(data: dict, scenario: Scenario, tolerance: float = 0.05,
                dt: float = 0.002, start: float | None = None) -> FleetCheck:
    """Measure a fleet's log (the content of ``poses.json``) against ``scenario``.

    ``start``: the first wall time checked (default the log's start).
    """
    ids = sorted(data["robots"], key=int)
    if not ids:
        raise ProblemError("poses.json holds no robot")
    t0 = float(data["start"] if start is None else start)
    t1 = float(data["end"])
    times = np.arange(t0, t1, dt)
    if times.size == 0:
        raise ProblemError("poses.json covers no time")
    segs = {rid: np.asarray(data["robots"][rid]["segments"], dtype=float) for rid in ids}
    pos = np.stack([poses_at(segs[rid], times)[:, :2] for rid in ids])  # (n, T, 2)
    radius = np.array([0.5 * float(data["robots"][rid]["diameter"]) for rid in ids])
    v_max = float(np.max(np.abs(np.concatenate((scenario.bounds.input_lower()[:1],
                                                 scenario.bounds.input_upper()[:1])))))
    collisions, worst, pair = 0, math.inf, (int(ids[0]), int(ids[0]))
    for a in range(len(ids)):
        for b in range(a + 1, len(ids)):
            gap = np.hypot(*(pos[a] - pos[b]).T) - radius[a] - radius[b]
            low = float(gap.min())
            collisions += int(low < 0.0)
            if low < worst:
                worst, pair = low, (int(ids[a]), int(ids[b]))
    final_t = t1 - float(data["epoch"])
    ref = scenario.reference_positions(min(final_t, scenario.t_end))
    errors = {}
    for k, rid in enumerate(ids):
        j = scenario.index_of(int(rid))
        errors[rid] = float(np.hypot(*(pos[k, -1] - ref[j])))
    epoch = float(data["epoch"])
    every = max(1, round(ARRIVAL_STEP / dt))
    grid = times[::every] - epoch
    refs = np.stack([scenario.reference_positions(min(max(t, 0.0), scenario.t_end))
                     for t in grid])  # (G, n, 2)
    arrival: dict[str, float | None] = {}
    for k, rid in enumerate(ids):
        err = np.hypot(*(pos[k, ::every] - refs[:, scenario.index_of(int(rid))]).T)
        out = np.flatnonzero(err > tolerance)
        arrival[rid] = (float(grid[0]) if out.size == 0 else
                        None if out[-1] + 1 >= grid.size else float(grid[out[-1] + 1]))
    stop_to_zero: dict[str, float | None] = {}
    moved: dict[str, bool] = {}
    for rid, t_stop in data.get("odom_stop", {}).items():
        when = float(data["epoch"]) + float(t_stop)
        after = segs[rid][1:][segs[rid][1:, 0] >= when]
        zero = np.flatnonzero((after[:, 4] == 0.0) & (after[:, 5] == 0.0))
        stop_to_zero[rid] = None if zero.size == 0 else float(after[zero[0], 0] - when)
        moved[rid] = bool(zero.size and (np.abs(after[zero[0]:, 4:6]) > 0.0).any())
    return FleetCheck(
        robots=len(ids), duration=t1 - t0, grid_step=dt, collisions=collisions,
        min_clearance=worst, certified_clearance=worst - v_max * dt, closest_pair=pair,
        final_errors=errors, arrived=sum(e <= tolerance for e in errors.values()),
        tolerance=tolerance, commands=sum(len(s) - 1 for s in segs.values()),
        stop_to_zero=stop_to_zero, moved_after_zero=moved, arrival_times=arrival,
        command_timeouts={rid: int(data["robots"][rid].get("command_timeouts", 0))
                          for rid in ids},
        timed_out={rid: float(data["robots"][rid].get("timed_out", 0.0)) for rid in ids},
        lagged_timeouts={rid: int(data["robots"][rid].get("lagged_timeouts", 0))
                         for rid in ids})


def build_parser(prog: str = "services.ros2.check") -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.ros2.check``."""
    p = Parser(prog=prog, description=__doc__.splitlines()[0])
    p.add_argument("folder", type=Path, help="the folder holding poses.json")
    p.add_argument("--scenario", required=True, help="TOML file or built-in name")
    p.add_argument("--tolerance", type=positive_float, default=0.05,
                   help="arrival: final distance to the reference, m (default 0.05)")
    p.add_argument("--dt", type=positive_float, default=0.002, help="grid step, s")
    return p


def main(argv: list[str] | None = None, prog: str = "services.ros2.check") -> int:
    """Entry point: 0 when the fleet is collision free and arrived, 1 if not, 2 bad input."""
    args = build_parser(prog).parse_args(argv)
    try:
        data = json.loads((args.folder / "poses.json").read_text())
        result = check_fleet(data, load_scenario(args.scenario), args.tolerance, args.dt)
    except (OSError, ValueError, KeyError, ScenarioError, ProblemError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    with atomic_path(args.folder / "check.json") as tmp:
        tmp.write_text(json.dumps(asdict(result), indent=1))
    print(f"{result.robots} robots, {result.duration:.1f} s: {result.collisions} collisions, "
          f"certified clearance {result.certified_clearance:.4f} m, "
          f"{result.arrived}/{result.robots} within {result.tolerance:g} m of their "
          f"references (largest {max(result.final_errors.values()):.3f} m)")
    return 0 if result.ok else 1


if __name__ == "__main__":
    sys.exit(main())

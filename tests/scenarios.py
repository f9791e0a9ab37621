"""Real :class:`sqpmpc.problem.scenario.Scenario` objects for unit tests, built in code."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import parse_scenario

__all__ = ["circle_scenario", "goal_scenario"]


def _scenario(references: list[dict], diameters: Sequence[float], *, name: str,
              ids: Sequence[int] | None, t_end: float, sample_time: float, horizon: int,
              Q: tuple[float, float], R: tuple[float, float],
              x_bounds: tuple[float, float] | None) -> Scenario:
    n = len(diameters)
    ids = list(ids) if ids is not None else list(range(1, n + 1))
    bounds: dict = {"v": [-0.6, 0.6], "omega": [-0.8, 0.8]}
    if x_bounds is not None:
        bounds["x"] = list(x_bounds)
    robots = [
        # start far apart (validation refuses overlaps); records set their own states
        {"id": ids[j], "initial_state": [0.0 if x_bounds else 10.0 * j, -50.0, 0.0],
         "diameter": float(diameters[j]), "reference": references[j]}
        for j in range(n)
    ]
    return parse_scenario({"name": name, "t_end": t_end, "sample_time": sample_time,
                           "horizon": horizon, "weights": {"Q": list(Q), "R": list(R)},
                           "bounds": bounds, "robots": robots}, source="<test>")


def goal_scenario(goals: np.ndarray, diameters: Sequence[float],
                  velocities: np.ndarray | None = None, ids: Sequence[int] | None = None,
                  Q: tuple[float, float] = (1.0, 1.0), R: tuple[float, float] = (0.5, 0.5),
                  x_bounds: tuple[float, float] | None = None, t_end: float = 10.0,
                  sample_time: float = 1.0, horizon: int = 5) -> Scenario:
    """References ``r_j(t) = goal_j + t vel_j`` on ``[0, t_end]`` (waypoints), else fixed goals."""
    goals = np.asarray(goals, dtype=float)
    refs = []
    for j, g in enumerate(goals):
        if velocities is None or not np.any(velocities[j]):
            refs.append({"type": "point", "position": g.tolist()})
        else:
            end = g + t_end * np.asarray(velocities[j], dtype=float)
            refs.append({"type": "waypoints", "times": [0.0, t_end],
                         "points": [g.tolist(), end.tolist()]})
    return _scenario(refs, diameters, name="unit", ids=ids, t_end=t_end,
                     sample_time=sample_time, horizon=horizon, Q=Q, R=R, x_bounds=x_bounds)


def circle_scenario(diameters: Sequence[float], t_end: float = 50.0) -> Scenario:
    """Robot ``j`` follows the circle of radius ``1 + j/2``, phase ``0.05 t + j``."""
    refs = []
    for j in range(len(diameters)):
        r = 1.0 + 0.5 * j
        refs.append({"type": "harmonic", "omega": 0.05,
                     "x": [0.0, -r * np.sin(j), r * np.cos(j)],
                     "y": [0.0, r * np.cos(j), r * np.sin(j)]})
    return _scenario(refs, diameters, name="circles", ids=None, t_end=t_end, sample_time=0.5,
                     horizon=8, Q=(1.0, 1.0), R=(0.5, 0.5), x_bounds=None)

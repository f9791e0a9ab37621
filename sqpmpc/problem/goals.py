"""Goals that the static map makes unreachable, found before a run.

A robot's goal is where its reference is at ``t_end`` (a point reference's position, a
path's last point). A goal inside a polygon obstacle, or nearer to a polygon's boundary
or to a static circular obstacle than the robot can come (its radius; for a circle,
``(d_robot + d_obstacle) / 2``), can never be reached: the commands refuse such a
scenario before running it (``sqpmpc run``, ``sqpmpc launch``), naming the robot. The
library still runs it (``metrics.json`` then lists the robot in ``no_route``).
"""

from __future__ import annotations

import numpy as np

from sqpmpc.problem.scenario import Scenario

__all__ = ["ARRIVAL_TOLERANCE", "unreachable_goals"]

ARRIVAL_TOLERANCE = 0.05
"""A robot has arrived when its final position error is at most this, m (the contract's
``arrived``, section 3; :mod:`sqpmpc.io.metrics` reports it)."""


def unreachable_goals(scenario: Scenario) -> list[str]:
    """One sentence per robot whose goal the static map makes unreachable (empty: none).

    Parameters
    ----------
    scenario
        The scenario.

    Returns
    -------
    list of str
        ``"robot id 1 (robots[0]): its goal (2, 0) at t_end = 20 s is inside
        polygons[0]"``, in robot order, one per robot at most.
    """
    goals = np.atleast_2d(scenario.reference_positions(scenario.t_end))
    radius = 0.5 * scenario.diameters()
    out: list[str] = []
    for j, robot in enumerate(scenario.robots):
        goal = goals[j]
        shown = f"({goal[0]:.6g}, {goal[1]:.6g})"
        problem = None
        for p, polygon in enumerate(scenario.polygons):
            gap = float(polygon.signed_distance(goal))
            if gap < radius[j]:
                problem = (f"inside polygons[{p}]" if gap < 0 else
                           f"{gap:.6g} m from the boundary of polygons[{p}], nearer than "
                           f"its radius {radius[j]:.6g} m")
                break
        if problem is None:
            for o, obstacle in enumerate(scenario.obstacles):
                if np.any(np.asarray(obstacle.velocity) != 0.0):
                    continue  # a moving obstacle leaves the goal free at some time
                gap = float(np.hypot(*(goal - np.asarray(obstacle.position))))
                need = 0.5 * (2.0 * radius[j] + obstacle.diameter)
                if gap < need:
                    problem = (f"{gap:.6g} m from the centre of obstacles[{o}], nearer than "
                               f"(d_robot + d_obstacle) / 2 = {need:.6g} m")
                    break
        if problem is not None:
            out.append(f"robot id {robot.id} (robots[{j}]): its goal {shown} at t_end = "
                       f"{scenario.t_end:g} s is {problem}: no motion reaches it")
    return out

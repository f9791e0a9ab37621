"""Maps for the coordination tests: a MovingAI maze turned off the axes."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from sqpmpc.problem.movingai import mapf_scenario
from sqpmpc.problem.polygons import PolygonObstacle
from sqpmpc.problem.references import PointReference
from sqpmpc.problem.scenario import Scenario

DATA = Path(__file__).parent / "data"


def turned_maze(name: str, robots: int, degrees: float) -> Scenario:
    """The test maze ``name`` (0.5 m cells, robots of 0.3 m with acceleration limits, its
    first ``robots`` agents) turned by ``degrees`` about its centre, with its box as four
    walls and no declared grid: its corridors, 0.5 m wide, run in no axis's direction,
    so no square grid of the roadmap's spacing has a line along each of them."""
    sc = mapf_scenario(DATA / f"{name}.map", robots, scen_path=DATA / f"{name}.scen",
                       cell=0.5, diameter=0.3, acceleration=2.0, angular_acceleration=10.0)
    angle = math.radians(degrees)
    turn = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    half = 0.15  # the bounds keep the robots' centres half a diameter inside the box
    low = np.array([sc.bounds.x[0] - half, sc.bounds.y[0] - half])
    high = np.array([sc.bounds.x[1] + half, sc.bounds.y[1] + half])
    centre = 0.5 * (low + high)

    def moved(points: object) -> np.ndarray:
        return (np.asarray(points, dtype=float) - centre) @ turn.T + centre

    t = 0.2  # wall thickness
    (x0, y0), (x1, y1) = low, high
    box = [[(x0 - t, y0 - t), (x1 + t, y0 - t), (x1 + t, y0), (x0 - t, y0)],
           [(x0 - t, y1), (x1 + t, y1), (x1 + t, y1 + t), (x0 - t, y1 + t)],
           [(x0 - t, y0), (x0, y0), (x0, y1), (x0 - t, y1)],
           [(x1, y0), (x1 + t, y0), (x1 + t, y1), (x1, y1)]]
    polygons = tuple(PolygonObstacle(tuple(map(tuple, moved(p))))
                     for p in [q.points for q in sc.polygons] + box)
    robots_turned = tuple(replace(
        r, initial_state=(*moved(r.initial_state[:2]), r.initial_state[2] + angle),
        reference=PointReference(tuple(moved(r.reference.goal)))) for r in sc.robots)
    corners = moved(np.array([low, [x1, y0], high, [x0, y1]]))
    bounds = replace(sc.bounds, x=(float(corners[:, 0].min()), float(corners[:, 0].max())),
                     y=(float(corners[:, 1].min()), float(corners[:, 1].max())))
    return sc.with_changes(roadmap=None, polygons=polygons, robots=robots_turned,
                           bounds=bounds, name=f"{name}-turned-{degrees:g}")

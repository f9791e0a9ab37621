"""Routes stay inside the scenario's [bounds] box."""

from __future__ import annotations

import tomllib

import numpy as np
import shapely

from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.routes import RoadMap, route_lengths
from sqpmpc.problem.scenario_file import parse_scenario
from sqpmpc.sim.simulation import simulate

WALL = """
name = "wall-box"
t_end = 30.0
sample_time = 0.5
horizon = 8
[weights]
Q = [1.0, 1.0]
R = [0.5, 0.5]
[bounds]
v = [-0.6, 0.6]
omega = [-0.7853981633974483, 0.7853981633974483]
{box}
[[robots]]
id = 1
initial_state = [-2.0, 0.3, 0.0]
diameter = 0.3
reference = {{ type = "point", position = [2.0, 0.0] }}
{second}
[[obstacles]]
points = [[-0.2, -1.0], [0.2, -1.0], [0.2, 1.0], [-0.2, 1.0]]
"""


def _scenario(box: str = "", second: str = ""):
    return parse_scenario(tomllib.loads(WALL.format(box=box, second=second)))


def test_routes_keep_inside_the_bounds_box() -> None:
    free = _scenario()
    boxed = _scenario("y = [-3.0, 1.1]")
    start, goal = np.array([-2.0, 0.3]), np.array([2.0, 0.0])
    over = RoadMap(free.polygons, (), 0.15, 0.1).route(start, goal)
    assert over is not None and over.points[:, 1].max() > 1.1  # the short way: over the top
    lo, hi = boxed.bounds.position_lower(), boxed.bounds.position_upper()
    road = RoadMap(boxed.polygons, (), 0.15, 0.1, (lo, hi))
    under = road.route(start, goal)
    assert under is not None and under.points[:, 1].min() < -1.0
    assert np.all(under.points >= lo - 1e-9) and np.all(under.points <= hi + 1e-9)
    wall = boxed.polygons[0].shape
    assert shapely.distance(wall, shapely.LineString(under.points)) >= 0.25 - 1e-6
    assert route_lengths(boxed, goal[None])[0] > route_lengths(free, goal[None])[0]
    # both ways around the wall cut off by the box, or a goal outside it: no route
    assert RoadMap(boxed.polygons, (), 0.15, 0.1, ((-3.0, -1.1), (3.0, 1.1))).route(
        start, goal) is None
    assert road.route(start, np.array([2.0, 1.5])) is None


def test_a_boxed_robot_goes_the_long_way_inside_the_box() -> None:
    sc = _scenario("y = [-3.0, 1.1]").with_changes(t_end=25.0)
    record = simulate(sc, "decentralized")
    m = compute_metrics(record)
    assert m["collisions"] == 0 and m["obstacle_collisions"] == 0
    assert m["max_final_position_error"] <= 0.05 and m["no_route"] == []
    assert m["counters"]["route_plans"] >= 1
    assert record.states[:, 0, 1].max() <= 1.1 + 1e-3  # never over the top


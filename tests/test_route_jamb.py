"""A robot pressed against a door jamb is not left there (issue 22).

Robot 5 of room-door, decentralized on the exact plant with acceleration limits
(``benchmarks.acceleration``), ended 4.70 m from its goal: pressed against the outer
face of the upper jamb, facing away from the room, tracking a route point it saw by its
radius only, while the rows against the wall keep half the model margin more
(``RuleContext.obstacle_margin``, 0.125 m here).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.plant import PlantSpec
from sqpmpc.problem.routes import RoadMap
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import ClosedLoopSimulation, simulate


def _entering() -> object:
    """Robots 4 and 5 of room-door coming in, with the benchmark's acceleration limits."""
    sc = load_scenario("room-door")
    bounds = dataclasses.replace(sc.bounds, acceleration=(-1.0, 1.0),
                                 angular_acceleration=(-3.0, 3.0))
    return sc.with_changes(robots=sc.robots[3:], bounds=bounds, plant=PlantSpec("exact"),
                           t_end=60.0)


def test_robots_entering_the_room_are_not_pinned_at_the_jamb() -> None:
    # before the fix robot 4 ended at (3.42, 0.44), 0.274 m from the jamb's corner
    # (3.2, 0.6): what the rows keep, 4.46 m from its goal
    sc = _entering()
    m = compute_metrics(simulate(sc, "decentralized"))
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0
    assert max(m["final_position_error"].values()) < 0.05


def test_sees_keeps_the_asked_room_off_the_walls() -> None:
    sc = load_scenario("room-door")
    road = RoadMap(sc.polygons, (), 0.15, 0.2)
    p = np.array([3.45, 0.49])  # 0.273 m from the jamb's corner (3.2, 0.6)
    inside = np.array([[1.21, -0.39], [3.55, 0.25]])  # grazes the corner; moves off it
    assert road.sees(p, inside).all()  # by the radius alone
    assert road.sees(p, inside, keep=0.125).tolist() == [False, True]


def test_the_route_rule_keeps_what_the_rows_keep_for_the_plant_only() -> None:
    # the paper's robot on the Euler plant: nothing beyond the radius (routes, reach and
    # the wall escape as before: the maps benchmark's closed loops are unchanged)
    plain = ClosedLoopSimulation(load_scenario("room-door"), "decentralized")
    assert plain.controllers[0].context.obstacle_margin == 0.0
    limited = ClosedLoopSimulation(_entering(), "decentralized")
    assert limited.controllers[0].context.obstacle_margin == 0.5 * limited.controllers[
        0].model_margin > 0.1

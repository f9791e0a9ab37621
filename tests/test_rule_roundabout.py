"""Rule ``roundabout``: a crowd ahead is passed counter-clockwise along its right tangent."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.kernels.rules import roundabout_directions
from sqpmpc.problem.fleets import antipodal_swap
from sqpmpc.rules.roundabout import Roundabout
from sqpmpc.sim.simulation import ClosedLoopSimulation
from tests.rule_helpers import fleet, only, shape, view

# robot 1 at the origin heading for (8, 0); a crowd of four 2 m ahead, centred on its path
CROWD = [[2.0, 0.0], [2.3, 0.3], [2.3, -0.3], [2.6, 0.0]]
STARTS = [[0.0, 0.0, 0.0]] + [[x, y, np.pi] for x, y in CROWD]
GOALS = [[8.0, 0.0]] + [[x - 6.0, y] for x, y in CROWD]


DEFAULT = Roundabout()


def _directions(positions: list[list[float]], goal: list[float], rule: Roundabout = DEFAULT,
                required: float = 0.31, headings: np.ndarray | None = None,
                rest_goals: np.ndarray | None = None) -> np.ndarray:
    p = np.array(positions, dtype=float)
    if headings is None:  # everyone but robot 0 faces it (head-on)
        headings = np.arctan2(p[0, 1] - p[:, 1], p[0, 0] - p[:, 0])
    out = np.full((1, 2), np.nan)
    rest = np.full(p.shape, np.nan) if rest_goals is None else np.asarray(rest_goals, float)
    roundabout_directions(p, np.asarray(headings, dtype=float), rest, np.array([0]),
                          np.array([goal], dtype=float), np.full((1, p.shape[0]), required),
                          rule.sense, math.cos(rule.cone), math.cos(rule.along),
                          rule.min_crowd, rule.goal_distance, out)
    return out[0]


def _cross(a: np.ndarray, b: np.ndarray) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


def test_a_crowd_on_the_path_is_passed_along_its_right_tangent() -> None:
    u = _directions([[0.0, 0.0]] + CROWD, [8.0, 0.0])
    assert np.hypot(*u) == pytest.approx(1.0)
    centre = np.mean(CROWD, axis=0)
    rho = max(np.hypot(*(np.array(CROWD) - centre).T)) + 0.31
    # the tangent touches the crowd disc: its distance to the centre is the disc's radius
    assert abs(_cross(u, centre)) == pytest.approx(rho)
    # and keeps the crowd on the robot's left (counter-clockwise around it)
    assert _cross(u, centre) > 0.0
    assert u[1] < 0.0


@pytest.mark.parametrize("case", ["three ahead", "crowd behind", "crowd beside", "goal near",
                                  "path clears the crowd", "crowd beyond the goal",
                                  "crowd going the same way", "crowd arrived"])
def test_the_rule_is_idle_without_a_crowd_on_the_path(case: str) -> None:
    crowd = np.array(CROWD)
    goal = [8.0, 0.0]
    if case == "three ahead":
        crowd = crowd[:3]
    elif case == "crowd behind":
        crowd[:, 0] *= -1.0
    elif case == "crowd beside":
        crowd = crowd[:, ::-1] + [0.0, 0.5]
    elif case == "goal near":
        goal = [0.9, 0.0]
    elif case == "path clears the crowd":  # goal up to the left, the crowd well to its right
        goal = [2.0, 8.0]
        crowd = crowd + [1.0, 0.8]
    elif case == "crowd beyond the goal":
        goal = [1.5, 0.0]
    headings = None
    if case == "crowd going the same way":  # within 45 degrees of the goal direction
        headings = np.array([0.0, 0.7, -0.7, 0.3, 0.0])
    rest_goals = None
    if case == "crowd arrived":  # each within 1 m of where its reference rests
        rest_goals = np.vstack([[np.nan, np.nan], crowd + [0.5, -0.5]])
    u = _directions([[0.0, 0.0]] + crowd.tolist(), goal, headings=headings,
                    rest_goals=rest_goals)
    np.testing.assert_array_equal(u, [0.0, 0.0])


def test_inside_the_crowd_the_robot_circles_counter_clockwise() -> None:
    ring = [[1.0 * np.cos(a), 1.0 * np.sin(a)] for a in np.linspace(0.3, 2.0, 5)]
    me = [-0.2, 0.05]
    u = _directions([me] + ring, [6.0, 6.0], Roundabout(sense=4.0, cone=1.5))
    assert np.hypot(*u) == pytest.approx(1.0)
    centre = np.mean(ring, axis=0)
    radial = np.array(me) - centre
    assert float(u @ radial) == pytest.approx(0.0, abs=1e-12)  # tangential
    assert _cross(radial, u) > 0.0  # counter-clockwise about the centre


def test_the_references_move_along_the_direction_at_the_reference_speed() -> None:
    rule = Roundabout(speed_fraction=0.5)
    ctrl = DecentralizedController(fleet(STARTS, GOALS), 1, only().with_rule(rule))
    inst = ctrl.rule("roundabout")
    states = np.array(STARTS)
    v = view(ctrl, states)
    v = shape(ctrl, inst, v)
    refs = v.references[0]
    steps = np.diff(np.vstack([states[0, :2], refs]), axis=0)
    np.testing.assert_allclose(np.hypot(*steps.T), 0.5 * 0.6 * 0.5)
    u = _directions(states[:, :2].tolist(), GOALS[0],
                    required=ctrl.scenario.required_distances()[0, 1])
    np.testing.assert_allclose(steps / np.hypot(*steps.T)[:, None], np.tile(u, (8, 1)),
                               atol=1e-12)
    assert ctrl.counters()["roundabout_samples"] == 1


@pytest.mark.parametrize(("field", "value"), [("min_crowd", 0), ("min_crowd", 2.5),
                                              ("sense", -1.0), ("cone", 1.6), ("along", 3.2),
                                              ("speed_fraction", 1.5),
                                              ("goal_distance", float("nan"))])
def test_bad_parameters_are_refused_by_name(field: str, value: float) -> None:
    with pytest.raises(ProblemError, match=f"roundabout.*{field}"):
        Roundabout(**{field: value})


@pytest.mark.parametrize("slots", [None, 8])
def test_a_swap_of_sixteen_arrives_without_collision(slots: int | None) -> None:
    scenario = antipodal_swap(16)
    sim = ClosedLoopSimulation(scenario, "decentralized", SolverSettings(neighbour_slots=slots))
    record = sim.run()
    m = compute_metrics(record)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    goals = scenario.reference_positions(record.t[-1])
    assert np.all(np.hypot(*(record.states[-1, :, :2] - goals).T) <= 0.05)
    assert m["counters"]["ring_samples"] > 0  # the swap's ways meet: its ring

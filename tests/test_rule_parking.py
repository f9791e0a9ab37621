"""Rule ``parking``: near a reference at rest, a larger position weight and a small speed."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.scenario_file import load_scenario, parse_scenario
from sqpmpc.rules.liveness import Parking
from sqpmpc.sim.simulation import simulate
from tests.rule_helpers import fleet, guess, only, shape, view


def test_only_robots_near_a_resting_reference_park() -> None:
    sc = load_scenario("crossing-4")
    ctrl = CentralizedController(sc, only("parking"))
    inst = ctrl.rule("parking")
    t_late = sc.t_end - sc.sample_time  # every reference is at rest at its goal
    states = np.zeros((4, 3))
    states[:, :2] = ctrl.reference(t_late)[:, -1] + 1.0  # robots 1, 2, 4 far from their goals
    states[2, :2] = ctrl.reference(t_late)[2, -1] + 0.1  # robot 3 near
    shape(ctrl, inst, view(ctrl, states, t=t_late))
    np.testing.assert_array_equal(ctrl.engine.qp.position_weight_scale, [1.0, 1.0, 20.0, 1.0])
    assert ctrl.counters()["parked_samples"] == 1
    # at t = 0 the references move over the horizon: nobody parks, even on its reference
    states[:, :2] = ctrl.reference(0.0)[:, -1]
    shape(ctrl, inst, view(ctrl, states, t=0.0))
    np.testing.assert_array_equal(ctrl.engine.qp.position_weight_scale, np.ones(4))


def test_gain_grows_for_short_horizons_and_radius_with_reach() -> None:
    short = fleet([[0, 0, 0]], [[0, 0.5]], horizon=5, sample_time=0.2)  # 1 s horizon
    inst = CentralizedController(short, only("parking")).rule("parking")
    assert inst.gain == pytest.approx(20.0 * (4.0 / 1.0) ** 2)
    assert inst.radius == pytest.approx(0.5 * 0.6 * 4.0)  # reach x v_max x max(N Ts, 4 s)


def test_parking_robot_at_rest_short_of_its_goal_is_linearized_moving() -> None:
    sc = fleet([[0, 0, 0]], [[0.0, 0.5]])
    ctrl = CentralizedController(sc, only("parking"))
    inst = ctrl.rule("parking")
    v = view(ctrl, sc.initial_states(), t=10.0)
    v = shape(ctrl, inst, v)
    speeds = np.zeros((1, sc.horizon))
    guess(inst, v, speeds)
    assert np.all(np.abs(speeds) == 0.05)
    # already there (within the tolerance): left alone
    at_goal = sc.initial_states()
    at_goal[0, :2] = [0.0, 0.495]
    v = view(ctrl, at_goal, t=10.0)
    v = shape(ctrl, inst, v)
    speeds = np.zeros((1, sc.horizon))
    guess(inst, v, speeds)
    np.testing.assert_array_equal(speeds, 0.0)


@pytest.mark.parametrize(("goal_y", "sample_time", "horizon"),
                         [(0.5, 0.5, 8), (1.0, 0.5, 8), (0.5, 0.1, 13), (0.8, 0.2, 6)])
def test_a_goal_beside_the_robot_is_reached(goal_y: float, sample_time: float,
                                            horizon: int) -> None:
    sc = parse_scenario({
        "name": "goal-beside", "t_end": 30.0, "sample_time": sample_time, "horizon": horizon,
        "weights": {"Q": [1.0, 1.0], "R": [0.5, 0.5]},
        "bounds": {"v": [-0.6, 0.6], "omega": [-0.7853981633974483, 0.7853981633974483]},
        "robots": [{"id": 1, "initial_state": [0.0, 0.0, 0.0], "diameter": 0.3,
                    "reference": {"type": "waypoints", "times": [0.0, 1.0],
                                  "points": [[0.0, goal_y], [0.0, goal_y]]}}],
    })
    m = compute_metrics(simulate(sc, "centralized", SolverSettings()))
    assert m["max_final_position_error"] <= 0.02
    assert m["input_bound_violations"] == 0
    assert m["counters"]["parked_samples"] > 0


@pytest.mark.parametrize("changes", [{"gain": 1.0}, {"gain": 0.5}, {"radius": -1.0},
                                     {"tolerance": float("nan")}])
def test_bad_parameters_are_refused_by_name(changes: dict[str, float]) -> None:
    with pytest.raises(ProblemError, match="parking"):
        Parking(**changes)

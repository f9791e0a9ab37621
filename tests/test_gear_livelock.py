"""A robot cycling its gear with no net motion counts as standing (stall-repair, detour).

Plain RTI at a neighbour can command ``+v, -v, +v, ...`` for ever, each plan backing off
the last (the pair stays at the distance its rows keep); the gear-cycle rule leaves a
robot a collision row holds to RTI. With acceleration bounds, corridor's last two robots
did so from t = 15 s to the end of the run (the first robot's start moved 1 mm on the
ideal plant, 2 mm on the MuJoCo plant): their speeds above the rules' "standing" speed,
neither stall-repair nor detour took over. :func:`sqpmpc.kernels.rules.idle` counts such a
cycle as standing (stall-repair at once, detour after ``cycle`` = 4 reversals in a row:
the paper's decentralized runs reverse up to three times at an encounter).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.kernels.rules import gear_streak, idle
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import load_scenario, parse_scenario
from sqpmpc.rules.liveness import StallRepair
from sqpmpc.sim.simulation import simulate
from tests.rule_helpers import guess, only, view

GOAL = 0.05
BOUNDS = {"acceleration": [-2.0, 2.0], "angular_acceleration": [-7.1, 7.1]}  # physics'


@pytest.mark.parametrize(("last", "before", "streak"), [
    (0.3, -0.3, 1), (-0.091, 0.093, 1),  # a reversal netting nothing
    (0.3, 0.3, 0), (0.09, 0.0, 0),  # moving; starting from rest
    (0.3, -0.1, 0),  # a reversal that gets somewhere
])
def test_gear_streak_counts_reversals_with_no_headway(last: float, before: float,
                                                      streak: int) -> None:
    assert gear_streak(last, before, 0.05, 0) == streak
    assert gear_streak(last, before, 0.05, 3) == (4 if streak else 0)


@pytest.mark.parametrize(("last", "streak", "standing"), [
    (0.0, 0, True), (0.04, 0, True),  # slower than 0.05: as before
    (0.3, 2, True), (0.3, 1, False), (0.3, 0, False),  # cycle = 2
])
def test_idle_is_slow_or_cycling_for_cycle_samples(last: float, streak: int,
                                                   standing: bool) -> None:
    assert idle(last, streak, 0.05, 2) is standing


def test_a_robot_cycling_its_gear_is_stuck_after_its_patience() -> None:
    sc = parse_scenario({
        "name": "cycle", "t_end": 10.0, "sample_time": 0.5, "horizon": 8,
        "weights": {"Q": [1.0, 1.0], "R": [0.5, 0.5]},
        "bounds": {"v": [-0.6, 0.6], "omega": [-0.785, 0.785]},
        "robots": [{"id": 1, "initial_state": [0.0, 0.0, np.pi], "diameter": 0.3,
                    "reference": {"type": "point", "position": [2.0, 0.5]}}]})
    ctrl = CentralizedController(sc, only().with_rule(StallRepair(patience=3, cycle=1)))
    inst = ctrl.rule("stall-repair")
    plan = np.full((1, 8), 0.3)  # a guess far above the repair speed
    outs = []
    for k in range(3):
        sign = 1.0 if k % 2 else -1.0
        v = view(ctrl, sc.initial_states(), applied=np.array([[0.3 * sign, 0.0]]),
                 applied_before=np.array([[-0.3 * sign, 0.0]]))
        out = plan.copy()
        guess(inst, v, out)
        outs.append(out)
    np.testing.assert_array_equal(outs[1], plan)
    np.testing.assert_array_equal(outs[2], -0.05)  # backwards, towards the goal
    assert ctrl.counters()["stall_repairs"] == 1


def _facing_away() -> Scenario:
    return parse_scenario({
        "name": "facing-away", "t_end": 20.0, "sample_time": 0.5, "horizon": 8,
        "weights": {"Q": [1.0, 1.0], "R": [0.5, 0.5]},
        "bounds": {"v": [-0.6, 0.6], "omega": [-0.785, 0.785], **BOUNDS},
        "robots": [{"id": 1, "initial_state": [0.0, 0.0, 0.3], "diameter": 0.3,
                    "reference": {"type": "point", "position": [-3.0, -1.5]}},
                   {"id": 2, "initial_state": [0.0, 4.0, 0.0], "diameter": 0.3,
                    "reference": {"type": "point", "position": [1.0, 4.0]}}]})


def _arrives_safely(sc: Scenario, scheme: str) -> None:
    rec = simulate(sc, scheme)
    m = compute_metrics(rec)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0
    errors = np.linalg.norm(rec.positions - rec.references(), axis=-1)
    assert (errors[-1] <= GOAL).all(), errors[-1]
    dv = np.diff(np.concatenate((np.zeros((1, sc.n_robots)), rec.inputs[..., 0])), axis=0)
    assert (np.abs(dv) <= sc.bounds.acceleration[1] * sc.sample_time + 1e-6).all()


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_a_robot_facing_away_from_its_goal_at_rest_turns_and_arrives(scheme: str) -> None:
    _arrives_safely(_facing_away(), scheme)


def test_corridor_pair_cycling_gear_at_its_kept_distance_arrives() -> None:
    """The ideal-plant livelock: robots 3 and 4 cycled ``+-0.32`` and ``+-0.09`` m/s 0.79 m
    apart (the rows keep 0.80 m at these bounds) from t = 20 s to the end, 4.5 m and
    4.2 m from their goals."""
    sc = load_scenario("corridor")
    sc = sc.with_changes(plant=dataclasses.replace(sc.plant, model="exact"),
                         bounds=dataclasses.replace(sc.bounds, acceleration=(-2.0, 2.0),
                                                    angular_acceleration=(-7.1, 7.1)))
    robots = list(sc.robots)
    x, y, psi = robots[0].initial_state
    robots[0] = dataclasses.replace(robots[0], initial_state=(x + 1e-3, y, psi))
    _arrives_safely(sc.with_changes(robots=tuple(robots)), "centralized")

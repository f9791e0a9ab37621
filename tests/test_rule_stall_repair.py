"""Rule ``stall-repair``: a stopped robot far from its goal is linearized at a small speed."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.errors import ProblemError
from sqpmpc.rules.liveness import StallRepair
from tests.rule_helpers import fleet, guess, only, view


def _repair(start: list[float], goal: list[float], speeds: np.ndarray,
            rule: StallRepair | None = None) -> tuple[np.ndarray, int]:
    sc = fleet([start], [goal])
    settings = only("stall-repair") if rule is None else only().with_rule(rule)
    ctrl = CentralizedController(sc, settings)
    inst = ctrl.rule("stall-repair")
    out = np.array(speeds, dtype=float)
    guess(inst, view(ctrl, sc.initial_states()), out)
    return out, ctrl.counters()["stall_repairs"]


def test_stopped_robot_with_its_goal_ahead_is_linearized_forwards() -> None:
    speeds, count = _repair([0, 0, 0], [2, 0.5], np.zeros((1, 8)))
    np.testing.assert_array_equal(speeds, 0.05)
    assert count == 1


def test_stopped_robot_with_its_goal_behind_is_linearized_backwards() -> None:
    speeds, _ = _repair([0, 0, 0], [-2, 0.5], np.zeros((1, 8)))
    np.testing.assert_array_equal(speeds, -0.05)


@pytest.mark.parametrize(("goal", "speeds"), [
    ([0.05, 0.0], np.zeros((1, 8))),  # goal within the distance: at rest is right
    ([2.0, 0.0], np.full((1, 8), 0.2)),  # a moving guess is not stalled
    ([2.0, 0.0], np.r_[np.zeros(7), 0.06][None]),  # one stage above the speed is enough
])
def test_robots_that_are_not_stalled_are_left_alone(goal: list[float],
                                                    speeds: np.ndarray) -> None:
    out, count = _repair([0, 0, 0], goal, speeds)
    np.testing.assert_array_equal(out, speeds)
    assert count == 0


def test_speed_is_clipped_to_the_bounds() -> None:
    speeds, _ = _repair([0, 0, 0], [3, 0], np.zeros((1, 8)), StallRepair(speed=2.0))
    np.testing.assert_array_equal(speeds, 0.6)


def test_a_robot_standing_for_its_patience_is_repaired_whatever_its_guess_plans() -> None:
    """The guess plans to go later (the RTI "wait, then go" of a local minimum); after
    ``patience`` samples standing with its reference at rest, it is linearized anyway."""
    sc = fleet([[0.0, 0.0, np.pi]], [[2.0, 0.5]])  # goal behind the heading
    ctrl = CentralizedController(sc, only().with_rule(StallRepair(patience=3)))
    inst = ctrl.rule("stall-repair")
    waiting = np.r_[0.0, np.full(7, 0.6)][None]
    outs = []
    for _ in range(3):
        out = waiting.copy()
        guess(inst, view(ctrl, sc.initial_states()), out)  # applied v = 0
        outs.append(out)
    np.testing.assert_array_equal(outs[0], waiting)
    np.testing.assert_array_equal(outs[1], waiting)
    np.testing.assert_array_equal(outs[2], -0.05)  # backwards, towards the goal
    assert ctrl.counters()["stall_repairs"] == 1
    # moving (applied v above the speed) resets the count
    out = waiting.copy()
    guess(inst, view(ctrl, sc.initial_states(), applied=np.array([[0.3, 0.0]])), out)
    np.testing.assert_array_equal(out, waiting)


def test_patience_needs_a_reference_at_rest() -> None:
    sc = fleet([[0.0, 0.0, 0.0]], [[2.0, 0.5]])
    ctrl = CentralizedController(sc, only().with_rule(StallRepair(patience=1)))
    inst = ctrl.rule("stall-repair")
    v = view(ctrl, sc.initial_states())
    v = v.but(references=v.references + np.linspace(0.0, 1.0, sc.horizon)[None, :, None])
    out = np.r_[0.0, np.full(7, 0.6)][None]
    guess(inst, v, out)
    assert ctrl.counters()["stall_repairs"] == 0


@pytest.mark.parametrize("changes", [{"speed": 0.0}, {"distance": -1.0},
                                     {"speed": float("inf")}, {"patience": 1.5},
                                     {"patience": 0}])
def test_bad_parameters_are_refused_by_name(changes: dict[str, float]) -> None:
    with pytest.raises(ProblemError, match="stall-repair"):
        StallRepair(**changes)


def test_forward_only_bounds_never_repair_backwards_nor_count_it() -> None:
    sc = fleet([[0, 0, 0]], [[-2, 0]])
    sc = sc.with_changes(bounds=dataclasses.replace(sc.bounds, v=(0.0, 0.6)))
    ctrl = CentralizedController(sc, only("stall-repair"))
    speeds = np.zeros((1, sc.horizon))
    guess(ctrl.rule("stall-repair"), view(ctrl, sc.initial_states()), speeds)
    np.testing.assert_array_equal(speeds, 0.0)
    assert ctrl.counters()["stall_repairs"] == 0


def test_a_robot_at_the_clipped_repair_speed_is_not_stalled() -> None:
    sc = fleet([[0, 0, 0]], [[2, 0]])
    sc = sc.with_changes(bounds=dataclasses.replace(sc.bounds, v=(-0.03, 0.03)))
    ctrl = CentralizedController(sc, only("stall-repair"))
    speeds = np.full((1, sc.horizon), 0.03)  # full speed under these bounds
    guess(ctrl.rule("stall-repair"), view(ctrl, sc.initial_states()), speeds)
    assert ctrl.counters()["stall_repairs"] == 0

"""Rule ``detour``: a robot blocked by a neighbour heads for a point to its right."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.errors import ProblemError
from sqpmpc.rules.liveness import Detour
from tests.rule_helpers import fleet, only, shape, view

# robot 1 at the origin heading for (3, 0); robot 2 right in front of it
STARTS = [[0.0, 0.0, 0.0], [0.35, 0.0, np.pi]]
GOALS = [[3.0, 0.0], [-3.0, 0.0]]


def _decentralized(rule: Detour | None = None) -> DecentralizedController:
    settings = only("detour") if rule is None else only().with_rule(rule)
    return DecentralizedController(fleet(STARTS, GOALS), 1, settings)


def test_blocked_robot_detours_to_the_right_after_its_patience() -> None:
    ctrl = _decentralized(Detour(patience=2, hold=3))
    inst = ctrl.rule("detour")
    states = np.array(STARTS)
    targets = []
    for _ in range(3):
        v = view(ctrl, states)
        raw = v.references.copy()
        v = shape(ctrl, inst, v)
        targets.append(v.references)
    np.testing.assert_array_equal(targets[0], raw)  # blocked once: patience not spent
    detour = targets[1][0]
    assert not np.array_equal(detour, raw[0])
    assert np.all(detour == detour[0])  # one point on every stage
    D = ctrl.scenario.required_distances()[0, 1]
    blocker = states[1, :2]
    assert np.hypot(*(detour[0] - blocker)) == pytest.approx(2.0 * D)
    away = states[0, :2] - blocker  # 60 degrees counter-clockwise from "away from the blocker"
    angle = np.arctan2(*(detour[0] - blocker)[::-1]) - np.arctan2(away[1], away[0])
    assert np.angle(np.exp(1j * angle)) == pytest.approx(np.deg2rad(60.0))
    assert ctrl.counters()["detour_activations"] == 1


def test_a_moving_robot_or_a_clear_path_is_left_alone() -> None:
    ctrl = _decentralized()
    inst = ctrl.rule("detour")
    states = np.array(STARTS)
    for applied in (np.array([[0.3, 0.0]]), None):
        s = states.copy()
        if applied is None:  # at rest, but the neighbour is beside it, not in front
            s[1, :2] = [0.0, 0.35]
        for _ in range(5):
            v = view(ctrl, s, applied=applied)
            raw = v.references.copy()
            v = shape(ctrl, inst, v)
            np.testing.assert_array_equal(v.references, raw)
    assert ctrl.counters()["detour_activations"] == 0


def test_centralized_controller_waits_longer() -> None:
    sc = fleet(STARTS, GOALS)
    inst = CentralizedController(sc, only("detour")).rule("detour")
    assert inst.patience == Detour().patience_centralized > Detour().patience


def test_a_robot_still_blocked_widens_its_detour_each_hold() -> None:
    ctrl = _decentralized(Detour(patience=2, hold=3, escalation=0.5, max_factor=3.0))
    inst = ctrl.rule("detour")
    states = np.array(STARTS)
    D = ctrl.scenario.required_distances()[0, 1]
    blocker = states[1, :2]
    radii = []
    for _ in range(14):  # never moves: blocked every sample
        v = view(ctrl, states)
        v = shape(ctrl, inst, v)
        if inst.active_for[0]:
            radii.append(np.hypot(*(v.references[0, 0] - blocker)) / D)
    # blocked samples 2-4: factor 2; 5-7: 2.5; 8-10: 3; then capped at max_factor 3
    np.testing.assert_allclose(radii, [2.0] * 3 + [2.5] * 3 + [3.0] * 7)
    assert ctrl.counters()["detour_activations"] == 1


@pytest.mark.parametrize("changes", [{"patience": 0}, {"hold": 2.5}, {"cone": -1.0},
                                     {"escalation": -0.1}, {"max_factor": 1.5},
                                     {"radius_factor": float("inf")}])
def test_bad_parameters_are_refused_by_name(changes: dict[str, float]) -> None:
    with pytest.raises(ProblemError, match="detour"):
        Detour(**changes)

"""Rule behaviour the per-rule files leave out: the detour's hold and renewal, the
turn limit on random normals, stall repair through the engine's strided iterate, and
every rule parameter refused by rule and field name."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.errors import ProblemError
from sqpmpc.kernels.rules import limit_turning, repair_speeds
from sqpmpc.rules.base import Contribution, Rule, RuleInstance, SampleView
from sqpmpc.rules.liveness import Detour, StallRepair
from sqpmpc.rules.registry import RULES
from tests.rule_helpers import fleet, only, shape, view

# robot 1 at the origin heading for (3, 0); robot 2 right in front of it, heading back
STARTS = [[0.0, 0.0, 0.0], [0.35, 0.0, np.pi]]
GOALS = [[3.0, 0.0], [-3.0, 0.0]]


def _detoured(ctrl: DecentralizedController | CentralizedController,
              states: np.ndarray, sample: int) -> np.ndarray:
    """Per own robot, whether the detour rule replaced its references this sample."""
    v = view(ctrl, states, sample=sample)
    raw = v.references.copy()
    v = shape(ctrl, ctrl.rule("detour"), v)
    return np.array([not np.array_equal(v.references[i], raw[i]) for i in range(raw.shape[0])])


def test_detour_holds_for_hold_samples_after_the_blocker_leaves_then_reverts() -> None:
    ctrl = DecentralizedController(fleet(STARTS, GOALS), 1,
                                   only().with_rule(Detour(patience=2, hold=3)))
    blocked = np.array(STARTS)
    clear = blocked.copy()
    clear[1, :2] = [0.0, 3.0]  # far away and beside the path: nobody in the cone
    sequence = [blocked] * 3 + [clear] * 4 + [blocked] * 2
    flags = [bool(_detoured(ctrl, s, k)[0]) for k, s in enumerate(sequence)]
    # patience 2: the second blocked sample activates; renewed on the third; held for the
    # two samples after it (hold 3 counts the last blocked one); then the scenario's
    # references; blocked again, the patience starts over
    assert flags == [False, True, True, True, True, False, False, False, True]
    assert ctrl.counters()["detour_activations"] == 2  # renewals are not activations


def test_detour_target_stays_put_while_the_robots_stand_still() -> None:
    ctrl = DecentralizedController(fleet(STARTS, GOALS), 1,
                                   only().with_rule(Detour(patience=1, hold=4)))
    states = np.array(STARTS)
    targets = []
    for k in range(4):
        v = view(ctrl, states, sample=k)
        v = shape(ctrl, ctrl.rule("detour"), v)
        targets.append(v.references[0, 0].copy())
    np.testing.assert_array_equal(np.diff(targets, axis=0), 0.0)
    assert ctrl.counters()["detour_activations"] == 1


def test_centralized_head_on_pair_detours_on_opposite_sides_after_longer_patience() -> None:
    """Both robots of a symmetric pair head for points on their own right: the targets
    lie on opposite sides of the line of centres, so the pair passes."""
    ctrl = CentralizedController(fleet(STARTS, GOALS), only("detour"))
    patience = Detour().patience_centralized
    states = np.array(STARTS)
    flags = [_detoured(ctrl, states, k) for k in range(patience + 1)]
    assert not np.any(flags[:patience - 1])
    assert np.all(flags[patience - 1:])
    assert ctrl.counters()["detour_activations"] == 2
    v = view(ctrl, states, sample=patience)
    v = shape(ctrl, ctrl.rule("detour"), v)
    first, second = v.references[0, 0], v.references[1, 0]
    assert first[1] < 0.0 < second[1]  # robot 1 heads +x: its right is -y; robot 2's is +y
    D = ctrl.scenario.required_distances()[0, 1]
    assert np.hypot(*(first - states[1, :2])) == pytest.approx(2.0 * D)
    assert np.hypot(*(second - states[0, :2])) == pytest.approx(2.0 * D)


def _angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unsigned angles between unit vectors ``(..., 2)``."""
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return np.abs(np.arctan2(cross, np.sum(a * b, axis=-1)))


def test_turn_limit_on_random_normals() -> None:
    """Consecutive turns stay within the limit, unit length is kept, a limited normal
    turns towards the raw one, and stages within the limit are untouched."""
    rng = np.random.default_rng(21)
    for _ in range(500):
        N = int(rng.integers(1, 12))
        max_turn = float(rng.uniform(0.05, 3.0))
        raw = rng.normal(size=(N, 2))
        raw /= np.hypot(raw[:, 0], raw[:, 1])[:, None]
        n0 = rng.normal(size=2)
        n0 /= np.hypot(*n0)
        out = raw.copy()
        limit_turning(n0[0], n0[1], out, max_turn)
        previous = np.vstack((n0, out[:-1]))
        turns = _angle(previous, out)
        assert np.all(turns <= max_turn + 1e-9)
        np.testing.assert_allclose(np.hypot(out[:, 0], out[:, 1]), 1.0, atol=1e-12)
        within = _angle(previous, raw) <= max_turn - 1e-9
        np.testing.assert_array_equal(out[within], raw[within])
        limited = ~np.all(out == raw, axis=1)
        if limited.any():  # on the arc from the previous normal towards the raw one
            np.testing.assert_allclose(turns[limited], max_turn, atol=1e-9)
            np.testing.assert_allclose(
                _angle(out[limited], raw[limited]),
                _angle(previous[limited], raw[limited]) - max_turn, atol=1e-9)


def test_stall_repair_kernel_counts_only_the_robots_it_may_change() -> None:
    speeds = np.zeros((4, 5))
    speeds[2] = 0.3  # moving
    goals = np.array([[2.0, 0.0], [-2.0, 0.0], [2.0, 0.0], [0.0, 2.0]])
    states = np.zeros((4, 3))
    only_mask = np.array([True, True, True, False])
    repaired = repair_speeds(speeds, goals, states, only_mask, 0.05, 0.1, 0.05, -0.04)
    assert repaired == 2
    np.testing.assert_array_equal(speeds[0], 0.05)  # goal ahead
    np.testing.assert_array_equal(speeds[1], -0.04)  # goal behind: the back speed
    np.testing.assert_array_equal(speeds[2], 0.3)
    np.testing.assert_array_equal(speeds[3], 0.0)  # not in the mask
    # a goal exactly abeam counts as ahead
    abeam = np.zeros((1, 5))
    assert repair_speeds(abeam, goals[3:], states[:1], only_mask[:1], 0.05, 0.1, 0.05,
                          -0.05) == 1
    np.testing.assert_array_equal(abeam, 0.05)


def test_stall_repair_lands_in_the_engine_linearization_point() -> None:
    """The hook sees the iterate's speeds read-only and returns new ones; the pipeline
    writes them into the engine."""
    sc = fleet([[0.0, 0.0, 0.0], [0.0, 3.0, 0.0]], [[-2.0, 0.5], [0.0, 3.05]])
    ctrl = CentralizedController(sc, only().with_rule(StallRepair(speed=0.07)))
    ctrl.step(0.0, sc.initial_states())
    engine = ctrl.engine
    engine.update_guess_speeds(np.zeros((2, sc.horizon)))
    v = view(ctrl, sc.initial_states()).but(guess_speeds=engine.guess_speeds())
    assert not v.guess_speeds.flags.writeable and not v.references.flags.writeable
    with pytest.raises(ValueError):
        v.guess_speeds[0, 0] = 1.0
    before = ctrl.counters()["stall_repairs"]
    v = ctrl.apply(ctrl.rule("stall-repair").shape_guess(v), v)
    _, inputs = engine.states_inputs()
    np.testing.assert_array_equal(inputs[0, :, 0], -0.07)  # goal behind
    np.testing.assert_array_equal(inputs[1, :, 0], 0.0)  # near its goal
    np.testing.assert_array_equal(v.guess_speeds, engine.guess_speeds())
    assert ctrl.counters()["stall_repairs"] == before + 1


_FIELDS = [(name, f.name) for name, cls in RULES.items() for f in dataclasses.fields(cls)]


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1.0])
@pytest.mark.parametrize(("rule", "field"), _FIELDS)
def test_every_rule_parameter_is_refused_by_rule_and_field(rule: str, field: str,
                                                            bad: float) -> None:
    with pytest.raises(ProblemError, match=f"rule '{rule}'.*{field}"):
        RULES[rule](**{field: bad})


def test_every_rule_has_parameters_or_none_to_check() -> None:
    """The parametrization above covers each rule with fields; touching-pairs and
    coordination have none."""
    assert {name for name, _ in _FIELDS} == set(RULES) - {"touching-pairs", "coordination"}
    assert RULES["touching-pairs"]().parameters() == {}
    assert RULES["coordination"]().parameters() == {}


class _Undeclared(RuleInstance):
    hooks = ("references",)
    calls = 0

    def shape_guess(self, view: SampleView) -> Contribution | None:  # not declared
        type(self).calls += 1
        return None


@dataclass(frozen=True)
class _Probe(Rule):
    name = "probe"
    instance = _Undeclared


def test_hooks_are_declared_explicitly() -> None:
    """The pipeline calls the hooks a rule declares (a method alone is not a hook), and an
    unknown hook name is refused at binding."""
    sc = fleet([[0.0, 0.0, 0.0], [0.0, 3.0, 0.0]], [[2.0, 0.0], [2.0, 3.0]])
    ctrl = CentralizedController(sc, only().with_rule(_Probe()))
    inst = ctrl.rule("probe")
    assert ctrl.rules_with("guess") == [] and ctrl.rules_with("references") == [inst]
    for k in range(3):
        ctrl.step(k * sc.sample_time, sc.initial_states())
    assert _Undeclared.calls == 0

    class Unknown(RuleInstance):
        hooks = ("reference",)

    with pytest.raises(ProblemError, match="unknown hooks"):
        Unknown(_Probe(), ctrl.context)

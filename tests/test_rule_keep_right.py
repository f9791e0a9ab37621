"""Rule ``keep-right``: the collision normals are rotated, nothing else changes."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.rules.liveness import KeepRight


def _geometry(rule: KeepRight | None) -> np.ndarray:
    settings = SolverSettings().without("keep-right")
    if rule is not None:
        settings = settings.with_rule(rule)
    return CentralizedController(load_scenario("head-on"), settings).geometry.rotation


def test_rotation_per_stage_is_the_clipped_growing_angle() -> None:
    N = load_scenario("head-on").horizon
    rotation = _geometry(KeepRight(angle=0.2, growth=0.1, max_angle=0.5))
    angles = np.minimum(0.2 + 0.1 * np.arange(N), 0.5)
    np.testing.assert_allclose(rotation, np.stack((np.cos(angles), np.sin(angles)), -1),
                               rtol=0, atol=1e-15)


def test_without_the_rule_the_normals_are_not_rotated() -> None:
    np.testing.assert_array_equal(_geometry(None), np.tile([1.0, 0.0], (8, 1))[:, :])


def test_rotated_rows_stay_inner_approximations() -> None:
    """Any unit normal gives n'(p_j - p_l) <= |p_j - p_l|: a satisfied row keeps the distance."""
    rng = np.random.default_rng(3)
    rotation = _geometry(KeepRight(angle=0.3))
    n = rotation[:, :1] * np.array([1.0, 0.0]) + rotation[:, 1:] * np.array([0.0, 1.0])
    gaps = rng.normal(size=(1000, 2))
    for normal in n:
        assert np.all(gaps @ normal <= np.hypot(gaps[:, 0], gaps[:, 1]) + 1e-12)


def test_centralized_rows_use_the_rotated_normal() -> None:
    sc = load_scenario("head-on")
    ctrl = CentralizedController(sc, SolverSettings().without("turn-limit"))
    ctrl.step(0.0, sc.initial_states())
    A = ctrl.engine.collision_blocks()["internal"][0]  # (P, N, 4): n, -n
    gap = sc.initial_states()[0, :2] - sc.initial_states()[1, :2]
    # stages 2..N: the plan's Taylor normal rotated by 0.3 rad
    turn = np.angle(np.exp(1j * (np.arctan2(A[0, 1:, 1], A[0, 1:, 0])
                                 - np.arctan2(gap[1], gap[0]))))
    # the head-on pair's plans stay near the line of centres: the rows sit ~0.3 rad off it
    assert np.all(np.abs(np.abs(turn) - 0.3) < 0.1)
    np.testing.assert_allclose(np.hypot(A[0, :, 0], A[0, :, 1]), 1.0, atol=1e-12)


@pytest.mark.parametrize("changes", [{"angle": -0.1}, {"angle": float("nan")},
                                     {"growth": -1.0}, {"max_angle": 2.0}])
def test_bad_parameters_are_refused_by_name(changes: dict[str, float]) -> None:
    with pytest.raises(ProblemError, match="keep-right"):
        KeepRight(**changes)


def test_an_angle_above_the_cap_is_refused() -> None:
    with pytest.raises(ProblemError, match="must not exceed max_angle"):
        KeepRight(angle=1.0, max_angle=0.5)


def test_numpy_numbers_are_accepted_as_parameters() -> None:
    from sqpmpc.rules.liveness import Detour

    assert KeepRight(angle=np.float64(0.2)).angle == 0.2
    assert Detour(patience=np.int64(3), speed=np.float32(0.3)).patience == 3

"""Rule ``turn-limit``: a pair's normal turns at most ``max_turn`` between stages."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.kernels.rules import limit_turning
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.rules.liveness import TurnLimit


def _turns(n0: np.ndarray, normals: np.ndarray) -> np.ndarray:
    angles = np.arctan2(normals[:, 1], normals[:, 0])
    return np.abs(np.diff(np.unwrap(np.concatenate(([np.arctan2(n0[1], n0[0])], angles)))))


def test_flipped_normals_turn_at_most_the_limit() -> None:
    normals = np.tile([0.0, -1.0], (4, 1))
    limit_turning(0.0, 1.0, normals, 0.6)
    assert np.all(_turns(np.array([0.0, 1.0]), normals) <= 0.6 + 1e-12)
    np.testing.assert_allclose(np.hypot(normals[:, 0], normals[:, 1]), 1.0, atol=1e-12)


def test_small_turns_are_left_alone() -> None:
    angles = 0.1 * np.arange(1, 6)
    normals = np.stack((np.cos(angles), np.sin(angles)), -1)
    before = normals.copy()
    limit_turning(1.0, 0.0, normals, 0.6)
    np.testing.assert_array_equal(normals, before)


def test_both_robots_of_a_pair_agree() -> None:
    """Negating the inputs (the other robot's view) negates the result."""
    rng = np.random.default_rng(0)
    raw = rng.normal(size=(6, 2))
    raw /= np.hypot(raw[:, 0], raw[:, 1])[:, None]
    mine, theirs = raw.copy(), -raw
    limit_turning(0.6, 0.8, mine, 0.5)
    limit_turning(-0.6, -0.8, theirs, 0.5)
    np.testing.assert_allclose(theirs, -mine, atol=1e-12)


def test_the_rule_sets_the_geometry_and_its_absence_leaves_it_unset() -> None:
    sc = load_scenario("head-on")
    on = CentralizedController(sc, SolverSettings().without("turn-limit").with_rule(
        TurnLimit(max_turn=0.4)))
    off = CentralizedController(sc, SolverSettings().without("turn-limit"))
    assert on.geometry.max_turn == 0.4 and on.geometry.kernel_max_turn == 0.4
    assert off.geometry.max_turn is None and off.geometry.kernel_max_turn < 0


@pytest.mark.parametrize("max_turn", [0.0, -0.5, np.pi, float("inf")])
def test_bad_limit_is_refused(max_turn: float) -> None:
    with pytest.raises(ProblemError, match="turn-limit"):
        TurnLimit(max_turn=max_turn)

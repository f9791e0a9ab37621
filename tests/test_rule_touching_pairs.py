"""Rule ``touching-pairs``: a pair inside the margin band repeats its stage-1 row on stage 2."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.plans import PlanMessage
from sqpmpc.control.settings import SolverSettings
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import simulate


def _rows(gap_in_margins: float, with_rule: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    sc = load_scenario("head-on")
    settings = SolverSettings() if with_rule else SolverSettings().without("touching-pairs")
    ctrl = DecentralizedController(sc, 1, settings)
    D = sc.required_distances()[0, 1]
    half = 0.5 * (D + gap_in_margins * settings.collision_margin)
    states = np.array([[-half, 0.0, 0.0], [half, 0.0, np.pi]])
    N = sc.horizon
    # both plans slide apart over the horizon (so stage 2's own row would differ)
    plans = {}
    for rid, sign in ((1, -1.0), (2, 1.0)):
        x = np.tile(states[rid - 1], (N + 1, 1))
        x[:, 1] += sign * 0.05 * np.arange(N + 1)
        plans[rid] = PlanMessage(rid, 0, x, np.zeros((N, 2)))
    ctrl.published = plans[1]
    ctrl.predict_neighbours(1, states, plans, states)
    c = ctrl.collisions
    return c.fixed_normals[0].copy(), c.fixed_rhs[0].copy(), states


def test_touching_pair_repeats_the_stage_one_row() -> None:
    n, rhs, states = _rows(0.5, with_rule=True)
    np.testing.assert_array_equal(n[1], n[0])
    assert rhs[1] == pytest.approx(n[0] @ states[0, :2])
    n_off, _, _ = _rows(0.5, with_rule=False)
    assert not np.array_equal(n_off[1], n_off[0])
    np.testing.assert_array_equal(n_off[2:], n[2:])  # later stages are untouched


def test_a_pair_outside_the_margin_band_is_left_alone() -> None:
    n, rhs, _ = _rows(5.0, with_rule=True)
    n_off, rhs_off, _ = _rows(5.0, with_rule=False)
    np.testing.assert_array_equal(n, n_off)
    np.testing.assert_array_equal(rhs, rhs_off)


def test_touching_swap_6_pair_slides_past_and_arrives() -> None:
    """Two robots of swap-6 left touching, one heading a hair inwards (a standoff state)."""
    import dataclasses

    sc = load_scenario("swap-6")
    a = dataclasses.replace(sc.robots[0], initial_state=(0.11267, 0.09963, -4.18528))
    b = dataclasses.replace(sc.robots[3], initial_state=(-0.14775, -0.05129, -1.04321))
    pair = sc.with_changes(robots=(a, b), name="touching-pair")
    m = compute_metrics(simulate(pair, "decentralized"))
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["max_final_position_error"] <= 0.05

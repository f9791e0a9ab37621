"""The safety rows as the QP solver receives them, and on random configurations.

Complements ``test_safety_rows.py``: the collision rows are read back from the
assembled CSC matrix (``SparseQP.matrices``), not from the kernels' outputs, and
the stage-one override and the missing-neighbour reach are checked on random
positions and predictions with the liveness geometry at its most aggressive
(large keep-right tilt, turn limit).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.models.unicycle import discrete_dynamics
from sqpmpc.ocp.collision_rows import (
    MISSING,
    SHARED,
    ExternalCollisionModel,
    PairwiseCollisionModel,
)
from sqpmpc.ocp.geometry import RowGeometry
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.rules.liveness import KeepRight, TurnLimit


def _aggressive_geometry(horizon: int) -> RowGeometry:
    """The row geometry of keep-right at its largest tilt plus a tight turn limit."""
    settings = SolverSettings().with_rule(KeepRight(angle=1.2, growth=0.05, max_angle=1.5))
    settings = settings.with_rule(TurnLimit(max_turn=0.3))
    sc = load_scenario("head-on").with_changes(horizon=horizon)
    return CentralizedController(sc, settings).geometry


def _row(A: sp.csr_matrix, row: int) -> tuple[np.ndarray, np.ndarray]:
    """Columns and values of the stored entries of one row of ``A``."""
    start, end = A.indptr[row], A.indptr[row + 1]
    return A.indices[start:end], A.data[start:end]


def _run_centralized(name: str, samples: int) -> CentralizedController:
    sc = load_scenario(name)
    ctrl = CentralizedController(sc)
    states = sc.initial_states()
    for k in range(samples):
        out = ctrl.step(k * sc.sample_time, states)
        states = np.array([discrete_dynamics(s, u, sc.sample_time, "euler")
                           for s, u in zip(states, out.inputs, strict=True)])
    return ctrl


@pytest.mark.parametrize("name", ["crossing-4", "swap-6"])
def test_centralized_qp_rows_are_inner_approximations(name: str) -> None:
    """Each internal row of the solver's matrix reads n'(p_a - p_b) (+ s) >= l with unit n
    on the stage's positions only, so with zero slack it implies |p_a - p_b| >= l."""
    ctrl = _run_centralized(name, 6)
    L = ctrl.engine.layout
    _, _, A, lower, upper = ctrl.engine.qp.matrices()
    A = A.tocsr()
    required = ctrl.required + ctrl.settings.collision_margin
    rng = np.random.default_rng(7)
    gaps = rng.uniform(-2.0, 2.0, size=(4000, 2))
    dist = np.hypot(gaps[:, 0], gaps[:, 1])
    for p, (a, b) in enumerate(ctrl.pairs):
        for i in range(L.horizon):
            row = L.internal_rows[p, i]
            cols, vals = _row(A, row)
            pos_a = L.state_index[a, i + 1, :2]
            pos_b = L.state_index[b, i + 1, :2]
            expected = set(pos_a) | set(pos_b)
            if i > 0:
                expected.add(L.slack_internal_index[p, i - 1])
            assert set(cols) == expected
            coef = dict(zip(cols.tolist(), vals.tolist(), strict=True))
            n = np.array([coef[pos_a[0]], coef[pos_a[1]]])
            np.testing.assert_array_equal([coef[pos_b[0]], coef[pos_b[1]]], -n)
            assert np.hypot(*n) == pytest.approx(1.0, abs=1e-12)
            if i > 0:
                assert coef[L.slack_internal_index[p, i - 1]] == 1.0
                assert lower[row] == pytest.approx(required[p], abs=1e-15)
            else:
                assert lower[row] <= required[p] + 1e-15
            assert upper[row] >= 1e19  # a one-sided row
            satisfied = gaps @ n >= lower[row]
            assert satisfied.any() and not satisfied.all()
            assert np.all(dist[satisfied] >= lower[row] - 1e-12)


def _run_decentralized(name: str, samples: int) -> dict[int, DecentralizedController]:
    sc = load_scenario(name)
    ctrls = {int(rid): DecentralizedController(sc, int(rid)) for rid in sc.ids}
    states, previous, plans = sc.initial_states(), None, {}
    for k in range(samples):
        outs = {rid: c.step(k, k * sc.sample_time, states, plans, previous)
                for rid, c in ctrls.items()}
        plans = {rid: c.published for rid, c in ctrls.items()}
        previous = states
        states = np.array([discrete_dynamics(states[sc.index_of(rid)], outs[rid].inputs[0],
                                             sc.sample_time, "euler") for rid in sc.ids])
    return ctrls


def test_decentralized_qp_rows_of_a_pair_together_imply_the_distance() -> None:
    """Robot j's row n'p_j (+ s) >= r_j and robot k's row -n'p_k (+ s) >= r_k, as the
    solvers receive them, imply |p_j - p_k| >= r_j + r_k, which is the required distance
    plus the margin on stages 2..N."""
    sc = load_scenario("crossing-4")
    ctrls = _run_decentralized("crossing-4", 6)
    rng = np.random.default_rng(8)
    N = sc.horizon
    for j, k in sc.pairs():
        cj, ck = ctrls[int(sc.ids[j])], ctrls[int(sc.ids[k])]
        ej = list(cj.others).index(k)
        ek = list(ck.others).index(j)
        assert cj.collisions.kind[ej] == SHARED and ck.collisions.kind[ek] == SHARED
        rows = []
        for c, e in ((cj, ej), (ck, ek)):
            L = c.engine.layout
            _, _, A, lower, _ = c.engine.qp.matrices()
            A = A.tocsr()
            per_stage = []
            for i in range(N):
                row = L.external_rows[0, e, i]
                cols, vals = _row(A, row)
                pos = L.state_index[0, i + 1, :2]
                expected = set(pos) | ({L.slack_external_index[0, e, i - 1]} if i else set())
                assert set(cols) == expected
                coef = dict(zip(cols.tolist(), vals.tolist(), strict=True))
                per_stage.append((np.array([coef[pos[0]], coef[pos[1]]]), lower[row]))
            rows.append(per_stage)
        D = sc.required_distances()[j, k] + cj.settings.collision_margin
        for i in range(N):
            (nj, rj), (nk, rk) = rows[0][i], rows[1][i]
            np.testing.assert_allclose(nk, -nj, atol=1e-12)
            assert np.hypot(*nj) == pytest.approx(1.0, abs=1e-12)
            if i > 0:
                assert rj + rk == pytest.approx(D, abs=1e-12)
            pj = rng.uniform(-3.0, 3.0, size=(3000, 2))
            pk = rng.uniform(-3.0, 3.0, size=(3000, 2))
            both = (pj @ nj >= rj) & (pk @ nk >= rk)
            assert both.any()
            gap = pj[both] - pk[both]
            assert np.all(np.hypot(gap[:, 0], gap[:, 1]) >= rj + rk - 1e-12)


def _random_configuration(rng: np.random.Generator, N: int, d: float
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Current positions ``(2, 2)`` from overlapping to far apart, and arbitrary
    predictions ``(2, N+1, 3)`` (crossing each other, jumping around)."""
    now = rng.uniform(-1.0, 1.0, size=(2, 2))
    offset = rng.normal(size=2)
    now[1] = now[0] + offset / np.hypot(*offset) * rng.uniform(0.3 * d, 3.0 * d)
    predictions = np.zeros((2, N + 1, 3))
    predictions[:, :, :2] = now[:, None] + rng.normal(scale=rng.uniform(0.01, 1.0),
                                                      size=(2, N + 1, 2))
    predictions[:, 0, :2] = now
    return now, predictions


def test_centralized_stage_one_is_feasible_standing_still_for_any_prediction() -> None:
    N = 8
    geometry = _aggressive_geometry(N)
    d = 0.3
    model = PairwiseCollisionModel(np.array([[0, 1]]), np.array([d]), 1e-3, geometry)
    rng = np.random.default_rng(11)
    A = np.empty((1, N, 4))
    lower = np.empty((1, N))
    overridden = 0
    for _ in range(3000):
        now, predictions = _random_configuration(rng, N, d)
        model.set_current_positions(now)
        model.write_rows(predictions, A, lower)
        overridden += model.stage_one_overrides
        # standing still: both robots at their current positions, stage 1
        assert A[0, 0, :2] @ now[0] + A[0, 0, 2:] @ now[1] >= lower[0, 0] - 1e-12
        np.testing.assert_allclose(np.hypot(A[0, :, 0], A[0, :, 1]), 1.0, atol=1e-12)
        np.testing.assert_array_equal(A[0, :, 2:], -A[0, :, :2])
        np.testing.assert_array_equal(lower[0, 1:], d + 1e-3)
    assert 0 < overridden < 3000  # both branches were exercised


def test_decentralized_stage_one_is_feasible_standing_still_for_any_prediction() -> None:
    """Shared and missing slots: the current position satisfies every stage-1 row and the
    first-stage check, whatever the exchanged predictions and the own iterate."""
    N = 8
    geometry = _aggressive_geometry(N)
    d, margin, reach = 0.3, 1e-3, 0.3
    rng = np.random.default_rng(12)
    overridden = 0
    for kind in (SHARED, MISSING):
        model = ExternalCollisionModel(np.array([d]), N, geometry, reach=reach, margin=margin)
        A = np.empty((1, 1, N, 2))
        lower = np.empty((1, 1, N))
        for _ in range(1500):
            now, predictions = _random_configuration(rng, N, d)
            iterate = predictions[:1].copy()
            iterate[0, 1:, :2] += rng.normal(scale=0.2, size=(N, 2))
            model.set_sample(now[0], now[1:], predictions[0, 1:], predictions[1:, 1:],
                             np.array([kind], dtype=np.int8))
            model.write_rows(iterate, A, lower)
            overridden += model.stage_one_overrides
            assert A[0, 0, 0] @ now[0] >= lower[0, 0, 0] - 1e-12
            assert model.first_stage_safe(now[0])
            np.testing.assert_allclose(np.hypot(A[0, 0, :, 0], A[0, 0, :, 1]), 1.0,
                                       atol=1e-12)
    assert overridden > 0


@pytest.mark.parametrize("room", [True, False])
def test_missing_neighbour_rows_keep_its_reach(room: bool) -> None:
    """A neighbour without a plan: with room, a satisfied stage-1 row keeps d + reach from
    its current position; without room, it only forbids approaching. Stages 2..N keep d
    from its extrapolated prediction."""
    N = 8
    geometry = _aggressive_geometry(N)
    d, margin, reach = 0.3, 1e-3, 0.3
    model = ExternalCollisionModel(np.array([d]), N, geometry, reach=reach, margin=margin)
    me = np.array([0.0, 0.0])
    other = np.array([[d + reach + (0.2 if room else -0.1), 0.05]])
    prediction = np.zeros((1, N, 3))
    prediction[0, :, 0] = other[0, 0] - 0.1 * np.arange(1, N + 1)  # coming at me
    prediction[0, :, 1] = other[0, 1]
    own = np.zeros((1, N + 1, 3))
    own[0, :, 0] = -0.05 * np.arange(N + 1)
    model.set_sample(me, other, own[0, 1:], prediction, np.array([MISSING], dtype=np.int8))
    A = np.empty((1, 1, N, 2))
    lower = np.empty((1, 1, N))
    model.write_rows(own, A, lower)
    rng = np.random.default_rng(13)
    p = rng.uniform(-2.0, 2.0, size=(20000, 2))
    n1 = A[0, 0, 0]
    satisfied = p @ n1 >= lower[0, 0, 0]
    assert satisfied.any()
    to_now = np.hypot(*(p[satisfied] - other[0]).T)
    current = np.hypot(*(me - other[0]))
    if room:
        assert np.all(to_now >= d + margin + reach - 1e-12)
    else:
        assert lower[0, 0, 0] == pytest.approx(n1 @ me)  # no closer along the normal
        assert np.all(to_now >= current - 1e-12)
    for i in range(1, N):
        ok = p @ A[0, 0, i] >= lower[0, 0, i]
        gap = p[ok] - prediction[0, i, :2]
        assert np.all(np.hypot(gap[:, 0], gap[:, 1]) >= d + margin - 1e-12)

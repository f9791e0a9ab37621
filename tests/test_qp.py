"""The sparse QP: in-place updates equal a QP rebuilt from scratch; solutions are KKT points."""

from __future__ import annotations

import numpy as np
import pytest
import qpsolvers
import scipy.sparse as sp

from sqpmpc.qp.backend import HANDOVER_ITERATIONS, QP_SOLVERS, OSQPSettings
from sqpmpc.qp.layout import QPLayout
from sqpmpc.qp.sparse import SparseQP

N = 4


def dense_qp(m, pairs, E, pos, data):
    """Assemble (P, q, A, l, u) densely with explicit loops: an independent rebuild."""
    nb = 5 * N + 3
    P_n = len(pairs)
    n_slack = (P_n + m * E) * (N - 1)
    n = m * nb + n_slack

    def xi(r, i):
        return r * nb + 5 * i

    def ui(r, i):
        return r * nb + 5 * i + 3

    P = np.zeros((n, n))
    q = np.zeros(n)
    rows, lo, up = [], [], []

    def row(coeffs, lower, upper):
        a = np.zeros(n)
        for j, c in coeffs:
            a[j] += c
        rows.append(a)
        lo.append(lower)
        up.append(upper)

    Qd, Rd, rho = data["Q"], data["R"], data["rho"]
    for r in range(m):
        for i in range(1, N + 1):
            for c in range(2):
                P[xi(r, i) + c, xi(r, i) + c] = 2 * Qd[c]
                q[xi(r, i) + c] = -2 * Qd[c] * data["ref"][r, i - 1, c]
        for i in range(N):
            for c in range(2):
                P[ui(r, i) + c, ui(r, i) + c] = 2 * Rd[c]
            H = data["curv"][r, i]
            trio = [xi(r, i) + 2, ui(r, i), ui(r, i) + 1]
            for a in range(3):
                for b in range(3):
                    P[trio[a], trio[b]] += H[a, b]
            zt = data["zbar"][trio]
            q[trio] -= H @ zt
    q[m * nb:] = rho
    for r in range(m):
        for c in range(3):
            row([(xi(r, 0) + c, 1.0)], data["x0"][r, c], data["x0"][r, c])
    for r in range(m):
        for i in range(N):
            for c in range(3):
                coeffs = [(xi(r, i + 1) + c, 1.0)]
                coeffs += [(xi(r, i) + k, -data["A"][r, i, c, k]) for k in range(3)]
                coeffs += [(ui(r, i) + k, -data["B"][r, i, c, k]) for k in range(2)]
                row(coeffs, data["c"][r, i, c], data["c"][r, i, c])
    for r in range(m):
        for i in range(N):
            for c in range(2):
                row([(ui(r, i) + c, 1.0)], data["ulo"][c], data["uup"][c])
    if pos:
        for r in range(m):
            for i in range(1, N + 1):
                for c in range(2):
                    row([(xi(r, i) + c, 1.0)], data["plo"][c], data["pup"][c])
    s = m * nb
    for p, (a, b) in enumerate(pairs):
        for i in range(N):
            nv = data["n_int"][p, i]
            coeffs = [(xi(a, i + 1), nv[0]), (xi(a, i + 1) + 1, nv[1]),
                      (xi(b, i + 1), -nv[0]), (xi(b, i + 1) + 1, -nv[1])]
            if i > 0:
                coeffs.append((s + p * (N - 1) + i - 1, 1.0))
            row(coeffs, data["b_int"][p, i], np.inf)
    s2 = s + P_n * (N - 1)
    for r in range(m):
        for e in range(E):
            for i in range(N):
                nv = data["n_ext"][r, e, i]
                coeffs = [(xi(r, i + 1), nv[0]), (xi(r, i + 1) + 1, nv[1])]
                if i > 0:
                    coeffs.append((s2 + (r * E + e) * (N - 1) + i - 1, 1.0))
                row(coeffs, data["b_ext"][r, e, i], np.inf)
    for k in range(n_slack):
        row([(s + k, 1.0)], 0.0, np.inf)
    return P, q, np.array(rows), np.array(lo), np.array(up)


def random_data(rng, m, pairs, E, n_var):
    A = np.tile(np.eye(3), (m, N, 1, 1))
    A[..., 0, 2] = rng.normal(size=(m, N))
    A[..., 1, 2] = rng.normal(size=(m, N))
    B = np.zeros((m, N, 3, 2))
    B[..., :2, :] = rng.normal(size=(m, N, 2, 2))
    B[..., 2, 1] = 0.5
    curv = rng.normal(size=(m, N, 3, 3))
    curv = np.einsum("...ij,...kj->...ik", curv, curv)  # PSD
    n_int = rng.normal(size=(len(pairs), N, 2))
    n_int /= np.linalg.norm(n_int, axis=-1, keepdims=True)
    n_ext = rng.normal(size=(m, E, N, 2))
    n_ext /= np.linalg.norm(n_ext, axis=-1, keepdims=True)
    return {
        "Q": np.array([1.0, 2.0]), "R": np.array([0.5, 0.3]), "rho": 100.0,
        "x0": rng.normal(size=(m, 3)), "ref": rng.normal(size=(m, N, 2)),
        "A": A, "B": B, "c": rng.normal(size=(m, N, 3)) * 0.1, "curv": curv,
        "zbar": rng.normal(size=n_var), "n_int": n_int,
        "b_int": rng.uniform(-3, -1, size=(len(pairs), N)),
        "n_ext": n_ext, "b_ext": rng.uniform(-3, -1, size=(m, E, N)),
        "ulo": np.array([-0.6, -0.8]), "uup": np.array([0.6, 0.8]),
        "plo": np.array([-20.0, -20.0]), "pup": np.array([20.0, 20.0]),
    }


def apply(qp: SparseQP, d) -> None:
    qp.update_cost_weights(d["Q"], d["R"], d["rho"])
    qp.update_reference(d["ref"])
    qp.update_initial_state(d["x0"])
    qp.update_dynamics(d["A"], d["B"], d["c"])
    qp.update_input_bounds(d["ulo"], d["uup"])
    if qp.layout.position_bounds:
        qp.update_position_bounds(d["plo"], d["pup"])
    qp.update_internal_collisions(d["n_int"], d["b_int"])
    qp.update_external_collisions(d["n_ext"], d["b_ext"])
    qp.update_curvature(d["curv"], d["zbar"])


CASES = [
    pytest.param(3, [(0, 1), (0, 2), (1, 2)], 0, True, id="centralized-3"),
    pytest.param(1, [], 3, False, id="decentralized-1of4"),
    pytest.param(2, [(0, 1)], 2, True, id="mixed"),
]


@pytest.mark.parametrize("solver", QP_SOLVERS)
@pytest.mark.parametrize(("m", "pairs", "E", "pos"), CASES)
def test_update_in_place_equals_rebuild(m, pairs, E, pos, solver) -> None:
    """On every backend: in-place updates equal the dense rebuild, and the solution equals
    Clarabel's on the rebuild and satisfies the KKT conditions."""
    layout = QPLayout(m, N, np.array(pairs, dtype=np.int64).reshape(-1, 2), E, pos)
    qp = SparseQP(layout, OSQPSettings(eps_abs=1e-9, eps_rel=1e-9, max_iter=100000,
                                       polishing=True, rescue_solver=None), solver)
    rng = np.random.default_rng(7)
    first = random_data(rng, m, pairs, E, layout.n_var)
    apply(qp, first)
    qp.solve()  # sets OSQP up with the first values
    second = random_data(rng, m, pairs, E, layout.n_var)
    apply(qp, second)
    res = qp.solve()
    backend = qp.backend
    assert backend.setup_count == 1  # values updated in place, never a second setup
    P_ref, q_ref, A_ref, l_ref, u_ref = dense_qp(m, pairs, E, pos, second)
    P, q, A, lo, up = qp.matrices()
    np.testing.assert_allclose(P.toarray(), np.triu(P_ref), atol=1e-14)
    np.testing.assert_allclose(q, q_ref, atol=1e-13)
    np.testing.assert_allclose(A.toarray(), A_ref, atol=1e-14)
    np.testing.assert_array_equal(lo, l_ref)
    np.testing.assert_array_equal(up, u_ref)
    # the in-place updated OSQP solves the rebuilt problem: compare with an interior-point
    # solver on the dense rebuild (independent high-accuracy reference)
    assert res.success, res.status
    problem = qpsolvers.Problem(P_ref, q_ref, G=np.vstack((-A_ref, A_ref)),
                                h=np.concatenate((-l_ref, u_ref)))
    finite = np.isfinite(problem.h)
    problem = qpsolvers.Problem(sp.csc_matrix(P_ref), q_ref,
                                G=sp.csc_matrix(problem.G[finite]), h=problem.h[finite])
    ref = qpsolvers.solve_problem(problem, solver="clarabel")
    assert ref.found
    np.testing.assert_allclose(res.x, ref.x, atol=2e-6)
    # residuals of the solution itself (OSQP's sign convention, whatever the backend)
    Pf = sp.csc_matrix(P_ref)
    stationarity = Pf @ res.x + q_ref + A_ref.T @ res.y
    assert np.abs(stationarity).max() < 1e-6
    Az = A_ref @ res.x
    assert np.all(Az >= l_ref - 1e-7) and np.all(Az <= u_ref + 1e-7)


def test_position_weight_scale_equals_scaled_weights() -> None:
    """Scaling one robot's position weight equals a QP built with that weight."""
    layout = QPLayout(3, N, np.array([(0, 1), (1, 2)]), 0, False)
    rng = np.random.default_rng(2)
    d = random_data(rng, 3, [(0, 1), (1, 2)], 0, layout.n_var)
    scaled = SparseQP(layout)
    apply(scaled, d)
    scaled.update_position_weight_scale(np.array([1.0, 20.0, 1.0]))
    scaled.update_reference(d["ref"])
    P, q, A, lo, up = scaled.matrices()
    P_ref, q_ref, A_ref, l_ref, u_ref = dense_qp(3, [(0, 1), (1, 2)], 0, False, d)
    # robot 1's position entries: 20 times the cost part, the curvature part unchanged
    pos = layout.state_index[1, 1:, :2].ravel()
    cost_part = np.zeros(layout.n_var)
    cost_part[pos] = 2.0 * np.tile(d["Q"], N)
    expected_P = np.triu(P_ref)
    expected_P[pos, pos] += 19.0 * cost_part[pos]
    np.testing.assert_allclose(P.toarray(), expected_P, atol=1e-12)
    expected_q = q_ref.copy()
    expected_q[pos] += 19.0 * (-2.0 * (d["Q"] * d["ref"][1]).ravel())
    np.testing.assert_allclose(q, expected_q, atol=1e-12)
    np.testing.assert_array_equal(A.toarray(), A_ref)
    # back to 1: exactly the unscaled QP again
    scaled.update_position_weight_scale(np.ones(3))
    scaled.update_reference(d["ref"])
    np.testing.assert_allclose(scaled.matrices()[0].toarray(), np.triu(P_ref), atol=1e-12)
    np.testing.assert_allclose(scaled.q, q_ref, atol=1e-12)


def test_vector_only_update_keeps_matrices() -> None:
    layout = QPLayout(1, N, np.zeros((0, 2), dtype=np.int64), 1, False)
    qp = SparseQP(layout)
    d = random_data(np.random.default_rng(3), 1, [], 1, layout.n_var)
    apply(qp, d)
    qp.solve()
    P_before, _, A_before, _, _ = qp.matrices()
    qp.update_reference(d["ref"] + 1.0)
    assert not qp.pending.A and not qp.pending.P
    res = qp.solve()
    assert res.success
    P_after, _, A_after, _, _ = qp.matrices()
    assert (P_before != P_after).nnz == 0 and (A_before != A_after).nnz == 0


@pytest.mark.parametrize(("m", "pairs", "E", "pos"), CASES)
def test_direct_osqp_calls_equal_the_public_wrapper(m, pairs, E, pos) -> None:
    """The fast path to OSQP's compiled solver gives the wrapper's results (the same QP
    data and calls: equal to solver precision, whatever OSQP does inside)."""
    layout = QPLayout(m, N, np.array(pairs, dtype=np.int64).reshape(-1, 2), E, pos)
    direct, wrapped = SparseQP(layout), SparseQP(layout)
    wrapped.use_osqp_wrapper = True
    rng = np.random.default_rng(5)
    warm = None
    for sample in range(6):
        d = random_data(rng, m, pairs, E, layout.n_var)
        for qp in (direct, wrapped):
            if sample % 2:  # every other sample only vectors change
                qp.update_reference(d["ref"])
                qp.update_initial_state(d["x0"])
            else:
                apply(qp, d)
        results = [qp.solve(*(warm or (None, None))) for qp in (direct, wrapped)]
        a, b = results
        assert a.success and b.success and a.status == b.status
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.y, b.y, rtol=0, atol=1e-9)
        warm = (a.x + 0.01, a.y)


def test_direct_osqp_results_are_not_overwritten_by_the_next_solve() -> None:
    """The fast path takes OSQP's compiled object's arguments by position and its solution
    arrays without a copy of its own (they are new at every access): a result kept stays
    as it was when the same backend solves again (the iterate and the fallback plan are
    kept across samples)."""
    layout = QPLayout(2, N, np.array([(0, 1)], dtype=np.int64), 1, True)
    qp = SparseQP(layout)
    rng = np.random.default_rng(7)
    apply(qp, random_data(rng, 2, [(0, 1)], 1, layout.n_var))
    first = qp.solve()
    assert not qp.use_osqp_wrapper  # the hot path
    kept_x, kept_y = first.x.copy(), first.y.copy()
    apply(qp, random_data(rng, 2, [(0, 1)], 1, layout.n_var))
    second = qp.solve(first.x, first.y)
    assert first.success and second.success
    assert not np.shares_memory(first.x, second.x) and not np.shares_memory(first.y, second.y)
    np.testing.assert_array_equal(first.x, kept_x)
    np.testing.assert_array_equal(first.y, kept_y)
    assert not np.array_equal(second.x, kept_x)


def test_matrix_free_products_equal_the_csc_matrix() -> None:
    layout = QPLayout(3, N, np.array([(0, 1), (1, 2)]), 2, True)
    rng = np.random.default_rng(11)
    values = rng.normal(size=layout.A_nnz)
    z, y = rng.normal(size=layout.n_var), rng.normal(size=layout.n_con)
    A = layout.csc(values, "A")
    np.testing.assert_allclose(layout.A_times(values, z), A @ z, atol=1e-12)
    np.testing.assert_allclose(layout.A_transpose_times(values, y), A.T @ y, atol=1e-12)


def _stopped_qp(rescue_solver: str | None) -> tuple[SparseQP, dict]:
    """A random QP whose OSQP solve stops after 5 ADMM iterations, unsolved."""
    layout = QPLayout(2, N, np.array([(0, 1)]), 1, True)
    settings = OSQPSettings(max_iter=5, accept_inaccurate=False, rescue_solver=rescue_solver)
    qp = SparseQP(layout, settings)
    d = random_data(np.random.default_rng(11), 2, [(0, 1)], 1, layout.n_var)
    apply(qp, d)
    return qp, d


def test_a_stopped_osqp_solve_is_rescued_by_the_interior_point_solver() -> None:
    qp, d = _stopped_qp(None)
    res = qp.solve()
    assert not res.success and res.status == "maximum iterations reached"
    assert qp.rescue_count == 0
    qp, d = _stopped_qp("clarabel")
    res = qp.solve()
    assert res.success and res.extra["rescued"] == 1.0 and qp.rescue_count == 1
    assert "clarabel" in res.status and "maximum iterations" in res.status
    # the rescued pair is a KKT point in OSQP's sign convention
    P_ref, q_ref, A_ref, l_ref, u_ref = dense_qp(2, [(0, 1)], 1, True, d)
    stationarity = P_ref @ res.x + q_ref + A_ref.T @ res.y
    assert np.abs(stationarity).max() < 1e-6
    Az = A_ref @ res.x
    assert np.all(Az >= l_ref - 1e-7) and np.all(Az <= u_ref + 1e-7)
    active_up = res.y > 1e-6
    active_lo = res.y < -1e-6
    np.testing.assert_allclose(Az[active_up], u_ref[active_up], atol=1e-6)
    np.testing.assert_allclose(Az[active_lo], l_ref[active_lo], atol=1e-6)
    # and agrees with OSQP run to convergence on the same data
    full = SparseQP(qp.layout, OSQPSettings(max_iter=100000, eps_abs=1e-8, eps_rel=1e-8))
    apply(full, d)
    ref = full.solve()
    assert ref.success
    np.testing.assert_allclose(res.x, ref.x, atol=1e-5)


def test_osqp_stopped_at_the_handover_cap_is_finished_by_piqp_in_place() -> None:
    layout = QPLayout(2, N, np.array([(0, 1)]), 1, True)
    qp = SparseQP(layout, OSQPSettings(max_iter=5, rescue_solver=None), "osqp+piqp")
    assert qp.settings.max_iter == 5  # the smaller of the cap and the settings' own
    capped = SparseQP(layout, OSQPSettings(rescue_solver=None), "osqp+piqp")
    assert capped.settings.max_iter == HANDOVER_ITERATIONS
    rng = np.random.default_rng(11)
    for _ in range(3):  # values change; PIQP is set up once, then updated
        d = random_data(rng, 2, [(0, 1)], 1, layout.n_var)
        apply(qp, d)
        res = qp.solve()
        assert res.success and "PIQP" in res.status, res.status
        P_ref, q_ref, A_ref, l_ref, u_ref = dense_qp(2, [(0, 1)], 1, True, d)
        assert np.abs(P_ref @ res.x + q_ref + A_ref.T @ res.y).max() < 1e-6
        Az = A_ref @ res.x
        assert np.all(Az >= l_ref - 1e-6) and np.all(Az <= u_ref + 1e-6)
    assert qp.handover_count == 3 and qp.handover.backend.setup_count == 1
    assert qp.rescue_count == 0


def test_unknown_rescue_solver_is_refused() -> None:
    from sqpmpc.errors import ProblemError

    with pytest.raises(ProblemError, match="rescue_solver"):
        OSQPSettings(rescue_solver="gurobi-that-is-not-installed")


def test_stage_order_makes_the_qp_block_tridiagonal() -> None:
    """In the multistage backend's order every row spans at most two consecutive stages
    (dynamics) and every other row one stage; the permutation is a bijection."""
    from sqpmpc.qp.piqp import stage_order

    layout = QPLayout(3, N, np.array([(0, 1), (0, 2), (1, 2)]), 2, True)
    order, row_stage = stage_order(layout)
    np.testing.assert_array_equal(np.sort(order), np.arange(layout.n_var))
    stage = np.empty(layout.n_var, dtype=np.int64)
    stage[layout.state_index] = np.arange(N + 1)[None, :, None]
    stage[layout.input_index] = np.arange(N)[None, :, None]
    stage[layout.slack_internal_index] = np.arange(2, N + 1)
    stage[layout.slack_external_index] = np.arange(2, N + 1)
    assert np.all(np.diff(stage[order]) >= 0)  # stages in order
    span = np.zeros(layout.n_con, dtype=np.int64)
    np.maximum.at(span, layout.A_rows, stage[layout.A_cols])
    span -= row_stage
    assert np.all(span[layout.dyn_rows.ravel()] == 1)
    others = np.setdiff1d(np.arange(layout.n_con), layout.dyn_rows.ravel())
    assert np.all(span[others] == 0)

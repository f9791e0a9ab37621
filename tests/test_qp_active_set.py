"""The active-set backend: its sparse LDL factorization, KKT points on random QPs, one
factorization from a right working set, the OSQP fallback, and the closed loop's QPs."""

from __future__ import annotations

import numpy as np
import pytest
import qpsolvers
import scipy.sparse as sp

from sqpmpc.control.settings import CENTRALIZED_QP_SOLVER, FLEET_ROBOTS, SolverSettings
from sqpmpc.kernels.kkt import ldl_factor, ldl_solve, ldl_symbolic
from sqpmpc.qp.active_set import ActiveSetBackend, ActiveSetSettings, kkt_order
from sqpmpc.qp.backend import ALL_CHANGED, OSQPSettings, make_backend
from sqpmpc.qp.layout import QPLayout
from sqpmpc.qp.sparse import SparseQP

from .test_qp import N, apply, dense_qp, random_data

CASES = [
    pytest.param(3, [(0, 1), (0, 2), (1, 2)], 0, True, id="centralized-3"),
    pytest.param(1, [], 3, False, id="decentralized-1of4"),
    pytest.param(2, [(0, 1)], 2, True, id="mixed"),
]


def _upper_csc(K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    upper = sp.csc_matrix(np.triu(K))
    upper.sort_indices()
    return (upper.indptr.astype(np.int64), upper.indices.astype(np.int64),
            upper.data.astype(float))


def test_ldl_of_a_permuted_quasi_definite_matrix_solves_it() -> None:
    """QDLDL's factorization, permuted: it solves the system as numpy does, and the
    positive pivots are the positive-definite block's size (Sylvester's inertia)."""
    rng = np.random.default_rng(3)
    n1, n2 = 12, 8
    H = rng.normal(size=(n1, n1)) * (rng.random((n1, n1)) < 0.3)
    H = H @ H.T + np.eye(n1)
    B = rng.normal(size=(n2, n1)) * (rng.random((n2, n1)) < 0.3)
    K = np.block([[H, B.T], [B, -np.diag(rng.uniform(0.1, 1.0, n2))]])
    perm = rng.permutation(n1 + n2)
    Kp, Ki, Kx = _upper_csc(K[np.ix_(perm, perm)])
    nk = n1 + n2
    etree, Lnz, iwork = (np.empty(nk, dtype=np.int64), np.empty(nk, dtype=np.int64),
                         np.empty(4 * nk, dtype=np.int64))
    nnz = ldl_symbolic(Kp, Ki, etree, Lnz, iwork)
    assert nnz >= 0
    Lp, Li, Lx = np.zeros(nk + 1, dtype=np.int64), np.zeros(nnz, dtype=np.int64), np.zeros(nnz)
    D, Dinv = np.zeros(nk), np.zeros(nk)
    positive = ldl_factor(Kp, Ki, Kx, Lp, Li, Lx, D, Dinv, Lnz, etree, iwork, np.zeros(nk))
    assert positive == n1
    b = rng.normal(size=nk)
    x = b[perm].copy()
    ldl_solve(Lp, Li, Lx, Dinv, x)
    solution = np.empty(nk)
    solution[perm] = x
    np.testing.assert_allclose(solution, np.linalg.solve(K, b), rtol=1e-10, atol=1e-10)


def test_kkt_order_is_a_permutation_in_stage_order() -> None:
    layout = QPLayout(3, N, np.array([(0, 1), (0, 2), (1, 2)]), 2, True)
    order = kkt_order(layout)
    n = layout.n_var
    np.testing.assert_array_equal(np.sort(order), np.arange(n + layout.n_con))
    stage = np.empty(n, dtype=np.int64)
    stage[layout.state_index] = np.arange(N + 1)[None, :, None]
    stage[layout.input_index] = np.arange(N)[None, :, None]
    stage[layout.slack_internal_index] = np.arange(2, N + 1)
    stage[layout.slack_external_index] = np.arange(2, N + 1)
    variables = order[order < n]
    assert np.all(np.diff(stage[variables]) >= 0)
    # every row comes after none of its own stage's variables' dynamics row: a row's
    # position lies within its stage's block
    row_stage = np.full(layout.n_con, N + 1)
    np.minimum.at(row_stage, layout.A_rows, stage[layout.A_cols])
    unknown_stage = np.concatenate((stage, row_stage))
    assert np.all(np.diff(unknown_stage[order]) >= 0)


def _reference(P_ref, q_ref, A_ref, l_ref, u_ref) -> np.ndarray:
    G = np.vstack((-A_ref, A_ref))
    h = np.concatenate((-l_ref, u_ref))
    finite = np.isfinite(h)
    problem = qpsolvers.Problem(sp.csc_matrix(P_ref), q_ref, G=sp.csc_matrix(G[finite]),
                                h=h[finite])
    ref = qpsolvers.solve_problem(problem, solver="clarabel")
    assert ref.found
    return ref.x


def _kkt_point(res_x, res_y, P_ref, q_ref, A_ref, l_ref, u_ref, tol) -> None:
    assert np.abs(P_ref @ res_x + q_ref + A_ref.T @ res_y).max() < tol
    Az = A_ref @ res_x
    assert np.all(Az >= l_ref - tol) and np.all(Az <= u_ref + tol)
    # complementarity: a multiplier only on a row at its side, of the side's sign
    up, lo = res_y > 0.0, res_y < 0.0
    assert np.all(np.isfinite(u_ref[up])) and np.all(np.isfinite(l_ref[lo]))
    assert np.all(res_y[up] * (u_ref[up] - Az[up]) < tol)
    assert np.all(-res_y[lo] * (Az[lo] - l_ref[lo]) < tol)


@pytest.mark.parametrize(("m", "pairs", "E", "pos"), CASES)
def test_active_set_finds_the_kkt_point_and_one_factorization_from_it(m, pairs, E, pos
                                                                      ) -> None:
    """From the working set of a solution of a close QP the method needs one factorization
    and no fallback; its answer is the QP's KKT point (Clarabel's solution, residuals to
    round-off) on the dense rebuild; in-place updates equal the rebuild."""
    layout = QPLayout(m, N, np.array(pairs, dtype=np.int64).reshape(-1, 2), E, pos)
    settings = OSQPSettings(eps_abs=1e-9, eps_rel=1e-9, max_iter=100000, polishing=True,
                            rescue_solver=None)
    qp = SparseQP(layout, settings, "active-set")
    assert isinstance(qp.backend, ActiveSetBackend) and qp.handover is None
    rng = np.random.default_rng(7)
    data = random_data(rng, m, pairs, E, layout.n_var)
    apply(qp, data)
    first = qp.solve()
    assert first.success, first.status
    # the same QP with its right-hand sides moved a little (a next sample's): warm-started
    data["x0"] = data["x0"] + 1e-4
    data["c"] = data["c"] + 1e-5
    apply(qp, data)
    before = qp.backend.fallback_count
    res = qp.solve(first.x, first.y)
    assert res.success and res.status == "solved", res.status
    assert res.extra["factorizations"] == 1 and qp.backend.fallback_count == before
    P_ref, q_ref, A_ref, l_ref, u_ref = dense_qp(m, pairs, E, pos, data)
    P, q, A, lo, up = qp.matrices()
    np.testing.assert_allclose(A.toarray(), A_ref, atol=1e-14)
    np.testing.assert_allclose(q, q_ref, atol=1e-13)
    _kkt_point(res.x, res.y, P_ref, q_ref, A_ref, l_ref, u_ref, 1e-8)
    assert res.primal_residual < 1e-9 and res.dual_residual < 1e-9  # the settings' eps_abs
    # Clarabel, at its default tolerances, agrees to its own accuracy
    np.testing.assert_allclose(res.x, _reference(P_ref, q_ref, A_ref, l_ref, u_ref), atol=2e-5)


@pytest.mark.parametrize("fallback", ["piqp", "osqp"])
def test_a_working_set_that_does_not_settle_goes_to_the_fallback(fallback: str) -> None:
    """Capped at one factorization from a cold start, the method hands the QP to its
    fallback, which solves it; the next QP, warm-started from that solution, is its own
    again."""
    m, pairs, E, pos = 3, [(0, 1), (0, 2), (1, 2)], 0, True
    layout = QPLayout(m, N, np.array(pairs), E, pos)
    settings = OSQPSettings(eps_abs=1e-7, eps_rel=1e-7, max_iter=100000, rescue_solver=None)
    backend = ActiveSetBackend(layout, settings, ActiveSetSettings(max_iter=1,
                                                                   fallback=fallback))
    qp = SparseQP(layout, settings, "osqp")
    data = random_data(np.random.default_rng(7), m, pairs, E, layout.n_var)
    apply(qp, data)
    values = (qp.P_values, qp.q, qp.A_values, qp.lower, qp.upper)
    sol = backend.solve(*values, ALL_CHANGED, np.zeros(layout.n_var), np.zeros(layout.n_con))
    assert sol.solved and f"by {fallback}" in sol.status and backend.fallback_count == 1
    assert sol.extra["fallback"] == 1.0
    _kkt_point(sol.x, sol.y, *dense_qp(m, pairs, E, pos, data), 1e-5)
    again = backend.solve(*values, ALL_CHANGED, sol.x, sol.y)
    assert again.solved and again.status == "solved" and backend.fallback_count == 1
    np.testing.assert_allclose(again.x, sol.x, atol=1e-5)


def test_the_closed_loop_qps_need_no_fallback_and_match_osqp() -> None:
    """paper-s2 centralized, 10 s: auto picks the active-set method; every QP after the
    first sample is solved by it, and OSQP, replaying the same QP, finds the same
    solution to its tolerance."""
    import sqpmpc
    from sqpmpc.sim.simulation import ClosedLoopSimulation

    assert SolverSettings().qp_solver_for(4, "centralized") == CENTRALIZED_QP_SOLVER
    assert SolverSettings().qp_solver_for(FLEET_ROBOTS + 1, "centralized") != "active-set"
    assert SolverSettings().qp_solver_for(4, "decentralized") != "active-set"
    assert SolverSettings().qp_solver_for(4, "centralized", velocity_states=True) != "active-set"
    sc = sqpmpc.load_scenario("paper-s2").with_changes(t_end=10.0)
    sim = ClosedLoopSimulation(sc, "centralized")
    qp = sim.controllers[0].engine.qp
    assert qp.solver_name == "active-set"
    osqp = make_backend("osqp", qp.layout, OSQPSettings())
    backend = qp.backend
    solve = backend.solve
    differences: list[float] = []

    def compared(*args):  # noqa: ANN202 - BackendSolution
        sol = solve(*args)
        ref = osqp.solve(*args[:5], ALL_CHANGED, *args[6:])
        if ref.solved:
            differences.append(float(np.abs(sol.x - ref.x).max()))
        return sol

    backend.solve = compared
    sim.run()
    assert backend.fallback_count == 0
    assert len(differences) >= sc.steps
    assert max(differences) < 1e-3

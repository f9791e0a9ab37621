r"""The active-set backend of :class:`sqpmpc.qp.sparse.SparseQP` (``qp_solver="active-set"``):
a primal-dual active-set method on the sparse KKT system, warm-started from the
previous sample, with PIQP behind it.

A real-time iteration's QP differs little from the previous sample's: the
working set (the rows at a bound) of the shifted solution is usually the new
QP's too, and then one factorization of the KKT matrix solves the QP exactly
(to round-off, after iterative refinement), where ADMM needs tens of
iterations for the same tolerance (measured on paper-s2 centralized: OSQP's
median 30 iterations from the same warm start; this method's mean 1.03
factorizations). The iteration (:func:`sqpmpc.kernels.kkt.active_set_solve`)
updates the working set by the semismooth-Newton rule

.. math::

    i \text{ at } u_i \iff y_i + c\,(a_i z - u_i) > 0, \qquad
    i \text{ at } l_i \iff y_i + c\,(a_i z - l_i) < 0,

and stops when it reproduces the working set: then :math:`(z, y)` satisfies the
KKT conditions of the QP. Each iteration is one :math:`LDL^\top` of the
quasi-definite matrix

.. math::

    \begin{pmatrix} P + \delta I & \tilde A^\top \\ \tilde A & -E \end{pmatrix}

on a pattern fixed at construction (rows off the working set have their
entries zeroed and :math:`E_{ii} = 1`, so their multipliers are exactly 0),
in *stage order*: the variables and rows of stage 0, then stage 1, ... (the
order of :func:`sqpmpc.qp.piqp.stage_order`, each stage's rows that bound its
own variables first, its dynamics rows last), which keeps the factor's fill
close to a minimum-degree ordering's on these banded systems and needs no
ordering library.

The answer is accepted only when its primal and dual residuals are within the
settings' ``eps_abs`` (the tolerance OSQP is held to): otherwise, or when the
working set does not settle within :data:`ACTIVE_SET_MAX_ITER` factorizations
(the method is not globally convergent: on QPs whose warm start is far off, as
a robot head-on with a moving obstacle, the working set can cycle), the same QP
goes to PIQP (``ActiveSetSettings.fallback``, set up on first need), and
:class:`~sqpmpc.qp.sparse.SparseQP`'s interior-point rescue is behind that. The
fallback is an accurate solver on purpose: the closed loop then follows the
QPs' exact solutions throughout (with OSQP's 1e-5 answers mixed in, the robot
head-on with a moving obstacle did not get round it in 45 s; with PIQP it does,
as with PIQP alone).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from sqpmpc.errors import SolverError
from sqpmpc.kernels.kkt import (
    ACTIVE_SET_CONVERGED,
    active_set_solve,
    ldl_symbolic,
    qp_residuals,
)
from sqpmpc.qp.backend import ALL_CHANGED, BackendSolution, Changes, OSQPSettings, make_backend
from sqpmpc.qp.layout import QPLayout
from sqpmpc.qp.piqp import stages

__all__ = ["ACTIVE_SET_MAX_ITER", "ActiveSetBackend", "ActiveSetSettings", "kkt_order"]

#: Factorizations before a QP is handed to the fallback (PIQP).
ACTIVE_SET_MAX_ITER = 8


@dataclass(frozen=True)
class ActiveSetSettings:
    r"""The active-set iteration's constants.

    ``delta``, ``epsilon``: the regularization :math:`\delta` of :math:`P` and
    :math:`\varepsilon` of the working rows (removed by ``refinements`` steps of
    iterative refinement); ``c``: the working-set rule's constant (on the
    closed loops' warm-started QPs 1 and 10 need the same factorizations, 1.03-1.04
    per QP on paper-s2 centralized; from a cold start on random QPs 10 settled on 9 of
    12, 1 on 5);
    ``max_iter``: factorizations before the ``fallback`` backend (a
    :data:`~sqpmpc.qp.backend.BACKENDS` name) takes the QP.
    """

    delta: float = 1e-9
    epsilon: float = 1e-9
    c: float = 10.0
    tau: float = 1e-7
    max_iter: int = ACTIVE_SET_MAX_ITER
    refinements: int = 1
    fallback: str = "piqp"


def kkt_order(layout: QPLayout) -> np.ndarray:
    """The KKT system's unknowns (``n_var`` variables, then ``n_con`` multipliers) in stage
    order: position ``k`` holds unknown ``order[k]``.

    Primary key the stage (a variable's stage as in :func:`sqpmpc.qp.piqp.stages`, a
    row's the smallest stage of its variables), then within a stage: rows that bound or
    couple that stage's variables, slacks, inputs, states, and last the dynamics and
    initial-state rows.
    """
    L = layout
    stage, row_stage = stages(L)
    var_kind = np.full(L.n_var, 1, dtype=np.int64)  # slacks
    var_kind[L.input_index] = 2
    var_kind[L.state_index] = 3
    row_kind = np.zeros(L.n_con, dtype=np.int64)
    row_kind[L.dyn_rows.ravel()] = row_kind[L.init_rows.ravel()] = 4
    return np.lexsort((np.concatenate((var_kind, row_kind)),
                       np.concatenate((stage, row_stage))))


class ActiveSetBackend:
    """The primal-dual active-set method (module docstring) on a :class:`QPLayout`.

    Parameters
    ----------
    layout
        Index maps and sparsity.
    settings
        OSQP's settings: ``eps_abs`` bounds the accepted residuals; the fallback
        runs with them (PIQP: its tolerances).
    active_set
        The iteration's constants.

    Attributes
    ----------
    setup_count
        Symbolic set-ups (1: the pattern is analysed at construction).
    fallback_count
        QPs handed to the fallback so far.
    """

    name = "active-set"

    def __init__(self, layout: QPLayout, settings: OSQPSettings,
                 active_set: ActiveSetSettings | None = None) -> None:
        self.layout = L = layout
        self.settings = settings
        self.active_set = active_set or ActiveSetSettings()
        self.fallback: object | None = None
        self.fallback_count = 0
        n, m = L.n_var, L.n_con
        nk = n + m
        pattern = L.P_pattern
        csc_cols = np.repeat(np.arange(pattern.shape[1]), np.diff(pattern.indptr))
        self.P_rows = np.ascontiguousarray(pattern.indices[L.P_order], dtype=np.int64)
        self.P_cols = np.ascontiguousarray(csc_cols[L.P_order], dtype=np.int64)
        if not (np.array_equal(self.P_rows[:n], np.arange(n))
                and np.array_equal(self.P_cols[:n], np.arange(n))):
            raise SolverError("internal error: P's first entries are not its diagonal")
        self.A_rows = np.ascontiguousarray(L.A_rows, dtype=np.int64)
        self.A_cols = np.ascontiguousarray(L.A_cols, dtype=np.int64)
        # the KKT matrix's upper triangle: P's entries, A's as (column, n + row), the diagonal
        rows = np.concatenate((self.P_rows, self.A_cols, n + np.arange(m)))
        cols = np.concatenate((self.P_cols, n + self.A_rows, n + np.arange(m)))
        self.order = kkt_order(L)
        position = np.empty(nk, dtype=np.int64)
        position[self.order] = np.arange(nk)
        r, c = position[rows], position[cols]
        r, c = np.minimum(r, c), np.maximum(r, c)
        csc = np.lexsort((r, c))
        if np.unique(c * nk + r).size != r.size:
            raise SolverError("internal error: duplicate entries in the KKT pattern")
        self.K_source = csc.astype(np.int64)  # entry index into (P, A, diagonal)
        self.Kp = np.zeros(nk + 1, dtype=np.int64)
        np.cumsum(np.bincount(c, minlength=nk), out=self.Kp[1:])
        self.Ki = np.ascontiguousarray(r[csc], dtype=np.int64)
        self.Kx = np.zeros(r.size)
        self.etree = np.empty(nk, dtype=np.int64)
        self.Lnz = np.empty(nk, dtype=np.int64)
        self.iwork = np.empty(4 * nk, dtype=np.int64)
        nnz = ldl_symbolic(self.Kp, self.Ki, self.etree, self.Lnz, self.iwork)
        if nnz < 0:
            raise SolverError("internal error: the KKT pattern is not upper triangular")
        self.Lp = np.zeros(nk + 1, dtype=np.int64)
        self.Li = np.zeros(max(nnz, 1), dtype=np.int64)
        self.Lx = np.zeros(max(nnz, 1))
        self.D = np.zeros(nk)
        self.Dinv = np.zeros(nk)
        self.fwork = np.zeros(3 * nk)
        self.side = np.zeros(m, dtype=np.int8)
        self.setup_count = 1
        self._z = np.zeros(n)
        self._y = np.zeros(m)

    @property
    def factor_nnz(self) -> int:
        r"""Entries of the factor :math:`L` (below the diagonal)."""
        return int(self.Lnz.sum())

    def solve(self, P_values: np.ndarray, q: np.ndarray, A_values: np.ndarray,
              lower: np.ndarray, upper: np.ndarray, changed: Changes,
              warm_x: np.ndarray | None = None, warm_y: np.ndarray | None = None
              ) -> BackendSolution:
        """Solve the QP with these values (the :class:`~sqpmpc.qp.backend.QPBackend`
        protocol); the iteration starts from ``(warm_x, warm_y)`` (default: the last
        solution). Every value is read each call."""
        s = self.active_set
        z = self._z if warm_x is None else np.array(warm_x, dtype=float)
        y = self._y if warm_y is None else np.array(warm_y, dtype=float)
        z0, y0 = z.copy(), y.copy()
        t0 = time.perf_counter()
        status, factorizations = active_set_solve(
            P_values, self.P_rows, self.P_cols, q, A_values, self.A_rows, self.A_cols,
            lower, upper, z, y, self.K_source, self.Kp, self.Ki, self.Kx, self.order,
            self.Lp, self.Li, self.Lx, self.D, self.Dinv, self.Lnz, self.etree, self.iwork,
            self.fwork, self.side, s.delta, s.epsilon, s.c, s.tau, s.max_iter, s.refinements)
        primal = dual = objective = float("inf")
        if status == ACTIVE_SET_CONVERGED:
            primal, dual, objective = qp_residuals(P_values, self.P_rows, self.P_cols, q, A_values,
                                        self.A_rows, self.A_cols, lower, upper, z, y)
        elapsed = time.perf_counter() - t0
        tolerance = self.settings.eps_abs
        if status == ACTIVE_SET_CONVERGED and primal <= tolerance and dual <= tolerance:
            self._z, self._y = z, y
            return BackendSolution(z.copy(), y.copy(), True, "solved", int(factorizations),
                                   elapsed, objective, float(primal), float(dual),
                                   extra={"factorizations": float(factorizations),
                                          "fallback": 0.0})
        return self._fall_back(P_values, q, A_values, lower, upper, z0, y0,
                               int(factorizations), elapsed)

    def _fall_back(self, P_values: np.ndarray, q: np.ndarray, A_values: np.ndarray,
                   lower: np.ndarray, upper: np.ndarray, warm_x: np.ndarray,
                   warm_y: np.ndarray, factorizations: int, spent: float) -> BackendSolution:
        """The QP by the fallback (every value pushed: it has not seen the QPs solved
        here)."""
        if self.fallback is None:
            self.fallback = make_backend(self.active_set.fallback, self.layout, self.settings)
        self.fallback_count += 1
        sol = self.fallback.solve(P_values, q, A_values, lower, upper, ALL_CHANGED, warm_x,
                                  warm_y)
        if sol.solved:
            self._z, self._y = sol.x.copy(), sol.y.copy()
        sol.iterations += factorizations
        sol.solve_time += spent
        sol.extra["factorizations"] = float(factorizations)
        sol.extra["fallback"] = 1.0
        if sol.solved:
            sol.status = (f"solved by {self.fallback.name} after {factorizations} active-set "
                          "factorizations")
        return sol


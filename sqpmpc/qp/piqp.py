r"""PIQP as the QP backend of :class:`sqpmpc.qp.sparse.SparseQP` (``qp_solver="piqp"``).

PIQP (a proximal interior-point method) takes

.. math::

    \min \tfrac12 z^\top P z + c^\top z \quad\text{s.t.}\quad A_e z = b,\;
    h_l \le G z \le h_u,

so the layout's rows are split once: the initial-state and dynamics rows
(equalities by construction) form :math:`A_e`, the rows that bound one
variable (inputs, positions, velocities, slacks) become PIQP's variable bounds
:math:`x_l \le z \le x_u` (fewer rows to factorize: on a robot's QP with
8 neighbour slots, 136 inequality rows become 64 rows and 72 bounds), every
other row :math:`G`.
Both patterns are fixed; every solve copies the current values into them
through index maps and calls PIQP's ``update`` (no new setup). The duals are
returned in OSQP's convention (:math:`Pz + q + A^\top y = 0`): ``y`` on the
equality rows, :math:`z_u - z_l` on the others and :math:`z_{bu} - z_{bl}` on
the bound rows.

Measured on the QPs the controllers solve (``docs/qp-backends.md``): an
interior-point method needs about 10 iterations whatever the conditioning, so
its time is nearly constant; OSQP is faster on most QPs but has a long tail
on ill-conditioned ones (robots pressed together). On swap-6 decentralized
PIQP's mean was 2.2 times lower than OSQP's, on paper-s2 OSQP's was lower.
PIQP has no warm start and no time limit; OSQP stays the default.

``multistage=True`` (backend ``"piqp-multistage"``) hands PIQP the same QP with
its variables and rows in *stage order*: stage ``k`` holds every own robot's
:math:`(\chi_k, u_k)` and the slacks of the collision rows of stage ``k``, so
the dynamics couple only neighbouring stages and every collision row lies in
one stage. PIQP's multistage KKT solver (``KKTSolver.sparse_multistage``,
piqp >= 0.7) detects that block-tridiagonal structure and factorizes it stage
by stage (a Riccati-like recursion on dense blocks) instead of with a general
sparse LDL^T. The permutation is fixed at construction; values are copied
through index maps as before and the solution is returned in the layout's
order.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from sqpmpc.errors import SolverError
from sqpmpc.kernels.ocp import split_rows
from sqpmpc.qp.backend import BackendSolution, Changes
from sqpmpc.qp.layout import QPLayout

__all__ = ["PIQPBackend", "stage_order", "stages"]

_INFINITY = 1e30
_ROW, _EQUALITY, _BOUND = 0, 1, 2
_FREE = 1e20
"""Rows with both bounds beyond this are off: PIQP gets ``0 <= 1`` instead (it warns on
stderr about rows free on both sides and zeroes them anyway)."""


class PIQPBackend:
    """PIQP's sparse solver on a :class:`QPLayout`, set up once, then updated in place.

    Parameters
    ----------
    layout
        Index maps and sparsity.
    eps_abs, eps_rel
        PIQP's absolute and relative tolerances.
    max_iter
        PIQP's iteration cap.
    multistage
        Variables and rows in stage order and PIQP's multistage KKT solver
        (:func:`stage_order`).
    """

    name = "piqp"

    def __init__(self, layout: QPLayout, eps_abs: float, eps_rel: float, max_iter: int,
                 multistage: bool = False) -> None:
        import piqp

        self._piqp = piqp
        self.layout = L = layout
        self.multistage = bool(multistage)
        if self.multistage:
            self.name = "piqp-multistage"
        # variable permutation: new index i holds the layout's variable order[i]
        order, row_stage = stage_order(L) if self.multistage else (
            np.arange(L.n_var), np.zeros(L.n_con, dtype=np.int64))
        self._order = order
        self._position = np.empty(L.n_var, dtype=np.int64)
        self._position[order] = np.arange(L.n_var)
        kind = np.full(L.n_con, _ROW)
        kind[L.init_rows.ravel()] = kind[L.dyn_rows.ravel()] = _EQUALITY
        # rows that bound one variable with coefficient 1 (inputs, positions, velocities, slacks)
        self.bound_rows = np.concatenate(
            [L.input_rows.ravel(), L.position_rows.ravel(), L.velocity_rows.ravel(),
             L.slack_rows.ravel()]).astype(np.int64)
        kind[self.bound_rows] = _BOUND
        eq_rows = np.flatnonzero(kind == _EQUALITY)
        ineq_rows = np.flatnonzero(kind == _ROW)
        # rows in stage order (stable: the layout's order within a stage)
        self.eq_rows = eq_rows[np.argsort(row_stage[eq_rows], kind="stable")]
        self.ineq_rows = ineq_rows[np.argsort(row_stage[ineq_rows], kind="stable")]
        # entry ids (1-based) carried through the row split give each block's value map
        ids = sp.csr_matrix((np.arange(1, L.A_nnz + 1, dtype=float),
                             (L.A_rows, self._position[L.A_cols])), shape=(L.n_con, L.n_var))
        bounds = ids[self.bound_rows]
        if np.any(np.diff(bounds.indptr) != 1):
            raise SolverError("PIQP backend: a bound row of the layout has more than one entry")
        self.bound_vars = bounds.indices.astype(np.int64)  # in PIQP's variable order
        self._x_l = np.full(L.n_var, -np.inf)
        self._x_u = np.full(L.n_var, np.inf)
        self.A_eq, self._eq_entries = _block(ids, self.eq_rows)
        self.G, self._g_entries = _block(ids, self.ineq_rows)
        self._g_rows = np.ascontiguousarray(self.G.indices, dtype=np.int64)
        self._b = np.zeros(self.eq_rows.size)
        self._h_l = np.zeros(self.ineq_rows.size)
        self._h_u = np.zeros(self.ineq_rows.size)
        self.P, self._P_entries = _permuted_upper(L, self._position)
        self._q = np.zeros(L.n_var)
        self.settings = (eps_abs, eps_rel, max_iter)
        self.solver: object | None = None
        self.setup_count = 0

    def solve(self, P_values: np.ndarray, q: np.ndarray, A_values: np.ndarray,
              lower: np.ndarray, upper: np.ndarray, changed: Changes,
              warm_x: np.ndarray | None = None, warm_y: np.ndarray | None = None
              ) -> BackendSolution:
        """Solve the QP with these values (entry order, as :class:`SparseQP` keeps them;
        the :class:`~sqpmpc.qp.backend.QPBackend` protocol, no warm start); ``P`` is
        handed over again only when ``changed.P``."""
        P_changed = changed.P
        if P_changed or self.solver is None:
            self.P.data[:] = P_values[self._P_entries]
        b, h_l, h_u, x_l, x_u = self._b, self._h_l, self._h_u, self._x_l, self._x_u
        split_rows(A_values, lower, upper, self._eq_entries, self._g_entries, self._g_rows,
                   self.eq_rows, self.ineq_rows, _FREE, _INFINITY, self.A_eq.data, self.G.data,
                   b, h_l, h_u)
        x_l[self.bound_vars] = np.maximum(lower[self.bound_rows], -_INFINITY)
        x_u[self.bound_vars] = np.minimum(upper[self.bound_rows], _INFINITY)
        q = np.take(q, self._order, out=self._q)
        t0 = time.perf_counter()
        if self.solver is None:
            solver = self._piqp.SparseSolver()
            eps_abs, eps_rel, max_iter = self.settings
            solver.settings.eps_abs, solver.settings.eps_rel = eps_abs, eps_rel
            solver.settings.max_iter = max_iter
            if self.multistage:
                solver.settings.kkt_solver = self._piqp.KKTSolver.sparse_multistage
            # the QPs of consecutive samples are alike: keep the first Ruiz scaling
            solver.settings.preconditioner_reuse_on_update = True
            solver.setup(self.P, q, self.A_eq, b, self.G, h_l, h_u, x_l, x_u)
            self.solver = solver
            self.setup_count += 1
        else:
            self.solver.update(P=self.P if P_changed else None, c=q, A=self.A_eq, b=b,
                               G=self.G, h_l=h_l, h_u=h_u, x_l=x_l, x_u=x_u)
        status = self.solver.solve()
        elapsed = time.perf_counter() - t0
        result = self.solver.result
        y = np.zeros(self.layout.n_con)
        y[self.eq_rows] = result.y
        y[self.ineq_rows] = result.z_u - result.z_l
        y[self.bound_rows] = (result.z_bu - result.z_bl)[self.bound_vars]
        info = result.info
        return BackendSolution(np.asarray(result.x, dtype=float)[self._position], y,
                               status == self._piqp.PIQP_SOLVED, f"PIQP: {status}",
                               int(info.iter), elapsed, float(info.primal_obj),
                               float(info.primal_res), float(info.dual_res))


def stages(layout: QPLayout) -> tuple[np.ndarray, np.ndarray]:
    """The stage of every variable and of every row of the layout.

    Stage ``k`` (0..N) holds every own robot's state of stage ``k``, its input
    of stage ``k`` (k < N) and the slacks of the collision rows on stage ``k``.
    A row's stage is the smallest stage of its variables: the dynamics rows
    from ``k`` to ``k + 1`` are stage ``k``, every other row lies in one stage.

    Returns
    -------
    tuple[np.ndarray, np.ndarray]
        ``stage (n_var,)`` and ``row_stage (n_con,)``.
    """
    L = layout
    N = L.horizon
    stage = np.full(L.n_var, -1, dtype=np.int64)
    stage[L.state_index] = np.arange(N + 1)[None, :, None]
    stage[L.input_index] = np.arange(N)[None, :, None]
    # the slack of collision row stage j + 2 (rows on stages 2..N carry slacks)
    stage[L.slack_internal_index] = np.arange(2, N + 1)[None, :]
    stage[L.slack_external_index] = np.arange(2, N + 1)[None, None, :]
    if np.any(stage < 0):
        raise SolverError("internal error: a QP variable without a stage")
    row_stage = np.full(L.n_con, N + 1, dtype=np.int64)
    np.minimum.at(row_stage, L.A_rows, stage[L.A_cols])
    return stage, row_stage


def stage_order(layout: QPLayout) -> tuple[np.ndarray, np.ndarray]:
    """The layout's variables in stage order (:func:`stages`) and the stage of every row.

    Returns
    -------
    tuple[np.ndarray, np.ndarray]
        ``order (n_var,)``: position ``i`` holds the layout's variable
        ``order[i]``; ``row_stage (n_con,)``.
    """
    stage, row_stage = stages(layout)
    return np.argsort(stage, kind="stable"), row_stage


def _permuted_upper(layout: QPLayout, position: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
    """The upper triangle of ``P`` with variable ``v`` at ``position[v]``, and for each of
    its CSC entries the entry index of the layout's ``P`` values."""
    pattern = layout.P_pattern.tocoo()
    entry_of_csc = np.argsort(layout.P_order)  # the layout's CSC position -> entry index
    # tocoo keeps CSC order: data position k is the layout's CSC position k
    r, c = position[pattern.row], position[pattern.col]
    upper = sp.csc_matrix((entry_of_csc + 1.0, (np.minimum(r, c), np.maximum(r, c))),
                          shape=pattern.shape)
    upper.sort_indices()
    entries = upper.data.astype(np.int64) - 1
    upper.data[:] = 1.0
    return upper, entries


def _block(ids: sp.csr_matrix, rows: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
    """The rows ``rows`` of the entry-id matrix as CSC, and their entry indices."""
    block = ids[rows].tocsc()
    block.sort_indices()
    return block, block.data.astype(np.int64) - 1

r"""DAQP as the QP backend of :class:`sqpmpc.qp.sparse.SparseQP` (``qp_solver="daqp"``).

DAQP is a dual active-set solver for dense QPs,

.. math::

    \min \tfrac12 z^\top H z + f^\top z \quad\text{s.t.}\quad b_l \le A z \le b_u,

with rows marked as equalities (the initial-state and dynamics rows here).
One ``daqp.Model`` is set up once; every solve writes the current values into
the same dense ``H`` and ``A`` through the layout's index maps and calls
``update`` *without* new constraint senses, so DAQP starts from the previous
sample's active set (a hot start: about 1.5 active-set iterations per QP on
the per-robot QPs). The semidefinite cost (no weight on headings and slacks)
is regularized by DAQP's automatic proximal term. Duals come back in OSQP's
convention (:math:`Hz + f + A^\top y = 0`).

Measured on the controllers' QPs (``docs/engine.md``): faster than OSQP on
the small decentralized QPs, much slower on the centralized ones (dense
factorizations of 200-400 variables). OSQP stays the default.
"""

from __future__ import annotations

import time

import numpy as np

from sqpmpc.qp.backend import BackendSolution, Changes
from sqpmpc.qp.layout import QPLayout

__all__ = ["DAQPBackend"]

_INFINITY = 1e30
_EQUALITY = 5


class DAQPBackend:
    """A hot-started ``daqp.Model`` on a :class:`QPLayout`.

    Parameters
    ----------
    layout
        Index maps and sparsity.
    """

    name = "daqp"

    def __init__(self, layout: QPLayout) -> None:
        import daqp

        self._daqp = daqp
        self.layout = L = layout
        self.H = np.zeros((L.n_var, L.n_var))
        self.A = np.zeros((L.n_con, L.n_var))
        pattern = L.P_pattern
        csc_rows = pattern.indices
        csc_cols = np.repeat(np.arange(pattern.shape[1]), np.diff(pattern.indptr))
        self._P_rows = csc_rows[L.P_order]  # entry order -> (row, col)
        self._P_cols = csc_cols[L.P_order]
        self.sense = np.zeros(L.n_con, dtype=np.int32)
        self.sense[L.init_rows.ravel()] = _EQUALITY
        self.sense[L.dyn_rows.ravel()] = _EQUALITY
        self.model: object | None = None
        self.setup_count = 0

    def solve(self, P_values: np.ndarray, q: np.ndarray, A_values: np.ndarray,
              lower: np.ndarray, upper: np.ndarray, changed: Changes,
              warm_x: np.ndarray | None = None, warm_y: np.ndarray | None = None
              ) -> BackendSolution:
        """Solve the QP with these values (entry order, as :class:`SparseQP` keeps them;
        the :class:`~sqpmpc.qp.backend.QPBackend` protocol, no warm start); ``H`` is
        handed over again only when ``changed.P``."""
        P_changed = changed.P
        L = self.layout
        if P_changed or self.model is None:
            self.H[self._P_rows, self._P_cols] = P_values
            self.H[self._P_cols, self._P_rows] = P_values
        self.A[L.A_rows, L.A_cols] = A_values
        b_u = np.minimum(upper, _INFINITY)
        b_l = np.maximum(lower, -_INFINITY)
        t0 = time.perf_counter()
        if self.model is None:
            model = self._daqp.Model()
            model.setup(self.H, q, self.A, b_u, b_l, self.sense)
            self.model = model
            self.setup_count += 1
        else:
            self.model.update(H=self.H if P_changed else None, f=q, A=self.A, bupper=b_u,
                              blower=b_l)
        x, _, flag, info = self.model.solve()
        elapsed = time.perf_counter() - t0
        y = np.asarray(info["lam"], dtype=float).copy()
        return BackendSolution(np.asarray(x, dtype=float).copy(), y, flag == 1,
                               f"DAQP exit flag {flag}", int(info["iterations"]), elapsed)

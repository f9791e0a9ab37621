"""What :class:`sqpmpc.qp.sparse.SparseQP` does when its backend leaves a QP unsolved.

Two explicit policies, applied in this order to a solve that did not give a
finite solved pair and did not run out of its time limit:

1. :class:`HandOver` (``qp_solver="osqp+piqp"``): OSQP is capped at
   :data:`~sqpmpc.qp.backend.HANDOVER_ITERATIONS` iterations and PIQP, set
   up once and updated in place, finishes the QPs it leaves;
2. :class:`Rescue` (``OSQPSettings.rescue_solver``, Clarabel by default): the
   same QP rebuilt and solved by an interior-point solver through
   ``qpsolvers`` (:func:`~sqpmpc.qp.backend.solve_interior_point`).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

from sqpmpc.kernels.ocp import all_finite
from sqpmpc.qp.backend import ALL_CHANGED, BackendSolution, QPBackend, solve_interior_point

__all__ = ["HandOver", "Rescue"]

Matrices = tuple[sp.csc_matrix, np.ndarray, sp.csc_matrix, np.ndarray, np.ndarray]


class HandOver:
    """A second backend that takes the QPs the first one leaves.

    Parameters
    ----------
    backend
        The backend that finishes (PIQP).

    Attributes
    ----------
    count
        QPs handed over so far.
    """

    def __init__(self, backend: QPBackend) -> None:
        self.backend = backend
        self.count = 0

    def apply(self, first: BackendSolution, P_values: np.ndarray, q: np.ndarray,
              A_values: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> BackendSolution:
        """The same QP by :attr:`backend`, after ``first`` failed: a solved solution says
        how many iterations the first backend spent; iterations and time add up."""
        sol = self.backend.solve(P_values, q, A_values, lower, upper, ALL_CHANGED)
        self.count += 1
        iterations = first.iterations + sol.iterations
        solve_time = first.solve_time + sol.solve_time
        if sol.solved and all_finite(sol.x) and all_finite(sol.y):
            return BackendSolution(
                sol.x, sol.y, True, f"solved by PIQP after {first.iterations} OSQP iterations",
                iterations, solve_time, first.objective, first.primal_residual,
                first.dual_residual, extra=first.extra)
        return BackendSolution(first.x, first.y, False, first.status, iterations, solve_time,
                               first.objective, first.primal_residual, first.dual_residual,
                               extra=first.extra)


class Rescue:
    """The interior-point rescue of a QP no backend solved.

    Parameters
    ----------
    solver
        A ``qpsolvers`` backend name (``"clarabel"``).

    Attributes
    ----------
    count
        QPs rescued so far.
    """

    def __init__(self, solver: str) -> None:
        self.solver = solver
        self.count = 0

    def apply(self, failed: BackendSolution, matrices: Callable[[], Matrices]
              ) -> tuple[BackendSolution, bool]:
        """``(solution, rescued)``: the QP of ``matrices()`` solved by :attr:`solver`
        (its time added), or ``failed`` with a status saying the rescue failed too."""
        t0 = time.perf_counter()
        rescue = solve_interior_point(*matrices(), solver=self.solver)
        spent = time.perf_counter() - t0
        f = failed
        if rescue is None:
            return BackendSolution(f.x, f.y, False,
                                   f"{f.status}; {self.solver} found no solution either",
                                   f.iterations, f.solve_time + spent, f.objective,
                                   f.primal_residual, f.dual_residual, extra=f.extra), False
        self.count += 1
        x, y = rescue
        return BackendSolution(x, y, True, f"solved by {self.solver} ({f.status})",
                               f.iterations, f.solve_time + spent, f.objective,
                               f.primal_residual, f.dual_residual, extra=f.extra), True

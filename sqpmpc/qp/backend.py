"""QP data shared by every backend: the backend protocol and its registry by name, OSQP's
settings, one solve's result and the interior-point reference solve.

Every backend (:mod:`sqpmpc.qp.osqp_backend`, :mod:`sqpmpc.qp.piqp`,
:mod:`sqpmpc.qp.daqp`, :mod:`sqpmpc.qp.active_set`) implements :class:`QPBackend`: one
``solve`` on the values of the fixed pattern, told what changed since its last solve.
:func:`make_backend` builds one by name, importing its module only then.
The two policies around a backend (the OSQP-to-PIQP hand-over and the
interior-point rescue) are in :mod:`sqpmpc.qp.policies`.
"""

from __future__ import annotations

import importlib
import warnings
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Protocol

import numpy as np
import qpsolvers
import scipy.sparse as sp

from sqpmpc.errors import ProblemError

if TYPE_CHECKING:
    from sqpmpc.qp.layout import QPLayout

__all__ = [
    "ALL_CHANGED", "BACKENDS", "HANDOVER_ITERATIONS", "OSQPSettings", "PIQP_MAX_ITER",
    "QPBackend", "QPResult", "QP_SOLVERS", "BackendSolution", "Changes", "make_backend",
    "solve_interior_point",
]


#: QP backends of :class:`SparseQP`.
QP_SOLVERS = ("osqp", "piqp", "piqp-multistage", "daqp", "osqp+piqp", "active-set")


#: ``"osqp+piqp"``: OSQP iterations before a QP is handed to PIQP.
HANDOVER_ITERATIONS = 100


#: PIQP's iteration cap (an interior-point method needs about 10 here).
PIQP_MAX_ITER = 250


@dataclass(frozen=True)
class OSQPSettings:
    """OSQP settings used by the controllers (see the OSQP documentation).

    Tolerances are tighter than OSQP's defaults: the collision rows carry a
    safety margin of 1e-3 m by default, and ``eps_abs`` must stay well below it.
    ``time_limit`` (s, 0 for none) bounds a solve for real-time use: a QP that
    runs out of time is a failed QP, and the controller applies its fallback.

    ``time_limit``: seconds a solve may take, or ``None``.

    ``rescue_solver``: ADMM can need tens of thousands of iterations on the
    ill-conditioned QPs of robots pressed against each other (measured: up to
    97,000 where the interior-point solver Clarabel needs about 1 ms). When
    OSQP stops without a solution for any reason but the time limit, the same
    QP is solved again with this ``qpsolvers`` backend (``"clarabel"``,
    default) and its solution is used (and warm-starts OSQP next time);
    ``None`` turns the rescue off.

    ``scaling``: one Ruiz equilibration pass instead of OSQP's 10. The data of
    these QPs are already of order one (unit collision normals, weights and
    Jacobians of order one), and every sample's matrix update re-scales the
    matrices before the numeric refactorization. Measured side by side on the
    benchmark scenarios: 7-12 % less controller time per sample (paper-s2
    centralized median 0.486 -> 0.435 ms), the same centralized closed loops
    to 0.1 %, and no loss in the liveness and random-scenario benchmarks.
    No scaling at all (0) was as fast but changed the head-on centralized
    closed loop from 460 to 611.

    ``adaptive_rho_interval``: 50 ADMM iterations between rho updates, fixed.
    OSQP's default (0) derives the interval from the measured setup time, so
    the iterates depended on the machine's load; 50 is the value it chose on
    every built-in closed loop here (identical closed-loop costs), now
    reproducible (``benchmarks/qp_backends.py`` compares the settings).
    """

    eps_abs: float = 1e-5
    eps_rel: float = 1e-5
    max_iter: int = 4000
    polishing: bool = False
    adaptive_rho: bool = True
    adaptive_rho_interval: int = 50
    rho: float = 0.1
    sigma: float = 1e-6
    alpha: float = 1.6
    scaling: int = 1
    check_termination: int = 10
    time_limit: float | None = None
    accept_inaccurate: bool = True
    rescue_solver: str | None = "clarabel"

    def __post_init__(self) -> None:
        if self.rescue_solver is not None and (
                self.rescue_solver not in qpsolvers.available_solvers):
            raise ProblemError(
                f"OSQPSettings.rescue_solver must be None or an installed qpsolvers backend "
                f"({', '.join(qpsolvers.available_solvers)}), got {self.rescue_solver!r}")
        for f in fields(self):
            value = getattr(self, f.name)
            if f.type in ("float", "int", "float | None") and value is not None and not (
                    isinstance(value, int | float) and np.isfinite(value) and value >= 0):
                raise ProblemError(f"OSQPSettings.{f.name} must be finite and >= 0, got {value}")
        if self.time_limit == 0.0:
            raise ProblemError("OSQPSettings.time_limit must be > 0 s (or None for no limit)")

    def to_osqp(self) -> dict[str, object]:
        """Keyword arguments for ``OSQP.setup``."""
        kwargs: dict[str, object] = {
            "eps_abs": self.eps_abs,
            "eps_rel": self.eps_rel,
            "max_iter": self.max_iter,
            "polishing": self.polishing,
            "adaptive_rho": self.adaptive_rho,
            "adaptive_rho_interval": self.adaptive_rho_interval,
            "rho": self.rho,
            "sigma": self.sigma,
            "alpha": self.alpha,
            "scaling": self.scaling,
            "check_termination": self.check_termination,
            "verbose": False,
            "warm_starting": True,
        }
        if self.time_limit is not None:
            kwargs["time_limit"] = self.time_limit
        return kwargs


@dataclass(slots=True)
class BackendSolution:
    """What one solve of a backend returned; duals in OSQP's convention.

    ``solved``: the backend's status says solved (OSQP: *solved*, or *solved
    inaccurate* when the settings accept it); ``time_limit_reached``: the
    solve ran out of its time limit (neither hand-over nor rescue then);
    ``extra``: backend-specific numbers for :attr:`QPResult.extra`.
    """

    x: np.ndarray
    y: np.ndarray
    solved: bool
    status: str
    iterations: int
    solve_time: float
    objective: float = float("nan")
    primal_residual: float = float("nan")
    dual_residual: float = float("nan")
    time_limit_reached: bool = False
    extra: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Changes:
    """What changed since a backend's last solve: ``P`` values, ``A`` values, the vectors
    (``q``, ``l``, ``u``)."""

    P: bool = True
    A: bool = True
    vectors: bool = True


#: every part changed (a first solve, a hand-over)
ALL_CHANGED = Changes()


class QPBackend(Protocol):
    """A QP solver on the fixed pattern of a :class:`~sqpmpc.qp.layout.QPLayout`.

    ``P_values`` (upper triangle) and ``A_values`` are in the layout's entry
    order; ``changed`` says what differs from the last call (a backend may
    push only that); ``warm_x``/``warm_y`` a warm start it may use.
    """

    name: str
    setup_count: int

    def solve(self, P_values: np.ndarray, q: np.ndarray, A_values: np.ndarray,
              lower: np.ndarray, upper: np.ndarray, changed: Changes,
              warm_x: np.ndarray | None = None, warm_y: np.ndarray | None = None
              ) -> BackendSolution:
        r"""Solve :math:`\min \tfrac12 z^\top P z + q^\top z` s.t. :math:`l \le Az \le u`."""


#: Backend name -> ``(module, class)``, imported when first built.
BACKENDS: dict[str, tuple[str, str]] = {
    "osqp": ("sqpmpc.qp.osqp_backend", "OSQPBackend"),
    "piqp": ("sqpmpc.qp.piqp", "PIQPBackend"),
    "piqp-multistage": ("sqpmpc.qp.piqp", "PIQPBackend"),
    "daqp": ("sqpmpc.qp.daqp", "DAQPBackend"),
    "active-set": ("sqpmpc.qp.active_set", "ActiveSetBackend"),
}


def make_backend(name: str, layout: QPLayout, settings: OSQPSettings) -> QPBackend:
    """The backend ``name`` (:data:`BACKENDS`) for ``layout``: OSQP with ``settings``,
    PIQP with its tolerances and :data:`PIQP_MAX_ITER` (``"piqp-multistage"``: in stage
    order, with PIQP's multistage KKT solver), DAQP as is, the active-set method with
    ``settings`` (its tolerance, and its PIQP fallback's)."""
    if name not in BACKENDS:
        raise ProblemError(f"QP backend must be one of {tuple(BACKENDS)}, got {name!r}")
    module, cls = BACKENDS[name]
    backend = getattr(importlib.import_module(module), cls)
    if name in ("osqp", "active-set"):
        return backend(layout, settings)
    if name in ("piqp", "piqp-multistage"):
        return backend(layout, settings.eps_abs, settings.eps_rel, PIQP_MAX_ITER,
                       multistage=name == "piqp-multistage")
    return backend(layout)


@dataclass
class QPResult:
    r"""Outcome of one QP solve.

    Attributes
    ----------
    success
        A finite primal/dual pair came back with status *solved* (or *solved
        inaccurate* when the settings accept it).
    status
        OSQP's status string.
    x, y
        Primal and dual solutions (copies); OSQP's sign convention
        :math:`Pz + q + A^\top y = 0`, ``y > 0`` on active upper bounds.
    primal_residual, dual_residual
        :math:`\|Az - \Pi_{[l,u]}(Az)\|_\infty` and :math:`\|Pz + q + A^\top y\|_\infty`
        as reported by OSQP.
    iterations
        ADMM iterations.
    solve_time, wall_time
        OSQP's own solve time and the wall time of ``update`` + ``solve``, s.
    """

    success: bool
    status: str
    x: np.ndarray
    y: np.ndarray
    objective: float
    primal_residual: float
    dual_residual: float
    iterations: int
    solve_time: float
    wall_time: float
    extra: dict[str, float] = field(default_factory=dict)


def solve_interior_point(
    P_upper: sp.csc_matrix, q: np.ndarray, A: sp.csc_matrix, lower: np.ndarray,
    upper: np.ndarray, solver: str = "clarabel",
) -> tuple[np.ndarray, np.ndarray] | None:
    r"""Solve :math:`\min \tfrac12 z^\top P z + q^\top z` s.t. :math:`l \le Az \le u`.

    The interior-point backend ``solver`` is called through ``qpsolvers``.

    Rows with :math:`l = u` become equalities, the finite sides of the others
    inequalities :math:`Gz \le h`.

    Returns
    -------
    tuple[np.ndarray, np.ndarray] | None
        ``(z, y)`` with the multipliers in OSQP's convention
        (:math:`Pz + q + A^\top y = 0`, ``y > 0`` on active upper sides), or
        ``None`` if the solver found no solution.
    """
    P = (P_upper + sp.triu(P_upper, k=1).T).tocsc()
    A = sp.csr_matrix(A)
    eq = lower == upper
    up = np.isfinite(upper) & ~eq
    lo = np.isfinite(lower) & ~eq
    G = sp.vstack((A[up], -A[lo])).tocsc()
    h = np.concatenate((upper[up], -lower[lo]))
    problem = qpsolvers.Problem(P, q, G, h, A[eq].tocsc(), upper[eq])
    with warnings.catch_warnings():
        # qpsolvers warns on a non-optimal exit; the caller reports it through the result
        warnings.simplefilter("ignore", UserWarning)
        solution = qpsolvers.solve_problem(problem, solver=solver)
    if not solution.found or solution.x is None or not np.all(np.isfinite(solution.x)):
        return None
    n_up = int(up.sum())
    y = np.zeros(lower.size)
    if solution.y is not None:
        y[eq] = solution.y
    if solution.z is not None:
        y[up] += solution.z[:n_up]
        y[lo] -= solution.z[n_up:]
    return np.asarray(solution.x, dtype=float), y

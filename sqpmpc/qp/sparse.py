r"""The sparse QP of one SQP/RTI iteration, held by OSQP and updated in place.

The QP is

.. math::

    \min_z \tfrac12 z^\top P z + q^\top z \quad \text{s.t.} \quad l \le A z \le u,

with the layout of :class:`sqpmpc.qp.layout.QPLayout`. OSQP is set up once, on the
first solve; afterwards every ``update_*`` method writes values into arrays
kept in the layout's entry order, and :meth:`SparseQP.solve` pushes only what
changed (vectors, ``A`` values, ``P`` values) with ``OSQP.update`` and warm
starts primal and dual variables. A change of vectors alone never triggers a
re-factorization.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import osqp
import scipy.sparse as sp

from sqpmpc.errors import ProblemError, SolverError
from sqpmpc.kernels.ocp import all_finite, clip_bounds, write_reference
from sqpmpc.qp.backend import (
    HANDOVER_ITERATIONS,
    PIQP_MAX_ITER,
    QP_SOLVERS,
    OSQPSettings,
    QPResult,
    solve_interior_point,
)
from sqpmpc.qp.layout import QPLayout

if TYPE_CHECKING:
    from sqpmpc.qp.daqp import DAQPBackend
    from sqpmpc.qp.piqp import PIQPBackend

__all__ = [
    "HANDOVER_ITERATIONS", "PIQP_MAX_ITER", "QP_SOLVERS", "OSQPSettings", "QPResult", "SparseQP",
    "solve_interior_point",
]


_SOLVED = {osqp.SolverStatus.OSQP_SOLVED, osqp.SolverStatus.OSQP_SOLVED_INACCURATE}
_SOLVED_EXACTLY = osqp.SolverStatus.OSQP_SOLVED
_SIGINT = osqp.SolverStatus.OSQP_SIGINT
_TIME_LIMIT = osqp.SolverStatus.OSQP_TIME_LIMIT_REACHED
_OSQP_INFINITY = float(osqp.constant("OSQP_INFTY"))
# what SparseQP calls on OSQP's compiled solver object (the calls osqp.OSQP makes itself)
_CORE_METHODS = ("update_data_vec", "update_data_mat", "warm_start", "solve", "info", "solution")


class SparseQP:
    """OSQP-backed QP with a fixed pattern and in-place value updates.

    After the one ``setup``, updates, warm starts and solves go straight to
    the compiled solver object that ``osqp.OSQP`` wraps, making the same
    calls the wrapper makes (infinite bounds clipped to ``OSQP_INFTY`` as it
    does) but without its per-call bookkeeping for derivatives and its
    result namespaces: about 30 us less per QP (measured: paper-s2
    decentralized, 0.30 -> 0.275 ms per robot and sample). The results are
    bitwise the same (tested). Setting
    ``use_osqp_wrapper = True``, or an OSQP build whose wrapper lacks that
    object, uses the public ``osqp.OSQP`` methods instead.

    With ``solver="piqp"`` the same interface solves with PIQP
    (:mod:`sqpmpc.qp.piqp`, in-place updates, no warm start), with
    ``solver="daqp"`` with DAQP (:mod:`sqpmpc.qp.daqp`, dense, hot-started
    from the previous active set); the rescue of ``settings`` applies to both,
    the tolerances to PIQP.

    Parameters
    ----------
    layout
        Index maps and sparsity.
    settings
        OSQP settings (tolerances and rescue also for PIQP).
    solver
        ``"osqp"`` (default), ``"piqp"`` or ``"daqp"``.
    """

    def __init__(self, layout: QPLayout, settings: OSQPSettings | None = None,
                 solver: str = "osqp") -> None:
        if solver not in QP_SOLVERS:
            raise ProblemError(f"qp_solver must be one of {QP_SOLVERS}, got {solver!r}")
        self.layout = layout
        self.settings = settings or OSQPSettings()
        self.solver_name = solver
        self._backend: PIQPBackend | DAQPBackend | None = None
        self._handover: PIQPBackend | None = None
        if solver in ("piqp", "osqp+piqp"):
            from sqpmpc.qp.piqp import PIQPBackend

            piqp_backend = PIQPBackend(layout, self.settings.eps_abs, self.settings.eps_rel,
                                       PIQP_MAX_ITER)
            if solver == "piqp":
                self._backend = piqp_backend
            else:  # OSQP first, capped; PIQP takes the QPs it leaves
                self._handover = piqp_backend
                self.settings = replace(self.settings, max_iter=min(
                    self.settings.max_iter, HANDOVER_ITERATIONS))
        elif solver == "daqp":
            from sqpmpc.qp.daqp import DAQPBackend

            self._backend = DAQPBackend(layout)
        L = layout
        self.A_values = np.zeros(L.A_nnz)
        sl = L.A_slices
        for name in ("init", "dyn_I", "input", "position", "velocity", "internal_slack",
                     "external_slack", "slack"):
            self.A_values[sl[name]] = 1.0
        self.P_values = np.zeros(L.P_nnz)
        self._P_diag_cost = np.zeros(L.n_var)
        self._P_diag_curvature = np.zeros(L.n_var)  # diagonal of the curvature blocks
        self._q_cost = np.zeros(L.n_var)
        self._q_curvature = np.zeros(L.n_var)
        self._Q_diag = np.zeros(2)
        self._position_scale = np.ones(L.n_robots)
        self._reference_scale = np.zeros((L.n_robots, 1, 2))
        self.lower = np.full(L.n_con, -np.inf)
        self.upper = np.full(L.n_con, np.inf)
        self.lower[L.slack_rows] = 0.0
        self.lower[L.internal_rows] = -np.inf
        self._lower_osqp = np.zeros(L.n_con)  # the bounds clipped to OSQP's infinity
        self._upper_osqp = np.zeros(L.n_con)
        self._no_curvature = True
        self._solver: osqp.OSQP | None = None
        self._core: object | None = None
        self.use_osqp_wrapper = False
        self._dirty_P = self._dirty_A = self._dirty_vec = True
        self.setup_count = 0
        self.rescue_count = 0
        self.handover_count = 0

    # ---------------------------------------------------------------- values
    @property
    def q(self) -> np.ndarray:
        """Linear cost vector (cost part plus curvature offset)."""
        return self._q_cost + self._q_curvature

    def update_cost_weights(
        self, Q_diag: np.ndarray, R_diag: np.ndarray, slack_penalty: float,
        velocity_weights: np.ndarray | None = None,
    ) -> None:
        r"""Set :math:`P` of :math:`\sum_i \|p_i - r_i\|_Q^2 + \|u_{i-1}\|_R^2`; the slack price.

        ``Q`` weighs positions of stages 1..N, ``R`` inputs of stages 0..N-1;
        OSQP's :math:`\tfrac12 z^\top P z` convention gives :math:`P = 2Q`, :math:`2R`.
        ``velocity_weights`` weigh the model's velocity states of stages 1..N
        (models with velocity states; default none).
        """
        L = self.layout
        self._P_diag_cost[:] = 0.0
        self._P_diag_cost[L.input_index] = 2.0 * np.asarray(R_diag, float)
        if velocity_weights is not None:
            vel = np.asarray(L.model.velocity_states, dtype=np.int64)
            self._P_diag_cost[L.state_index[:, 1:][:, :, vel]] = 2.0 * np.asarray(
                velocity_weights, float)
        self._Q_diag = np.asarray(Q_diag, float)
        self._write_position_weights(np.ones(L.n_robots))
        self.P_values[L.P_diag_slice] = self._P_diag_cost + self._P_diag_curvature
        self._q_cost[L.n_var - L.n_slack:] = float(slack_penalty)
        self._dirty_P = self._dirty_vec = True

    def update_position_weight_scale(self, scale: np.ndarray) -> None:
        r"""Scale the position weight of each own robot: :math:`Q_r = s_r Q`, ``scale (m,)``.

        Changes ``P`` (and the reference term of ``q`` from the next
        :meth:`update_reference` on) only where the scale changed.
        """
        scale = np.asarray(scale, dtype=float)
        if np.array_equal(scale, self._position_scale):
            return
        L = self.layout
        self._write_position_weights(scale)
        self.P_values[L.P_diag_slice] = self._P_diag_cost + self._P_diag_curvature
        self._dirty_P = True

    def _write_position_weights(self, scale: np.ndarray) -> None:
        """Position weights :math:`s_r Q` into ``P``'s cost diagonal and the reference scale."""
        Q = scale[:, None, None] * self._Q_diag  # (m, 1, 2)
        self._position_scale = scale.copy()
        self._P_diag_cost[self.layout.state_index[:, 1:, :2]] = 2.0 * Q
        self._reference_scale = -2.0 * Q

    def update_reference(self, reference: np.ndarray) -> None:
        """Reference positions ``(m, N, 2)`` of stages 1..N: :math:`q_p = -2 Q r`."""
        write_reference(self._q_cost, reference, self._reference_scale, self.layout.block_size,
                        self.layout.stage_size)
        self._dirty_vec = True

    def update_initial_state(self, initial_states: np.ndarray) -> None:
        """Measured states ``(m, nx)``: :math:`\\chi_0 = \\chi(k)`."""
        rows = self.layout.init_rows
        self.lower[rows] = initial_states
        self.upper[rows] = initial_states
        self._dirty_vec = True

    def update_input_bounds(self, lower: np.ndarray, upper: np.ndarray) -> None:
        """Input bounds ``(nu,)`` applied on every stage."""
        rows = self.layout.input_rows
        self.lower[rows] = lower
        self.upper[rows] = upper
        self._dirty_vec = True

    def update_position_bounds(self, lower: np.ndarray, upper: np.ndarray) -> None:
        """Position bounds ``(2,)`` on stages 1..N (only if the layout has the rows)."""
        rows = self.layout.position_rows
        self.lower[rows] = lower
        self.upper[rows] = upper
        self._dirty_vec = True

    def update_velocity_bounds(self, lower: np.ndarray, upper: np.ndarray) -> None:
        """Bounds of the model's velocity states on stages 1..N: ``(nv,)`` for every stage, or
        ``(m, N, nv)`` per robot and stage (models with velocity states only)."""
        rows = self.layout.velocity_rows
        self.lower[rows] = lower
        self.upper[rows] = upper
        self._dirty_vec = True

    def update_dynamics(self, A_k: np.ndarray, B_k: np.ndarray, c_k: np.ndarray) -> None:
        r"""Linearized dynamics :math:`\chi_{i+1} - A_i\chi_i - B_i u_i = c_i`.

        Parameters
        ----------
        A_k, B_k, c_k
            ``(m, N, nx, nx)``, ``(m, N, nx, nu)`` and ``(m, N, nx)``.
        """
        L = self.layout
        sl = L.A_slices
        self.A_values[sl["dyn_A"]] = -A_k[:, :, L.a_pattern[0], L.a_pattern[1]].ravel()
        self.A_values[sl["dyn_B"]] = -B_k[:, :, L.b_pattern[0], L.b_pattern[1]].ravel()
        rows = self.layout.dyn_rows
        self.lower[rows] = c_k
        self.upper[rows] = c_k
        self._dirty_A = self._dirty_vec = True

    def update_internal_collisions(self, normals: np.ndarray, rhs: np.ndarray) -> None:
        r"""Rows :math:`n^\top(p_a - p_b) + s \ge b` for pairs ``(P, N, 2)``, ``(P, N)``."""
        if self.layout.n_pairs == 0:
            return
        self.A_values[self.layout.A_slices["internal"]] = np.concatenate(
            (normals, -normals), axis=2
        ).ravel()
        self.lower[self.layout.internal_rows] = rhs
        self._dirty_A = self._dirty_vec = True

    def update_external_collisions(self, normals: np.ndarray, rhs: np.ndarray) -> None:
        r"""Rows :math:`n^\top p_j + s \ge b`: ``(m, E, N, 2)``, ``(m, E, N)``; -inf disables."""
        if self.layout.n_external == 0:
            return
        self.A_values[self.layout.A_slices["external"]] = normals.ravel()
        self.lower[self.layout.external_rows] = rhs
        self._dirty_A = self._dirty_vec = True

    def update_curvature(self, blocks: np.ndarray | None, z_bar: np.ndarray) -> None:
        r"""Add PSD curvature blocks ``(m, N, c, c)`` on the model's curvature variables
        (the unicycle's :math:`(\psi_i, v_i, \omega_i)`).

        In absolute variables the SQP model :math:`\tfrac12\Delta^\top H\Delta +
        \nabla f^\top\Delta` with :math:`z = \bar z + \Delta` needs the offset
        :math:`q \mathrel{-}= H_c\bar z`. ``None`` removes the curvature (Gauss-Newton).
        """
        L = self.layout
        self._P_diag_curvature[:] = 0.0
        curv = L.curvature_pattern
        off = curv[0] != curv[1]
        self._q_curvature[:] = 0.0
        self._no_curvature = blocks is None
        if blocks is None:
            self.P_values[L.P_curv_slice] = 0.0
        else:
            idx = L.curvature_index  # (m, N, 3)
            diag_add = np.einsum("...ii->...i", blocks)
            np.add.at(self._P_diag_curvature, idx, diag_add)
            self.P_values[L.P_curv_slice] = blocks[
                :, :, curv[0][off], curv[1][off]
            ].ravel()
            zt = z_bar[idx]
            self._q_curvature[:] = 0.0
            np.add.at(self._q_curvature, idx, -np.einsum("...ij,...j->...i", blocks, zt))
        self.P_values[L.P_diag_slice] = self._P_diag_cost + self._P_diag_curvature
        self._dirty_P = self._dirty_vec = True

    def mark_changed(self, matrix: bool = True, vectors: bool = True) -> None:
        """Tell the QP that ``A_values`` (``matrix``) or ``lower``/``upper`` were written directly.

        The engine's compiled kernels write into views of these arrays; the
        next :meth:`solve` pushes what was marked.
        """
        self._dirty_A = self._dirty_A or matrix
        self._dirty_vec = self._dirty_vec or vectors

    # -------------------------------------------------------------- matrices
    def matrices(self) -> tuple[sp.csc_matrix, np.ndarray, sp.csc_matrix, np.ndarray, np.ndarray]:
        """Current ``(P (upper triangle), q, A, l, u)`` as new objects."""
        return (
            self.layout.csc(self.P_values, "P"),
            self.q.copy(),
            self.layout.csc(self.A_values, "A"),
            self.lower.copy(),
            self.upper.copy(),
        )

    # ----------------------------------------------------------------- solve
    def _rescue(self, x: np.ndarray, y: np.ndarray, status: str
                ) -> tuple[np.ndarray, np.ndarray, str, bool, float]:
        """The same QP by the rescue solver: ``(x, y, status, rescued, seconds)``."""
        if self.settings.rescue_solver is None:
            return x, y, status, False, 0.0
        t0 = time.perf_counter()
        rescue = solve_interior_point(*self.matrices(), solver=self.settings.rescue_solver)
        spent = time.perf_counter() - t0
        if rescue is None:
            return x, y, f"{status}; {self.settings.rescue_solver} found no solution either", \
                False, spent
        self.rescue_count += 1
        return (*rescue, f"solved by {self.settings.rescue_solver} ({status})", True, spent)

    def _solve_backend(self, t0: float) -> QPResult:
        """Solve with the PIQP or DAQP backend; the rescue as for OSQP."""
        q = self._q_cost if self._no_curvature else self.q
        sol = self._backend.solve(self.P_values, q, self.A_values, self.lower, self.upper,
                                  self._dirty_P)
        self._dirty_P = self._dirty_A = self._dirty_vec = False
        x, y, status = sol.x, sol.y, sol.status
        ok = sol.solved and x.size == self.layout.n_var and all_finite(x) and all_finite(y)
        rescued, rescue_time = False, 0.0
        if not ok:
            x, y, status, rescued, rescue_time = self._rescue(x, y, status)
            ok = rescued
        return QPResult(ok, status, x, y, sol.objective, sol.primal_residual,
                        sol.dual_residual, sol.iterations, sol.solve_time + rescue_time,
                        time.perf_counter() - t0, {"rescued": float(rescued)})

    def _push(self) -> None:
        L = self.layout
        if self._solver is None:
            P, q, A, lo, up = self.matrices()
            self._solver = osqp.OSQP()
            self._solver.setup(P, q, A, lo, up, **self.settings.to_osqp())
            self.setup_count += 1
            core = getattr(self._solver, "_solver", None)
            self._core = core if all(hasattr(core, a) for a in _CORE_METHODS) else None
        elif self._core is not None and not self.use_osqp_wrapper:
            core = self._core
            if self._dirty_vec:
                q = self._q_cost if self._no_curvature else self.q
                clip_bounds(self.lower, self.upper, _OSQP_INFINITY, self._lower_osqp,
                            self._upper_osqp)
                core.update_data_vec(q=q, l=self._lower_osqp, u=self._upper_osqp)
            if self._dirty_P or self._dirty_A:
                core.update_data_mat(
                    P_x=self.P_values[L.P_order_inverse] if self._dirty_P else None, P_i=None,
                    A_x=self.A_values[L.A_order_inverse] if self._dirty_A else None, A_i=None)
        else:
            kwargs: dict[str, np.ndarray] = {}
            if self._dirty_vec:
                kwargs.update(q=self.q, l=self.lower, u=self.upper)
            if self._dirty_P:
                kwargs["Px"] = self.P_values[L.P_order_inverse]
            if self._dirty_A:
                kwargs["Ax"] = self.A_values[L.A_order_inverse]
            if kwargs:
                self._solver.update(**kwargs)
        self._dirty_P = self._dirty_A = self._dirty_vec = False

    def solve(
        self, warm_x: np.ndarray | None = None, warm_y: np.ndarray | None = None
    ) -> QPResult:
        """Push pending updates, warm start, solve; never raises on solver failure.

        A Ctrl-C that OSQP caught during the solve is raised as ``KeyboardInterrupt``.

        Returns
        -------
        QPResult
            With ``success`` False on any status other than solved, or on
            non-finite output.
        """
        t0 = time.perf_counter()
        if self._backend is not None:
            return self._solve_backend(t0)
        try:
            self._push()
            if self._core is not None and not self.use_osqp_wrapper:
                core = self._core
                if warm_x is not None or warm_y is not None:
                    core.warm_start(warm_x, warm_y)
                core.solve()
                info, solution = core.info, core.solution
            else:
                if warm_x is not None or warm_y is not None:
                    self._solver.warm_start(x=warm_x, y=warm_y)
                solution = self._solver.solve(raise_error=False)
                info = solution.info
        except (ValueError, RuntimeError) as exc:  # OSQP setup/update errors
            raise SolverError(f"OSQP rejected the QP data: {exc}") from exc
        wall = time.perf_counter() - t0
        if info.status_val == _SIGINT:
            # OSQP catches Ctrl-C during a solve; hand it back to the caller
            raise KeyboardInterrupt
        x = np.array(solution.x, dtype=float, copy=True)
        y = np.array(solution.y, dtype=float, copy=True)
        finite = x.size == self.layout.n_var and all_finite(x) and all_finite(y)
        ok_status = info.status_val == _SOLVED_EXACTLY or (
            self.settings.accept_inaccurate and info.status_val in _SOLVED
        )
        status = str(info.status)
        rescued = False
        rescue_time = 0.0
        iterations = int(info.iter)
        if not (finite and ok_status) and self._handover is not None and (
                info.status_val != _TIME_LIMIT):
            q = self._q_cost if self._no_curvature else self.q
            sol = self._handover.solve(self.P_values, q, self.A_values, self.lower, self.upper,
                                       True)
            self.handover_count += 1
            rescue_time += sol.solve_time
            iterations += sol.iterations
            if sol.solved and all_finite(sol.x) and all_finite(sol.y):
                x, y, finite, ok_status = sol.x, sol.y, True, True
                status = f"solved by PIQP after {iterations - sol.iterations} OSQP iterations"
            wall = time.perf_counter() - t0
        if not (finite and ok_status) and info.status_val != _TIME_LIMIT:
            x, y, status, rescued, rescue_time = self._rescue(x, y, status)
            finite = ok_status = rescued
            wall = time.perf_counter() - t0
        return QPResult(
            success=bool(finite and ok_status),
            status=status,
            x=x,
            y=y,
            objective=float(info.obj_val),
            primal_residual=float(info.prim_res),
            dual_residual=float(info.dual_res),
            iterations=iterations,
            solve_time=float(info.solve_time) + rescue_time,
            wall_time=wall,
            extra={"polish_status": float(info.status_polish),
                   "rho_updates": float(info.rho_updates), "rescued": float(rescued)},
        )

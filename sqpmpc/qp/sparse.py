r"""The sparse QP of one SQP/RTI iteration, held by a backend and updated in place.

The QP is

.. math::

    \min_z \tfrac12 z^\top P z + q^\top z \quad \text{s.t.} \quad l \le A z \le u,

with the layout of :class:`sqpmpc.qp.layout.QPLayout`. Every ``update_*``
method writes values into arrays kept in the layout's entry order; the
compiled kernels of the OCP write whole blocks through the views
:meth:`SparseQP.matrix_entries` and :meth:`SparseQP.row_bounds` hand out by
name, then say so with :meth:`SparseQP.mark_changed`. :meth:`SparseQP.solve`
hands the backend (:class:`~sqpmpc.qp.backend.QPBackend`, chosen by name:
OSQP, PIQP, DAQP or the active-set method) only what changed, then applies the policies of
:mod:`sqpmpc.qp.policies` (hand-over, rescue) to a QP it left unsolved. A
change of vectors alone never triggers a re-factorization.
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import scipy.sparse as sp

from sqpmpc.errors import ProblemError
from sqpmpc.kernels.ocp import all_finite, kkt_residual, write_reference
from sqpmpc.qp.backend import (
    HANDOVER_ITERATIONS,
    PIQP_MAX_ITER,
    QP_SOLVERS,
    Changes,
    OSQPSettings,
    QPBackend,
    QPResult,
    make_backend,
    solve_interior_point,
)
from sqpmpc.qp.layout import QPLayout
from sqpmpc.qp.policies import HandOver, Rescue

__all__ = [
    "HANDOVER_ITERATIONS", "PIQP_MAX_ITER", "QP_SOLVERS", "OSQPSettings", "QPResult", "SparseQP",
    "solve_interior_point",
]

# every combination, built once (a solve looks its own up)
_CHANGES = {(P, A, v): Changes(P, A, v) for P in (False, True) for A in (False, True)
            for v in (False, True)}

#: The row blocks :meth:`SparseQP.row_bounds` hands out (the layout's ``<name>_rows``).
ROW_BLOCKS = ("init", "dyn", "input", "position", "internal", "external")


class SparseQP:
    """A QP with a fixed pattern, in-place value updates and a backend chosen by name.

    With ``solver="osqp"`` (default) the QP is solved by OSQP
    (:mod:`sqpmpc.qp.osqp_backend`, warm-started), with ``"piqp"`` by PIQP
    (:mod:`sqpmpc.qp.piqp`, in-place updates, no warm start), with ``"daqp"``
    by DAQP (:mod:`sqpmpc.qp.daqp`, dense, hot-started from the previous
    active set), with ``"osqp+piqp"`` by OSQP capped at
    :data:`HANDOVER_ITERATIONS` iterations and PIQP for what it leaves
    (:class:`~sqpmpc.qp.policies.HandOver`), with ``"active-set"`` by the
    primal-dual active-set method (:mod:`sqpmpc.qp.active_set`, warm-started, one
    KKT factorization when the working set is right) and PIQP for the QPs it
    leaves. The rescue of ``settings``
    (:class:`~sqpmpc.qp.policies.Rescue`) applies to all, the tolerances to PIQP.

    Parameters
    ----------
    layout
        Index maps and sparsity.
    settings
        OSQP settings (tolerances and rescue also for PIQP).
    solver
        ``"osqp"`` (default), ``"piqp"``, ``"piqp-multistage"``, ``"daqp"``,
        ``"osqp+piqp"`` or ``"active-set"``.

    Attributes
    ----------
    backend
        The backend that solves first (:class:`~sqpmpc.qp.backend.QPBackend`).
    handover, rescue
        The policies for a QP it leaves unsolved (``None``: off).
    A_values, P_values, lower, upper
        The QP's values in the layout's entry order (read them; write through
        the ``update_*`` methods or the views of :meth:`matrix_entries` and
        :meth:`row_bounds`).
    """

    def __init__(self, layout: QPLayout, settings: OSQPSettings | None = None,
                 solver: str = "osqp") -> None:
        if solver not in QP_SOLVERS:
            raise ProblemError(f"qp_solver must be one of {QP_SOLVERS}, got {solver!r}")
        self.layout = layout
        self.settings = settings or OSQPSettings()
        self.solver_name = solver
        self.handover: HandOver | None = None
        if solver == "osqp+piqp":  # OSQP first, capped; PIQP takes the QPs it leaves
            self.handover = HandOver(make_backend("piqp", layout, self.settings))
            self.settings = replace(self.settings, max_iter=min(
                self.settings.max_iter, HANDOVER_ITERATIONS))
            solver = "osqp"
        self.backend: QPBackend = make_backend(solver, layout, self.settings)
        self.rescue = None if self.settings.rescue_solver is None else Rescue(
            self.settings.rescue_solver)
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
        self._R_diag = np.zeros(L.model.nu)
        self._V_diag: np.ndarray | None = None
        self._position_scale = np.ones(L.n_robots)
        self._reference_scale = np.zeros((L.n_robots, 1, 2))
        self._sizes = (L.block_size, L.stage_size)  # of the reference's kernel
        self.lower = np.full(L.n_con, -np.inf)
        self.upper = np.full(L.n_con, np.inf)
        self.lower[L.slack_rows] = 0.0
        self.lower[L.internal_rows] = -np.inf
        self._no_curvature = True
        self._dirty_P = self._dirty_A = self._dirty_vec = True

    @property
    def setup_count(self) -> int:
        """Setups of the first backend so far (1 after the first solve)."""
        return self.backend.setup_count

    @property
    def rescue_count(self) -> int:
        """QPs rescued by the interior-point solver so far."""
        return 0 if self.rescue is None else self.rescue.count

    @property
    def handover_count(self) -> int:
        """QPs handed over from OSQP to PIQP so far (``"osqp+piqp"``)."""
        return 0 if self.handover is None else self.handover.count

    @property
    def use_osqp_wrapper(self) -> bool:
        """OSQP: solve through the public ``osqp.OSQP`` methods (default: its compiled
        object, bitwise the same and faster)."""
        return bool(getattr(self.backend, "use_osqp_wrapper", False))

    @use_osqp_wrapper.setter
    def use_osqp_wrapper(self, value: bool) -> None:
        if not hasattr(self.backend, "use_osqp_wrapper"):
            raise ProblemError(f"use_osqp_wrapper: the {self.backend.name} backend is not OSQP")
        self.backend.use_osqp_wrapper = bool(value)

    @property
    def pending(self) -> Changes:
        """What changed since the last solve (the backend gets only that)."""
        return _CHANGES[self._dirty_P, self._dirty_A, self._dirty_vec]

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
        self._R_diag = np.asarray(R_diag, float)
        self._V_diag = None if velocity_weights is None else np.asarray(velocity_weights, float)
        self._write_position_weights(np.ones(L.n_robots))
        self.P_values[L.P_diag_slice] = self._P_diag_cost + self._P_diag_curvature
        self._q_cost[L.n_var - L.n_slack:] = float(slack_penalty)
        self._dirty_P = self._dirty_vec = True

    @property
    def position_weight_scale(self) -> np.ndarray:
        """``(m,)`` the current factor on each own robot's position weight (a copy)."""
        return self._position_scale.copy()

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
        write_reference(self._q_cost, reference, self._reference_scale, *self._sizes)
        self._dirty_vec = True

    def update_input_references(self, robots: np.ndarray, inputs: np.ndarray,
                                velocities: np.ndarray | None = None) -> None:
        r"""Reference inputs ``(k, N, nu)`` (and velocity states ``(k, N, nv)`` of stages
        1..N) of the own robots ``robots (k,)``: the cost
        :math:`\|u_i - u^{\mathrm{ref}}_i\|_R^2` gives :math:`q_u = -2 R u^{\mathrm{ref}}`
        (the paper's cost is the reference 0, every robot's at construction)."""
        L = self.layout
        rows = np.asarray(robots, dtype=np.int64)
        self._q_cost[L.input_index[rows]] = -2.0 * self._R_diag * np.asarray(inputs, float)
        if velocities is not None and self._V_diag is not None:
            vel = np.asarray(L.model.velocity_states, dtype=np.int64)
            self._q_cost[L.state_index[rows, 1:][:, :, vel]] = -2.0 * self._V_diag * velocities
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
        """Tell the QP that ``A`` values (``matrix``) or bounds (``vectors``) were written
        through the views of :meth:`matrix_entries` / :meth:`row_bounds`.

        The next :meth:`solve` pushes what was marked.
        """
        self._dirty_A = self._dirty_A or matrix
        self._dirty_vec = self._dirty_vec or vectors

    def matrix_entries(self, name: str) -> np.ndarray:
        """A writable view of the ``A`` values of block ``name`` (a key of the layout's
        ``A_slices``: ``"dyn_A"``, ``"dyn_B"``, ``"internal"``, ``"external"``, ...), in
        entry order; call :meth:`mark_changed` after writing."""
        if name not in self.layout.A_slices:
            raise ProblemError(f"matrix_entries: no block {name!r}; blocks: "
                               f"{', '.join(self.layout.A_slices)}")
        return self.A_values[self.layout.A_slices[name]]

    def row_bounds(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Writable views ``(lower, upper)`` of the bounds of the row block ``name``
        (:data:`ROW_BLOCKS`, the layout's ``<name>_rows``, contiguous), flat; call
        :meth:`mark_changed` after writing."""
        if name not in ROW_BLOCKS:
            raise ProblemError(f"row_bounds: no row block {name!r}; blocks: "
                               f"{', '.join(ROW_BLOCKS)}")
        flat = np.asarray(getattr(self.layout, f"{name}_rows")).ravel()
        if flat.size and not np.array_equal(flat, np.arange(flat[0], flat[0] + flat.size)):
            raise ProblemError(f"internal error: QP row block {name!r} is not contiguous")
        rows = slice(int(flat[0]), int(flat[0]) + flat.size) if flat.size else slice(0, 0)
        return self.lower[rows], self.upper[rows]

    # ------------------------------------------------------------------ cost
    def cost_value(self, z: np.ndarray) -> float:
        r"""The quadratic cost :math:`\tfrac12 z^\top P_c z + q_c^\top z` at ``z`` (weights,
        reference and slack price; curvature terms excluded)."""
        return float(0.5 * z @ (self._P_diag_cost * z) + self._q_cost @ z)

    def cost_gradient(self, z: np.ndarray) -> np.ndarray:
        """The gradient :math:`P_c z + q_c` of :meth:`cost_value` at ``z``."""
        return self._P_diag_cost * z + self._q_cost

    def kkt_residual(self, z: np.ndarray, y: np.ndarray, Az: np.ndarray,
                     ATy: np.ndarray) -> float:
        r"""Largest of :math:`\|\nabla f + A^\top y\|_\infty`, the violation of
        :math:`l \le Az \le u` and the complementarity at ``(z, y)``, with the cost of
        :meth:`cost_gradient` (scratch ``Az (n_con,)``, ``ATy (n_var,)``)."""
        L = self.layout
        return float(kkt_residual(self.A_values, L.A_rows, L.A_cols, z, y, self.lower,
                                  self.upper, self._P_diag_cost, self._q_cost, Az, ATy))

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
    def solve(
        self, warm_x: np.ndarray | None = None, warm_y: np.ndarray | None = None
    ) -> QPResult:
        """Solve with the backend (what changed pushed, warm-started where it can), then
        the hand-over and the rescue for a QP it left unsolved (not after its time
        limit); never raises on solver failure.

        A Ctrl-C that OSQP caught during the solve is raised as ``KeyboardInterrupt``.

        Returns
        -------
        QPResult
            With ``success`` False on any status other than solved, or on
            non-finite output.
        """
        t0 = time.perf_counter()
        q = self._q_cost if self._no_curvature else self.q
        sol = self.backend.solve(self.P_values, q, self.A_values, self.lower, self.upper,
                                 _CHANGES[self._dirty_P, self._dirty_A, self._dirty_vec],
                                 warm_x, warm_y)
        self._dirty_P = self._dirty_A = self._dirty_vec = False
        ok = sol.solved and sol.x.size == self.layout.n_var and all_finite(sol.x) and (
            all_finite(sol.y))
        rescued = False
        if not ok and not sol.time_limit_reached:
            if self.handover is not None:
                sol = self.handover.apply(sol, self.P_values, q, self.A_values, self.lower,
                                          self.upper)
                ok = sol.solved
            if not ok and self.rescue is not None:
                sol, rescued = self.rescue.apply(sol, self.matrices)
                ok = rescued
        extra = sol.extra  # the backend's, new per solve
        extra["rescued"] = float(rescued)
        return QPResult(ok, sol.status, sol.x, sol.y, sol.objective, sol.primal_residual,
                        sol.dual_residual, sol.iterations, sol.solve_time,
                        time.perf_counter() - t0, extra)

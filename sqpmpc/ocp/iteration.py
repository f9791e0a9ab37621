r"""Real-time iteration and SQP on the multiple-shooting OCP (paper eq. 4 / eq. 7).

Each iteration linearizes the dynamics :math:`\chi_{i+1} = f_d(\chi_i, u_i)`
and the collision constraints at the current iterate :math:`\bar z`, writes the
values into the fixed-pattern QP (:class:`sqpmpc.qp.sparse.SparseQP`) and solves it
with OSQP, warm-started with :math:`(\bar z, \bar y)`:

.. math::

    \chi_{i+1} - A_i\chi_i - B_i u_i = f_d(\bar\chi_i, \bar u_i) - A_i\bar\chi_i - B_i\bar u_i.

**RTI** (default): at every sample the previous solution is shifted by one
stage (states, inputs, slacks and multipliers), :math:`\chi_0` is set to the
measurement and exactly one QP is solved. **SQP**: the same iteration is
repeated with an Armijo line search on the exact L1 merit function

.. math::

    \phi_\mu(z) = f(z) + \mu \big(\|c(z)\|_1 + \textstyle\sum \max(0, h(z))\big),

until the NLP's KKT residual (stationarity, primal feasibility and
complementarity, infinity norms; stationarity and complementarity relative to
the multipliers' size, :func:`sqpmpc.kernels.ocp.kkt_residual`) is below
``kkt_tolerance``, or until a QP step is numerically insignificant,

.. math::

    \|\Delta z\|_\infty \le \epsilon_{step}\,(1 + \|\bar z\|_\infty), \qquad
    \epsilon_{step} = 10^{-10}

(:data:`STEP_TOLERANCE`): the iterate is then a fixed point of the QP map to
the QP's resolution, the step is taken whole (no line search: the merit
function cannot resolve it) with the QP's multipliers, and iterating further
only repeats it. The Hessian is
either Gauss-Newton (the cost's, exact for this quadratic cost) or the exact
Hessian of the Lagrangian, whose dynamics part
:math:`-\sum_i \lambda_i^\top\nabla^2 f_d` is projected per stage onto the
positive semi-definite cone.
"""

from __future__ import annotations

import time
from typing import Literal

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.kernels.ocp import all_finite, rows_shortfall
from sqpmpc.models.base import RobotModel
from sqpmpc.models.paper import UnicycleModel
from sqpmpc.ocp.report import CollisionRows, IterationReport, IterationSettings
from sqpmpc.qp.backend import QPResult
from sqpmpc.qp.layout import QPLayout
from sqpmpc.qp.sparse import SparseQP

__all__ = ["STEP_TOLERANCE", "MultipleShootingSQP", "engaged_robots"]

#: :math:`\epsilon_{step}` of the module docstring: a QP step below
#: ``STEP_TOLERANCE * (1 + |z|_inf)`` (infinity norms) ends an SQP solve.
STEP_TOLERANCE = 1e-10


class MultipleShootingSQP:
    r"""The RTI/SQP engine for ``m`` own robots.

    Parameters
    ----------
    layout
        QP layout (robots, horizon, collision rows).
    sample_time
        :math:`T_s`, s.
    Q_diag, R_diag
        Cost weights on (x, y) and (v, omega) (the paper's objective); a model with
        velocity states has ``R`` on them (stages 1..N, the commands) and
        ``R Ts^2`` on its acceleration inputs.
    input_lower, input_upper
        ``(nu,)`` input bounds.
    position_lower, position_upper
        ``(2,)`` position bounds (``±inf`` where absent); used if the layout has rows.
    settings
        Iteration settings.
    model
        The robot model (default: the paper's unicycle with the input bounds);
        the layout must be built for it. Its compiled kernels, if it has them
        for ``settings.discretization``, run the hot path; else its NumPy
        functions do.
    """

    def __init__(
        self,
        layout: QPLayout,
        sample_time: float,
        Q_diag: np.ndarray,
        R_diag: np.ndarray,
        input_lower: np.ndarray,
        input_upper: np.ndarray,
        position_lower: np.ndarray,
        position_upper: np.ndarray,
        settings: IterationSettings,
        model: RobotModel | None = None,
    ) -> None:
        self.model = model if model is not None else UnicycleModel(input_lower, input_upper)
        if layout.model.nx != self.model.nx or layout.model.nu != self.model.nu:
            raise ProblemError(f"internal error: the layout is not built for the "
                               f"{self.model.name} model")
        self.model.check_discretization(settings.discretization)
        self.kernels = self.model.kernels(settings.discretization)
        self.layout = layout
        self.sample_time = float(sample_time)
        self.settings = settings
        self.input_lower = np.asarray(input_lower, float)
        self.input_upper = np.asarray(input_upper, float)
        self.qp = SparseQP(layout, settings.osqp, settings.qp_solver)
        if self.model.velocity_states:
            # the paper's R on the velocities (the commands), R Ts^2 on the accelerations: the
            # same price on a velocity change over a sample as on the velocity itself
            self.qp.update_cost_weights(Q_diag, np.asarray(R_diag) * self.sample_time ** 2,
                                        settings.slack_penalty, R_diag)
        else:
            self.qp.update_cost_weights(Q_diag, R_diag, settings.slack_penalty)
        self.qp.update_input_bounds(self.input_lower, self.input_upper)
        if layout.position_bounds:
            self.qp.update_position_bounds(position_lower, position_upper)
        self.z: np.ndarray | None = None
        self.y = np.zeros(layout.n_con)
        self.merit_weight = 1.0
        self.samples = 0
        self._motion = False  # some robots' input references are not 0 (update_motion)
        self._dynamics_point: np.ndarray | None = None
        self._initial_index = np.ascontiguousarray(layout.state_index[:, 0])
        self._command_speed = np.ascontiguousarray(
            np.arange(layout.n_robots) * layout.block_size + self.model.command_speed_offset)
        self._velocity_rows = bool(layout.velocity_rows.size)
        if self._velocity_rows:
            self.qp.update_velocity_bounds(self.model.state_lower, self.model.state_upper)
        self._build_views()
        self._collision_rows = np.concatenate((layout.internal_rows.ravel(),
                                               layout.external_rows.ravel()))
        # A's entries on the collision rows, in entry order: A z on those rows alone,
        # accumulated in the same order as layout.A_times
        local = np.full(layout.n_con, -1, dtype=np.int64)
        local[self._collision_rows] = np.arange(self._collision_rows.size)
        on_rows = local[layout.A_rows] >= 0
        self._collision_entries = np.ascontiguousarray(np.flatnonzero(on_rows), dtype=np.int64)
        self._collision_entry_rows = np.ascontiguousarray(local[layout.A_rows[on_rows]])
        self._collision_entry_cols = np.ascontiguousarray(layout.A_cols[on_rows])
        self._collision_rows = np.ascontiguousarray(self._collision_rows, dtype=np.int64)
        self._row_scratch = np.zeros(self._collision_rows.size)
        self._Az = np.zeros(layout.n_con)
        self._ATy = np.zeros(layout.n_var)
        first_slack = layout.n_var - layout.n_slack
        slack_rows_int = layout.slack_rows[layout.slack_internal_index - first_slack]
        slack_rows_ext = layout.slack_rows[layout.slack_external_index - first_slack]
        # one gather per vector shifts every stage-indexed block by one stage
        self._shift_z = np.arange(layout.n_var)
        for idx, axis in ((layout.state_index, 1), (layout.input_index, 1),
                          (layout.slack_internal_index, 1), (layout.slack_external_index, 2)):
            _shift_indexed(self._shift_z, idx, axis)
        self._shift_y = np.arange(layout.n_con)
        for idx, axis in ((layout.dyn_rows, 1), (layout.input_rows, 1),
                          (layout.position_rows, 1), (layout.velocity_rows, 1),
                          (layout.internal_rows, 1),
                          (layout.external_rows, 2), (slack_rows_int, 1), (slack_rows_ext, 2)):
            _shift_indexed(self._shift_y, idx, axis)

    def _build_views(self) -> None:
        """The QP's blocks the compiled kernels write (:meth:`SparseQP.matrix_entries`,
        :meth:`SparseQP.row_bounds`)."""
        L, qp = self.layout, self.qp
        m, N, E, P = L.n_robots, L.horizon, L.n_external, L.n_pairs
        self._init_lower, self._init_upper = qp.row_bounds("init")
        self._dyn_A = qp.matrix_entries("dyn_A")
        self._dyn_B = qp.matrix_entries("dyn_B")
        self._dyn_lower, self._dyn_upper = qp.row_bounds("dyn")
        self._internal_A = qp.matrix_entries("internal").reshape(P, N, 4)
        self._internal_lower = qp.row_bounds("internal")[0].reshape(P, N)
        self._external_A = qp.matrix_entries("external").reshape(m, E, N, 2)
        self._external_lower = qp.row_bounds("external")[0].reshape(m, E, N)
        self._block = L.block_size
        self._robot_span = L.n_robots * self._block  # the speeds: blocks, then a stride
        self._speed_stages = slice(self.model.speed_offset, L.stage_size * N, L.stage_size)

    def collision_blocks(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """The collision rows as the QP holds them: ``"internal"``: ``(P, N, 4)`` entries
        (``n, -n``) and ``(P, N)`` lower bounds; ``"external"``: ``(m, E, N, 2)`` and
        ``(m, E, N)`` (read-only copies)."""
        return {"internal": (self._internal_A.copy(), self._internal_lower.copy()),
                "external": (self._external_A.copy(), self._external_lower.copy())}

    # ------------------------------------------------------------ iterate
    @property
    def has_solution(self) -> bool:
        """Whether a previous iterate exists (to shift)."""
        return self.z is not None

    def states_inputs(self) -> tuple[np.ndarray, np.ndarray]:
        """Current iterate as ``(m, N+1, nx)`` states and ``(m, N, nu)`` inputs."""
        if self.z is None:
            raise ProblemError("no iterate yet: call solve() first")
        return self.layout.split_primal(self.z)

    def inputs(self) -> np.ndarray:
        """Inputs ``(m, N, nu)`` of the current iterate (a copy)."""
        if self.z is None:
            raise ProblemError("no iterate yet: call solve() first")
        return self.z[self.layout.input_index]

    def set_guess(self, initial_states: np.ndarray, inputs: np.ndarray,
                  converge_first: bool = True) -> None:
        """Set the iterate to the rollout of ``inputs (m, N, nu)`` from ``initial_states (m, nx)``.

        With ``converge_first`` the next :meth:`solve` iterates up to
        ``first_sample_iterations`` (a converged start); otherwise it proceeds as
        an ordinary sample.
        """
        L = self.layout
        u = np.clip(np.asarray(inputs, float), self.input_lower, self.input_upper)
        states = self.rollout(np.asarray(initial_states, float), u)
        self.z = L.join_primal(states, u)
        self.y = np.zeros(L.n_con)
        self.samples = 0 if converge_first else max(self.samples, 1)

    def shift(self) -> None:
        """Shift iterate and multipliers by one stage (last input held, state extrapolated)."""
        if self.z is None:
            return
        L = self.layout
        if self.kernels is not None:
            z, y = np.empty(self.z.shape), np.empty(self.y.shape)  # float64, as the iterate
            self.kernels.shift(self.z, self.y, self._shift_z, self._shift_y, L.n_robots, L.horizon,
                          self._block, self.sample_time, z, y)
            self.z, self.y = z, y
            return
        last_state = L.state_index[:, -1]
        x, u = self.z[last_state], self.z[L.input_index[:, -1]]
        last = self.model.discrete_dynamics(x, u, self.sample_time, self.settings.discretization)
        self.z = self.z[self._shift_z]
        self.z[last_state] = last
        self.y = self.y[self._shift_y]

    def start_sample(self, initial_states: np.ndarray) -> None:
        """The guess of a sample: the shifted iterate (zero inputs at the first) from ``x0``."""
        if self.z is None:
            L = self.layout
            self.set_guess(initial_states, np.zeros((L.n_robots, L.horizon, self.model.nu)))
        self.z[self._initial_index] = initial_states
        if self._velocity_rows:
            self.qp.update_velocity_bounds(*self.model.velocity_bounds(
                initial_states, self.layout.horizon, self.sample_time))

    def begin_sample(self, initial_states: np.ndarray) -> np.ndarray | None:
        """A sample's start in one call (the pipeline's hot path): :meth:`shift`, the shifted
        inputs ``(m, N, nu)`` kept (``None`` without a previous iterate), then
        :meth:`start_sample` from ``initial_states`` and :meth:`clear_motion`; returns the
        shifted inputs."""
        shifted = None
        if self.z is not None:
            self.shift()
            shifted = self.z[self.layout.input_index]
        self.start_sample(initial_states)
        self._dynamics_point = None
        if self._motion:
            self.clear_motion()
        return shifted

    def guess_speeds(self) -> np.ndarray:
        """Speeds ``(m, N)`` of stages 0..N-1 of the current iterate, a read-only view (the
        linearization point; :meth:`update_guess_speeds` changes them): the model's forward
        speed, an input of the unicycle, a state of a model with velocity states."""
        out = self.z[:self._robot_span].reshape(-1, self._block)[:, self._speed_stages]
        out.setflags(write=False)
        return out

    def update_guess_speeds(self, speeds: np.ndarray) -> None:
        """Set the speeds ``(m, N)`` of the current iterate (the linearization point)."""
        self.z[:self._robot_span].reshape(-1, self._block)[:, self._speed_stages] = speeds

    def update_motion(self, robots: np.ndarray, states: np.ndarray, inputs: np.ndarray) -> None:
        r"""The own robots ``robots (k,)`` track a motion of ``states (k, N+1, nx)`` and
        ``inputs (k, N, nu)`` at this sample: its inputs (clipped to their bounds) and its
        velocity states of stages 1..N become the references of theirs
        (:meth:`SparseQP.update_input_references`; the other robots' are 0, the paper's
        cost, until :meth:`clear_motion`), and their dynamics are linearized, in the
        sample's first QP, along the rollout of the motion's inputs from their stage-0
        states; the iterate itself (the QP's warm start, the point of the collision rows)
        stays the shifted previous solution.

        Why: a robot standing in the shifted iterate (:math:`\bar v_k = 0`) has
        linearized positions that cannot leave its heading's line,
        :math:`\partial p_{k+1}/\partial\theta_k = T_s \bar v_k (-\sin\bar\theta_k,
        \cos\bar\theta_k) = 0`, so its QP sees no use in a turn the motion asks for (in
        place, then along the path) and dithers its turn rate: a 64-robot grid formation
        (seed 0) stood with two robots pressed together until a re-plan, 3.29 times the
        straight trip; 1.98 with the dynamics along the motion. A robot that tracks its
        motion has it as its shifted iterate anyway; linearizing only the robots standing
        in the iterate (speeds within the QP's tolerance of 0) did worse on grid formations
        (seeds 0-12: median 1.94 and at most 2.23 times the straight trip, against 1.88
        and 2.04).

        Why not the collision rows at the motion: they are the separating hyperplanes
        between where the robot and its neighbours are predicted to be; at the motion's
        positions they bound a robot held behind its motion by a neighbour to the far side
        of that neighbour, and it deferred moving (maze-32-32-2 random-2, 32 robots: 98.6 s
        instead of 88 s). Safety depends on neither point: the rows are inner
        approximations at any point and the first input is verified on the nonlinear model
        (:mod:`sqpmpc.control.pipeline`)."""
        rows = np.asarray(robots, dtype=np.int64)
        states = np.asarray(states, dtype=float)
        inputs = np.clip(inputs, self.model.input_lower, self.model.input_upper)
        if self._motion:
            self.clear_motion()
        vel = list(self.model.velocity_states)
        self.qp.update_input_references(rows, inputs, states[:, 1:, vel] if vel else None)
        self._motion = True
        if self.z is not None and rows.size:
            L = self.layout
            point = self.z.copy()
            u = np.clip(inputs, self.input_lower, self.input_upper)
            point[L.state_index[rows]] = self.rollout(self.z[L.state_index[rows, 0]], u)
            point[L.input_index[rows]] = u
            self._dynamics_point = point

    def clear_motion(self) -> None:
        """Every own robot's input reference back to 0 (the paper's cost), and its
        dynamics linearized at the iterate again."""
        self._dynamics_point = None
        if not self._motion:
            return
        L = self.layout
        nv = len(self.model.velocity_states)
        everyone = np.arange(L.n_robots)
        self.qp.update_input_references(
            everyone, np.zeros((L.n_robots, L.horizon, self.model.nu)),
            np.zeros((L.n_robots, L.horizon, nv)) if nv else None)
        self._motion = False

    def first_speeds(self) -> np.ndarray:
        """The speed commanded at this sample ``(m,)`` of each own robot in the current iterate
        (a copy): the unicycle's first input ``v``, a velocity model's ``v`` of stage 1."""
        return self.z[self._command_speed]

    def update_position_weight_scale(self, scale: np.ndarray) -> None:
        """Per-robot factor ``(m,)`` on the position weight ``Q`` (see :class:`SparseQP`)."""
        self.qp.update_position_weight_scale(scale)

    def rollout(self, initial_states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """States ``(m, N+1, nx)`` of ``inputs (m, N, nu)`` from ``initial_states (m, nx)``."""
        return self.model.rollout(initial_states, inputs, self.sample_time,
                                  self.settings.discretization)

    def _linearize(
        self,
        z: np.ndarray,
        initial_states: np.ndarray,
        internal: CollisionRows | None,
        external: CollisionRows | None,
        dynamics_point: np.ndarray | None = None,
    ) -> None:
        """Write the QP of the iterate ``z``: dynamics (linearized at ``dynamics_point``
        when given: :meth:`update_motion`), initial state, collision rows, curvature."""
        L, s, qp = self.layout, self.settings, self.qp
        N = L.horizon
        zd = z if dynamics_point is None else dynamics_point
        if self.kernels is not None:
            self.kernels.linearize(zd, L.n_robots, N, self._block, self.sample_time, self._dyn_A,
                            self._dyn_B, self._dyn_lower, self._dyn_upper)
            states = None
        else:
            states, inputs = L.split_primal(zd)
            nxt, A_k, B_k = self.model.discrete_jacobians(states[:, :N], inputs, self.sample_time,
                                                          s.discretization)
            c_k = (nxt - np.einsum("mnij,mnj->mni", A_k, states[:, :N])
                   - np.einsum("mnij,mnj->mni", B_k, inputs))
            qp.update_dynamics(A_k, B_k, c_k)
        flat = initial_states.ravel()
        self._init_lower[:] = flat
        self._init_upper[:] = flat
        qp.mark_changed()  # the views written: the dynamics (Euler) and the initial state
        if internal is not None or external is not None:
            if states is None and (internal is not None or external.needs_states):
                states = z[L.state_index]
            if internal is not None:
                internal.write_rows(states, self._internal_A, self._internal_lower)
            if external is not None:
                external.write_rows(states, self._external_A, self._external_lower)
        if s.hessian == "exact":
            states, inputs = L.split_primal(z)
            lam = self.y[L.dyn_rows]
            H = -self.model.weighted_dynamics_hessian(states[:, :N], inputs, lam,
                                                      self.sample_time, s.discretization)
            w, V = np.linalg.eigh(H)
            H = np.einsum("...ij,...j,...kj->...ik", V, np.maximum(w, 0.0), V)
            qp.update_curvature(H, z)

    # ------------------------------------------------------------ NLP values
    def _cost(self, z: np.ndarray) -> tuple[float, np.ndarray]:
        """Value and gradient of the quadratic cost (curvature terms excluded)."""
        return self.qp.cost_value(z), self.qp.cost_gradient(z)

    def _infeasibility(self, z: np.ndarray, initial_states: np.ndarray) -> float:
        r"""L1 norm of the constraint violations at ``z`` for the merit function.

        Dynamics and initial state are measured on the nonlinear model; the
        collision rows as the QP holds them for this iteration (separating
        hyperplanes, slacks included). Those rows are inner approximations
        chosen per iteration (rotated normals, the stage-1 rule), so measuring
        them, not the raw distances, keeps the merit consistent with the QP and
        lets full steps be accepted.
        """
        L = self.layout
        if self.kernels is not None:
            total = self.kernels.defect_l1(z, initial_states, L.n_robots, L.horizon, self._block,
                                    self.sample_time)
        else:
            states, inputs = L.split_primal(z)
            defect = states[:, 1:] - self.model.discrete_dynamics(
                states[:, :-1], inputs, self.sample_time, self.settings.discretization)
            total = float(np.abs(defect).sum() + np.abs(states[:, 0] - initial_states).sum())
        rows = self._collision_rows
        if rows.size:
            total += rows_shortfall(self.qp.A_values, self._collision_entries,
                                    self._collision_entry_rows, self._collision_entry_cols,
                                    z, self.qp.lower, rows, self._row_scratch)
        return float(total)

    def kkt_residual(self, z: np.ndarray, y: np.ndarray) -> float:
        r"""KKT residual of the NLP at ``z`` with multipliers ``y``.

        Must be called right after linearizing at ``z``: the QP's constraint
        matrix is then the constraint Jacobian at ``z`` and the QP rows evaluated
        at ``z`` are the (shifted) constraint values. Returns the largest of
        :math:`\|\nabla f + J^\top y\|_\infty`, the primal violation and the
        complementarity :math:`|y_i|\,\mathrm{dist}_i`.
        """
        return self.qp.kkt_residual(z, y, self._Az, self._ATy)

    # ------------------------------------------------------------ solve
    def solve(
        self,
        initial_states: np.ndarray,
        reference: np.ndarray,
        internal: CollisionRows | None = None,
        external: CollisionRows | None = None,
        max_iterations: int | None = None,
        iteration_scheme: Literal["rti", "sqp"] | None = None,
        deadline: float | None = None,
        started: bool = False,
    ) -> IterationReport:
        """Run RTI (one QP) or SQP from the current iterate.

        Parameters
        ----------
        initial_states
            Measured states ``(m, nx)`` (the model's states).
        reference
            Reference positions of stages 1..N, ``(m, N, 2)``.
        internal, external
            Collision models (centralized pairs; neighbours as data).
        max_iterations
            Overrides the number of QPs (RTI: 1, SQP: ``max_sqp_iterations``).
        iteration_scheme
            Overrides ``settings.iteration_scheme`` for this call.
        deadline
            ``time.perf_counter()`` value after which no new QP is started
            (the first always runs); default: ``settings.time_budget`` from now.
        started
            :meth:`start_sample` was called with ``initial_states`` (only the guess's
            speeds changed since): not called again, and ``initial_states`` were found
            finite by the caller (the pipeline's measurement): not checked again.
        """
        t_start = time.perf_counter()
        s, L = self.settings, self.layout
        if deadline is None and s.time_budget is not None:
            deadline = t_start + s.time_budget
        initial_states = np.asarray(initial_states, float)
        if initial_states.shape != (L.n_robots, self.model.nx) or not (
                started or all_finite(initial_states.ravel())):
            raise ProblemError(
                f"initial_states must be finite with shape ({L.n_robots}, {self.model.nx}), "
                f"got {initial_states.shape}"
            )
        if not started or self.z is None:
            self.start_sample(initial_states)
        sqp = (iteration_scheme or s.iteration_scheme) == "sqp"
        if max_iterations is None:
            if self.samples == 0:
                max_iterations = max(s.first_sample_iterations, 1)
                sqp = True
            else:
                max_iterations = s.max_sqp_iterations if sqp else s.rti_max_iterations
        self.qp.update_reference(reference)
        # a new NLP every sample: the L1 merit weight follows its own multipliers (a weight
        # kept from a past encounter, 1000+, made every line search backtrack ~17 times)
        self.merit_weight = 1.0
        z, y = self.z, self.y  # never written in place: iterates are new arrays
        motion, self._dynamics_point = self._dynamics_point, None  # this sample's first QP
        if not sqp and max_iterations == 1 and s.rti_kkt_threshold is None:
            return self._rti_step(z, y, initial_states, internal, external, motion, t_start)
        assembly = qp_time = osqp_time = 0.0
        kkt = float("nan")
        converged = False
        iterations = qp_iters = 0
        status = "not run"
        last: QPResult | None = None
        check_kkt = sqp or s.rti_kkt_threshold is not None
        tol = s.kkt_tolerance if sqp else s.rti_kkt_threshold
        insignificant = False  # the last SQP step was below STEP_TOLERANCE
        while True:
            t0 = time.perf_counter()
            self.y = y
            self._linearize(z, initial_states, internal, external,
                            motion if iterations == 0 else None)
            if check_kkt and iterations > 0:
                kkt = self.kkt_residual(z, y)
                if kkt <= tol:
                    converged = True
                    assembly += time.perf_counter() - t0
                    break
            assembly += time.perf_counter() - t0
            if insignificant or iterations >= max_iterations or (
                    iterations and deadline is not None and time.perf_counter() > deadline):
                break
            res = self.qp.solve(z, y)
            last = res
            iterations += 1
            qp_iters += res.iterations
            qp_time += res.wall_time
            osqp_time += res.solve_time
            status = res.status
            if not res.success:
                self.samples += 1
                return IterationReport(False, iterations, kkt, False, status, assembly,
                                       qp_time, osqp_time, time.perf_counter() - t_start,
                                       qp_iters, last)
            t1 = time.perf_counter()
            if sqp:
                insignificant = _insignificant(res.x, z)
                if insignificant:  # the merit function cannot resolve it: taken whole
                    z, y = res.x, res.y
                else:
                    alpha = self._line_search(z, res, initial_states)
                    z = z + alpha * (res.x - z)
                    y = y + alpha * (res.y - y)
            else:
                z, y = res.x, res.y
            assembly += time.perf_counter() - t1
            if not check_kkt and iterations >= max_iterations:
                break
        self.z, self.y = z, y
        self.samples += 1
        return IterationReport(True, iterations, kkt, converged, status, assembly, qp_time,
                               osqp_time, time.perf_counter() - t_start, qp_iters, last)

    def _rti_step(self, z: np.ndarray, y: np.ndarray, initial_states: np.ndarray,
                  internal: CollisionRows | None, external: CollisionRows | None,
                  motion: np.ndarray | None, t_start: float) -> IterationReport:
        """RTI's usual sample, one QP without KKT checks: what the loop of :meth:`solve`
        does for one iteration (same iterate, same report), in fewer steps."""
        t0 = time.perf_counter()
        self.y = y
        self._linearize(z, initial_states, internal, external, motion)
        assembly = time.perf_counter() - t0
        res = self.qp.solve(z, y)
        self.samples += 1
        if res.success:
            self.z, self.y = res.x, res.y
        return IterationReport(bool(res.success), 1, float("nan"), False, res.status, assembly,
                               res.wall_time, res.solve_time, time.perf_counter() - t_start,
                               res.iterations, res)

    def engaged_robots(self, y: np.ndarray, tolerance: float = 1e-4) -> np.ndarray:
        """Own robots with an active collision row (``|y_i| > tolerance``), ``(m,)`` bool."""
        return engaged_robots(self.layout, y, tolerance)

    def _line_search(self, z: np.ndarray, res: QPResult, initial_states: np.ndarray) -> float:
        """Armijo backtracking on the L1 merit function; returns the step length."""
        dz = res.x - z
        L = self.layout
        duals = np.concatenate((res.y[L.dyn_rows].ravel(), res.y[L.init_rows].ravel(),
                                res.y[L.internal_rows].ravel(), res.y[L.external_rows].ravel()))
        largest = float(np.abs(duals).max(initial=0.0))
        self.merit_weight = max(self.merit_weight, 1.5 * largest + 1.0)
        mu = self.merit_weight
        f0, g0 = self._cost(z)
        h0 = self._infeasibility(z, initial_states)
        phi0 = f0 + mu * h0
        slope = float(g0 @ dz) - mu * h0
        if slope >= 0.0:
            return 1.0
        alpha = 1.0
        while alpha > 1e-6:
            zt = z + alpha * dz
            h = self._infeasibility(zt, initial_states)
            phi = self.qp.cost_value(zt) + mu * h
            if phi <= phi0 + 1e-4 * alpha * slope:
                return alpha
            alpha *= 0.5
        return alpha


def _insignificant(x: np.ndarray, z: np.ndarray) -> bool:
    r"""Whether the QP step :math:`x - z` is numerically insignificant:
    :math:`\|x - z\|_\infty \le \epsilon_{step}\,(1 + \|z\|_\infty)`
    (:data:`STEP_TOLERANCE`)."""
    return float(np.abs(x - z).max(initial=0.0)) <= STEP_TOLERANCE * (
        1.0 + float(np.abs(z).max(initial=0.0)))


def _shift_indexed(vec: np.ndarray, idx: np.ndarray, axis: int) -> None:
    """In place: ``vec[idx]`` shifted by one along ``axis`` of ``idx``, last entry repeated."""
    if idx.size == 0 or idx.shape[axis] == 0:
        return
    vals = vec[idx]
    head = np.take(vals, np.arange(1, vals.shape[axis]), axis=axis)
    tail = np.take(vals, [vals.shape[axis] - 1], axis=axis)
    vec[idx] = np.concatenate((head, tail), axis=axis)


def engaged_robots(layout: QPLayout, y: np.ndarray, tolerance: float = 1e-4) -> np.ndarray:
    """Own robots of ``layout`` with an active collision row (``|y_i| > tolerance`` in the
    multipliers ``y``), ``(m,)`` bool."""
    L = layout
    engaged = np.zeros(L.n_robots, dtype=bool)
    if L.n_pairs:
        active = np.abs(y[L.internal_rows]).max(axis=1) > tolerance
        engaged[np.asarray(L.internal_pairs).reshape(-1, 2)[active].ravel()] = True
    if L.n_external:
        engaged |= np.abs(y[L.external_rows]).max(axis=(1, 2)) > tolerance
    return engaged

r"""Centralized (paper Algorithm 3.1) and decentralized (Algorithm 3.2) NMPC controllers.

Both wrap :class:`sqpmpc.rti.MultipleShootingSQP`. Every sample a controller

1. shifts its previous solution and linearizes around it (robots near a
   reference at rest get the parking weights, see ``SolverSettings``),
2. solves the QP (RTI) or iterates (SQP); in RTI a robot free of collision
   rows that would reverse gear a second sample in a row has that sample
   iterated to convergence (``gear_cycle_sqp``),
3. clips the first input to its bounds and *verifies* it on the nonlinear
   model: the next positions must satisfy the stage-1 collision rows (and
   position bounds). A failed QP, a non-finite output or a failed check applies
   a fallback instead: the first input of the shifted previous plan if it
   passes the same check, else a braking input (``v`` as close to 0 as the
   bounds allow, ``omega`` likewise), which the stage-1 rule of
   :mod:`sqpmpc.collision` keeps safe. Fallbacks are counted, never raised.

The decentralized controller owns one robot. Its neighbours' predicted
horizons arrive as :class:`PlanMessage`. In the default ``"shared"`` mode each
pair uses one hyperplane built by both robots from the same two exchanged
predictions, each keeping half the distance. In ``"paper"`` mode each robot
treats the others' predictions as fixed obstacles (the seed paper's literal
scheme, no guarantee). A neighbour whose plan is missing or stale is
predicted as in the paper's section 3.2: its last input is estimated from its
current and previous states and held over the horizon; it is then kept at the
full distance as an obstacle.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from .collision import ExternalCollisionModel, PairwiseCollisionModel, segment_distances
from .deadlock import DetourRule
from .errors import ProblemError
from .layout import QPLayout
from .model import discrete_dynamics, estimate_input, rollout
from .references import ReferenceSet
from .rti import CollisionRows, IterationReport, MultipleShootingSQP
from .scenario import Scenario
from .settings import SolverSettings

__all__ = [
    "CentralizedController",
    "ControlOutput",
    "DecentralizedController",
    "PlanMessage",
    "braking_input",
    "predict_from_plan",
    "predict_from_states",
]

DecentralizedMode = Literal["shared", "paper"]

log = logging.getLogger(__name__)
_paper_mode_warned = False


@dataclass(frozen=True)
class PlanMessage:
    """A robot's predicted horizon as exchanged between controllers.

    Attributes
    ----------
    robot_id
        Sender.
    sample
        Sample index ``k`` at which the plan was computed (its stage 0 is time ``t_k``).
    states
        ``(N+1, 3)`` predicted states.
    inputs
        ``(N, 2)`` predicted inputs.
    """

    robot_id: int
    sample: int
    states: np.ndarray
    inputs: np.ndarray


@dataclass
class ControlOutput:
    """Result of one controller sample.

    Attributes
    ----------
    inputs
        ``(m, 2)`` inputs to apply (within bounds).
    predicted_states, predicted_inputs
        ``(m, N+1, 3)`` and ``(m, N, 2)``: the plan consistent with ``inputs``.
    fallback
        ``None``, ``"shifted-plan"`` or ``"brake"``.
    report
        What the iteration did.
    compute_time
        Wall time of the whole sample computation, s.
    """

    inputs: np.ndarray
    predicted_states: np.ndarray
    predicted_inputs: np.ndarray
    fallback: str | None
    report: IterationReport
    compute_time: float
    info: dict[str, float] = field(default_factory=dict)


def braking_input(lower: np.ndarray, upper: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The input closest to zero within ``[lower, upper]``, broadcast to ``shape + (2,)``."""
    return np.broadcast_to(np.clip(0.0, lower, upper), shape + (2,)).copy()


def predict_from_plan(
    plan: PlanMessage, sample: int, horizon: int, sample_time: float, method: str
) -> np.ndarray | None:
    """States ``(N+1, 3)`` for times ``t_k .. t_{k+N}`` from a plan computed at an earlier sample.

    Stages past the plan's end are extrapolated holding its last input.
    Returns ``None`` when the plan is from the future or older than ``N`` samples.
    """
    d = sample - plan.sample
    if d < 0 or d > horizon:
        return None
    known = plan.states[d:]
    missing = horizon + 1 - known.shape[0]
    if missing == 0:
        return known.copy()
    if missing == 1:
        tail = discrete_dynamics(known[-1], plan.inputs[-1], sample_time, method)[None]
    else:
        tail = rollout(known[-1], np.repeat(plan.inputs[-1:], missing, axis=0), sample_time,
                       method)[1:]
    return np.concatenate((known, tail), axis=0)


def predict_from_states(
    current: np.ndarray,
    previous: np.ndarray | None,
    horizon: int,
    sample_time: float,
    method: str,
) -> np.ndarray:
    """Paper section 3.2 fallback: hold the input estimated from two states, ``(N+1, 3)``."""
    u = np.zeros(2) if previous is None else estimate_input(previous, current, sample_time)
    return rollout(current, np.repeat(u[None], horizon, axis=0), sample_time, method)


class _ControllerBase:
    """Shared parts: engine construction, reference sampling, verification, fallback."""

    def __init__(self, scenario: Scenario, indices: np.ndarray, layout: QPLayout,
                 settings: SolverSettings, detour_patience: int) -> None:
        self.scenario = scenario
        self.settings = settings
        self.indices = np.asarray(indices, dtype=np.int64)
        b = scenario.bounds
        self.input_lower, self.input_upper = b.input_lower(), b.input_upper()
        self.position_lower, self.position_upper = b.position_lower(), b.position_upper()
        self.engine = MultipleShootingSQP(
            layout, scenario.sample_time, np.asarray(scenario.weights.Q),
            np.asarray(scenario.weights.R), self.input_lower, self.input_upper,
            self.position_lower, self.position_upper, settings,
        )
        self.horizon = scenario.horizon
        self.sample_time = scenario.sample_time
        self.detour = DetourRule(self.indices, scenario.required_distances(), settings.detour,
                                 detour_patience)
        self._references = ReferenceSet([scenario.robots[i].reference for i in self.indices])
        self._stage_offsets = self.sample_time * np.arange(1, self.horizon + 1)
        v_max = max(abs(self.input_lower[0]), abs(self.input_upper[0]))
        horizon_time = max(self.horizon * self.sample_time, settings.parking_horizon)
        self.parking_radius = max(settings.parking_radius,
                                  settings.parking_reach * v_max * horizon_time)
        self._position_low = self.position_lower - 1e-9
        self._position_high = self.position_upper + 1e-9
        self.last_speed = np.zeros(self.indices.size)
        self._speed_before_last = np.zeros(self.indices.size)
        self.gear_cycle_samples = 0
        self._shifted_inputs: np.ndarray | None = None

    def references(self, t: float, positions: np.ndarray) -> np.ndarray:
        """References ``(m, N, 2)`` with the detour rule applied (positions of all robots).

        Also tells the engine which robots park: their scenario reference is
        at rest over the horizon and at most :attr:`parking_radius` away
        (``SolverSettings.parking_gain``).
        """
        raw = self.reference(t)
        if self.settings.parking_gain != 1.0:
            spread = np.abs(raw - raw[:, :1])
            to_goal = raw[:, -1] - positions[self.indices]
            self.engine.update_parking(
                (np.max(spread, axis=(1, 2)) <= 1e-9)
                & (np.hypot(to_goal[:, 0], to_goal[:, 1]) <= self.parking_radius))
        return self.detour.apply(positions, self.last_speed, raw)

    def reference(self, t: float) -> np.ndarray:
        """Reference positions ``(m, N, 2)`` of stages 1..N at sample time ``t``."""
        return self._references.positions(t + self._stage_offsets)

    def _solve(self, states: np.ndarray, reference: np.ndarray, t0: float,
               **rows: CollisionRows) -> IterationReport:
        """The engine's sample; a gear 2-cycle is iterated to convergence (``gear_cycle_sqp``).

        ``t0`` is the sample's start (``time.perf_counter()``): both calls share
        ``settings.time_budget`` from it.
        """
        s = self.settings
        deadline = t0 + s.time_budget if s.time_budget > 0.0 else None
        report = self.engine.solve(states, reference, deadline=deadline, **rows)
        if not (s.gear_cycle_sqp and s.iteration_scheme == "rti" and report.success):
            return report
        v = self.engine.inputs()[:, 0, 0]
        eps = 0.1 * s.stall_speed
        v1, v2 = self.last_speed, self._speed_before_last
        moving = (np.abs(v) > eps) & (np.abs(v1) > eps) & (np.abs(v2) > eps)
        cycle = moving & (np.sign(v) == np.sign(v2)) & (np.sign(v) != np.sign(v1))
        if not np.count_nonzero(cycle) or not np.count_nonzero(
                cycle & ~self.engine.engaged_robots(self.engine.y)):
            return report
        if deadline is not None and time.perf_counter() > deadline:
            return report
        self.gear_cycle_samples += 1
        more = self.engine.solve(states, reference, iteration_scheme="sqp", deadline=deadline,
                                 **rows)
        last = more if more.success else report  # a failed SQP keeps the RTI iterate
        return replace(
            last, success=True, iterations=report.iterations + more.iterations,
            assembly_time=report.assembly_time + more.assembly_time,
            qp_time=report.qp_time + more.qp_time,
            osqp_solve_time=report.osqp_solve_time + more.osqp_solve_time,
            total_time=report.total_time + more.total_time,
            qp_iterations=report.qp_iterations + more.qp_iterations,
        )

    def _record_speed(self, out: ControlOutput) -> None:
        self._speed_before_last = self.last_speed
        self.last_speed = out.inputs[:, 0].copy()

    def _next(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        return discrete_dynamics(states, inputs, self.sample_time, self.settings.discretization)

    def _in_position_bounds(self, positions: np.ndarray) -> bool:
        inside = (positions >= self._position_low) & (positions <= self._position_high)
        return np.count_nonzero(inside) == inside.size

    def _rollout(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """States ``(m, N+1, 3)`` of applying ``inputs (m, N, 2)`` from ``states (m, 3)``."""
        return np.swapaxes(rollout(states, np.swapaxes(inputs, 0, 1), self.sample_time,
                                   self.settings.discretization), 0, 1)

    def _plan_from(self, states: np.ndarray, first: np.ndarray,
                   rest: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Plan applying ``first (m, 2)`` then ``rest (m, N-1, 2)`` (or braking)."""
        m = states.shape[0]
        if rest is None:
            rest = braking_input(self.input_lower, self.input_upper, (m, self.horizon - 1))
        u = np.concatenate((first[:, None], rest), axis=1)
        return self._rollout(states, u), u

    def _finish(self, states: np.ndarray, report: IterationReport, t0: float,
                safe: Callable[[np.ndarray, np.ndarray], bool]) -> ControlOutput:
        """Verify the QP's first input, fall back if needed, store the consistent plan.

        ``safe(states, next_states)`` judges the motion over one sample.
        """
        previous = self._shifted_inputs
        fallback = None
        if report.success:
            plan_u = self.engine.inputs()
            u0 = np.clip(plan_u[:, 0], self.input_lower, self.input_upper)
            if np.isfinite(u0).all():
                plan_u[:, 0] = u0
                # stage 1 of the rollout is exactly the next state of the first input
                plan_x = self._rollout(states, plan_u)
                if safe(states, plan_x[:, 1]):
                    return ControlOutput(u0, plan_x, plan_u, None, report,
                                         time.perf_counter() - t0)
        candidates = []
        if previous is not None:
            candidates.append(("shifted-plan", previous[:, 0], previous[:, 1:]))
        m = states.shape[0]
        brake = braking_input(self.input_lower, self.input_upper, (m,))
        candidates.append(("brake", brake, None))
        for name, first, rest in candidates:
            first = np.clip(first, self.input_lower, self.input_upper)
            if name == "brake" or safe(states, self._next(states, first)):
                fallback = name
                plan_x, plan_u = self._plan_from(states, first, rest)
                break
        self.engine.set_guess(states, plan_u, converge_first=False)
        return ControlOutput(plan_u[:, 0].copy(), plan_x, plan_u, fallback, report,
                             time.perf_counter() - t0)

    def _remember_shifted(self) -> None:
        if self.engine.has_solution:
            self.engine.shift()
            self._shifted_inputs = self.engine.inputs()
        else:
            self._shifted_inputs = None


class CentralizedController(_ControllerBase):
    """One QP over all robots (paper Algorithm 3.1, eq. 7).

    Parameters
    ----------
    scenario
        The problem.
    settings
        Iteration settings.
    """

    def __init__(self, scenario: Scenario, settings: SolverSettings | None = None) -> None:
        settings = settings or SolverSettings()
        pairs = scenario.pairs().reshape(-1, 2)
        required = scenario.required_distances()[pairs[:, 0], pairs[:, 1]]
        layout = QPLayout(
            scenario.n_robots, scenario.horizon, pairs, 0,
            bool(np.isfinite(scenario.bounds.position_lower()).any()
                 or np.isfinite(scenario.bounds.position_upper()).any()),
        )
        super().__init__(scenario, np.arange(scenario.n_robots), layout, settings,
                         settings.detour.patience_centralized)
        self.pairs = pairs
        self.required = required
        self.collisions = PairwiseCollisionModel(
            pairs, required + settings.collision_margin,
            settings.keep_right_angles(scenario.horizon)[None, :], settings.max_normal_turn,
        )

    def _safe(self, states: np.ndarray, next_states: np.ndarray) -> bool:
        """Every pair keeps its distance along the straight segments of the sample.

        With the Euler model the robots move on straight segments at constant
        speed, so the smallest distance of a pair during the sample is
        :func:`~sqpmpc.collision.segment_distances` of its relative positions:
        checking it (not only the next sample) keeps robots from passing
        through each other between samples. (With RK4 the path is an arc; the
        chord is then an approximation.)
        """
        p = next_states[:, :2]
        if self.pairs.size:
            a, b = self.pairs[:, 0], self.pairs[:, 1]
            now = states[:, :2]
            if (segment_distances(now[a] - now[b], p[a] - p[b]) < self.required).any():
                return False
        return self._in_position_bounds(p)

    def step(self, t: float, states: np.ndarray) -> ControlOutput:
        """Compute the inputs of every robot at time ``t`` from the measured ``states (n, 3)``."""
        t0 = time.perf_counter()
        states = np.asarray(states, dtype=float)
        if states.shape != (self.scenario.n_robots, 3) or not np.isfinite(states).all():
            raise ProblemError(
                f"states must be finite with shape ({self.scenario.n_robots}, 3), "
                f"got {states.shape}"
            )
        self._remember_shifted()
        self.collisions.set_current_positions(states[:, :2])
        report = self._solve(states, self.references(t, states[:, :2]), t0,
                             internal=self.collisions)
        out = self._finish(states, report, t0, self._safe)
        self._record_speed(out)
        out.info["stage_one_overrides"] = float(self.collisions.stage_one_overrides)
        return out


class DecentralizedController(_ControllerBase):
    """One robot's controller with its own QP (paper Algorithm 3.2).

    Parameters
    ----------
    scenario
        The problem (all robots: ids, diameters, references).
    robot_id
        The robot this controller drives.
    settings
        Iteration settings.
    mode
        ``"shared"`` (default, shared-responsibility hyperplanes) or ``"paper"``.
    """

    def __init__(self, scenario: Scenario, robot_id: int,
                 settings: SolverSettings | None = None,
                 mode: DecentralizedMode = "shared") -> None:
        settings = settings or SolverSettings()
        if mode not in ("shared", "paper"):
            raise ProblemError(f"decentralized mode must be 'shared' or 'paper', got {mode!r}")
        index = scenario.index_of(robot_id)
        others = np.array([i for i in range(scenario.n_robots) if i != index], dtype=np.int64)
        layout = QPLayout(
            1, scenario.horizon, np.zeros((0, 2), dtype=np.int64), others.size,
            bool(np.isfinite(scenario.bounds.position_lower()).any()
                 or np.isfinite(scenario.bounds.position_upper()).any()),
        )
        super().__init__(scenario, np.array([index]), layout, settings,
                         settings.detour.patience)
        self.robot_id = int(robot_id)
        self.index = index
        self.others = others
        self.other_ids = scenario.ids[others]
        self._neighbours = list(zip(others.tolist(), self.other_ids.tolist(), strict=True))
        self.mode = mode
        self.required = scenario.required_distances()[index, others]
        self.collisions = ExternalCollisionModel(
            self.required, scenario.horizon,
            settings.keep_right_angles(scenario.horizon)[None, :],
            reach=scenario.sample_time * max(abs(self.input_lower[0]), abs(self.input_upper[0])),
            max_turn=settings.max_normal_turn, margin=settings.collision_margin,
        )
        self.collisions.stage_one_rule_for_obstacles = mode == "shared"
        if mode == "paper":
            _warn_paper_mode()
        self.published: PlanMessage | None = None

    def _safe(self, states: np.ndarray, next_state: np.ndarray) -> bool:
        return (self.collisions.first_stage_safe(next_state[0, :2])
                and self._in_position_bounds(next_state[:, :2]))

    def _predictions(
        self,
        sample: int,
        states: np.ndarray,
        plans: Mapping[int, PlanMessage | None],
        previous_states: np.ndarray | None,
    ) -> tuple[np.ndarray, list[str]]:
        """Own published prediction and the neighbours' ``(1 + E, N+1, 3)``, the slot kinds.

        Row 0 is this robot's published plan (as the neighbours see it), rows
        ``1..E`` the neighbours. Plans one sample old (the usual case) are
        extrapolated by one step together, others by :func:`predict_from_plan`.
        """
        N, method = self.horizon, self.settings.discretization
        preds = np.empty((self.others.size + 1, N + 1, 3))
        kinds: list[str] = []
        recent: list[int] = []  # rows filled from a plan computed at sample - 1
        last_states: list[np.ndarray] = []
        last_inputs: list[np.ndarray] = []

        def from_plan(row: int, plan: PlanMessage) -> bool:
            if sample - plan.sample == 1 and plan.states.shape[0] == N + 1:
                preds[row, :N] = plan.states[1:]
                recent.append(row)
                last_states.append(plan.states[-1])
                last_inputs.append(plan.inputs[-1])
                return True
            pred = predict_from_plan(plan, sample, N, self.sample_time, method)
            if pred is None:
                return False
            preds[row] = pred
            return True

        if self.published is None or not from_plan(0, self.published):
            preds[0] = predict_from_states(states[self.index], None, N, self.sample_time, method)
        shared = self.mode == "shared"
        for row, (j, jid) in enumerate(self._neighbours, start=1):
            plan = plans.get(jid)
            # shared hyperplanes need the plan the neighbour itself uses: the previous one
            if plan is not None and (not shared or plan.sample == sample - 1) and from_plan(row,
                                                                                          plan):
                kinds.append("shared" if shared else "obstacle")
                continue
            prev = None if previous_states is None else previous_states[j]
            preds[row] = predict_from_states(states[j], prev, N, self.sample_time, method)
            kinds.append("missing" if shared else "obstacle")
        if recent:
            preds[recent, N] = discrete_dynamics(np.array(last_states), np.array(last_inputs),
                                                 self.sample_time, method)
        return preds, kinds

    def step(
        self,
        sample: int,
        t: float,
        states: np.ndarray,
        plans: Mapping[int, PlanMessage | None],
        previous_states: np.ndarray | None = None,
    ) -> ControlOutput:
        """Compute this robot's input at sample ``k`` (time ``t``).

        Parameters
        ----------
        sample
            Sample index ``k``.
        t
            Time ``t_k``.
        states
            Measured states of all robots ``(n, 3)`` (scenario order).
        plans
            Latest plan received from each neighbour id (``None`` or absent if none).
        previous_states
            States at ``k - 1`` (for the fallback estimate), or ``None``.
        """
        t0 = time.perf_counter()
        states = np.asarray(states, dtype=float)
        n = self.scenario.n_robots
        if states.shape != (n, 3) or not np.isfinite(states).all():
            raise ProblemError(f"states must be finite with shape ({n}, 3), got {states.shape}")
        preds, kinds = self._predictions(sample, states, plans, previous_states)
        self.collisions.set_sample(
            states[self.index, :2], states[self.others, :2], preds[0, 1:, :2],
            preds[1:, 1:, :2], kinds,
        )
        self._remember_shifted()
        report = self._solve(states[self.index][None], self.references(t, states[:, :2]), t0,
                             external=self.collisions)
        out = self._finish(states[self.index][None], report, t0, self._safe)
        self._record_speed(out)
        out.info["stage_one_overrides"] = float(self.collisions.stage_one_overrides)
        out.info["fallback_neighbours"] = float(kinds.count("missing"))
        self.published = PlanMessage(self.robot_id, sample, out.predicted_states[0].copy(),
                                     out.predicted_inputs[0].copy())
        return out


def _warn_paper_mode() -> None:
    """Log once per process that ``"paper"`` mode has no collision guarantee."""
    global _paper_mode_warned
    if not _paper_mode_warned:
        _paper_mode_warned = True
        log.warning("decentralized mode 'paper' (the seed paper's literal scheme, for "
                    "comparison) has no collision guarantee: robots avoid each other's "
                    "previous plans, and every built-in scenario collides with it "
                    "(docs/decomposition.md); use 'shared' (default) to be safe")

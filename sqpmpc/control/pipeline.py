r"""The per-sample pipeline both schemes run (paper Algorithms 3.1 and 3.2).

Every sample of every controller is :meth:`ControllerPipeline.run_sample`,
one function that reads top to bottom:

1. **measure**: validate the measured states of all robots;
2. **predict neighbours**: the scheme's collision data (centralized: the
   current positions; decentralized: the neighbours' exchanged plans, or the
   paper's fallback prediction when a plan is missing);
3. **rules shape**: the scenario's references of stages 1..N, then every
   rule's ``shape_references`` hook (detour targets, parking weights);
4. **shift**: the previous solution moved one stage (kept as the fallback
   plan), the measured state put in stage 0, then every rule's
   ``shape_guess`` hook on the linearization point (stall repair, parking);
5. **linearize and solve**: :meth:`sqpmpc.ocp.iteration.MultipleShootingSQP.solve`
   (one QP in RTI, iterations in SQP);
6. **rules after solve**: a rule may ask for the sample to be iterated to
   convergence (gear cycle), within the sample's time budget;
7. **verify**: the first input is clipped to its bounds and checked on the
   nonlinear model over the whole sample, the plant's possible deviation from
   the predicted path included (:mod:`sqpmpc.problem.plant`); a failed QP, a non-finite plan or
   a failed check applies the shifted previous plan if it passes the same
   check, else a braking input (always safe by the stage-one rule; with
   acceleration limits, the braking the last accepted input left room for);
8. **publish**: the counters, the applied-input history the rules read and,
   decentralized, the plan the neighbours will receive.

The pipeline is written against the robot model of the scenario
(:meth:`sqpmpc.problem.scenario.Scenario.robot_model`): the measured poses (and
velocities, CONTRACT 1c) become the model's states, the plan's commands and
the poses and velocities the neighbours receive come from the model.

The scheme-specific parts are three methods of the controllers in
:mod:`sqpmpc.control.decentralized`: ``_predict_neighbours``, ``_safe`` and
``_publish``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.kernels.ocp import all_finite
from sqpmpc.kernels.warmup import warm_up
from sqpmpc.models.base import RobotModel
from sqpmpc.ocp.geometry import RowGeometry
from sqpmpc.ocp.iteration import MultipleShootingSQP
from sqpmpc.ocp.obstacle_rows import ObstacleRows
from sqpmpc.ocp.report import CollisionRows, IterationReport
from sqpmpc.problem.plant import acceleration_path_deviation, model_margin, path_deviation
from sqpmpc.problem.references import Reference, ReferenceSet
from sqpmpc.problem.scenario import Scenario
from sqpmpc.qp.layout import QPLayout
from sqpmpc.rules.base import RuleContext, RuleInstance, SampleView

if TYPE_CHECKING:
    from sqpmpc.control.plans import PlanMessage

__all__ = ["RECOVERY_TOLERANCE", "ControlOutput", "ControllerPipeline", "braking_input",
           "kernel_warm_up_seconds"]

#: Smallest tolerance of the ``overlap-recovery`` rule, m (the solver's accuracy).
RECOVERY_TOLERANCE = 1e-4

@functools.cache
def kernel_warm_up_seconds() -> float:
    """Seconds this process spent compiling or loading the kernels (once per process)."""
    return warm_up()


@dataclass
class ControlOutput:
    """Result of one controller sample.

    Attributes
    ----------
    inputs
        ``(m, 2)`` velocity commands ``(v, omega)`` to apply (within bounds).
    predicted_states, predicted_inputs
        ``(m, N+1, 3)`` poses and ``(m, N, 2)`` paper-unicycle inputs of the plan
        consistent with ``inputs`` (for the paper's unicycle the plan itself; for a
        model with velocity states, :meth:`~sqpmpc.models.base.RobotModel.poses` and
        :meth:`~sqpmpc.models.base.RobotModel.velocity_plan`).
    fallback
        ``None``, ``"shifted-plan"`` or ``"brake"``.
    report
        What the iteration did.
    compute_time
        Wall time of the whole sample, s.
    counters
        Cumulative counts of the controller after this sample: the engine's
        (``samples``, ``fallbacks``, ``qp_rescues``, ``stage_one_overrides``,
        ...) and every rule's (``sqpmpc rules``).
    plan
        Decentralized: the plan to send to the neighbours
        (:class:`~sqpmpc.control.plans.PlanMessage`, the same object as the
        controller's ``published``); ``None`` for the centralized controller.
    """

    inputs: np.ndarray
    predicted_states: np.ndarray
    predicted_inputs: np.ndarray
    fallback: str | None
    report: IterationReport
    compute_time: float
    counters: Mapping[str, int] = field(default_factory=dict)
    plan: PlanMessage | None = None
    model_states: np.ndarray | None = None
    model_inputs: np.ndarray | None = None


def braking_input(lower: np.ndarray, upper: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The input closest to zero within ``[lower, upper]``, broadcast to ``shape + (2,)``."""
    return np.broadcast_to(np.clip(0.0, lower, upper), shape + (2,)).copy()


def _overrides(instance: RuleInstance, hook: str) -> bool:
    return getattr(type(instance), hook) is not getattr(RuleInstance, hook)


class ControllerPipeline:
    """Shared per-sample pipeline of both controllers (see the module docstring).

    Parameters
    ----------
    scenario
        The problem.
    indices
        ``(m,)`` scenario indices of the own robots.
    layout
        QP layout.
    settings
        Solver settings (rules included).
    scheme
        ``"centralized"`` or ``"decentralized"``.
    """

    scheme = ""

    def __init__(self, scenario: Scenario, indices: np.ndarray, layout: QPLayout,
                 settings: SolverSettings) -> None:
        kernel_warm_up_seconds()
        self.scenario = scenario
        self.settings = settings
        self.indices = np.asarray(indices, dtype=np.int64)
        b = scenario.bounds
        self.input_lower, self.input_upper = b.input_lower(), b.input_upper()
        self.position_lower, self.position_upper = b.position_lower(), b.position_upper()
        self._position_low = self.position_lower - 1e-9
        self._position_high = self.position_upper + 1e-9
        self._bounded = bool(np.isfinite(self.position_lower).any()
                             or np.isfinite(self.position_upper).any())
        self.horizon = scenario.horizon
        self.sample_time = scenario.sample_time
        #: the robot model (the paper's unicycle unless the scenario declares acceleration bounds)
        self.model = layout.model if isinstance(layout.model, RobotModel) \
            else scenario.robot_model()
        self._unicycle = self.model.nx == 3
        kernels = self.model.kernels(settings.discretization)
        self._clip_kernel = None if kernels is None else kernels.clip_and_roll_out
        self.engine = MultipleShootingSQP(
            layout, scenario.sample_time, np.asarray(scenario.weights.Q),
            np.asarray(scenario.weights.R), self.model.input_lower, self.model.input_upper,
            self.position_lower, self.position_upper, settings, self.model,
        )
        self.counts: dict[str, int] = {
            "samples": 0, "fallbacks": 0, "shifted_plan_fallbacks": 0, "brake_fallbacks": 0,
            "qp_rescues": 0, "stage_one_overrides": 0, "converged_samples": 0}
        self.geometry = RowGeometry.plain(self.horizon)
        self.context = RuleContext(scenario, self.indices, self.scheme,
                                   settings.iteration_scheme, self.engine, self.geometry,
                                   self.counts)
        self.rules = [rule.bind(self.context) for rule in settings.rules]
        for rule in self.rules:
            rule.configure_rows(self.geometry)
        self._reference_rules = [r for r in self.rules if _overrides(r, "shape_references")]
        self._guess_rules = [r for r in self.rules if _overrides(r, "shape_guess")]
        self._after_rules = [r for r in self.rules if _overrides(r, "after_solve")]
        self._references = ReferenceSet([scenario.robots[i].reference for i in self.indices])
        self._stage_offsets = self.sample_time * np.arange(1, self.horizon + 1)
        m = self.indices.size
        self._applied = np.zeros((m, 2))
        self._applied_before = np.zeros((m, 2))
        self._n = scenario.n_robots
        self._rows: dict[str, CollisionRows] = {}  # the scheme's collision models
        # a plant unlike the prediction: the margin of the rows and the check's path bound
        plant = scenario.plant
        limits = None if self._unicycle else (self.model.input_lower, self.model.input_upper)
        self.model_margin = model_margin(self.input_lower, self.input_upper,
                                         self.sample_time, settings.discretization, plant,
                                         limits)
        self._deviates = plant.model != settings.discretization or plant.noisy or not \
            self._unicycle
        self._own = np.zeros((self.indices.size, self.model.nx))
        self._noise_bound = plant.noise_bound
        #: the margin of the rows between two robots: solver tolerance + plant deviation
        self.pair_margin = settings.collision_margin + self.model_margin
        #: tolerance of the ``overlap-recovery`` rule (:mod:`sqpmpc.ocp.collision_rows`), m
        self.recovery_tolerance = max(settings.collision_margin, RECOVERY_TOLERANCE)
        self.obstacle_rows: ObstacleRows | None = None
        if scenario.obstacles:
            self.obstacle_rows = ObstacleRows(
                scenario.obstacles, scenario.diameters()[self.indices], self.horizon,
                self.sample_time, self.geometry,
                settings.collision_margin + 0.5 * self.model_margin,
                (float(self.input_lower[0]), float(self.input_upper[0])),
                self.recovery_tolerance)

    # ------------------------------------------------------------------ pipeline
    def run_sample(self, sample: int, t: float, states: np.ndarray,
                   plans: Mapping[int, object] | None = None,
                   previous_states: np.ndarray | None = None) -> ControlOutput:
        """One sample, steps 1-8 of the module docstring."""
        t0 = time.perf_counter()
        # 1. measure
        states = np.asarray(states, dtype=float)
        if states.shape not in ((self._n, 3), (self._n, 5)) or not all_finite(states.ravel()):
            raise ProblemError(f"states must be finite with shape ({self._n}, 3) (poses) or "
                               f"({self._n}, 5) (poses and measured v, omega), got "
                               f"{states.shape}")
        if states.shape[1] == 5:
            measured, states = states[self.indices], np.ascontiguousarray(states[:, :3])
        else:
            measured = states[self.indices]
        own = measured if self._unicycle else self.model.measured_states(measured,
                                                                         self._applied)
        self._own = own
        # 2. predict neighbours (and the obstacles)
        if self.obstacle_rows is not None:
            self.obstacle_rows.set_sample(t, own)
        self._predict_neighbours(sample, states, plans or {}, previous_states)
        # 3. rules shape the references
        raw = self.reference(t)
        view = SampleView(sample, t, np.ascontiguousarray(states[:, :2]),
                          own if self._unicycle else own[:, :3], raw, raw,
                          self._applied, self._applied_before,
                          np.ascontiguousarray(states[:, 2]))
        for rule in self._reference_rules:
            rule.shape_references(view)
        # 4. shift, then rules shape the linearization point
        engine = self.engine
        shifted = None
        if engine.has_solution:
            engine.shift()
            shifted = engine.inputs()
        engine.start_sample(own)
        if self._guess_rules:
            speeds = engine.guess_speeds()
            for rule in self._guess_rules:
                rule.shape_guess(view, speeds)
        # 5. linearize and solve
        budget = self.settings.time_budget
        deadline = None if budget is None else t0 + budget
        report = engine.solve(own, view.references, deadline=deadline, **self._rows)
        # 6. rules after the solve
        if report.success and self._after_rules:
            wants = [rule.after_solve(view) for rule in self._after_rules]
            if any(wants) and (deadline is None or time.perf_counter() <= deadline):
                report = self._converge(own, view.references, report, deadline)
        # 7. verify the first input, fall back if needed
        out = self._verify(own, report, shifted, t0)
        # 8. publish
        self._count(out)
        self._publish(sample, out)
        return out

    # ------------------------------------------------------------------- steps
    def _predict_neighbours(self, sample: int, states: np.ndarray,
                            plans: Mapping[int, object],
                            previous_states: np.ndarray | None) -> None:
        """Scheme-specific collision data of the sample (override)."""
        raise NotImplementedError

    def _safe(self, states: np.ndarray, next_states: np.ndarray, inputs: np.ndarray) -> bool:
        """Whether moving the own robots ``states -> next_states`` with the first
        ``inputs (m, 2)`` is safe (override)."""
        raise NotImplementedError

    def path_deviation(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r"""The plant's deviation from the predicted segments, :math:`(\alpha, \beta)` per own
        robot, for the first inputs ``(m, nu)`` of the model from this sample's states
        (:func:`sqpmpc.problem.plant.path_deviation`; zeros when the plant moves as predicted)."""
        if not self._deviates:
            zero = np.zeros(inputs.shape[0])
            return zero, zero
        if self._unicycle:
            return path_deviation(inputs, self.sample_time, self.settings.discretization,
                                  self.scenario.plant.model, self._noise_bound)
        return acceleration_path_deviation(
            self._own[:, 3:5], inputs, self.sample_time, self.settings.discretization,
            self.scenario.plant.model, self._noise_bound)

    def _obstacles_safe(self, states: np.ndarray, next_states: np.ndarray,
                        growth: np.ndarray, beta: np.ndarray | None = None) -> bool:
        """The own robots' paths keep their distances to the obstacles over the sample (a
        path strays ``growth s``, or with ``beta`` ``growth s + beta s (1 - s)``)."""
        if self.obstacle_rows is None:
            return True
        return self.obstacle_rows.first_input_safe(states[:, :2], next_states[:, :2], growth,
                                                   beta)

    def _publish(self, sample: int, out: ControlOutput) -> None:
        """Hand the sample's result to the scheme (override if there is something to send)."""

    def _converge(self, own: np.ndarray, references: np.ndarray, report: IterationReport,
                  deadline: float | None) -> IterationReport:
        """Iterate the sample to convergence (SQP) after the RTI step; reports merged."""
        self.counts["converged_samples"] += 1
        more = self.engine.solve(own, references, iteration_scheme="sqp", deadline=deadline,
                                 **self._rows)
        last = more if more.success else report  # a failed SQP keeps the RTI iterate
        return replace(
            last, success=True, iterations=report.iterations + more.iterations,
            assembly_time=report.assembly_time + more.assembly_time,
            qp_time=report.qp_time + more.qp_time,
            osqp_solve_time=report.osqp_solve_time + more.osqp_solve_time,
            total_time=report.total_time + more.total_time,
            qp_iterations=report.qp_iterations + more.qp_iterations,
        )

    def _verify(self, own: np.ndarray, report: IterationReport, shifted: np.ndarray | None,
                t0: float) -> ControlOutput:
        """Clip and verify the QP's first input; else the shifted plan, else brake."""
        engine, model, h = self.engine, self.model, self.sample_time
        if report.success:
            plan_u = engine.inputs()
            if self._clip_kernel is not None:  # clip, check and roll out in one kernel
                plan_x = np.empty((plan_u.shape[0], self.horizon + 1, model.nx))
                finite = self._clip_kernel(own, plan_u, model.input_lower, model.input_upper, h,
                                           plan_x)
            else:
                model.clip_first_input(own, plan_u, h)
                finite = all_finite(plan_u.ravel())
                plan_x = engine.rollout(own, plan_u) if finite else None
            # stage 1 of the rollout is exactly the next state of the first input
            if finite and self._safe(own, plan_x[:, 1], plan_u[:, 0]) and (
                    self._unicycle or self._brakes_safely(plan_x[:, 1])):
                if self._unicycle:
                    return ControlOutput(plan_u[:, 0].copy(), plan_x, plan_u, None, report,
                                         time.perf_counter() - t0)
                return self._output(plan_x, plan_u, None, report, t0)
        fallback, plan_u, plan_x = "brake", None, None
        if shifted is not None:
            candidate = np.clip(shifted, model.input_lower, model.input_upper)
            model.clip_first_input(own, candidate, h)
            if all_finite(candidate.ravel()):
                candidate_x = engine.rollout(own, candidate)
                if self._safe(own, candidate_x[:, 1], candidate[:, 0]) and \
                        self._brakes_safely(candidate_x[:, 1]):
                    fallback, plan_u, plan_x = "shifted-plan", candidate, candidate_x
        if plan_u is None:
            plan_u = model.braking_inputs(own, self.horizon, h)
            plan_x = engine.rollout(own, plan_u)
        engine.set_guess(own, plan_u, converge_first=False)
        return self._output(plan_x, plan_u, fallback, report, t0)

    def _output(self, plan_x: np.ndarray, plan_u: np.ndarray, fallback: str | None,
                report: IterationReport, t0: float) -> ControlOutput:
        """The sample's output: the model's commands, poses and velocity plan."""
        if self._unicycle:
            return ControlOutput(plan_u[:, 0].copy(), plan_x, plan_u, fallback, report,
                                 time.perf_counter() - t0)
        model = self.model
        return ControlOutput(model.commands(plan_x, plan_u), model.poses(plan_x),
                             np.ascontiguousarray(model.velocity_plan(plan_x, plan_u)),
                             fallback, report, time.perf_counter() - t0,
                             model_states=plan_x, model_inputs=plan_u)

    def _brakes_safely(self, next_states: np.ndarray) -> bool:
        """Whether braking from the next states ``(m, nx)`` keeps the distances (override;
        the paper's unicycle stops at once: always)."""
        return True

    def braking_path(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r"""The model's braking from ``states (m, nx)`` until every robot stands still:
        states ``(m, B+1, nx)`` and inputs ``(m, B, nu)``, :math:`B \ge 1` samples
        (:meth:`~sqpmpc.models.base.RobotModel.braking_inputs`; one sample for the paper's
        unicycle, :math:`\lceil \max |v| / (|a| T_s) \rceil` with acceleration limits)."""
        model, h = self.model, self.sample_time
        samples = 1
        if model.velocity_states:
            vel = np.abs(states[:, list(model.velocity_states)])
            slowest = np.minimum(-model.input_lower, model.input_upper)
            slowest = np.where(slowest > 0.0, slowest, np.inf)
            need = float((vel / slowest).max(initial=0.0)) / h
            samples = int(min(max(1, math.ceil(need - 1e-9)), 10_000))
        inputs = model.braking_inputs(states, samples, h)
        return self.engine.rollout(states, inputs), inputs

    def _count(self, out: ControlOutput) -> None:
        """Counters and the applied-input history (rules read both)."""
        c = self.counts
        c["samples"] += 1
        if out.fallback is not None:
            c["fallbacks"] += 1
            c["shifted_plan_fallbacks" if out.fallback == "shifted-plan"
              else "brake_fallbacks"] += 1
        c["qp_rescues"] = self.engine.qp.rescue_count
        if self.engine.qp.solver_name == "osqp+piqp":
            c["qp_handovers"] = self.engine.qp.handover_count
        for rows in self._rows.values():
            c["stage_one_overrides"] += rows.stage_one_overrides
        self._applied_before = self._applied
        self._applied = out.inputs
        out.counters = dict(c)

    def _in_position_bounds(self, positions: np.ndarray) -> bool:
        if not self._bounded:
            return True
        inside = (positions >= self._position_low) & (positions <= self._position_high)
        return np.count_nonzero(inside) == inside.size

    # ------------------------------------------------------------------ setters
    def update_reference(self, robot_id: int, reference: Reference) -> None:
        """Track ``reference`` for robot ``robot_id`` from the next step on.

        The controller then computes exactly what a controller constructed on
        a scenario with that reference would compute from the same internal
        state (warm start, rule state and counters are kept). The
        controller's :attr:`scenario` is replaced by the updated copy.

        Parameters
        ----------
        robot_id
            Id of a robot of the scenario. For a decentralized controller, an
            id other than its own changes only what its rules know of that
            neighbour (where its reference comes to rest).
        reference
            A :class:`~sqpmpc.problem.references.HarmonicReference`,
            :class:`~sqpmpc.problem.references.PointReference` or
            :class:`~sqpmpc.problem.references.WaypointReference` (validated when it
            was constructed).

        Raises
        ------
        ProblemError
            Unknown robot id, or ``reference`` is not a reference; the message
            names the robot.
        """
        if isinstance(robot_id, bool) or not isinstance(robot_id, numbers.Integral):
            raise ProblemError(f"update_reference: robot_id must be an integer robot id, got "
                               f"{robot_id!r}")
        if not isinstance(reference, Reference):
            raise ProblemError(f"update_reference: robot {int(robot_id)}: expected a "
                               "HarmonicReference, PointReference or WaypointReference, got "
                               f"{type(reference).__name__} {reference!r:.60}")
        try:
            index = self.scenario.index_of(int(robot_id))
        except ProblemError as exc:
            raise ProblemError(f"update_reference: {exc}") from None
        robots = list(self.scenario.robots)
        robots[index] = dataclasses.replace(robots[index], reference=reference)
        self.scenario = self.scenario.with_changes(robots=tuple(robots))
        self.context.scenario = self.scenario
        self._references = ReferenceSet([self.scenario.robots[i].reference
                                         for i in self.indices])
        for rule in self.rules:
            rule.references_changed()

    # ------------------------------------------------------------------ queries
    def reference(self, t: float) -> np.ndarray:
        """The scenario's reference positions ``(m, N, 2)`` of stages 1..N at time ``t``."""
        return self._references.positions(t + self._stage_offsets)

    def counters(self) -> dict[str, int]:
        """Cumulative counts of the engine and the rules so far."""
        return dict(self.counts)

    def rule(self, name: str) -> RuleInstance | None:
        """The bound rule ``name``, if it is on."""
        return next((r for r in self.rules if r.rule.name == name), None)

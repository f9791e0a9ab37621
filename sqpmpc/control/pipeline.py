r"""The per-sample pipeline both schemes run (paper Algorithms 3.1 and 3.2).

Every sample of every controller is :meth:`ControllerPipeline.run_sample`,
one function that reads top to bottom:

1. **measure**: validate the measured states of all robots;
2. **predict neighbours**: the scheme's collision data (centralized: the
   current positions; decentralized: the neighbours' exchanged plans, or the
   paper's fallback prediction when a plan is missing);
3. **shift**: the previous solution moved one stage (kept as the fallback
   plan), the measured state put in stage 0;
4. **rules shape**: the scenario's references of stages 1..N, then every
   rule's ``"references"`` hook (detour targets, parking weights), then every
   rule's ``"guess"`` hook on the linearization point (stall repair, parking);
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

Rules see the sample through a read-only :class:`~sqpmpc.rules.base.SampleView`
and return a :class:`~sqpmpc.rules.base.Contribution`, which the pipeline
applies through the engine's update methods (:meth:`ControllerPipeline.apply`).
The scheme-specific parts are three public methods of the controllers in
:mod:`sqpmpc.control.centralized` and :mod:`sqpmpc.control.decentralized`:
:meth:`ControllerPipeline.predict_neighbours`,
:meth:`ControllerPipeline.first_input_safe` and :meth:`ControllerPipeline.publish`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import time
from collections.abc import Iterable, Mapping
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from sqpmpc.control.output import ControlOutput, braking_input
from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.kernels.ocp import all_finite, measure_sample, within_box
from sqpmpc.kernels.warmup import warm_up
from sqpmpc.models.base import RobotModel, continuous_headings
from sqpmpc.ocp.geometry import RowGeometry
from sqpmpc.ocp.iteration import MultipleShootingSQP, engaged_robots
from sqpmpc.ocp.obstacle_rows import ObstacleRows, scenario_map_slots
from sqpmpc.ocp.polygon_rows import MapRows, PolygonRows
from sqpmpc.ocp.report import CollisionRows, IterationReport
from sqpmpc.problem.margins import RowMargins
from sqpmpc.problem.plant import acceleration_path_deviation, path_deviation
from sqpmpc.problem.references import Reference, ReferenceSet
from sqpmpc.problem.scenario import Scenario
from sqpmpc.qp.layout import QPLayout
from sqpmpc.rules.base import Contribution, RuleContext, RuleInstance, SampleView, read_only

if TYPE_CHECKING:
    from sqpmpc.control.plans import PlanAges

__all__ = ["RECOVERY_TOLERANCE", "ControlOutput", "ControllerPipeline", "braking_input",
           "kernel_warm_up_seconds"]

#: A plant that lags: the shares of a refused first input's change from the last command
#: tried before the fallbacks (:meth:`ControllerPipeline.verify`).
EASED_SHARES = (0.5, 0.25)
#: Smallest tolerance of the ``overlap-recovery`` rule, m (the solver's accuracy).
RECOVERY_TOLERANCE = 1e-4

@functools.cache
def kernel_warm_up_seconds() -> float:
    """Seconds this process spent compiling or loading the kernels (once per process)."""
    return warm_up()


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
        self.scenario, self.settings = scenario, settings
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
        plant = scenario.plant
        limits = None if self._unicycle else (self.model.input_lower, self.model.input_upper)
        self.margins = RowMargins(self.input_lower, self.input_upper, self.sample_time,
                                  settings.discretization, plant, limits)
        self.model_margin = self.margins.model_margin
        obstacle_margin = settings.collision_margin + 0.5 * self.model_margin  # walls, pillars
        # the rules measure "near" beyond RowMargins.rules (problem.margins)
        kept = self.model_margin if limits is None else self.margins.kept  # between two at rest
        self.context = RuleContext(scenario, self.indices, self.scheme, settings.iteration_scheme,
                                   self.counts, self.margins.rules, 0.5 * self.model_margin,
                                   settings.collision_margin + kept, obstacle_margin)
        self.rules = [rule.bind(self.context) for rule in settings.rules]
        geometry = RowGeometry.plain(self.horizon)
        for rule in self.rules_with("rows"):
            geometry = rule.configure_rows(geometry)
        #: the collision-row geometry the rules configured (read by the scheme's rows)
        self.geometry = geometry
        self._bind_hooks()  # the per-sample hook lists
        self._engaged = lambda: engaged_robots(self.engine.layout, self.engine.y)  # held robots
        self._references = ReferenceSet([scenario.robots[i].reference for i in self.indices])
        self._stage_offsets = self.sample_time * np.arange(1, self.horizon + 1)
        m = self.indices.size
        self._applied = read_only(np.zeros((m, 2)))  # the rules read both (read-only)
        self._applied_before = self._applied
        n = self._n = scenario.n_robots
        self._shapes = ((n, 3), (n, 5))  # of the measured states
        #: the own robots' headings of the last sample, unwrapped (once known)
        self._headings, self._known = np.zeros(m), False
        self._view_buffers = (np.zeros((n, 2)), np.zeros(n), np.zeros((m, 3)))  # measured:
        self._views = tuple(map(read_only, self._view_buffers))  # positions, headings, poses
        self._rows: dict[str, CollisionRows] = {}  # the scheme's collision models
        # a plant unlike the prediction: the margin of the rows and the check's path bound
        self._deviates = plant.model != settings.discretization or plant.noisy or not \
            self._unicycle or plant.response is not None
        #: a plant that lags (``[plant] response``): the checks' bound takes the change from
        #: the command of the sample before and the coast of a brake after the sample
        self._response = plant if plant.response is not None else None
        if self._response is not None:
            self.counts["eased_inputs"] = 0
        self._own = np.zeros((self.indices.size, self.model.nx))
        self._noise_bound = plant.noise_bound
        #: the margin of the rows between two robots: solver tolerance + plant deviation
        self.pair_margin = settings.collision_margin + self.model_margin
        #: tolerance of the ``overlap-recovery`` rule (:mod:`sqpmpc.ocp.collision_rows`), m
        self.recovery_tolerance = max(settings.collision_margin, RECOVERY_TOLERANCE)
        self.obstacle_rows: ObstacleRows | MapRows | None = None
        slots, speed = scenario_map_slots(scenario), self.context.max_speed  # rows by reach
        if scenario.obstacles:
            self.obstacle_rows = ObstacleRows(
                scenario.obstacles, scenario.diameters()[self.indices], self.horizon,
                self.sample_time, self.geometry, obstacle_margin,
                (float(self.input_lower[0]), float(self.input_upper[0])),
                self.recovery_tolerance, slots[0], speed)
        if scenario.polygons:  # circles first, then every polygon's convex pieces
            self.obstacle_rows = MapRows(self.obstacle_rows, PolygonRows(
                scenario.polygons, scenario.diameters()[self.indices], self.horizon,
                self.geometry, obstacle_margin, slots[1], speed * self.sample_time))

    # ------------------------------------------------------------------ pipeline
    def run_sample(self, sample: int, t: float, states: np.ndarray,
                   plans: Mapping[int, object] | None = None,
                   previous_states: np.ndarray | None = None,
                   plan_ages: PlanAges | None = None) -> ControlOutput:
        """One sample, steps 1-8 of the module docstring.

        ``plans``, ``previous_states`` and ``plan_ages`` are the neighbours'
        data of the sample (:meth:`predict_neighbours`).
        """
        t0 = time.perf_counter()
        # 1. measure
        states = np.asarray(states, dtype=float)
        # finite; the headings kept (odometry wraps the yaw: models.base); the view's arrays
        checked = -1 if (shape := states.shape) not in self._shapes else measure_sample(
            states, self.indices, measured := np.empty((self.indices.size, shape[1])),
            self._headings, self._known, *self._view_buffers)
        if checked < 0:
            raise ProblemError(f"states must be finite with shape ({self._n}, 3) (poses) or "
                               f"({self._n}, 5) (poses and measured v, omega), got {shape}")
        if checked:  # rarely: a wrapped yaw
            measured[:, 2] = continuous_headings(measured[:, 2], self._headings)
            self._headings[:] = self._view_buffers[2][:, 2] = measured[:, 2]
        self._known = True
        if shape[1] == 5:
            states = np.ascontiguousarray(states[:, :3])
        own = measured if self._unicycle else self.model.measured_states(measured,
                                                                         self._applied)
        self._own = own
        # 2. predict neighbours (and the obstacles)
        if self.obstacle_rows is not None:
            self.obstacle_rows.set_sample(t, own)
        self.predict_neighbours(sample, states, plans or {}, previous_states, plan_ages)
        # 3. shift the previous solution (kept as the fallback plan), x0 in stage 0
        engine = self.engine
        # the shifted inputs kept (the fallback plan); a rule's motions hold for their
        # sample only
        shifted = engine.begin_sample(own)
        # 4. rules shape the references, then the linearization point; their view's arrays:
        # the references made read-only, read-only views of the others (for this sample)
        raw = self.reference(t)
        raw.setflags(write=False)
        view = SampleView.of_sample(
            sample, t, self._views[0], self._views[2], raw, self._applied,
            self._applied_before, self._views[1],
            engine.guess_speeds() if self._guess_rules else None)
        for rule in self._reference_rules:
            contribution = rule.shape_references(view)
            if contribution is not None:
                view = self.apply(contribution, view)
        for rule in self._guess_rules:
            contribution = rule.shape_guess(view)
            if contribution is not None:
                view = self.apply(contribution, view)
        # 5. linearize and solve
        budget = self.settings.time_budget
        deadline = None if budget is None else t0 + budget
        report = engine.solve(own, view.references, deadline=deadline, started=True,
                              **self._rows)
        # 6. rules after the solve
        if report.success and self._after_rules:
            view = view.solved(engine.first_speeds(), self._engaged)
            iterate = False
            for rule in self._after_rules:  # every rule sees the solution
                contribution = rule.after_solve(view)
                iterate = iterate or (contribution is not None and contribution.iterate)
            if iterate and (deadline is None or time.perf_counter() <= deadline):
                report = self.converge(own, view.references, report, deadline)
        # 7. verify the first input, fall back if needed
        out = self.verify(own, report, shifted, t0)
        # 8. publish
        self.count(out)
        self.publish(sample, out)
        return out

    def apply(self, contribution: Contribution | None, view: SampleView) -> SampleView:
        """Apply a rule's contribution through the engine's update methods; returns the
        view the next rule sees."""
        if contribution is None:
            return view
        c = contribution
        if c.position_weight_scale is not None:
            self.engine.update_position_weight_scale(c.position_weight_scale)
        if c.guess_speeds is not None:  # view.guess_speeds views the iterate: it shows them
            self.engine.update_guess_speeds(c.guess_speeds)
        if c.motions is not None:
            rows, poses, velocities = c.motions
            self.engine.update_motion(rows, *self.model.motion_states(poses, velocities,
                                                                       self.sample_time))
        if c.references is not None:
            view = view.but(references=c.references)
        return view

    def rules_with(self, hook: str) -> list[RuleInstance]:
        """The bound rules that declare ``hook`` (:data:`sqpmpc.rules.base.HOOKS`), in order."""
        return [r for r in self.rules if hook in r.hooks]

    def _bind_hooks(self) -> None:
        """The per-sample hook lists: the rules that declare them, less the idle ones
        (:attr:`~sqpmpc.rules.base.RuleInstance.idle`: nothing to do until the references
        change)."""
        self._reference_rules: list[RuleInstance] = [
            r for r in self.rules_with("references") if not r.idle]
        self._guess_rules = [r for r in self.rules_with("guess") if not r.idle]
        self._after_rules = [r for r in self.rules_with("after_solve") if not r.idle]

    # ------------------------------------------------------------------- steps
    def predict_neighbours(self, sample: int, states: np.ndarray,
                           plans: Mapping[int, object],
                           previous_states: np.ndarray | None,
                           plan_ages: PlanAges | None = None) -> None:
        """Step 2, scheme-specific: the collision data of the sample from the measured
        ``states (n, 3)``, the neighbours' ``plans`` by id, the states of ``k - 1`` and
        the relayed ``plan_ages`` (decentralized)."""
        raise NotImplementedError

    def first_input_safe(self, states: np.ndarray, next_states: np.ndarray,
                         inputs: np.ndarray) -> bool:
        """Step 7, scheme-specific: whether moving the own robots ``states ->
        next_states`` with the first ``inputs (m, 2)`` is safe over the whole sample."""
        raise NotImplementedError

    def path_deviation(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r"""The plant's deviation from the predicted segments, :math:`(\alpha, \beta)` per own
        robot, for the first inputs ``(m, nu)`` of the model from this sample's states
        (:func:`sqpmpc.problem.plant.path_deviation`; zeros when the plant moves as predicted;
        a plant that lags: from the commands of the sample before, and with the coast of the
        brake that may follow, so that the unchecked brake fallback stays safe)."""
        if not self._deviates:
            zero = np.zeros(inputs.shape[0])
            return zero, zero
        if self._unicycle:
            return path_deviation(inputs, self.sample_time, self.settings.discretization,
                                  self.scenario.plant.model, self._noise_bound, self._response,
                                  self._applied)
        return acceleration_path_deviation(
            self._own[:, 3:5], inputs, self.sample_time, self.settings.discretization,
            self.scenario.plant.model, self._noise_bound)

    def obstacles_safe(self, states: np.ndarray, next_states: np.ndarray,
                       growth: np.ndarray, beta: np.ndarray | None = None) -> bool:
        """The own robots' paths keep their distances to the obstacles over the sample (a
        path strays ``growth s``, or with ``beta`` ``growth s + beta s (1 - s)``)."""
        if self.obstacle_rows is None:
            return True
        return self.obstacle_rows.first_input_safe(states[:, :2], next_states[:, :2], growth,
                                                   beta)

    def publish(self, sample: int, out: ControlOutput) -> None:
        """Step 8: hand the sample's result to the scheme (override if there is something
        to send)."""

    def converge(self, own: np.ndarray, references: np.ndarray, report: IterationReport,
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

    def verify(self, own: np.ndarray, report: IterationReport, shifted: np.ndarray | None,
                t0: float) -> ControlOutput:
        """Step 7: clip and verify the QP's first input; else the shifted plan, else brake."""
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
            first = plan_u[:, 0]
            if finite and self.first_input_safe(own, plan_x[:, 1], first) and (
                    self._unicycle or self._brakes_safely(plan_x[:, 1])):
                if self._unicycle:
                    return ControlOutput(first.copy(), plan_x, plan_u, None, report,
                                         time.perf_counter() - t0)
                return self._output(plan_x, plan_u, None, report, t0)
            if finite and self._response is not None:
                eased = self._eased(own, plan_u)
                if eased is not None:
                    plan_u, plan_x = eased
                    return ControlOutput(plan_u[:, 0].copy(), plan_x, plan_u, None, report,
                                         time.perf_counter() - t0)
        fallback, plan_u, plan_x = "brake", None, None
        if shifted is not None:
            candidate = np.clip(shifted, model.input_lower, model.input_upper)
            model.clip_first_input(own, candidate, h)
            if all_finite(candidate.ravel()):
                candidate_x = engine.rollout(own, candidate)
                if self.first_input_safe(own, candidate_x[:, 1], candidate[:, 0]) and \
                        self._brakes_safely(candidate_x[:, 1]):
                    fallback, plan_u, plan_x = "shifted-plan", candidate, candidate_x
        if plan_u is None:
            plan_u = model.braking_inputs(own, self.horizon, h)
            plan_x = engine.rollout(own, plan_u)
        engine.set_guess(own, plan_u, converge_first=False)
        return self._output(plan_x, plan_u, fallback, report, t0)

    def _eased(self, own: np.ndarray, plan_u: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray] | None:
        """A plant that lags: the QP's first input refused, the same change from the last
        command at half and a quarter of its size (the lag's bound shrinks with the square of
        it; the QP's rows cannot see it), the plan's rest kept; checked alike. ``None``: none
        passes."""
        previous = np.asarray(self._applied)
        for share in EASED_SHARES:
            candidate = plan_u.copy()
            candidate[:, 0] = previous + share * (plan_u[:, 0] - previous)
            candidate_x = self.engine.rollout(own, candidate)
            if self.first_input_safe(own, candidate_x[:, 1], candidate[:, 0]):
                self.counts["eased_inputs"] += 1
                return candidate, candidate_x
        return None

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

    def count(self, out: ControlOutput) -> None:
        """Step 8: counters and the applied-input history (rules read both)."""
        c = self.counts
        c["samples"] += 1
        if out.fallback is not None:
            c["fallbacks"] += 1
            c["shifted_plan_fallbacks" if out.fallback == "shifted-plan"
              else "brake_fallbacks"] += 1
        qp = self.engine.qp
        c["qp_rescues"] = qp.rescue_count
        if qp.solver_name == "osqp+piqp":
            c["qp_handovers"] = qp.handover_count
        for rows in self._rows.values():
            c["stage_one_overrides"] += rows.stage_one_overrides
        self._applied_before = self._applied
        self._applied = read_only(out.inputs)  # the rules' view of it
        out.counters = dict(c)

    def in_position_bounds(self, positions: np.ndarray) -> bool:
        if not self._bounded:
            return True
        return within_box(positions, self._position_low, self._position_high)

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
        self._bind_hooks()

    def update_departed(self, robot_ids: Iterable[int]) -> None:
        """The robots whose controllers left the run for good, from the next step on
        (all of them: an id not given is taking part again).

        Every controller of a run must be told the same set at the same sample (a
        plant's states message carries it), since rules may plan the fleet anew from
        it (:mod:`sqpmpc.rules.coordination`: a departed robot then stands where it is
        and the others are planned around it). Its plant brakes a departed robot from
        that sample on, so the decentralized rows keep no plan-age margin from it and,
        from the next sample, only the reach it showed over the sample before (0 once it
        stands: :meth:`~sqpmpc.control.decentralized.DecentralizedController.predict_neighbours`);
        otherwise it is kept apart from as any robot is.

        Raises
        ------
        ProblemError
            An id that is not an integer robot id of the scenario, or one of this
            controller's own robots (the message names it).
        """
        indices = set()
        for robot_id in robot_ids:
            if isinstance(robot_id, bool) or not isinstance(robot_id, numbers.Integral):
                raise ProblemError(f"update_departed: robot ids must be integers, got "
                                   f"{robot_id!r}")
            try:
                index = self.scenario.index_of(int(robot_id))
            except ProblemError as exc:
                raise ProblemError(f"update_departed: {exc}") from None
            if index in self.indices:
                raise ProblemError(f"update_departed: robot {int(robot_id)} is driven by "
                                   "this controller; it cannot have left")
            indices.add(index)
        departed = frozenset(indices)
        if departed == self.context.departed:
            return
        self.context.departed = departed
        for rule in self.rules:
            rule.departed_changed()
        self._bind_hooks()

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

r"""The decentralized NMPC controller (paper Algorithm 3.2): one QP per robot.

Both run the per-sample pipeline of :mod:`sqpmpc.control.pipeline` (measure,
predict neighbours, rules, shift, linearize, solve, verify, publish); this
module holds what differs between the schemes: the QP layout, the collision
model, how neighbours are predicted and how a first input is verified.

The decentralized controller owns one robot. Its neighbours' predicted
horizons arrive as :class:`PlanMessage`. In the default ``"shared"`` mode each
pair uses one hyperplane built by both robots from the same two exchanged
predictions, each keeping half the distance. In ``"paper"`` mode each robot
treats the others' predictions as fixed obstacles (the seed paper's literal
scheme, no guarantee). A neighbour whose plan is missing or stale is
predicted as in the paper's section 3.2: its last input is estimated from its
current and previous states and held over the horizon; it is then kept at the
full distance as an obstacle.

How plans, their ages and the pair's common sample work is explained in
:mod:`sqpmpc.control.plans`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from types import MappingProxyType
from typing import Literal

import numpy as np

from sqpmpc.control.centralized import has_position_bounds
from sqpmpc.control.neighbours import NeighbourSelector, NeighbourSlots
from sqpmpc.control.pipeline import ControllerPipeline, ControlOutput, braking_input
from sqpmpc.control.plans import (
    PlanAges,
    PlanBook,
    PlanMessage,
    PlanSource,
    fill_from_plan,
    pair_sample,
    predict_from_plan,
    predict_from_states,
)
from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.kernels.collision import halfplanes_hold_path
from sqpmpc.ocp.collision_rows import MISSING, OBSTACLE, OFF, SHARED, ExternalCollisionModel
from sqpmpc.ocp.obstacle_rows import StackedRows, scenario_map_slots
from sqpmpc.problem.plant import acceleration_path_deviation, largest_deviation
from sqpmpc.problem.scenario import Scenario
from sqpmpc.qp.layout import QPLayout
from sqpmpc.rules.registry import default_rules

__all__ = [
    "ControlOutput", "DecentralizedController", "NeighbourSlots", "PlanAges", "PlanMessage",
    "PlanSource", "braking_input", "pair_sample", "predict_from_plan", "predict_from_states",
]

DecentralizedMode = Literal["shared", "paper"]
"""``"shared"`` (shared-responsibility rows, default) or ``"paper"`` (the seed paper's scheme)."""

log = logging.getLogger(__name__)
paper_mode_warned = False
"""Whether this process logged the warning of ``"paper"`` mode (logged once)."""


class DecentralizedController(ControllerPipeline):
    """One robot's controller with its own QP (paper Algorithm 3.2).

    Parameters
    ----------
    scenario
        The problem (all robots: ids, diameters, references).
    robot_id
        The robot this controller drives.
    settings
        Solver settings (default: :class:`SolverSettings` with every rule).
    mode
        ``"shared"`` (default, shared-responsibility hyperplanes) or ``"paper"``.

    Attributes
    ----------
    selector
        The neighbour selection (:class:`~sqpmpc.control.neighbours.NeighbourSelector`),
        which the services use for the plans they wait for and send.
    selecting
        Whether the slots are chosen per sample (``neighbour_slots`` set).
    slot_data
        What the slots hold at the current sample
        (:class:`~sqpmpc.control.neighbours.NeighbourSlots`).
    own_prediction
        ``(N, 3)`` this robot's stages 1..N from its published plan (or the fallback).
    plan_ages
        The report of the last step (also :attr:`ControlOutput.plan_ages`): per
        neighbour (slotted then) whose newest plan held then was ``age >= 2``
        samples old, ``age`` (at most ``N + 2``); the services send it with
        the input and the plant relays it to every robot with the next states.
    published
        The plan of the last step (``None`` before the first).
    """

    scheme = "decentralized"

    def __init__(self, scenario: Scenario, robot_id: int,
                 settings: SolverSettings | None = None,
                 mode: DecentralizedMode = "shared") -> None:
        settings = (settings or SolverSettings(rules=default_rules(scenario))).resolved(
            scenario.n_robots)
        if mode not in ("shared", "paper"):
            raise ProblemError(f"decentralized mode must be 'shared' or 'paper', got {mode!r}")
        index = scenario.index_of(robot_id)
        others = scenario.n_robots - 1
        slots = others if settings.neighbour_slots is None else min(
            others, settings.neighbour_slots)
        layout = QPLayout(1, scenario.horizon, np.zeros((0, 2), dtype=np.int64),
                          slots + sum(scenario_map_slots(scenario)), has_position_bounds(scenario),
                          scenario.robot_model())
        super().__init__(scenario, np.array([index]), layout, settings)
        self.robot_id = int(robot_id)
        self.index = index
        self.mode = mode
        self.slots = slots
        self.selector = NeighbourSelector(scenario, index, slots, self.pair_margin,
                                          self.context.max_speed)
        self.selecting = settings.neighbour_slots is not None
        self.required = scenario.required_distances()[index, self.selector.others]
        N = scenario.horizon
        self.collisions = ExternalCollisionModel(
            self.required[:slots], N, self.geometry,
            reach=scenario.sample_time * self.context.max_speed, margin=self.pair_margin,
            stage_one_rule_for_obstacles=mode == "shared", recovery=self.recovery_tolerance,
            deviation=self.margins.deviation, shared_margin=settings.collision_margin)
        self._rows = {"external": self.collisions if self.obstacle_rows is None
                      else StackedRows(self.collisions, self.obstacle_rows, slots, N)}
        for name in ("fallback_neighbours", "unslotted_neighbours", "late_plan_neighbours",
                     "older_shared_neighbours"):
            self.counts[name] = 0
        self.slot_data = NeighbourSlots.empty(self.selector.others, self.selector.other_ids,
                                              slots, N)
        self.own_prediction = np.zeros((N, 3))
        self._timing = (N, scenario.sample_time, settings.discretization)  # of the plans
        self.book = PlanBook(N)
        self._aged = False  # some age margin positive (track_plan_ages)
        self._reach = self.context.max_speed * scenario.sample_time  # a plan age's margin
        self._braked: dict[int, int] = {}  # departed robots: the sample they were first seen
        self.plan_ages: dict[int, int] = {}
        self.published: PlanMessage | None = None
        self._received: dict[int, PlanMessage] = {}
        if mode == "paper":
            _warn_paper_mode()

    @property
    def others(self) -> np.ndarray:
        """Scenario indices of the other robots (scenario order)."""
        return self.selector.others

    @property
    def other_ids(self) -> np.ndarray:
        """Ids of the other robots (scenario order)."""
        return self.selector.other_ids

    @property
    def interaction_radius(self) -> np.ndarray:
        """``(n - 1,)`` distance beyond which a neighbour gets no row (``required +
        pair_margin + 2 v_max N Ts``)."""
        return self.selector.interaction_radius

    def first_input_safe(self, states: np.ndarray, next_state: np.ndarray,
                         inputs: np.ndarray) -> bool:
        if not self._deviates:  # the paper's unicycle, moving as predicted: no deviation
            return (self.collisions.first_stage_safe(next_state[0, :2])
                    and (self.obstacle_rows is None
                         or self.obstacles_safe(states, next_state, np.zeros(inputs.shape[0])))
                    and (not self._bounded or self.in_position_bounds(next_state[:, :2])))
        alpha, beta = self.path_deviation(inputs)
        if not self.collisions.first_stage_safe(next_state[0, :2], alpha=float(alpha[0]),
                                                beta=float(beta[0])):
            return False
        if not self._unicycle or self._response is not None:  # the bound itself
            return (self.obstacles_safe(states, next_state, alpha, beta)
                    and self.in_position_bounds(next_state[:, :2]))
        growth = alpha + np.maximum(beta, 0.0) if self._deviates else alpha  # as predicted: 0
        return (self.obstacles_safe(states, next_state, growth)
                and self.in_position_bounds(next_state[:, :2]))

    def _brakes_safely(self, next_states: np.ndarray) -> bool:
        """With acceleration limits: braking right after the first input keeps this robot
        clear of the obstacles as they move on and on
        its side of every shared hyperplane of this sample (stage ``1 + j`` of the braking
        against the row of stage ``1 + j``, the last row beyond the horizon) and its true
        distance from the predicted stages of the neighbours held as obstacles or missing.

        The neighbour of a shared pair checks the same hyperplanes from the other side, so
        if both fall back to braking at the next sample they stay apart: each braking
        position keeps half the true distance plus its deviation from the predicted
        segments (:func:`~sqpmpc.problem.plant.acceleration_path_deviation`) from the
        hyperplane (the rows themselves keep half of :attr:`pair_margin` more).
        """
        if not self.model.velocity_states:
            return True
        path, inputs = self.braking_path(next_states)
        c = self.collisions
        pos = path[0, 1:, :2]                                   # stages 2..B+1
        rows = np.minimum(np.arange(1, pos.shape[0] + 1), self.horizon - 1)
        alpha, beta = acceleration_path_deviation(
            path[0, :-1, 3:5], inputs[0], self.sample_time, self.settings.discretization,
            self.scenario.plant.model, self._noise_bound)
        if self.obstacle_rows is not None and not self.obstacle_rows.braking_safe(
                path[..., :2], alpha[None], beta[None]):
            return False
        growth = largest_deviation(alpha, beta)                 # (B,)
        shared = c.kind == SHARED
        inside = c.inside()
        shared &= ~inside
        if shared.any():
            # each robot keeps half the true distance plus its own deviation: the rows' half
            # margin less the braking path's growth may be used
            slack = c.own_margin[shared][:, None] - growth[None]
            normals = c.fixed_normals[shared][:, rows]          # (S, B, 2)
            held = np.einsum("sbk,bk->sb", normals, pos) - c.fixed_rhs[shared][:, rows]
            if (held < -slack - 1e-9).any():
                return False
            # and the true-distance line the neighbour keeps from the other side (a stage-1
            # row overridden in the margin band only holds "no closer than now")
            lines, xy = np.ascontiguousarray(c.check_normals[shared]), path[0, :, :2]
            if not all(halfplanes_hold_path(lines, c.check_rhs[shared], *xy[b], *xy[b + 1],
                                            alpha[b], beta[b], 1e-12) for b in range(len(pos))):
                return False
        if inside.any():
            # overlap-recovery: a pair already inside its distance cannot keep it; braking
            # must not take this robot across the current mid-line's check line
            held = pos @ c.check_normals[inside].T - c.check_rhs[inside]
            if (held < -self.recovery_tolerance).any():
                return False
        avoid = (c.kind == OBSTACLE) | (c.kind == MISSING)
        if avoid.any():
            gap = np.linalg.norm(c.obstacles[avoid][:, rows, :2] - pos[None], axis=-1)
            if (gap < c.safe_distance[avoid][:, None]).any():
                return False
        return True

    def _own_at(self, pair: int, sample: int, cache: dict[int, np.ndarray | None]
                ) -> np.ndarray | None:
        """Own stages 1..N at ``sample`` from the own plan of sample ``pair`` (``None``: not
        held, or published twice)."""
        if pair not in cache:
            plan = self.book.own_plan(pair, self.published)
            if plan is None:
                cache[pair] = None
            elif plan is self.published and sample - pair <= self.horizon:
                cache[pair] = self.own_prediction  # filled from it by the own prediction
            else:
                out = np.empty((self.horizon, 3))
                cache[pair] = out if fill_from_plan(out, plan, sample, *self._timing) else None
        return cache[pair]

    # ------------------------------------------------------- predict neighbours
    def predict_neighbours(self, sample: int, states: np.ndarray, plans: Mapping[int, object],
                           previous_states: np.ndarray | None,
                           plan_ages: PlanAges | None = None) -> None:
        """Own published prediction and the neighbours', stages 1..N, with the slot kinds.

        Five named steps: :meth:`select_neighbours` (with neighbour slots),
        :meth:`predict_own`, :meth:`track_plan_ages` (then, with departed neighbours,
        their braked margins and reach), :meth:`classify` (shared, obstacle or missing,
        the fallback prediction for a missing one), then the collision rows are given
        the sample. A departed neighbour, braked by its plant, keeps no plan-age margin
        and, once braked over a sample, only the reach it showed over it (0 standing).

        A shared hyperplane of the pair with neighbour ``l`` is built from both
        robots' plans of the sample :func:`pair_sample` gives (``k - 1``
        unless plans have been late), which both compute from the same relayed
        ``plan_ages`` (the reports of every robot's step ``k - 1``); a robot
        that does not hold both plans of that sample predicts the neighbour by
        the paper's fallback (input estimated from two states, or its newest
        late plan) and its slot is *missing*.
        """
        if self.selecting:
            self.select_neighbours(states)
        self.predict_own(sample, states)
        self.plan_ages = self.track_plan_ages(sample, plans)
        if self.context.departed or self._braked:
            self._braked_neighbours(sample, states, previous_states)
        self.classify(sample, states, plans, previous_states, plan_ages)
        d = self.slot_data
        self.collisions.set_age_margins(d.age_margins, self._aged)
        self.collisions.set_sample(states[self.index, :2], states[:, :2].take(d.index, axis=0),
                                   d.own_predictions, d.predictions, d.kinds)

    def select_neighbours(self, states: np.ndarray) -> None:
        """Fill the slots with the nearest neighbours within the interaction radius.

        A neighbour farther than its required distance plus margin plus
        ``2 v_max N Ts`` cannot come within that distance over the horizon
        (each robot moves at most ``v_max N Ts``), so it gets no row. The
        nearest of the others get the slots (free slots are off); those within
        the radius left without a slot are handed to the first-input check,
        which keeps their distance plus their one-sample reach, or stands still.
        """
        selection = self.selector.select(states)
        chosen, rest = selection.slotted, selection.unslotted
        used, others, d = chosen.size, self.selector.others, self.slot_data
        d.index[:used] = others[chosen]
        d.index[used:] = self.index  # free slots: off (their position is unused)
        d.neighbours = list(zip(range(used), self.selector.other_ids[chosen].tolist(),
                                strict=True))
        d.kinds[used:] = OFF
        required = np.zeros(self.slots)
        required[:used] = self.required[chosen]
        self.collisions.set_required(required)
        self.collisions.set_unslotted(states[others[rest], :2], self.required[rest])
        self.counts["unslotted_neighbours"] += int(rest.size)

    def predict_own(self, sample: int, states: np.ndarray) -> None:
        """:attr:`own_prediction` from the published plan, or the paper's fallback."""
        if self.published is None or not fill_from_plan(self.own_prediction, self.published,
                                                        sample, *self._timing):
            self.own_prediction[:] = predict_from_states(
                states[self.index], None, self.horizon, self.sample_time,
                self.settings.discretization)[1:]

    def track_plan_ages(self, sample: int, plans: Mapping[int, object]) -> dict[int, int]:
        r"""Keep the slotted neighbours' plans, their ages' margins; returns the ages to report.

        A neighbour whose newest plan seen is ``a >= 2`` samples old has
        re-planned ``a - 1`` times unseen: its rows keep ``v_max Ts min(a - 1, N)``
        more (:attr:`NeighbourSlots.age_margins`). Its age is reported once it
        has been late :data:`LATE_STEPS` steps in a row (:class:`PlanBook.age`).
        A departed neighbour keeps none (:meth:`_braked_neighbours`).
        """
        d = self.slot_data
        report, self._aged, late = self.book.track(d.neighbours, plans, sample, d.age_margins,
                                                   self._reach)
        if late:
            self.counts["late_plan_neighbours"] += late
        return report

    def classify(self, sample: int, states: np.ndarray, plans: Mapping[int, object],
                 previous_states: np.ndarray | None, plan_ages: PlanAges | None) -> None:
        """Each slot's kind and prediction: shared (both plans of the pair's sample held),
        obstacle (``"paper"`` mode) or missing (the fallback prediction)."""
        shared = self.mode == "shared"
        d = self.slot_data
        own_cache: dict[int, np.ndarray | None] = {}
        missing: list[int] = []  # the slots predicted by the fallback, and their plans
        late: list[PlanMessage | None] = []
        for e, jid in d.neighbours:
            plan = plans.get(jid)
            if shared:
                pair = pair_sample(sample, self.robot_id, jid, plan_ages) if plan_ages else (
                    sample - 1)
                mine = own_cache[pair] if pair in own_cache else self._own_at(pair, sample,
                                                                              own_cache)
                theirs = None if mine is None else plan if (
                    plan is not None and plan.sample == pair) else self.book.neighbour_plan(
                        plans, jid, pair, plan)
                if theirs is not None and fill_from_plan(d.predictions[e], theirs, sample,
                                                         *self._timing):
                    d.own_predictions[e] = mine
                    d.kinds[e] = SHARED
                    if pair != sample - 1:
                        self.counts["older_shared_neighbours"] += 1
                    continue
            elif plan is not None and fill_from_plan(d.predictions[e], plan, sample, *self._timing):
                d.kinds[e] = OBSTACLE
                continue
            d.kinds[e] = MISSING if shared else OBSTACLE
            missing.append(e)
            late.append(plan)
        if missing:
            self.predict_fallback(missing, sample, states, late, previous_states)
            self.counts["fallback_neighbours"] += len(missing)

    def _braked_neighbours(self, sample: int, states: np.ndarray,
                           previous_states: np.ndarray | None) -> None:
        r"""The departed neighbours
        (:meth:`~sqpmpc.control.pipeline.ControllerPipeline.update_departed`), braked by
        their plant: no plan-age margin, and a one-sample
        reach (:meth:`ExternalCollisionModel.set_reach
        <sqpmpc.ocp.collision_rows.ExternalCollisionModel.set_reach>`) of what they moved
        over the last sample once braked over it; :math:`v_{\max} T_s` for every other slot.

        A departed robot re-plans nothing: with no age margin it is predicted from its last
        two measured states (the paper's fallback, :meth:`predict_fallback`: standing once
        it has stopped); its reach stays in the check of the first input, which never had
        the age margin. Without this a robot that left kept a disc of :math:`v_{\max} T_s N`
        (2 m at 1 m/s, 0.2 s, N = 10) around it for good, and the robots around it stood. A
        departed robot's plant brakes it from the sample at which its controllers are told
        (``v = omega = 0`` clipped to the bounds: the services' plant brakes a robot its
        states message lists as gone,
        :meth:`~sqpmpc.sim.simulation.ClosedLoopSimulation.depart` sends zero from the next
        step). Braked, its speed does not grow (a velocity plant: 0, or the bound nearest 0,
        at once; with acceleration bounds it slows at the bound), so from the second sample
        on it moves at most what it moved in the sample before: 0 once it stands. A noisy
        plant's input noise can move it: there it keeps :math:`v_{\max} T_s`. Without this a
        robot whose path passes a departed robot within :math:`d + v_{\max} T_s` stood
        before it for good (a 3 x 3 formation: robot 4, 0.5 m from robot 5 that left, which
        it had to keep 0.6 m from)."""
        departed = self.context.departed
        for j in [j for j in self._braked if j not in departed]:
            del self._braked[j]
        for j in departed:
            self._braked.setdefault(j, sample)
        reach = np.full(self.slots, self._reach)
        known = previous_states is not None and not self.scenario.plant.noisy
        d = self.slot_data
        for e, _ in d.neighbours:
            j = int(d.index[e])
            if j not in departed:
                continue
            d.age_margins[e] = 0.0
            if known and self._braked[j] < sample:
                moved = float(np.hypot(*(states[j, :2] - previous_states[j, :2])))
                reach[e] = min(self._reach, moved)
        self._aged = bool((d.age_margins > 0.0).any())
        self.collisions.set_reach(reach)

    def predict_fallback(self, slots: list[int], sample: int, states: np.ndarray,
                         plans: list[PlanMessage | None],
                         previous_states: np.ndarray | None) -> None:
        """The paper's fallback for the neighbours in ``slots``: each one's newest late
        plan in ``plans`` (it still says where it was going), else the input estimated
        from two states, held (:func:`predict_from_states`: the neighbours without a plan
        in one rollout, each predicted exactly as alone)."""
        d = self.slot_data
        rest = [slot for slot, plan in zip(slots, plans, strict=True)
                if d.age_margins[slot] == 0.0 or plan is None
                or not fill_from_plan(d.predictions[slot], plan, sample, *self._timing)]
        if rest:
            j = d.index[rest]
            prev = None if previous_states is None else previous_states[j]
            d.predictions[rest] = np.swapaxes(predict_from_states(
                states[j], prev, self.horizon, self.sample_time,
                self.settings.discretization)[1:], 0, 1)

    def publish(self, sample: int, out: ControlOutput) -> None:
        """Keep the sample's plan as :attr:`published` (and in ``out.plan``), the step's
        plan-age report in ``out.plan_ages``."""
        self.published = PlanMessage(self.robot_id, sample, out.predicted_states[0],
                                     out.predicted_inputs[0])
        out.plan = self.published
        out.plan_ages = self.plan_ages
        self.book.publish(self.published, sample)

    def update_neighbour_plan(self, plan: PlanMessage) -> None:
        """Keep a neighbour's plan for the next steps called without ``plans``.

        The newest plan of each neighbour is kept (a plan of an earlier sample
        than the one held is ignored, as a late message). Passing ``plans`` to
        :meth:`step` instead uses exactly those plans.

        Parameters
        ----------
        plan
            What the neighbour's controller returned as ``ControlOutput.plan``
            (or a plan rebuilt from a message).

        Raises
        ------
        ProblemError
            Not a :class:`PlanMessage`, the sender is this robot or not in the
            scenario, a negative sample, or states/inputs not finite arrays of
            shape ``(N+1, 3)`` / ``(N, 2)``; the message names the robot.
        """
        if not isinstance(plan, PlanMessage):
            raise ProblemError(f"robot {self.robot_id}: update_neighbour_plan expects a "
                               f"PlanMessage, got {type(plan).__name__}")
        sender = plan.robot_id
        where = f"robot {self.robot_id}: plan of robot {sender!r}"
        if sender not in set(self.other_ids.tolist()):
            raise ProblemError(f"{where}: not a neighbour; neighbours: "
                               f"{', '.join(map(str, self.other_ids.tolist())) or 'none'}")
        if isinstance(plan.sample, bool) or not isinstance(plan.sample, int | np.integer) or (
                plan.sample < 0):
            raise ProblemError(f"{where}: sample must be an integer >= 0, got {plan.sample!r}")
        N = self.horizon
        arrays = {}
        for name, shape in (("states", (N + 1, 3)), ("inputs", (N, 2))):
            value = np.ascontiguousarray(getattr(plan, name), dtype=np.float64)
            if value.shape != shape or not np.isfinite(value).all():
                raise ProblemError(f"{where}: {name} must be finite with shape {shape}, got "
                                   f"shape {value.shape}" + (
                                       "" if value.shape != shape else " with non-finite values"))
            arrays[name] = value
        kept = PlanMessage(int(sender), int(plan.sample), arrays["states"], arrays["inputs"])
        newest = self._received.get(sender)
        self.book.remember(int(sender), kept, kept.sample if newest is None else newest.sample)
        if newest is not None and newest.sample > plan.sample:
            return
        self._received[sender] = kept

    @property
    def neighbour_plans(self) -> Mapping[int, PlanMessage]:
        """The plans kept by :meth:`update_neighbour_plan`, by neighbour id (read-only view)."""
        return MappingProxyType(self._received)

    def step(
        self,
        sample: int,
        t: float,
        states: np.ndarray,
        plans: Mapping[int, PlanMessage | None] | None = None,
        previous_states: np.ndarray | None = None,
        plan_ages: PlanAges | None = None,
    ) -> ControlOutput:
        """Compute this robot's input at sample ``k`` (time ``t``).

        Parameters
        ----------
        sample
            Sample index ``k``.
        t
            Time ``t_k``.
        states
            Measured states of all robots (scenario order): ``(n, 3)`` poses, or ``(n, 5)``
            with the measured ``(v, omega)`` appended (CONTRACT 1c; with poses alone a robot
            with acceleration limits is taken to move at what it was last commanded).
        plans
            Latest plan received from each neighbour id (``None`` or absent if
            none); ``None`` (default): the plans kept by
            :meth:`update_neighbour_plan`.
        previous_states
            States at ``k - 1`` (for the fallback estimate), or ``None``.
        plan_ages
            The :attr:`plan_ages` every robot reported at its step ``k - 1``,
            by robot id, exactly as every other robot receives them (the
            services: relayed by the plant with the states of ``k``); ``None``
            (default): none reported, every shared row uses the plans of
            ``k - 1``. With plans late by ``D`` samples, passing them lets each
            pair share rows built from the plans of ``k - D``
            (:func:`pair_sample`).

        Returns
        -------
        ControlOutput
            The input to apply (``inputs[0]``) and, in ``plan``, the plan to
            send to the neighbours for their step ``k + 1``, in ``plan_ages``
            this step's report (also :attr:`plan_ages`).
        """
        if plans is None:
            plans = self._received
        cpu = time.thread_time()
        out = self.run_sample(sample, t, states, plans, previous_states, plan_ages)
        out.cpu_time = time.thread_time() - cpu
        return out


def _warn_paper_mode() -> None:
    """Log once per process that ``"paper"`` mode has no collision guarantee."""
    global paper_mode_warned
    if not paper_mode_warned:
        paper_mode_warned = True
        log.warning("decentralized mode 'paper' (the seed paper's literal scheme, for "
                    "comparison) has no collision guarantee: robots avoid each other's "
                    "previous plans, and every built-in scenario collides with it "
                    "(docs/decomposition.md); use 'shared' (default) to be safe")

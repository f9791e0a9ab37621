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
from collections.abc import Mapping
from types import MappingProxyType
from typing import Literal

import numpy as np

from sqpmpc.control.centralized import _has_position_bounds
from sqpmpc.control.pipeline import ControllerPipeline, ControlOutput, braking_input
from sqpmpc.control.plans import (
    AGE_HOLD,
    LATE_STEPS,
    PlanAges,
    PlanMessage,
    PlanSource,
    pair_sample,
    predict_from_plan,
    predict_from_states,
)
from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.kernels.collision import nearest_within
from sqpmpc.kernels.ocp import shift_plan
from sqpmpc.ocp.collision_rows import (
    MISSING,
    OBSTACLE,
    OFF,
    SHARED,
    ExternalCollisionModel,
)
from sqpmpc.ocp.obstacle_rows import StackedRows
from sqpmpc.problem.plant import acceleration_path_deviation, largest_deviation
from sqpmpc.problem.scenario import Scenario
from sqpmpc.qp.layout import QPLayout

__all__ = [
    "ControlOutput", "DecentralizedController", "PlanAges", "PlanMessage", "PlanSource",
    "braking_input", "pair_sample", "predict_from_plan", "predict_from_states",
]

DecentralizedMode = Literal["shared", "paper"]
"""Samples a robot keeps reporting the largest plan age it saw of a neighbour whose plans
come late (at :data:`LATE_STEPS` steps in a row; lost plans are rarely reported): a plan
that comes one sample later than usual then costs one sample without a shared row with
that neighbour, not one every time."""
"""Steps in a row a neighbour's newest plan must be late before its age is reported.
Under random loss of plans older shared rows help little and cost fallbacks: in process,
paper-s2, 4 seeds at 20 and 50 % loss, 2 steps gave 11-25 % more fallbacks than no relay,
3 steps 2-10 %; plans late by 2-3 samples are reported either way."""
"""Per robot id, per neighbour id: the age (samples) of the newest plan of that neighbour
the robot held at its previous step, as relayed by the plant; a pair not listed: 1."""

log = logging.getLogger(__name__)
_paper_mode_warned = False


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
    """

    scheme = "decentralized"

    def __init__(self, scenario: Scenario, robot_id: int,
                 settings: SolverSettings | None = None,
                 mode: DecentralizedMode = "shared") -> None:
        settings = (settings or SolverSettings()).resolved(scenario.n_robots)
        if mode not in ("shared", "paper"):
            raise ProblemError(f"decentralized mode must be 'shared' or 'paper', got {mode!r}")
        index = scenario.index_of(robot_id)
        others = np.array([i for i in range(scenario.n_robots) if i != index], dtype=np.int64)
        slots = others.size if settings.neighbour_slots is None else min(
            others.size, settings.neighbour_slots)
        layout = QPLayout(1, scenario.horizon, np.zeros((0, 2), dtype=np.int64),
                          slots + len(scenario.obstacles), _has_position_bounds(scenario),
                          scenario.robot_model())
        super().__init__(scenario, np.array([index]), layout, settings)
        self.robot_id = int(robot_id)
        self.index = index
        self.others = others
        self.other_ids = scenario.ids[others]
        self.slots = slots
        self._selecting = settings.neighbour_slots is not None
        self._chosen = np.zeros(slots, dtype=np.int64)  # selection scratch (indices into others)
        self._rest = np.zeros(others.size, dtype=np.int64)
        # slot e holds neighbour self._slot_index[e] (scenario index; fixed without selection)
        self._slot_index = others[:slots].copy()
        self._neighbours = list(enumerate(self.other_ids[:slots].tolist()))
        self.mode = mode
        self.required = scenario.required_distances()[index, others]
        N = scenario.horizon
        v_max = self.context.max_speed
        # beyond this, a neighbour cannot come within its distance over the horizon
        self.interaction_radius = (self.required + self.pair_margin
                                   + 2.0 * v_max * N * scenario.sample_time)
        self.collisions = ExternalCollisionModel(
            self.required[:slots], N, self.geometry, reach=scenario.sample_time * v_max,
            margin=self.pair_margin, stage_one_rule_for_obstacles=mode == "shared",
            recovery=self.recovery_tolerance,
        )
        self._rows = {"external": self.collisions if self.obstacle_rows is None
                      else StackedRows(self.collisions, self.obstacle_rows, slots, N)}
        self.counts["fallback_neighbours"] = 0
        self.counts["unslotted_neighbours"] = 0
        self.counts["late_plan_neighbours"] = 0
        self.counts["older_shared_neighbours"] = 0
        self._plan_seen: dict[int, int] = {}  # per neighbour id: newest plan sample seen
        self._age_margins = np.zeros(slots)
        self._own_prediction = np.zeros((N, 3))
        self._own_pair_predictions = np.zeros((slots, N, 3))
        # own plans by sample (None: two different plans of that sample were published)
        # and the neighbours' plans seen, by id and sample: a shared row may use older ones
        self._own_plans: dict[int, PlanMessage | None] = {}
        self._history: dict[int, dict[int, PlanMessage]] = {}
        self._plan_ages_in: PlanAges | None = None
        # per neighbour: (steps late in a row, largest age of the last samples, held until)
        self._age_hold: dict[int, tuple[int, int, int]] = {}
        #: per neighbour (slotted at the last step) whose newest plan held then was
        #: ``age >= 2`` samples old: ``age`` (at most ``N + 2``); the services send it with
        #: the input and the plant relays it to every robot with the next states
        self.plan_ages: dict[int, int] = {}
        self._other_predictions = np.zeros((slots, N, 3))
        self._kinds = np.zeros(slots, dtype=np.int8)
        if mode == "paper":
            _warn_paper_mode()
        self.published: PlanMessage | None = None
        self._received: dict[int, PlanMessage] = {}

    def _safe(self, states: np.ndarray, next_state: np.ndarray, inputs: np.ndarray) -> bool:
        alpha, beta = self.path_deviation(inputs)
        if not self.collisions.first_stage_safe(next_state[0, :2], alpha=float(alpha[0]),
                                                beta=float(beta[0])):
            return False
        if not self._unicycle:  # robots with velocity states: the bound itself
            return (self._obstacles_safe(states, next_state, alpha, beta)
                    and self._in_position_bounds(next_state[:, :2]))
        growth = alpha + np.maximum(beta, 0.0)
        return (self._obstacles_safe(states, next_state, growth)
                and self._in_position_bounds(next_state[:, :2]))

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
            slack = 0.5 * (c.required - c.safe_distance)[shared][:, None] - growth[None]
            normals = c.fixed_normals[shared][:, rows]          # (S, B, 2)
            held = np.einsum("sbk,bk->sb", normals, pos) - c.fixed_rhs[shared][:, rows]
            if (held < -slack - 1e-9).any():
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

    def _fill_from_plan(self, out: np.ndarray, plan: PlanMessage, sample: int) -> bool:
        """Stages 1..N ``out (N, 3)`` at sample ``k`` from a plan of an earlier sample.

        A plan of ``k - 1`` (the usual case) is shifted by one stage, holding its
        last input (one kernel call); older ones by :func:`predict_from_plan`.
        Returns ``False`` for a plan that cannot be used (from the future, too old).
        """
        N, h, method = self.horizon, self.sample_time, self.settings.discretization
        if (sample - plan.sample == 1 and method == "euler" and plan.states.shape[0] == N + 1
                and plan.states.flags.c_contiguous and plan.inputs.flags.c_contiguous):
            shift_plan(plan.states, plan.inputs, h, out)
            return True
        pred = predict_from_plan(plan, sample, N, h, method)
        if pred is None:
            return False
        out[:] = pred[1:]
        return True

    def _own_at(self, pair: int, sample: int, cache: dict[int, np.ndarray | None]
                ) -> np.ndarray | None:
        """Own stages 1..N at ``sample`` from the own plan of sample ``pair`` (``None``: not
        held, or published twice)."""
        if pair not in cache:
            published = self.published
            plan = self._own_plans.get(pair, published if published is not None
                                       and published.sample == pair else None)
            if plan is None:
                cache[pair] = None
            elif plan is self.published and sample - pair <= self.horizon:
                cache[pair] = self._own_prediction  # filled from it above
            else:
                out = np.empty((self.horizon, 3))
                cache[pair] = out if self._fill_from_plan(out, plan, sample) else None
        return cache[pair]

    def _neighbour_at(self, plans: Mapping[int, object], jid: int, pair: int,
                      newest: PlanMessage | None) -> PlanMessage | None:
        """The plan neighbour ``jid`` computed at sample ``pair``, if held."""
        if newest is not None and newest.sample == pair:
            return newest
        if isinstance(plans, PlanSource):
            return plans.plan_at(jid, pair)
        return self._history.get(jid, {}).get(pair)

    def _remember(self, jid: int, plan: PlanMessage, sample: int) -> None:
        """Keep a neighbour's plan for shared rows of later samples (the first of a sample
        wins, as in the services' plan store)."""
        held = self._history.setdefault(jid, {})
        if plan.sample in held:
            return
        held[plan.sample] = plan
        if len(held) > self.horizon + 2:
            for old in [s for s in held if s < sample - self.horizon - 1]:
                del held[old]

    def _predict_neighbours(self, sample: int, states: np.ndarray, plans: Mapping[int, object],
                            previous_states: np.ndarray | None) -> None:
        """Own published prediction and the neighbours', stages 1..N, with the slot kinds.

        A shared hyperplane of the pair with neighbour ``l`` is built from both
        robots' plans of the sample :func:`pair_sample` gives (``k - 1``
        unless plans have been late), which both compute from the same relayed
        ``plan_ages``; a robot that does not hold both plans of that sample
        predicts the neighbour by the paper's fallback (input estimated from
        two states, or its newest late plan) and its slot is *missing*.
        """
        N, h, method = self.horizon, self.sample_time, self.settings.discretization
        if self._selecting:
            self._select_neighbours(states)
        if self.published is None or not self._fill_from_plan(self._own_prediction,
                                                                self.published, sample):
            self._own_prediction[:] = predict_from_states(states[self.index], None, N, h,
                                                          method)[1:]
        shared = self.mode == "shared"
        kinds = self._kinds
        preds = self._other_predictions
        own_preds = self._own_pair_predictions
        own_cache: dict[int, np.ndarray | None] = {}
        ages_in = self._plan_ages_in
        report: dict[int, int] = {}
        missing = 0
        margins = self._age_margins
        margins[:] = 0.0
        for e, jid in self._neighbours:
            plan = plans.get(jid)
            if plan is not None:
                self._remember(jid, plan, sample)
                if self._plan_seen.get(jid, -1) < plan.sample < sample:
                    self._plan_seen[jid] = plan.sample
            age = sample - self._plan_seen.get(jid, sample - 1)
            if age > 1:  # its plans are late or lost: it re-planned age - 1 times unseen
                margins[e] = self.context.max_speed * h * min(age - 1, N)
                self.counts["late_plan_neighbours"] += 1
            late, held_age, until = self._age_hold.get(jid, (0, 1, -1))
            late = late + 1 if age > 1 else 0
            if age >= held_age or sample > until:  # the largest age of the last few samples
                held_age, until = age, sample + AGE_HOLD - 1
            self._age_hold[jid] = (late, held_age, until)
            if late >= LATE_STEPS:  # delayed, not a plan or two lost
                report[jid] = min(held_age, N + 2)
            if shared:
                pair = pair_sample(sample, self.robot_id, jid, ages_in)
                mine = self._own_at(pair, sample, own_cache)
                theirs = None if mine is None else self._neighbour_at(plans, jid, pair, plan)
                if theirs is not None and self._fill_from_plan(preds[e], theirs, sample):
                    own_preds[e] = mine
                    kinds[e] = SHARED
                    if pair != sample - 1:
                        self.counts["older_shared_neighbours"] += 1
                    continue
            elif plan is not None and self._fill_from_plan(preds[e], plan, sample):
                kinds[e] = OBSTACLE
                continue
            if margins[e] == 0.0 or plan is None or not self._fill_from_plan(
                    preds[e], plan, sample):  # a late plan still says where it was going
                j = self._slot_index[e]
                prev = None if previous_states is None else previous_states[j]
                preds[e] = predict_from_states(states[j], prev, N, h, method)[1:]
            kinds[e] = MISSING if shared else OBSTACLE
            missing += 1
        if missing:
            self.counts["fallback_neighbours"] += missing
        self.plan_ages = report
        self.collisions.set_age_margins(margins)
        self.collisions.set_sample(states[self.index, :2], states[self._slot_index, :2],
                                   own_preds, self._other_predictions, kinds)

    def _select_neighbours(self, states: np.ndarray) -> None:
        """Fill the slots with the nearest neighbours within the interaction radius.

        A neighbour farther than its required distance plus margin plus
        ``2 v_max N Ts`` cannot come within that distance over the horizon
        (each robot moves at most ``v_max N Ts``), so it gets no row. The
        nearest of the others get the slots (free slots are off); those within
        the radius left without a slot are handed to the first-input check,
        which keeps their distance plus their one-sample reach, or stands still.
        """
        positions = np.ascontiguousarray(states[:, :2])
        used, extra = nearest_within(positions[self.index], positions, self.others,
                                     self.interaction_radius, self._chosen, self._rest)
        chosen, rest = self._chosen[:used], self._rest[:extra]
        self._slot_index[:used] = self.others[chosen]
        self._slot_index[used:] = self.index  # free slots: off (their position is unused)
        self._neighbours = list(zip(range(used), self.other_ids[chosen].tolist(), strict=True))
        self._kinds[used:] = OFF
        required = np.zeros(self.slots)
        required[:used] = self.required[chosen]
        self.collisions.set_required(required)
        self.collisions.set_unslotted(states[self.others[rest], :2], self.required[rest])
        self.counts["unslotted_neighbours"] += int(rest.size)

    def _publish(self, sample: int, out: ControlOutput) -> None:
        self.published = PlanMessage(self.robot_id, sample, out.predicted_states[0],
                                     out.predicted_inputs[0])
        out.plan = self.published
        # a sample computed twice (a forged future state) published two plans: a
        # neighbour may hold either, so that sample's pair rows are never shared
        self._own_plans[sample] = None if sample in self._own_plans else self.published
        if len(self._own_plans) > self.horizon + 2:
            for old in [s for s in self._own_plans if s < sample - self.horizon - 1]:
                del self._own_plans[old]

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
        self._remember(int(sender), kept, kept.sample if newest is None else newest.sample)
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
            send to the neighbours for their step ``k + 1``; :attr:`plan_ages`
            then holds this step's report.
        """
        if plans is None:
            plans = self._received
        self._plan_ages_in = plan_ages
        return self.run_sample(sample, t, states, plans, previous_states)


def _warn_paper_mode() -> None:
    """Log once per process that ``"paper"`` mode has no collision guarantee."""
    global _paper_mode_warned
    if not _paper_mode_warned:
        _paper_mode_warned = True
        log.warning("decentralized mode 'paper' (the seed paper's literal scheme, for "
                    "comparison) has no collision guarantee: robots avoid each other's "
                    "previous plans, and every built-in scenario collides with it "
                    "(docs/decomposition.md); use 'shared' (default) to be safe")

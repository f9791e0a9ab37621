r"""Plans exchanged between decentralized controllers, their ages, and predictions from them.

**Late and lost plans.** The hard part of the safety argument does not depend
on plans arriving: stage 1 and the first-input check use the *measured*
positions of sample ``k``; a neighbour without a fresh plan (late, lost,
never sent) is kept at its distance plus its one-sample reach ``v_max Ts``
(``missing-neighbour-reach``). What plan age changes is the soft stages
2..N: a neighbour whose newest plan seen is ``a >= 2`` samples old has
re-planned ``a - 1`` times unseen, so its obstacle or missing rows ask for
``v_max Ts min(a - 1, N)`` more distance (in the spirit of RMADER's delay
check; counted in ``late_plan_neighbours``). A neighbour never heard from (the
first sample) gets no extra margin: a run without loss is unchanged.

**Which plans a shared row is built from.** The pair ``(j, l)`` shares a row at
sample ``k`` built from *both robots' plans of one sample* ``s``, which both
compute alike with :func:`pair_sample` from the ``plan_ages`` every robot
reported at its step ``k - 1`` (the age of the newest plan it held of each
late neighbour, the services' input message carries it and the plant relays
it with the states of ``k``, the same message to every robot): ``s = k - a``,
``a`` the larger of the two robots' ages for each other (``k - 1`` when
neither reported one). With plans ``D`` samples late that is ``k - D``, whose
plans both hold; without delay it is ``k - 1``. The argument:

1. *Same row or none.* Each robot builds the pair's row from the measured
   positions of ``k`` (one state message), the two plans of ``s`` shifted
   ``k - s`` stages by the same code (its own as it published it, the other's
   as received: msgpack float64 is exact), the scenario's distance and the
   rules' row geometry, which is antisymmetric in the pair; so if both build
   it, ``j`` keeps :math:`n^\top p_j \ge c + d/2` and ``l`` keeps
   :math:`-n^\top p_l \ge -c + d/2`, and together :math:`n^\top(p_j - p_l)
   \ge d`. A robot that does not hold both plans of ``s`` (a plan later than
   usual, lost, or a sample it published twice after a forged state) treats
   the neighbour as *missing*: it keeps distance plus the neighbour's
   one-sample reach from its measured position, which holds whatever the
   neighbour does within its bounds, shared row or not.
2. *The age of the plans does not enter stage 1's feasibility.* The stage-1
   offset ``c`` is clipped so that both measured positions are on their sides
   (and overridden by the current normal when the row's normal would not keep
   them apart): standing still satisfies stage 1 whatever plans the line came
   from, so the QP stays feasible and the first-input check (the whole path of
   the sample, against the same half-plane) accepts at least stopping. Older
   plans only move the line (stages 2..N are soft): the row constrains the
   robots' *new* plans, which both satisfy from the opposite sides.
3. *Forged relays* can only change which common ``s`` both use (every robot
   reads the same state message), never make the two sides differ; a state
   message that differs between robots is outside this argument as it is for
   the measured positions themselves (authenticated runs, ``docs/security.md``).

Ages are reported only for neighbours late at :data:`LATE_STEPS` steps in a
row (a plan or two lost keep the pair on ``k - 1``), and the largest age of the last
:data:`AGE_HOLD` samples is kept, so a plan one sample later than usual costs
one sample without that shared row, not one per jitter.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from sqpmpc.kernels.ocp import shift_plan
from sqpmpc.models.unicycle import discrete_dynamics, estimate_input, rollout

__all__ = [
    "AGE_HOLD", "LATE_STEPS", "PlanAges", "PlanBook", "PlanMessage", "PlanSource",
    "fill_from_plan", "pair_sample", "predict_from_plan", "predict_from_states",
]


AGE_HOLD = 10
"""Samples a robot keeps reporting the largest plan age it saw of a neighbour whose plans
come late (at :data:`LATE_STEPS` steps in a row; lost plans are rarely reported): a plan
that comes one sample later than usual then costs one sample without a shared row with
that neighbour, not one every time."""


LATE_STEPS = 3
"""Steps in a row a neighbour's newest plan must be late before its age is reported.
Under random loss of plans older shared rows help little and cost fallbacks: in process,
paper-s2, 4 seeds at 20 and 50 % loss, 2 steps gave 11-25 % more fallbacks than no relay,
3 steps 2-10 %; plans late by 2-3 samples are reported either way."""


PlanAges = Mapping[int, Mapping[int, int]]
"""Per robot id, per neighbour id: the age (samples) of the newest plan of that neighbour
the robot held at its previous step, as relayed by the plant; a pair not listed: 1."""


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


@runtime_checkable
class PlanSource(Protocol):
    """A ``plans`` mapping that can also give a neighbour's plan of a given sample."""

    def plan_at(self, robot_id: int, sample: int) -> PlanMessage | None:
        """The plan robot ``robot_id`` computed at ``sample``, if held."""


def pair_sample(sample: int, a: int, b: int, plan_ages: PlanAges | None) -> int:
    """The sample of the two plans robots ``a`` and ``b`` build their shared row from.

    At sample ``k`` both robots of a pair read the same relayed ``plan_ages``
    (the plant's state message of ``k``): each reported, at its step ``k - 1``,
    how old the newest plan of the other it held was (``1`` when not listed).
    With ``a`` the larger of the two ages the pair uses the plans of
    ``k - a``: with plans late by ``D`` samples this is ``k - D``, whose
    plans both hold by now; without delay it is ``k - 1`` (as before).
    Both robots compute the same number from the same message, which is all
    the safety argument needs (module notes); whether they hold the plans is
    each one's own business (a robot that does not holds the pair as missing).
    """
    age = 1
    if plan_ages:
        mine, theirs = plan_ages.get(a), plan_ages.get(b)
        if mine:
            age = max(age, int(mine.get(b, 1)))
        if theirs:
            age = max(age, int(theirs.get(a, 1)))
    return sample - age


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


def fill_from_plan(out: np.ndarray, plan: PlanMessage, sample: int, horizon: int,
                   sample_time: float, method: str) -> bool:
    """Stages 1..N ``out (N, 3)`` at sample ``k`` from a plan of an earlier sample.

    A plan of ``k - 1`` (the usual case) is shifted by one stage, holding its
    last input (one kernel call); older ones by :func:`predict_from_plan`.
    Returns ``False`` for a plan that cannot be used (from the future, too old).
    """
    if (sample - plan.sample == 1 and method == "euler" and plan.states.shape[0] == horizon + 1
            and plan.states.flags.c_contiguous and plan.inputs.flags.c_contiguous):
        shift_plan(plan.states, plan.inputs, sample_time, out)
        return True
    pred = predict_from_plan(plan, sample, horizon, sample_time, method)
    if pred is None:
        return False
    out[:] = pred[1:]
    return True


def predict_from_states(
    current: np.ndarray,
    previous: np.ndarray | None,
    horizon: int,
    sample_time: float,
    method: str,
) -> np.ndarray:
    r"""Paper section 3.2 fallback: hold the input estimated from two states.

    The input :math:`\hat u` of :func:`~sqpmpc.models.unicycle.estimate_input`
    (``previous`` ``None``: :math:`\hat u = 0`, standing) is held over the horizon:
    :math:`\hat\chi_0 = \chi_k`, :math:`\hat\chi_{i+1} = f_d(\hat\chi_i, \hat u)`.
    ``current`` and ``previous`` are ``(..., 3)``: several robots are predicted in
    one rollout, each exactly as alone.

    Returns
    -------
    np.ndarray
        ``(N+1, ..., 3)``, the current states first.
    """
    current = np.asarray(current, dtype=float)
    u = np.zeros(current.shape[:-1] + (2,)) if previous is None else estimate_input(
        previous, current, sample_time)
    return rollout(current, np.repeat(u[None], horizon, axis=0), sample_time, method)


class PlanBook:
    """What a decentralized robot keeps of plans between samples.

    Its own plans by sample (``None``: two different plans of that sample were
    published, after a forged state), its neighbours' plans by id and sample (a
    shared row may be built from older ones) and, per neighbour, the newest
    plan sample seen and the age bookkeeping of :meth:`age`. Plans older than
    ``N + 1`` samples are dropped.

    Parameters
    ----------
    horizon
        ``N``.
    """

    def __init__(self, horizon: int) -> None:
        self.horizon = int(horizon)
        self.own: dict[int, PlanMessage | None] = {}
        self.neighbours: dict[int, dict[int, PlanMessage]] = {}
        self.seen: dict[int, int] = {}
        # per neighbour: (steps late in a row, largest age of the last samples, held until)
        self.hold: dict[int, tuple[int, int, int]] = {}
        # no plan of a sample below these is held (own, per neighbour): pruning visits
        # only the samples from there (:func:`_drop_before`)
        self._own_floor: int = sys.maxsize
        self._floors: dict[int, int] = {}

    def publish(self, plan: PlanMessage, sample: int) -> None:
        """Keep the own plan of ``sample`` (a second one of the same sample: never shared)."""
        own = self.own
        if sample in own:
            own[sample] = None
        else:
            own[sample] = plan
            self._own_floor = min(self._own_floor, sample)
        if len(own) > self.horizon + 2:
            self._own_floor = _drop_before(own, self._own_floor, sample - self.horizon - 1)

    def own_plan(self, sample: int, published: PlanMessage | None) -> PlanMessage | None:
        """The own plan of ``sample`` (``None``: not held, or published twice)."""
        return self.own.get(sample, published if published is not None
                            and published.sample == sample else None)

    def remember(self, robot_id: int, plan: PlanMessage, sample: int) -> None:
        """Keep a neighbour's plan for shared rows of later samples (the first of a sample
        wins, as in the services' plan store)."""
        held = self.neighbours.get(robot_id)
        key = plan.sample
        if held is None:
            held = self.neighbours[robot_id] = {}
            floor = key
        elif key in held:
            return
        else:
            floor = self._floors[robot_id]
            if key < floor:
                floor = key
        held[key] = plan
        if len(held) > self.horizon + 2:
            floor = _drop_before(held, floor, sample - self.horizon - 1)
        self._floors[robot_id] = floor

    def neighbour_plan(self, plans: Mapping[int, object], robot_id: int, sample: int,
                       newest: PlanMessage | None) -> PlanMessage | None:
        """The plan neighbour ``robot_id`` computed at ``sample``, if held (``newest``, a
        :class:`PlanSource` ``plans``, or kept by :meth:`remember`)."""
        if newest is not None and newest.sample == sample:
            return newest
        if isinstance(plans, PlanSource):
            return plans.plan_at(robot_id, sample)
        return self.neighbours.get(robot_id, {}).get(sample)

    def age(self, robot_id: int, plan: PlanMessage | None, sample: int
            ) -> tuple[int, int | None]:
        """Take the newest ``plan`` of a neighbour at ``sample``; returns its plans' age
        and the age to report (``None`` until late :data:`LATE_STEPS` steps in a row; then
        the largest age of the last :data:`AGE_HOLD` samples)."""
        if plan is not None:
            self.remember(robot_id, plan, sample)
            if self.seen.get(robot_id, -1) < plan.sample < sample:
                self.seen[robot_id] = plan.sample
        age = sample - self.seen.get(robot_id, sample - 1)
        late, held_age, until = self.hold.get(robot_id, (0, 1, -1))
        late = late + 1 if age > 1 else 0
        if age >= held_age or sample > until:  # the largest age of the last few samples
            held_age, until = age, sample + AGE_HOLD - 1
        self.hold[robot_id] = (late, held_age, until)
        return age, (held_age if late >= LATE_STEPS else None)

    def track(self, neighbours: list[tuple[int, int]], plans: Mapping[int, object],
              sample: int, margins: np.ndarray, reach: float) -> tuple[dict[int, int], bool, int]:
        """:meth:`age` of every slotted neighbour at ``sample`` in one pass.

        ``neighbours`` are ``(slot, id)`` pairs, ``plans`` the newest plans by id. A
        neighbour whose plans' age ``a`` is above 1 gets ``margins[slot] = reach min(a - 1,
        N)`` (the others 0). Returns the ages to report by id (``min(age, N + 2)``),
        whether some margin is positive and how many neighbours were late.
        """
        N = self.horizon
        seen, hold = self.seen, self.hold
        report: dict[int, int] = {}
        aged, late_count = False, 0
        margins.fill(0.0)
        for e, jid in neighbours:
            plan = plans.get(jid)
            if plan is not None:
                self.remember(jid, plan, sample)
                if seen.get(jid, -1) < plan.sample < sample:
                    seen[jid] = plan.sample
            age = sample - seen.get(jid, sample - 1)
            late, held_age, until = hold.get(jid, (0, 1, -1))
            if age > 1:  # its plans are late or lost: it re-planned age - 1 times unseen
                late += 1
                margins[e] = reach * min(age - 1, N)
                aged = aged or margins[e] > 0.0
                late_count += 1
            else:
                late = 0
            if age >= held_age or sample > until:  # the largest age of the last few samples
                held_age, until = age, sample + AGE_HOLD - 1
            hold[jid] = (late, held_age, until)
            if late >= LATE_STEPS:  # delayed, not a plan or two lost
                report[jid] = min(held_age, N + 2)
        return report, aged, late_count


def _drop_before(held: dict[int, object], floor: int, threshold: int) -> int:
    """Delete the entries of ``held`` whose sample is below ``threshold``, knowing none is
    below ``floor``; returns the new floor. Integer samples close to the floor (the usual
    case: one sample per step) are looked up, others scanned."""
    if type(floor) is int and type(threshold) is int and threshold - floor <= len(held):
        if threshold == floor + 1:  # the usual case: one sample per step
            held.pop(floor, None)
        else:
            for old in range(floor, threshold):
                held.pop(old, None)
    else:
        for old in [s for s in held if s < threshold]:
            del held[old]
    return max(floor, threshold)

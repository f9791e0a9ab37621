"""Plan filtering: a robot receives and decodes the plans of the robots that can matter.

A decentralized robot with neighbour slots
(:attr:`sqpmpc.control.settings.SolverSettings.neighbour_slots`) reads, at sample
``k``, the plans (of ``k - 1``) of the neighbours it gives a slot: the
``slots`` nearest within the interaction radius ``d + margin + 2 v_max N Ts``
(:class:`sqpmpc.control.neighbours.NeighbourSelector`). Every
other plan of the fleet is traffic it pays for and never uses.

- The sender filters (:func:`recipients`, the sender's
  :meth:`~sqpmpc.control.neighbours.NeighbourSelector.recipients`): after its step at ``k`` a robot
  sends its plan to each robot that may give it a slot at ``k + 1``, on
  ``robot/<id>/plan/<to>``; between two samples a distance changes by at most
  ``2 v_max Ts``, so the states of ``k`` bound the selection of ``k + 1``. A
  robot subscribes to ``robot/*/plan/<own id>`` only: Zenoh delivers nothing
  else.
- The receiver waits, in lockstep, for exactly the plans its controller will
  read (:func:`slotted`, the controller's own kernel call) and decodes a plan
  only when the step reads it (:class:`PlanStore`, :class:`StepPlans`): the
  header (sender, sample) is peeked on arrival and checked against the
  acceptance policy (:mod:`services.protocol`), the body decoded and
  validated when read.

Plans are claims, checked: a plan's stage 0 must be where the plant's state of
its sample put its robot (within :data:`START_TOLERANCE`), when this robot has
that state (``truth``). A plan that is not is refused as false: the
controller predicts that neighbour from its states for that sample (the
paper's fallback), and the robot is named in the log (:attr:`PlanStore.false`).
So a process holding a robot's key cannot place it where it is not; as only
the first plan of a sample is kept, a false plan that comes first costs the
neighbours that robot's plan of that sample.

Both sides compute from the same states with the same rule, so a lockstep
run equals the in-process run; a plan that is late or lost is what the
controller already handles (the paper's fallback). ``docs/fleet-services.md``
has the measured costs. Without neighbour slots (or with ``--all-plans``)
every plan is received on ``robot/<id>/plan`` and decoded on arrival, as
before; every robot of a run must use the same setting.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Iterator, Mapping

import numpy as np

from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.neighbours import recipients
from sqpmpc.control.plans import PlanMessage

from .messages import InvalidMessage, PlanMsg, peek_plan
from .protocol import AcceptancePolicy, Verdict
from .validator import MessageValidator

__all__ = ["START_TOLERANCE", "PlanStore", "StepPlans", "recipients", "slotted"]

log = logging.getLogger(__name__)

START_TOLERANCE = 1.0e-6
"""How far a plan's stage 0 may be from the plant's state of its sample, m (both are the
same numbers: the controller starts its plan at the state it was given)."""


def slotted(states: np.ndarray, controller: DecentralizedController) -> list[int]:
    """Ids of the neighbours ``controller`` gives a slot at ``states`` (nearest first).

    The controller's own selection
    (:meth:`sqpmpc.control.neighbours.NeighbourSelector.slotted_ids`), so the set
    is exactly the one the controller's step will read plans of.
    """
    return controller.selector.slotted_ids(states)


def _as_plan(msg: PlanMsg) -> PlanMessage:
    return PlanMessage(msg.id, msg.sample, msg.states, msg.inputs)


class PlanStore:
    """Per neighbour and sample, the plan received (bytes until decoded).

    Parameters
    ----------
    validator
        The node's validator (order checked on arrival, body when decoded; it
        counts what it refuses).
    neighbours
        Ids whose plans are kept.
    lazy
        Keep payloads undecoded until used (``False``: decode on arrival).
    policy
        The run's acceptance rules (:meth:`AcceptancePolicy.plan`).
    cursor
        The receiving robot's cursor in the state stream (sample), called per plan.
    truth
        ``truth(robot_id, sample)``: the plant's state of that robot at that sample, if
        this robot has it (``None``: not checked).

    Attributes
    ----------
    received, decoded, repeats
        Plans accepted so far, plans decoded so far, copies dropped.
    in_order
        Per robot, ``(count, newest)``: the plans of it that came (accepted, or too old
        by then: stale) newer than every one that came before, and the newest one's
        sample. A sender's plans to one receiver travel one reliable, ordered link, so
        without a loss ``count`` is the number of plans it sent this robot up to
        ``newest`` (copies sent again, plans accepted again after :meth:`clear`: not
        counted); those sent after ``newest`` may still be on their way when a run ends.
    false
        Per robot, plans refused as false (not starting at the plant's state).
    """

    def __init__(self, validator: MessageValidator, neighbours: Iterable[int],
                 policy: AcceptancePolicy, cursor: Callable[[], int],
                 lazy: bool = True,
                 truth: Callable[[int, int], np.ndarray | None] | None = None) -> None:
        self.validator = validator
        self.truth = truth
        self.false: dict[int, int] = {}
        self.policy = policy
        self.cursor = cursor
        self.lazy = lazy
        self.repeats = 0
        self._plans: dict[int, dict[int, bytes | PlanMessage]] = {int(i): {} for i in neighbours}
        self._newest = dict.fromkeys(self._plans, -1)
        self.received = 0
        self.decoded = 0
        self.in_order: dict[int, tuple[int, int]] = {}

    def __contains__(self, robot_id: object) -> bool:
        return robot_id in self._plans

    def add(self, robot_id: int, payload: bytes) -> None:
        """Keep a plan received on robot ``robot_id``'s key.

        A repeat (a second plan of the same sample) or a stale one is dropped
        without an error (:meth:`AcceptancePolicy.plan`).

        Raises
        ------
        InvalidMessage
            Refused (counted by the validator): ahead of the run, or, when it is
            decoded at once, malformed.
        """
        head = peek_plan(payload) if self.lazy else None
        if head is None or head[0] != robot_id:
            msg = self.validator.check(payload, "plan", robot_id)
            if not isinstance(msg, PlanMsg):  # the validator matches the type to the key
                raise InvalidMessage(f"a {type(msg).__name__} on a plan key")
            item: bytes | PlanMessage = _as_plan(msg)
            sample = msg.sample
            if self._is_false(item):
                return
            if self._admit(robot_id, sample):
                self.decoded += 1
            else:
                return
        else:
            if robot_id not in self._plans:
                self.validator.refuse(f"plan of robot {robot_id}, not a neighbour")
                raise InvalidMessage(self.validator.last_error)
            item, sample = payload, head[1]
            if not self._admit(robot_id, sample):
                return
        self._plans[robot_id][sample] = item
        self._newest[robot_id] = max(self._newest[robot_id], sample)
        self.received += 1

    def _admit(self, robot_id: int, sample: int) -> bool:
        """Whether a plan of ``sample`` is kept (:meth:`AcceptancePolicy.plan`)."""
        decision = self.policy.plan(self.cursor(), sample, sample in self._plans[robot_id])
        if decision.verdict in (Verdict.ACCEPT, Verdict.STALE):
            count, newest = self.in_order.get(robot_id, (0, -1))
            if sample > newest:
                self.in_order[robot_id] = (count + 1, sample)
        if decision.verdict is Verdict.ACCEPT:
            return True
        if decision.verdict is Verdict.REPEAT:
            self.repeats += 1
        elif decision.verdict is Verdict.STALE:
            self.validator.stale += 1
        else:
            self.validator.refuse(decision.reason)
            raise InvalidMessage(decision.reason)
        return False

    def _is_false(self, plan: PlanMessage) -> bool:
        """Whether ``plan`` does not start where the plant's state of its sample put its
        robot (counted and, the first time, logged with the robot's name)."""
        if self.truth is None:
            return False
        true = self.truth(plan.robot_id, plan.sample)
        if true is None:
            return False
        off = float(np.hypot(*(np.asarray(plan.states[0, :2]) - np.asarray(true[:2]))))
        if off <= START_TOLERANCE:
            return False
        n = self.false[plan.robot_id] = self.false.get(plan.robot_id, 0) + 1
        if n == 1:
            log.warning("robot %d is untrusted: its plan of sample %d starts %.3f m from its "
                        "state (refused, as every such plan)", plan.robot_id, plan.sample, off)
        return True

    def add_decoded(self, msg: PlanMsg) -> None:
        """Keep a plan already decoded and validated (if :meth:`AcceptancePolicy.plan`
        admits it)."""
        if self._is_false(_as_plan(msg)) or not self._admit(msg.id, msg.sample):
            return
        self._plans[msg.id][msg.sample] = _as_plan(msg)
        self._newest[msg.id] = max(self._newest[msg.id], msg.sample)
        self.received += 1

    def has(self, robot_id: int, sample: int) -> bool:
        """Whether a plan of ``sample`` or later from ``robot_id`` is here."""
        return self._newest[robot_id] >= sample

    def has_before(self, robot_id: int, sample: int) -> bool:
        """Whether a plan computed before ``sample`` from ``robot_id`` is here."""
        return any(s < sample for s in self._plans[robot_id])

    def newest_before(self, robot_id: int, sample: int) -> PlanMessage | None:
        """The newest valid plan computed before ``sample`` (decoding it if needed)."""
        stored = self._plans[robot_id]
        for s in sorted((s for s in stored if s < sample), reverse=True):
            plan = self.at(robot_id, s)
            if plan is not None:
                return plan
        return None

    def at(self, robot_id: int, sample: int) -> PlanMessage | None:
        """The valid plan of ``sample`` (decoding it if needed; ``None``: not here)."""
        stored = self._plans[robot_id]
        item = stored.get(sample)
        if item is None or isinstance(item, PlanMessage):
            return item
        try:
            msg = self.validator.check(item, "plan", robot_id)
        except InvalidMessage as exc:
            log.warning("dropped an invalid plan of robot %d (%d invalid so far): %s",
                        robot_id, self.validator.invalid, exc)
            del stored[sample]
            return None
        self.decoded += 1
        if not isinstance(msg, PlanMsg) or msg.sample != sample:
            # cannot happen with a matching header; refuse rather than trust it
            self.validator.refuse(f"plan header of sample {sample} over another body")
            del stored[sample]
            return None
        plan = _as_plan(msg)
        if self._is_false(plan):
            del stored[sample]
            return None
        stored[sample] = plan
        return plan

    def clear(self, robot_id: int) -> None:
        """Forget every plan of ``robot_id`` (it is gone)."""
        self._plans[robot_id].clear()
        self._newest[robot_id] = -1

    def prune(self, before: int) -> None:
        """Forget plans computed before sample ``before``."""
        for rid, stored in self._plans.items():
            for s in [s for s in stored if s < before]:
                del stored[s]
            if not stored:
                self._newest[rid] = -1


class StepPlans(Mapping[int, PlanMessage]):
    """The plans a controller's step may read: per candidate, the newest before ``sample``.

    Reading one decodes it (once); a candidate without a valid plan is absent.

    Parameters
    ----------
    store
        Where the plans are.
    sample
        The sample being computed.
    candidates
        The neighbours whose plans may be read.
    """

    def __init__(self, store: PlanStore, sample: int, candidates: Iterable[int]) -> None:
        self.store = store
        self.sample = sample
        self.candidates = [int(i) for i in candidates]
        self._ids = frozenset(self.candidates)
        self._cache: dict[int, PlanMessage | None] = {}

    def _get(self, robot_id: int) -> PlanMessage | None:
        if robot_id not in self._cache:
            self._cache[robot_id] = self.store.newest_before(robot_id, self.sample)
        return self._cache[robot_id]

    def plan_at(self, robot_id: int, sample: int) -> PlanMessage | None:
        """The plan of candidate ``robot_id`` of ``sample`` (before this step's), if kept
        (:class:`sqpmpc.control.plans.PlanSource`)."""
        if robot_id not in self._ids or sample >= self.sample:
            return None
        return self.store.at(robot_id, sample)

    def __getitem__(self, robot_id: int) -> PlanMessage:
        plan = self._get(robot_id) if robot_id in self._ids else None
        if plan is None:
            raise KeyError(robot_id)
        return plan

    def __iter__(self) -> Iterator[int]:
        return (i for i in self.candidates if self.store.has_before(i, self.sample))

    def __len__(self) -> int:
        return sum(1 for _ in self)

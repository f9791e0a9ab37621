"""What the plant knows of its controllers: who is there, who left, who sends nonsense.

Two mixins of :class:`services.plant.PlantNode` (they use its attributes:
``scheme``, ``mode``, ``k``, ``running``, ``alive``, the timeouts, ...):

- :class:`Presence`: the controllers the scheme needs, those alive, the wait
  for them before sample 0, the lockstep wait for one that left mid-run
  (``--rejoin-timeout``) and the end of a run every controller left;
- :class:`FaultyInputs`: inputs on a robot's key that are inconsistent with
  the run (schema, sample, settings digest), counted per robot; one of the
  current sample with another settings digest brakes that robot at that
  sample.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from .agreement import describe_difference
from .messages import CmdMsg, Message
from .protocol import Verdict

__all__ = ["REJOIN_TIMEOUT", "FaultyInputs", "Presence"]

log = logging.getLogger("services.plant")

REJOIN_TIMEOUT = 30.0
"""Default ``--rejoin-timeout``, s: of the plant (:mod:`services.plant`) and of a ROS 2
robot's controller (:mod:`services.ros2.robot`: how long a peer's controller is gone before
it is told departed)."""


def _robot_of(name: str) -> int | None:
    """The robot of a decentralized controller's liveliness name ``robot/<id>``, else
    ``None`` (the centralized controller's ``central``)."""
    return int(name.split("/")[1]) if name.startswith("robot/") else None


class Presence:
    """The plant's view of its controllers' liveliness (a mixin of the plant node)."""

    scheme: str
    mode: str
    k: int
    ids: list[int]
    alive: set[str]
    running: bool
    missed: dict[int, int]
    departed: dict[str, float]
    gone: set[int]
    all_gone_since: float | None
    rejoin_timeout: float
    startup_timeout: float
    gave_up: str | None
    refusing: set[str]
    silent: set[int]
    status: Any
    stop: Any

    publish_states: Callable[[int], None]  # the plant's
    wait_until: Callable[[Callable[[], bool], float | None], bool]  # the node's

    @property
    def controllers(self) -> list[str]:
        """Liveliness names of the controllers this scheme needs."""
        if self.scheme == "centralized":
            return ["central"]
        return [f"robot/{i}" for i in self.ids]

    def expected(self) -> list[int]:
        """Robots whose controller is alive now and not silent (:meth:`went_silent`)."""
        if self.scheme == "centralized":
            return [i for i in self.ids if i not in self.silent] if "central" in self.alive \
                else []
        return [i for i in self.ids if f"robot/{i}" in self.alive and i not in self.silent]

    def went_silent(self, robots: list[int]) -> None:
        """Lockstep: ``robots`` sent no input within ``--timeout`` while their controller is
        alive (hung, or compromised and silent): braked and not waited for from now on, the
        others going on at their pace, until an input of theirs comes again."""
        fresh = sorted(set(robots) - self.silent)
        if fresh:
            self.silent.update(fresh)
            log.warning("robots %s: alive but silent, braked and not waited for until they "
                        "send again", fresh)

    def spoke(self, rid: int) -> None:
        """An input of robot ``rid`` came (of any sample): waited for again."""
        if rid in self.silent:
            self.silent.discard(rid)
            log.info("robot %d sends again at sample %d: waited for again", rid, self.k)

    # ------------------------------------------------------------------ events
    def on_liveliness(self, name: str, alive: bool) -> None:
        # a controller joining mid-run missed the current sample's states: send them again
        # (the others ignore a sample they already handled); runs on the main thread
        if not self.running or name not in self.controllers:
            return
        if alive:
            self.departed.pop(name, None)
            if (rid := _robot_of(name)) is not None:
                self.gone.discard(rid)
            self.all_gone_since = None
            log.info("%s joined at sample %d", name, self.k)
            self.publish_states(self.k)
            return
        if name in self.refusing:  # it runs other settings: braked, never waited for
            log.info("%s left at sample %d", name, self.k)
            return
        now = time.perf_counter()
        self.departed[name] = now
        if self.scheme == "centralized":  # gone, not silent: waited for as one that left
            self.silent.clear()
        elif (rid := _robot_of(name)) is not None:
            self.silent.discard(rid)
        if not self.expected():
            self.all_gone_since = now
        log.warning("%s left at sample %d%s", name, self.k,
                    f": waiting up to {self.rejoin_timeout:g} s for it to rejoin"
                    if self.mode == "lockstep" else "")

    def awaited(self) -> list[str]:
        """Lockstep: controllers that left less than ``--rejoin-timeout`` ago (the plant
        waits for them); one whose time is up is braked from then on (logged once)."""
        if self.mode != "lockstep":
            return []
        now = time.perf_counter()
        for name, left in list(self.departed.items()):
            if now - left >= self.rejoin_timeout:
                del self.departed[name]
                if (rid := _robot_of(name)) is not None:
                    self.gone.add(rid)
                log.warning("%s did not rejoin within %g s: its robots are braked", name,
                            self.rejoin_timeout)
        return list(self.departed)

    def gone_for_good(self) -> tuple[int, ...]:
        """Robots whose controllers left and did not rejoin within ``--rejoin-timeout``
        (told to every controller in the states message, its ``gone``); in real
        time counted here, in lockstep when :meth:`awaited` stops waiting for them."""
        if self.mode == "realtime":
            now = time.perf_counter()
            self.gone.update(rid for name, left in self.departed.items()
                             if (rid := _robot_of(name)) is not None
                             and now - left >= self.rejoin_timeout)
        return tuple(sorted(self.gone))

    def rejoin_deadline(self) -> float:
        return max((t + self.rejoin_timeout for t in self.departed.values()), default=0.0) \
            if self.mode == "lockstep" else 0.0

    def abandoned(self) -> bool:
        """Every controller left during the run and none came back within
        ``--rejoin-timeout``: the run stops (one error line, status 1)."""
        if self.all_gone_since is None or self.expected():
            return False
        if time.perf_counter() - self.all_gone_since < self.rejoin_timeout:
            return False
        self.gave_up = (f"every controller left ({', '.join(self.controllers)}) and none came "
                        f"back within {self.rejoin_timeout:g} s (--rejoin-timeout): stopping at "
                        f"sample {self.k}")
        log.error("%s", self.gave_up)
        return True

    def wait_for_controllers(self) -> bool:
        """Wait up to ``--startup-timeout`` for every controller's token, with a status
        line every ``--status-every`` s; ``True`` if they all came."""
        start = time.perf_counter()
        period = self.status.period if self.status.period > 0 else self.startup_timeout

        def ready() -> bool:
            return all(c in self.alive for c in self.controllers)

        while True:
            left = start + self.startup_timeout - time.perf_counter()
            if self.wait_until(ready, min(period, left)):
                return True
            if self.stop.is_set() or left <= period:
                return False
            self.status.note(f"waiting for {', '.join(sorted(set(self.controllers) - self.alive))}"
                             f" ({time.perf_counter() - start:.0f} s)")

    def never_controlled(self) -> list[int]:
        """Robots no input ever came for in the samples run (braked all along)."""
        return [int(rid) for rid in self.ids if self.k > 0 and self.missed[rid] >= self.k]



class FaultyInputs:
    """Inputs inconsistent with the run, per robot (a mixin of the plant node)."""

    scheme: str
    k: int
    running: bool
    policy: Any
    agreed: dict[str, str] | None
    faulty: dict[int, int]
    faulty_now: set[int]
    refused: str | None
    refusing: set[str]
    ids: list[int]
    late_commands: int

    def on_mismatch(self, msg: Message, reason: str) -> None:
        if not isinstance(msg, CmdMsg):
            super().on_mismatch(msg, reason)
            return
        # the sample first: an old input is stale whatever it carries (it cannot act)
        decision = self.policy.cmd(self.k, msg.sample)
        if decision.verdict is Verdict.STALE:
            self.late_commands += 1
            return
        if decision.verdict is Verdict.REFUSE or not self.running:
            self.faulty_message(msg.id, decision.reason or reason)
            return
        # an input of this sample from a controller with other settings: that robot is
        # faulty at this sample (braked, not waited for); the run goes on
        self.faulty_message(msg.id, reason)
        # the key's owner (the access control says who may publish there): the central
        # controller holds every robot, a robot itself
        centralized = self.scheme == "centralized"
        owner = "central" if centralized else f"robot/{msg.id}"
        self.faulty_now.update(self.ids if centralized else [msg.id])
        self.refusing.add(owner)  # not waited for when it leaves
        if self.refused is None:
            detail = msg.detail or {}
            who = detail.get("process") or owner
            self.refused = describe_difference(self.agreed or {}, detail or None, who)
            log.error("%s; its robots are braked while it does", self.refused)

    def on_invalid(self, kind: str, key_id: int | None, reason: str) -> None:
        if kind == "cmd" and key_id is not None:
            self.faulty_message(key_id, reason)

    def faulty_message(self, rid: int, reason: str) -> None:
        """Count a message on robot ``rid``'s cmd key inconsistent with the run (schema,
        sample, settings digest); it is dropped (``faulty_messages`` in the metrics)."""
        if rid in self.faulty:
            self.faulty[rid] += 1
            if self.faulty[rid] <= 3 or self.faulty[rid] % 1000 == 0:
                log.warning("robot %d: inconsistent input dropped (%d so far): %s", rid,
                            self.faulty[rid], reason)


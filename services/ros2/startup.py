"""The start-up and waits of a ROS 2 robot's controller (:class:`services.ros2.robot.Ros2Robot`).

Before its first sample a robot publishes plans standing where it is, until the
fleet's epoch and until every neighbour seen alive has sent one; during the run
it announces a phase shift with a standing plan and, before a sample, waits for
a plan in flight of a neighbour that decides before it; when its plan exchange
loses its last link it commands zero.
"""

from __future__ import annotations

import logging
import time

import numpy as np

__all__ = ["PUBLISH_SLACK", "StartUp"]

log = logging.getLogger("services.ros2.robot")

PUBLISH_SLACK = 0.005
"""A plan not ready this long before its instant is dropped: the robot stands still."""


class StartUp:
    """Mixin of :class:`services.ros2.robot.Ros2Robot` (its attributes and methods:
    ``brake``, ``publish_plan``, ``own_state``, ``neighbours``, the node's event pump)."""

    def _wait_for_epoch(self) -> float | None:
        """Publish standing plans until ``--epoch-file`` holds a number (``None``: stopped,
        or a file that is not a number)."""
        while not self.stop.is_set():
            if self.epoch_file.exists():
                text = self.epoch_file.read_text().strip()
                try:
                    return float(text)
                except ValueError:
                    log.error("%s: --epoch-file %s holds %r, not a time in Unix s",
                              self.name, self.epoch_file, text[:40])
                    return None
            self.brake(time.time(), 0)
            self.wait_until(lambda: False, min(self.Ts, 0.2))
        return None

    def _announce(self, start: float) -> None:
        """Publish standing plans until the epoch and until a plan of every neighbour seen
        alive has come (at most ``--timeout``): a robot that moves knows where every
        running neighbour is."""
        deadline = start + self.timeout
        while not self.stop.is_set():
            now = time.time()
            self.brake(now, 0)
            plans = self.neighbours.plans
            alive = [i for i in plans if f"robot/{i}" in self.alive]
            if now >= self.epoch - self.Ts and (all(plans[i] for i in alive)
                                                or now >= deadline):
                break
            self.wait_until(lambda: False, min(self.Ts, 0.2))
        missing = [i for i, kept in self.neighbours.plans.items() if not kept]
        if missing:
            log.warning("%s starts without plans from %s", self.name, missing)

    def _announce_shift(self, sample: int, stamp: float) -> None:
        """A plan standing where the robot stands, stamped a sample before its new instant
        (true: zero until then): the neighbours see when it decides next, instead of a
        plan in flight that holds them by its reach (and shifts them in turn)."""
        N = self.scenario.horizon
        self.publish_plan(sample, stamp, np.repeat(self._standing[None], N + 1, axis=0),
                          np.zeros((N, 2)))

    def _await_plans(self, Tk: float) -> None:
        """Handle events while a plan of a neighbour that decided before this robot is in
        flight (:meth:`services.ros2.neighbours.Neighbours.awaited`), at most until the
        sample's computation must start (``Tk`` less :data:`PUBLISH_SLACK` and twice the
        longest of the recent steps)."""
        self.drain()
        budget = 2.0 * max(self._step_seconds, default=0.05) + PUBLISH_SLACK
        deadline = Tk - budget
        own = self.own_state(Tk)
        if own is None or time.time() >= deadline:
            return
        waited = False
        while not self.stop.is_set() and self.neighbours.awaited(own, Tk, time.time()):
            now = time.time()
            if now >= deadline:
                break
            waited = True
            self.pump(deadline - now)
        self.counts["plan_waits"] += waited

    def plan_network_lost(self) -> bool:
        """Whether the plan exchange's session had a link (a router or a peer) and has none
        now: the neighbours no longer see this robot's plans, nor it theirs."""
        info = self.bus.session.info
        linked = bool(info.routers_zid()) or bool(info.peers_zid())
        if linked:
            self._linked = True
        return self._linked and not linked

    def _stop_if_lost(self) -> bool:
        """Command zero at once when the plan exchange is lost (once per loss); ``True``
        while it is lost."""
        lost = self.plan_network_lost()
        if lost and not self._lost:
            with self._cmd_lock:
                # lost before the zero, under the lock: a sample about to send its command
                # sees it and leaves the zero standing (else its input followed the zero)
                self._lost = True
                self.counts["plan_network_lost"] += 1
                if not self._done:
                    self.command(0.0, 0.0, time.time())
            log.warning("%s: the plan exchange has no link left: commanding zero", self.name)
        elif not lost and self._lost:
            log.info("%s: the plan exchange has a link again", self.name)
        self._lost = lost
        return lost

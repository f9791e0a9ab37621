"""The loop a controller service (robot or central) runs.

It accepts the plant's ``state`` messages by the run's acceptance policy
(:class:`services.protocol.AcceptancePolicy`: a state beyond the run, with an
inconsistent time or older than the cursor is dropped, unless the plant asks for
an older sample again) and, whenever one was accepted since the last step, calls
:meth:`ControllerNode.step_sample` with the ``(n, 3)`` states in scenario
order. In lockstep the plant publishes one sample at a time, so every sample
is handled in order; in real time a controller that falls behind skips to the
newest sample. A repeated state of the sample last handled means the plant
still misses something of it: the controller re-sends what it published for
it (its inputs, a robot's plan too). The loop ends on the plant's ``done``
message, when the plant's liveliness token disappears, or on SIGINT/SIGTERM.
"""

from __future__ import annotations

import argparse
import logging
import time
from dataclasses import dataclass

import numpy as np

from sqpmpc.cli.options import add_controller_options, nonnegative_float, positive_float
from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.problem.scenario import Scenario

from .agreement import ADVICE
from .messages import CmdMsg, DoneMsg, Message, StateMsg, encode
from .node import POLL, Node, options_of
from .protocol import StateCursor, Verdict

__all__ = [
    "RESEND_GAP",
    "STARTUP_TIMEOUT",
    "ControllerNode",
    "SampleStates",
    "add_controller_arguments",
    "controller_settings",
]

log = logging.getLogger(__name__)

STARTUP_TIMEOUT = 120.0
"""Default longest wait for the plant's first state, s."""
RESEND_GAP = 0.01
"""Shortest time between two re-sends of a sample's outputs, s (a flood of repeated
states cannot make a controller flood the network)."""


def add_controller_arguments(parser: argparse.ArgumentParser, timeout_help: str,
                             decentralized: bool = True) -> None:
    """The options both controller services take (read by :func:`controller_settings`):
    the process's own (timeouts, QP time limit) and the run's
    (:func:`sqpmpc.cli.options.add_controller_options`; ``decentralized``: the robots')."""
    parser.add_argument("--timeout", type=positive_float, default=5.0, help=timeout_help)
    parser.add_argument("--qp-time-limit", type=nonnegative_float, default=0.0,
                        help="bound on one QP solve and on one sample's iterations, s (0: "
                             "none); real-time runs pass a fraction of Ts, a QP out of time "
                             "is a counted fallback")
    parser.add_argument("--startup-timeout", type=positive_float, default=STARTUP_TIMEOUT,
                        help="give up with one error line when no state of the plant came "
                             f"within this time, s (default {STARTUP_TIMEOUT:g})")
    add_controller_options(parser, decentralized=decentralized, all_plans=decentralized,
                           overrides=False)


def controller_settings(args: argparse.Namespace, scenario: Scenario | None = None
                        ) -> SolverSettings:
    """The settings of the run's options (:func:`services.node.options_of`);
    ``--qp-time-limit`` bounds each QP and the sample.

    The same value is the sample's ``time_budget``: iterations (the first
    sample's SQP, a sample a rule asks to converge) start no new QP once it is spent.
    The default rules are ``scenario``'s (:func:`sqpmpc.rules.registry.default_names`).
    """
    limit = float(args.qp_time_limit) or None
    return options_of(args).solver_settings(limit, scenario)


@dataclass
class SampleStates:
    """The states of one sample."""

    t: float
    budget: float | None
    states: np.ndarray
    plan_ages: dict[int, dict[int, int]] | None = None
    gone: tuple[int, ...] = ()
    velocities: np.ndarray | None = None

    @property
    def measured(self) -> np.ndarray:
        """What the controllers step on: the poses ``(n, 3)``, with the plant's measured
        velocities ``(n, 5)`` when it sent them (as the in-process loop measures)."""
        if self.velocities is None:
            return self.states
        return np.concatenate((self.states, self.velocities), axis=1)


class ControllerNode(Node):
    """Base of :mod:`services.robot` and :mod:`services.central`.

    Parameters
    ----------
    scenario, args, name
        See :class:`~services.node.Node`; ``args.timeout`` bounds waits for
        peers' messages, ``args.startup_timeout`` the wait for the plant's first
        state (then the process ends with one error line, status 1). Subclasses set
        ``controller`` first.
    """

    controller: CentralizedController | DecentralizedController

    def __init__(self, scenario: Scenario, args: argparse.Namespace, name: str,
                 scheme: str) -> None:
        super().__init__(scenario, args, name, scheme)
        self.mismatch: str | None = None  # the plant runs another scenario or other settings
        self.timeout = float(args.timeout)
        self.startup_timeout = args.startup_timeout
        self.samples: dict[int, SampleStates] = {}
        self.cursor = StateCursor()
        self.pending: int | None = None  # the newest state accepted and not handled yet
        self.last_sample = -1
        self.done: DoneMsg | None = None
        self.plant_lost = False
        self.steps_done = 0
        self.resends = 0
        # what was published per sample computed (the last few), for resend()
        self._outputs: dict[int, list[tuple[bytes, tuple[object, ...]]]] = {}
        self._in_hand = -1
        self._resent_at = 0.0

    # ------------------------------------------------------------------ events
    def on_message(self, kind: str, msg: Message) -> None:
        if isinstance(msg, StateMsg):
            self.on_state(msg)
        elif isinstance(msg, DoneMsg):
            decision = self.policy.done(self.cursor, msg.sample, msg.completed)
            if decision.accepted:
                self.done = msg
            else:
                self._refused(decision.reason)
        else:
            self.on_other(kind, msg)

    def on_state(self, msg: StateMsg) -> None:
        """A valid state message: accept, answer or drop it (the acceptance policy)."""
        decision = self.policy.state(self.cursor, msg.sample, msg.t)
        if decision.accepted:
            self.policy.advance(self.cursor, msg.sample)
            for later in [s for s in self.samples if s > msg.sample]:
                del self.samples[later]  # back to the plant's sample after a forged one
            self.samples[msg.sample] = SampleStates(msg.t, msg.budget, msg.x, msg.plan_ages,
                                                    msg.gone, msg.v)
            self.pending = msg.sample
        elif decision.verdict is Verdict.REPEAT:
            # the plant misses an input of this sample: if it is handled, this process's
            # may be lost; if it is being handled, a robot may wait for a plan of the one
            # before
            if msg.sample == self.last_sample:
                self.resend(msg.sample, inputs=True)
            else:
                self.resend(msg.sample - 1, inputs=False)
        elif decision.verdict is Verdict.STALE:
            self.validator.stale += 1
        else:
            self._refused(decision.reason)

    def sent(self, payload: bytes, *parts: object) -> None:
        """Publish ``payload`` on ``parts`` and keep it for :meth:`resend`."""
        self.bus.put(payload, *parts)
        self._outputs.setdefault(self._in_hand, []).append((payload, parts))

    def resend(self, sample: int, inputs: bool = True) -> None:
        """Publish again what was published for ``sample`` (the plant asked again: a
        message was lost), without the inputs when ``inputs`` is false; at most every
        :data:`RESEND_GAP` s."""
        now = time.monotonic()
        sent = self._outputs.get(sample)
        if not sent or now - self._resent_at < RESEND_GAP:
            return
        self._resent_at = now
        self.resends += 1
        for payload, parts in sent:
            if inputs or parts[-1] != "cmd":
                self.bus.put(payload, *parts)

    def on_other(self, kind: str, msg: Message) -> None:
        """Messages other than state and done (override)."""

    def on_mismatch(self, msg: Message, reason: str) -> None:
        """A state of a plant started with another scenario or other settings: do not step;
        tell the plant this process's settings (a braking ``cmd`` with ``detail``; again
        when it asks again) and end the loop (status 2)."""
        if not isinstance(msg, StateMsg):
            super().on_mismatch(msg, reason)
            return
        if self.mismatch is None:
            what, theirs, mine = ("another scenario", msg.scenario, self.digest)
            if msg.scenario == self.digest:
                what, theirs, mine = ("other settings", msg.settings, self.settings_digest)
            self.mismatch = (f"{self.name}: the plant runs with {what} (digest {theirs}, this "
                             f"process's {mine}; the plant's log names what differs): {ADVICE}")
            log.error("%s", self.mismatch)
        now = time.monotonic()
        if now - self._resent_at < RESEND_GAP:
            return
        self._resent_at = now
        rid = self.ids[0] if self.name == "central" else int(self.name.split("/")[1])
        detail = {**(self.agreed or {}), "process": self.name}
        self.bus.put(encode(CmdMsg(rid, msg.sample, np.zeros(2), 0.0, "settings-mismatch",
                                   self.validator.invalid, None, self.settings_digest,
                                   detail)), "robot", rid, "cmd")

    def on_liveliness(self, name: str, alive: bool) -> None:
        if name == "plant" and not alive:
            self.plant_lost = True

    # -------------------------------------------------------------------- loop
    def _finished(self) -> bool:
        return (self.stop.is_set() or self.done is not None or self.plant_lost
                or self.mismatch is not None)

    def previous_states(self, sample: int) -> np.ndarray | None:
        """The states of ``sample - 1`` if this process has them."""
        prev = self.samples.get(sample - 1)
        return None if prev is None else prev.states

    def step_sample(self, sample: int, entry: SampleStates) -> None:
        """Compute and publish for ``sample`` (override)."""
        raise NotImplementedError

    def publish_cmd(self, robot_id: int, sample: int, u: np.ndarray, compute_time: float,
                    fallback: str | None, plan_ages: dict[int, int] | None = None) -> None:
        """Publish one robot's input for ``sample`` (with its controller's ``plan_ages``,
        which the plant relays)."""
        msg = CmdMsg(robot_id, sample, u, compute_time, fallback, self.validator.invalid,
                     self.controller.counters(), self.settings_digest,
                     plan_ages=plan_ages)
        self.sent(encode(msg), "robot", robot_id, "cmd")

    def run(self) -> int:
        """Serve until the plant is done; returns the exit status."""
        log.info("%s waiting for the plant's states", self.name)
        if not self.wait_until(lambda: self.pending is not None or self._finished(),
                               self.startup_timeout) and self.mismatch is None:
            if self.stop.is_set():
                log.info("%s stopping on signal %s before any state", self.name,
                         self.signals.get("signal"))
                return 0
            log.error("%s: no state from the plant within %.3g s (--startup-timeout): "
                      "is it running with the same --run and endpoints?", self.name,
                      self.startup_timeout)
            return 1
        while not self._finished():
            self.drain()  # so that a late controller skips to the newest sample
            k = self.pending
            if k is None:
                self.pump(POLL)
                continue
            self.pending = None
            entry = self.samples[k]
            self._in_hand = k
            self._outputs.pop(k, None)
            try:
                self.step_sample(k, entry)
            except KeyboardInterrupt:  # OSQP caught the SIGINT during a solve
                self.stop.set()
                break
            self.steps_done += 1
            if entry.budget is not None:  # real time: the samples after the first are timed
                self.raise_priority()
            self.last_sample = k
            while len(self._outputs) > 4:
                del self._outputs[min(self._outputs)]
            for old in [s for s in self.samples if s < min(k, self.cursor.sample) - 1]:
                del self.samples[old]
        if self.mismatch is not None:  # answer the plant's repeats until it gives up
            self.wait_until(lambda: self.done is not None or self.plant_lost
                            or self.stop.is_set(), max(self.timeout, 2.0))
            return 2
        if self.plant_lost and self.done is None and not self.stop.is_set():
            # the token's removal can overtake the plant's last message
            self.wait_until(lambda: self.done is not None, 1.0)
        if self.stop.is_set():
            log.info("%s stopping on signal %s", self.name, self.signals.get("signal"))
            return 0
        if self.done is not None:
            log.info("%s: the plant is done after %d samples (%d computed here, %d invalid "
                     "messages dropped)", self.name, self.done.sample, self.steps_done,
                     self.validator.invalid)
            return 0
        log.error("%s: the plant disappeared without finishing", self.name)
        return 1

"""Live view of a distributed run: Zenoh in, Foxglove's WebSocket out.

``python -m services.viewer --scenario S --run R [--connect EP] [--listen EP]
[--host H] [--port P] [--token T] [--allow-origin O] [--exit-on-done]`` (also
``sqpmpc viewer ...``)

The viewer is a subscriber of the run ``R`` and nothing else: it declares no
liveliness token and publishes nothing on Zenoh. It receives the plant's
states (``plant/state``), the controllers' plans (``robot/<id>/plan``; the
central service publishes one per robot too) and inputs (``robot/<id>/cmd``,
for the solve times), and serves them with Foxglove's WebSocket server
(``foxglove-sdk``) behind :class:`services.wsgate.WebSocketGate` on ``ws://H:P``
(default ``ws://127.0.0.1:8765``), as the topics of :mod:`sqpmpc.recording`
(the same as ``recording.mcap``), stamped with the wall clock. The gate speaks
both subprotocols, ``foxglove.sdk.v1`` and ``foxglove.websocket.v1`` (Foxglove,
Lichtblick, ``@foxglove/ws-protocol``'s client), and admits only the run's
clients: the token (``--token``, default ``$SQPMPC_VIEWER_TOKEN`` or a fresh
random one) in the URL it prints, ``ws://H:P/?token=T``, and browser pages of
the allowed origins only (Foxglove's web app by default; ``--allow-origin``).
Open that URL in Foxglove (desktop or app.foxglove.dev): *Open connection* ->
*Foxglove WebSocket*, add a 3D panel (fixed frame ``world``, topic ``/scene``)
and a Plot panel (``/clearance.min``, ``/solve_time.total_ms`` against
``/solve_time.budget_ms``).

The plant publishes the states of samples ``0 .. K-1`` (those an input is
computed for), so the live view ends one sample before ``trajectory.npz``.
Sample ``k`` is shown as soon as its states, every robot's plan and input of
``k`` have arrived, or ``--wait`` seconds after it began arriving once a later
sample's states are there (a plan travels on another link than the states
and may arrive before or after them). It takes the same scenario options as the other services (the
scenario digest must match, or the states are refused as invalid) and the
same Zenoh options (``--connect`` to the plant's or a router's endpoint, or
``--listen`` on a fixed endpoint that the run's plant connects to:
``services.launch --connect EP``). It runs until Ctrl-C (or, with
``--exit-on-done``, until the plant's ``done``).
"""

from __future__ import annotations

import argparse
import logging
import os
import secrets
import sys
import time

import foxglove
import numpy as np

from sqpmpc.cli.options import Parser, nonnegative_float, port_number
from sqpmpc.io.recording import FleetLog
from sqpmpc.problem.scenario import Scenario

from .messages import CmdMsg, DoneMsg, Message, PlanMsg, StateMsg
from .node import (
    POLL,
    Node,
    add_common_arguments,
    fail,
    install_signal_handlers,
    open_node,
    scenario_from_args,
    setup_logging,
)
from .wsgate import DEFAULT_ORIGINS, WebSocketGate

__all__ = ["ViewerNode", "build_parser", "main"]

log = logging.getLogger(__name__)
PROG = "services.viewer"


class _Sample:
    """What arrived for one sample so far (plans and inputs may come before its states)."""

    def __init__(self, n: int, horizon: int) -> None:
        self.state: StateMsg | None = None
        self.plans = np.full((n, horizon + 1, 3), np.nan)
        self.solve = np.full(n, np.nan)
        self.plan_ids: set[int] = set()
        self.cmds: set[int] = set()
        self.first_seen = time.perf_counter()  # first message of this sample

    def complete(self, n: int) -> bool:
        return self.state is not None and len(self.plan_ids) == n and len(self.cmds) == n


class ViewerNode(Node):
    """A subscriber of a run that shows it on a Foxglove WebSocket server.

    Parameters
    ----------
    scenario
        The run's scenario (with the same overrides).
    args
        Parsed arguments (see :func:`build_parser`).
    """

    def __init__(self, scenario: Scenario, args: argparse.Namespace) -> None:
        self.context = foxglove.Context()
        self.fleet = FleetLog(scenario, self.context)  # channels before any client connects
        self.host = str(args.host)
        self.token = str(args.token)
        # the SDK's server on a loopback port of its own; clients reach it through the gate
        self.server = foxglove.start_server(name=f"sqpmpc {args.run}", host="127.0.0.1",
                                            port=0, context=self.context)
        try:
            self.gate = WebSocketGate(self.host, args.port, int(self.server.port), self.token,
                                      [*DEFAULT_ORIGINS, *args.allow_origin])
        except BaseException:
            self.server.stop()
            raise
        try:
            super().__init__(scenario, args, "viewer")
        except BaseException:
            self.gate.stop()
            self.server.stop()
            raise
        self.exit_on_done = bool(args.exit_on_done)
        self.index = {rid: j for j, rid in enumerate(self.ids)}
        self.pending: dict[int, _Sample] = {}  # samples received, not yet shown
        self.shown = 0  # samples sent to the server
        self.complete = 0  # ... of them with every robot's plan and input
        self.linger = float(args.linger)
        self.wait = float(args.wait)
        self.late = 0  # plans and inputs that came after their sample was shown
        self.shown_upto = -1  # the last sample shown
        self.done = False

    @property
    def port(self) -> int:
        """The port clients connect to (the gate's)."""
        return self.gate.port

    @property
    def url(self) -> str:
        """The URL to open in Foxglove, the token included."""
        return f"ws://{self.host}:{self.port}/?token={self.token}"

    def start_viewing(self) -> None:
        """Subscribe and watch liveliness (no token: the viewer only listens)."""
        for parts in (("plant", "state"), ("plant", "done"), ("robot", "*", "plan"),
                      ("robot", "*", "cmd")):
            self.bus.subscribe(*parts)
        self.bus.watch_liveliness()
        self.signals = install_signal_handlers(self.stop)

    def _entry(self, sample: int) -> _Sample:
        entry = self.pending.get(sample)
        if entry is None:
            entry = self.pending[sample] = _Sample(len(self.ids), self.scenario.horizon)
        return entry

    def _flush(self, everything: bool = False) -> None:
        """Show the pending samples that are complete or waited long enough, in order.

        A sample is shown when its states, every plan and every input have
        arrived, or ``--wait`` seconds after its first message once a later
        sample's states have come (``everything``: all now). Plans and
        inputs of a sample whose states never came are dropped.
        """
        n = len(self.ids)
        now = time.perf_counter()
        newest = max((k for k, e in self.pending.items() if e.state is not None), default=-1)
        for sample in sorted(self.pending):
            entry = self.pending[sample]
            due = everything or (sample < newest and now - entry.first_seen >= self.wait)
            if not (entry.complete(n) or due):
                break
            del self.pending[sample]
            self._show(entry)

    def _show(self, entry: _Sample) -> None:
        """Send one sample to the server."""
        msg = entry.state
        if msg is None:
            return
        solve = entry.solve if entry.cmds else None
        if solve is not None and "central" in self.alive:
            solve = solve[:1]  # every cmd carries the central computation's time
        self.fleet.log_sample(msg.t, msg.x, entry.plans,
                              None if solve is None else np.nan_to_num(solve),
                              log_time=time.time_ns())
        self.shown_upto = msg.sample
        self.shown += 1
        self.complete += entry.complete(len(self.ids))
        if self.shown == 1 or self.shown % 100 == 0:
            log.info("showing sample %d (%d shown)", msg.sample, self.shown)

    def on_message(self, kind: str, msg: Message) -> None:
        n = len(self.ids)
        if isinstance(msg, StateMsg):
            if msg.sample == 0 and self.shown_upto >= 0 and self.done:
                # a new run after the plant's 'done' (sample 0 again before it is the
                # plant re-sending the states to a controller that is late or joined)
                log.info("a new run started")
                self._flush(everything=True)
                self.shown_upto = -1
                self.done = False
            if msg.sample <= self.shown_upto:
                return  # re-sent to a controller that joined late
            entry = self._entry(msg.sample)
            if entry.state is not None:
                return  # likewise
            entry.state = msg
            self._flush()
            return
        if isinstance(msg, DoneMsg):
            log.info("the plant is done after %d samples (%d shown)", msg.sample, self.shown)
            self.done = True
            return
        if msg.sample <= self.shown_upto:
            self.late += 1
            log.debug("late %s of robot %d for sample %d", kind, msg.id, msg.sample)
            return
        entry = self._entry(msg.sample)
        j = self.index[msg.id]
        if isinstance(msg, PlanMsg):
            entry.plans[j] = msg.states
            entry.plan_ids.add(msg.id)
        elif isinstance(msg, CmdMsg):
            entry.solve[j] = msg.compute_time
            entry.cmds.add(msg.id)
        if entry.complete(n):
            self._flush()

    def run(self) -> int:
        """Pump events until Ctrl-C (or the plant's ``done`` with ``--exit-on-done``)."""
        log.info("serving ws://%s:%d for run %s", self.host, self.port,
                 self.bus.prefix.rsplit("/", 1)[-1])
        end = None
        while not self.stop.is_set() and (end is None or time.perf_counter() < end):
            self.pump(POLL)
            self._flush()
            if self.exit_on_done and self.done and end is None:
                end = time.perf_counter() + self.wait  # the last plans and inputs
        self._flush(everything=True)
        log.info("%d samples shown (%d with every plan and input, %d plans or inputs late); "
                 "%d client(s) admitted, refused %d without the token, %d from another "
                 "origin", self.shown, self.complete, self.late, self.gate.admitted,
                 self.gate.refused["token"], self.gate.refused["origin"])
        if self.done and not self.stop.is_set():  # let the server send what is queued
            self.stop.wait(self.linger)
        return 0

    def close(self) -> None:
        """Stop the gate and the server, close the session."""
        try:
            self.gate.stop()
            self.server.stop()
        finally:
            super().close()


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.viewer`` (``sqpmpc viewer``)."""
    parser = Parser(prog=prog, description=__doc__.splitlines()[0])
    add_common_arguments(parser)
    parser.add_argument("--host", default="127.0.0.1",
                        help="address of the WebSocket server (default 127.0.0.1)")
    parser.add_argument("--port", type=port_number, default=8765,
                        help="port of the WebSocket server (default 8765; 0: any free port)")
    parser.add_argument("--token", default=os.environ.get("SQPMPC_VIEWER_TOKEN") or None,
                        help="the secret a client must give (ws://H:P/?token=T or a header "
                             "'Authorization: Bearer T'; default $SQPMPC_VIEWER_TOKEN, else a "
                             "random one, printed with the URL)")
    parser.add_argument("--allow-origin", action="append", default=[], metavar="ORIGIN",
                        help="also admit browser pages of ORIGIN, e.g. http://localhost:8080 "
                             "(repeatable; '*': any; default: "
                             f"{', '.join(DEFAULT_ORIGINS)})")
    parser.add_argument("--exit-on-done", action="store_true",
                        help="exit when the plant says the run is done (default: serve until "
                             "Ctrl-C, also the run's next start)")
    parser.add_argument("--wait", type=nonnegative_float, default=0.25,
                        help="longest wait for a sample's plans and inputs once a later "
                             "sample's states came, s (default 0.25)")
    parser.add_argument("--linger", type=nonnegative_float, default=1.0,
                        help="with --exit-on-done: seconds to keep serving after the run, so "
                             "clients receive what is queued (default 1)")
    return parser


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit status (0, or 2 for bad input)."""
    args = build_parser(prog).parse_args(argv)
    setup_logging(args.log_level, "viewer")
    if args.token is not None and len(args.token) < 16:
        fail(prog, "--token: expected at least 16 characters (a guessable token admits anyone)")
    args.token = args.token or secrets.token_urlsafe(18)
    scenario = scenario_from_args(prog, args)
    try:
        node = open_node(prog, lambda: ViewerNode(scenario, args))
    except (RuntimeError, OSError) as exc:  # the WebSocket server could not bind
        fail(prog, f"cannot serve on {args.host}:{args.port}: {exc}")
    try:
        node.start_viewing()
        print(f"viewer: open {node.url} in Foxglove", flush=True)
        return node.run()
    finally:
        node.close()


if __name__ == "__main__":
    sys.exit(main())

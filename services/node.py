"""What every service process shares: command line, scenario loading, signals, the event pump.

A :class:`Node` owns a :class:`~services.transport.Bus`, a
:class:`~services.validator.MessageValidator` and the set of processes known to
be alive (from liveliness tokens). :meth:`Node.pump` takes one event from the
inbox, validates it and hands it to :meth:`Node.on_message` or
:meth:`Node.on_liveliness`; an invalid message is logged, counted and dropped.
SIGINT and SIGTERM set :attr:`Node.stop`; every wait loop checks it at least
every :data:`POLL` seconds, then the process closes its session and exits.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn, TypeVar

import zenoh

from sqpmpc import __version__
from sqpmpc.cli.options import (
    RunOptions,
    add_override_options,
    positive_float,
    resolve_options,
    with_overrides,
)
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import load_scenario

from .agreement import agreed_settings, scenario_digest, settings_digest
from .credentials import config_for
from .early import RECEIVED
from .faults import FaultInjector
from .limits import interceptors
from .messages import InvalidMessage, Message, Mismatch
from .priority import Priority, check_priority, parse_priority, raise_priority
from .protocol import AcceptancePolicy
from .transport import Bus, Event, check_run_name, run_prefix
from .validator import MessageValidator

__all__ = [
    "POLL",
    "Node",
    "add_common_arguments",
    "add_credential_arguments",
    "fail",
    "install_signal_handlers",
    "open_node",
    "options_of",
    "scenario_digest",
    "scenario_from_args",
    "session_lost",
    "setup_logging",
]

log = logging.getLogger(__name__)

POLL = 0.1
"""Longest time a wait loop blocks before looking at the stop flag, s."""
LOGGED_INVALID = 20
"""Invalid messages logged one by one; after that, one line per thousand."""


def fail(prog: str, message: str, status: int = 2) -> NoReturn:
    """Print one clear error line and exit (status 2: bad user input)."""
    print(f"{prog}: error: {message}", file=sys.stderr)
    raise SystemExit(status)


def setup_logging(level: str, name: str) -> None:
    """Log to stderr with the process name in every line."""
    logging.basicConfig(level=getattr(logging, level.upper(), logging.INFO),
                        format=f"%(asctime)s {name} %(levelname)s %(message)s",
                        stream=sys.stderr)


def add_common_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments every service takes: version, scenario and its overrides, run namespace,
    Zenoh endpoints."""
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--scenario", required=True, help="TOML file or built-in name")
    add_override_options(parser)
    parser.add_argument("--run", default="default", help="run namespace in the key space")
    parser.add_argument("--connect", action="append", default=[], metavar="EP",
                        help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    parser.add_argument("--listen", action="append", default=[], metavar="EP",
                        help="Zenoh endpoint to listen on (repeatable; default "
                             "tcp/127.0.0.1:0 for a peer)")
    parser.add_argument("--zenoh-mode", choices=("peer", "client"), default="peer",
                        help="peer (default) or client of a router")
    parser.add_argument("--max-rate", type=positive_float, default=None, metavar="HZ",
                        help="drop what a robot publishes on one of its keys faster than this "
                             "(services.limits; services.launch passes 20/Ts in real time; "
                             "default: no rate limit, payloads above 64 KiB are always "
                             "dropped)")
    parser.add_argument("--no-flood-limits", action="store_true",
                        help="neither the rate nor the size limit (the opt-out; benchmarks)")
    parser.add_argument("--priority", type=parse_priority, default=None,
                        metavar="off|auto|N",
                        help="scheduling priority of the sample loop in real time "
                             "(services.priority; a lockstep run's loops keep theirs): auto "
                             "(default: SCHED_RR where permitted, else a negative nice, else "
                             "unchanged), off (the opt-out) or a SCHED_RR priority 1-99")
    add_credential_arguments(parser)
    parser.add_argument("--log-level", default="INFO", help="DEBUG, INFO, WARNING, ERROR")


def add_credential_arguments(parser: argparse.ArgumentParser) -> None:
    """``--credentials DIR`` / ``--zenoh-config FILE`` (:func:`services.credentials.config_for`)."""
    parser.add_argument("--credentials", type=Path, default=None, metavar="DIR",
                        help="the run's credentials folder (sqpmpc credentials): this "
                             "process's certificate and Zenoh config (mutual TLS, access "
                             "control) by its identity; endpoints are then tls/...")
    parser.add_argument("--zenoh-config", type=Path, default=None, metavar="FILE",
                        help="a Zenoh config file to start from (e.g. DIR/robot-1.json5)")
    parser.add_argument("--credentials-fd", type=int, default=None, metavar="FD",
                        help="services.launch hands this process its own credentials over "
                             "this inherited socket (services.handover)")


def options_of(args: argparse.Namespace) -> RunOptions:
    """The controller options of ``args`` (resolved once by :func:`scenario_from_args`)."""
    options = getattr(args, "options", None)
    if not isinstance(options, RunOptions):
        options = resolve_options(args)
        args.options = options
    return options


def scenario_from_args(prog: str, args: argparse.Namespace) -> Scenario:
    """Load the scenario with the overrides and resolve the controller options (kept as
    ``args.options``), or exit with status 2 and one message naming the flag."""
    try:
        check_run_name(args.run)
        options = options_of(args)
        return with_overrides(load_scenario(args.scenario), options)
    except (ScenarioError, ProblemError, ValueError) as exc:
        fail(prog, str(exc))


_N = TypeVar("_N")


def open_node(prog: str, factory: Callable[[], _N]) -> _N:
    """``factory()`` (which opens a Zenoh session); a bad endpoint or bad controller
    options (``--rules``, ...) exit with status 2 and one message."""
    try:
        return factory()
    except zenoh.ZError as exc:
        fail(prog, f"cannot open the Zenoh session: {str(exc).split(' at /')[0]}")
    except (ProblemError, ValueError) as exc:  # ValueError: a bad SQPMPC_FAULTS
        fail(prog, str(exc))


def session_lost(prog: str, exc: zenoh.ZError) -> int:
    """Report a Zenoh session that failed mid-run (e.g. timed out on a lossy network) in
    one line, without a traceback; returns the exit status 1."""
    log.error("%s: the Zenoh session failed: %s", prog, str(exc).split(" at /")[0])
    return 1


def install_signal_handlers(stop: threading.Event) -> dict[str, int]:
    """SIGINT and SIGTERM set ``stop``; the returned dict records the signal number (also
    of one received during start-up, :mod:`services.early`: ``stop`` is then set at once)."""
    received: dict[str, int] = {}

    def handler(signum: int, _frame: object) -> None:
        received.setdefault("signal", signum)
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    if hasattr(signal, "pthread_sigmask"):  # started with them blocked (services.early)
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    if "signal" in RECEIVED:  # it came during start-up (services.early)
        handler(RECEIVED["signal"], None)
    return received


class Node:
    """Base of the plant, robot and central services.

    Parameters
    ----------
    scenario
        The problem every process of the run shares.
    args
        Parsed common arguments (run, endpoints, Zenoh mode).
    name
        Liveliness name below ``alive/``, e.g. ``"plant"`` or ``"robot/3"``.
    scheme
        The run's scheme: with it, the settings the processes must agree on
        (:mod:`services.agreement`) are checked; ``None``: not checked.
    """

    def __init__(self, scenario: Scenario, args: argparse.Namespace, name: str,
                 scheme: str | None = None) -> None:
        self.scenario = scenario
        self.name = name
        self.ids = [int(i) for i in scenario.ids]
        self.digest = scenario_digest(scenario)
        self.agreed: dict[str, str] | None = None
        self.settings_digest = ""
        if scheme is not None:
            self.agreed = agreed_settings(scenario, scheme, options_of(args))
            self.settings_digest = settings_digest(self.agreed)
        self.validator = MessageValidator(self.ids, scenario.horizon, self.digest,
                                          self.settings_digest)
        self.policy = AcceptancePolicy(scenario.steps, scenario.sample_time, scenario.horizon)
        self.alive: set[str] = set()
        self.stop = threading.Event()
        self.signals: dict[str, int] = {}
        # auto by default: raised only when a real-time sample loop starts (never in lockstep)
        self.priority: Priority = getattr(args, "priority", None) or Priority("auto")
        try:
            check_priority(self.priority)
        except PermissionError as exc:
            raise ProblemError(str(exc)) from exc
        config = config_for(args, name)
        try:
            self.bus = Bus(args.run, args.listen, args.connect, args.zenoh_mode, config,
                           FaultInjector.from_env(name),
                           None if getattr(args, "no_flood_limits", False) else
                           interceptors(run_prefix(args.run), self.ids, name,
                                        getattr(args, "max_rate", None)))
        except ValueError as exc:
            raise ProblemError(str(exc)) from exc
        self.insecure = config is None
        """This process's Zenoh session runs without credentials (plain, unauthenticated)."""
        if config is None and getattr(args, "insecure", False):  # sqpmpc robot --insecure
            log.warning("INSECURE (--insecure): the plan exchange runs without credentials "
                        "on plain TCP; any process that reaches its endpoints can publish as "
                        "any robot")
        elif config is None:
            log.warning("no --credentials: unauthenticated Zenoh traffic, any process that "
                        "reaches the endpoints can publish on the run's keys")

    def start(self, subscriptions: list[tuple[object, ...]], signals: bool = True) -> None:
        """Subscribe, watch liveliness, then declare this process alive (in that order).

        A peer that sees the token therefore also knows the subscriptions.
        ``signals``: install the SIGINT/SIGTERM handlers that set :attr:`stop`
        (a process hosting several nodes installs them once and shares ``stop``).
        """
        for parts in subscriptions:
            self.bus.subscribe(*parts)
        self.bus.watch_liveliness()
        self.bus.declare_alive(*self.name.split("/"))
        if signals:
            self.signals = install_signal_handlers(self.stop)

    def raise_priority(self) -> None:
        """Put every thread of this process at the ``--priority`` it asked for (once; the
        sample loop starts: :mod:`services.priority`)."""
        if self.priority.mode != "off":
            raise_priority(self.priority, self.name)
            self.priority = Priority("off")

    def close(self) -> None:
        """Close the Zenoh session."""
        self.bus.close()

    # ------------------------------------------------------------------ events
    def on_message(self, kind: str, msg: Message) -> None:
        """Handle a valid message received on a ``kind`` key (override)."""

    def on_liveliness(self, name: str, alive: bool) -> None:
        """A token ``alive/<name>`` appeared or disappeared (override to react)."""

    def on_invalid(self, kind: str, key_id: int | None, reason: str) -> None:
        """A message on a ``kind`` key (of robot ``key_id``) was refused by the validator and
        counted invalid (override to attribute it)."""

    def on_mismatch(self, msg: Message, reason: str) -> None:
        """A message from a process started with another scenario or other settings
        (override; default: dropped as invalid)."""
        self._log_invalid(reason)

    def _dispatch(self, event: Event) -> None:
        parts = self.bus.relative(event.key)
        if parts is None:
            return
        if event.kind in ("alive", "gone"):
            if parts[0] != "alive":
                return
            name = "/".join(parts[1:])
            if event.kind == "alive":
                self.alive.add(name)
            else:
                self.alive.discard(name)
            log.info("%s %s", name, "is alive" if event.kind == "alive" else "is gone")
            self.on_liveliness(name, event.kind == "alive")
            return
        if event.kind != "put":
            return
        if parts[0] == "robot" and (len(parts) == 3 or (len(parts) == 4 and parts[2] == "plan")):
            # robot/<id>/<kind>, or robot/<id>/plan/<to>: a plan addressed to robot <to>
            kind, key_id = parts[2], None
            try:
                key_id = int(parts[1])
            except ValueError:
                pass
            if key_id is None or key_id not in self.validator.ids:
                self._refused(f"message on the key of unknown robot {parts[1]!r}")
                return
        elif len(parts) == 2 and parts[0] == "plant" and parts[1] in ("state", "done"):
            kind, key_id = parts[1], None
        else:
            return
        if key_id is not None and kind == "plan":
            try:
                if self.take_plan(key_id, event.payload):
                    return
            except InvalidMessage as exc:
                self._log_invalid(f"on {event.key}: {exc}")
                return
        try:
            msg = self.validator.check(event.payload, kind, key_id)
        except Mismatch as exc:
            self.on_mismatch(exc.msg, f"on {event.key}: {exc}")
            return
        except InvalidMessage as exc:
            self._log_invalid(f"on {event.key}: {exc}")
            self.on_invalid(kind, key_id, str(exc))
            return
        self.on_message(kind, msg)

    def take_plan(self, robot_id: int, payload: bytes) -> bool:
        """Keep a plan's payload as received, without the full decode (override).

        ``True``: taken (a :class:`~services.plans.PlanStore` checks its header
        now and its body when used); ``False`` (default): decode and hand it to
        :meth:`on_message`. Raises :class:`InvalidMessage` to drop it.
        """
        return False

    def _refused(self, reason: str) -> None:
        self.validator.refuse(reason)
        self._log_invalid(reason)

    def _log_invalid(self, what: str) -> None:
        n = self.validator.invalid
        if n <= LOGGED_INVALID or n % 1000 == 0:  # a flood must not flood the log
            log.warning("dropped an invalid message (%d so far) %s", n, what)

    def pump(self, timeout: float) -> bool:
        """Handle at most one event, waiting up to ``timeout`` s; ``True`` if one came."""
        event = self.bus.get(min(timeout, POLL))
        if event is None:
            return False
        self._dispatch(event)
        return True

    def drain(self) -> None:
        """Handle every event already queued, without waiting."""
        while self.pump(0.0):
            pass

    def wait_until(self, ready: Callable[[], bool], timeout: float | None) -> bool:
        """Pump events until ``ready()`` holds, the timeout expires or a stop is asked.

        Returns
        -------
        bool
            Whether ``ready()`` held.
        """
        deadline = None if timeout is None else time.perf_counter() + timeout
        while True:
            if ready():
                return True
            if self.stop.is_set():
                return False
            remaining = POLL if deadline is None else deadline - time.perf_counter()
            if remaining <= 0.0:
                return ready()
            self.pump(remaining)

"""Helpers for tests and benchmarks that run the services as real processes.

- :func:`start_service` starts ``python -m services.<name> ...`` in its own
  process group with its output in a log file; :func:`stop_processes` stops
  and reaps them (SIGTERM, then SIGKILL).
- :class:`Probe` is a Zenoh peer of a run used to watch liveliness and
  messages and to inject payloads (e.g. malformed ones) on the run's keys.
- :func:`child_pids` lists the children of a process (from ``/proc``).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from sqpmpc.errors import ProblemError

from .children import free_ports
from .node import POLL
from .transport import Bus, Event

__all__ = [
    "INSECURE_FLAGS",
    "REPO",
    "Probe",
    "ProcessId",
    "ServiceProcess",
    "child_pids",
    "free_ports",
    "pid_alive",
    "start_service",
    "stop_processes",
]

REPO = Path(__file__).resolve().parent.parent
"""The project's root (services run with it as working directory)."""
INSECURE_FLAGS = frozenset({"--insecure", "--credentials", "--credentials-fd", "--zenoh-config"})
"""A robot started by :func:`start_service` must be given one of these: credentials, or
``--insecure`` named by its caller (as ``sqpmpc robot`` itself requires)."""


class ServiceProcess:
    """A started service: ``proc`` (``subprocess.Popen``) and its ``log`` file."""

    def __init__(self, name: str, argv: list[str], log: Path,
                 env: dict[str, str] | None = None) -> None:
        self.name = name
        self.argv = argv
        self.log = log
        with open(log, "wb") as fh:
            self.proc = subprocess.Popen(argv, cwd=REPO, stdout=fh, stderr=subprocess.STDOUT,
                                         start_new_session=True, env=env)

    @property
    def pid(self) -> int:
        """Process id (and process group id)."""
        return self.proc.pid

    def output(self) -> str:
        """What the process wrote so far."""
        return self.log.read_text(errors="replace")

    def wait(self, timeout: float) -> int:
        """Wait for the exit status (``subprocess.TimeoutExpired`` after ``timeout``)."""
        return self.proc.wait(timeout=timeout)


def start_service(module: str, args: Sequence[str], log_dir: Path, name: str | None = None,
                  env: dict[str, str] | None = None) -> ServiceProcess:
    """Start ``python -m services.<module> <args>`` with its output in ``log_dir``.

    A robot must be given credentials or ``--insecure`` (:data:`INSECURE_FLAGS`): an
    insecure run is named where it is started, never added here.

    Raises
    ------
    ProblemError
        A robot given none of :data:`INSECURE_FLAGS`.
    """
    name = name or module
    args = list(args)
    if module == "robot" and not INSECURE_FLAGS.intersection(args):
        raise ProblemError(f"start_service('robot', ...) needs credentials or --insecure, "
                         f"named by the caller (one of {sorted(INSECURE_FLAGS)}); got {args}")
    log_dir.mkdir(parents=True, exist_ok=True)
    argv = [sys.executable, "-m", f"services.{module}", *args]
    return ServiceProcess(name, argv, log_dir / f"{name.replace('/', '-')}.log", env)


def stop_processes(procs: Sequence[ServiceProcess], grace: float = 10.0) -> None:
    """SIGTERM every running process group, SIGKILL after ``grace`` s, reap all."""
    for p in procs:
        if p.proc.poll() is None:
            try:
                os.killpg(p.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
    deadline = time.monotonic() + grace
    for p in procs:
        try:
            p.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            try:
                os.killpg(p.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p.proc.wait(timeout=10.0)


class ProcessId(int):
    """A process id with the process's start time (``/proc/<pid>/stat`` field 22, clock
    ticks since boot): :func:`pid_alive` then does not mistake a later process or thread
    that was given the same number (ids wrap at ``kernel.pid_max``, 32,768 on many
    machines, and a suite that starts many threaded processes gets there) for this one."""

    start: int | None

    def __new__(cls, pid: int, start: int | None = None) -> ProcessId:
        self = super().__new__(cls, pid)
        self.start = start
        return self


def _stat(pid: int) -> list[str] | None:
    """The fields of ``/proc/<pid>/stat`` after the command name (state first), or ``None``
    if no process or thread has this id."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()
    except OSError:  # gone, or not ours to read
        return None


def pid_alive(pid: int) -> bool:
    """Whether the process ``pid`` exists and is not a zombie. For a :class:`ProcessId`
    (what :func:`child_pids` returns) also that it is the same process: same start time.
    ``/proc/<id>`` also answers for a thread's id; a thread is not a process here."""
    fields = _stat(pid)
    if fields is None or fields[0] in ("Z", "X"):
        return False
    try:
        with open(f"/proc/{pid}/status") as fh:
            tgid = next(int(ln.split()[1]) for ln in fh if ln.startswith("Tgid:"))
    except (OSError, StopIteration, ValueError):
        return False
    if tgid != pid:
        return False
    start = getattr(pid, "start", None)
    return start is None or int(fields[19]) == start


def child_pids(pid: int) -> list[ProcessId]:
    """The live children of ``pid`` (Linux ``/proc``), each with its start time."""
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        fields = _stat(int(entry))
        if fields is not None and int(fields[1]) == pid and fields[0] not in ("Z", "X"):
            out.append(ProcessId(int(entry), int(fields[19])))
    return out


class Probe:
    """A Zenoh peer in a run, for tests: watch liveliness and messages, inject payloads.

    Parameters
    ----------
    run
        Run name.
    connect
        Endpoints of the run's processes (e.g. the plant's).
    subscriptions
        Key parts below the run prefix to subscribe to, e.g. ``[("plant", "state")]``.
    listen
        Endpoints to listen on (processes started later can connect to the probe).
    config
        A Zenoh config file (e.g. an identity's from :mod:`services.credentials`;
        then the endpoints are ``tls/`` ones).
    mode
        ``"peer"`` or ``"client"`` (of a router in ``connect``).
    """

    def __init__(self, run: str, connect: Sequence[str] = (),
                 subscriptions: Sequence[tuple[object, ...]] = (),
                 listen: Sequence[str] = ("tcp/127.0.0.1:0",),
                 config: Path | None = None, mode: str = "peer") -> None:
        self.bus = Bus(run, listen, connect, mode, config)
        self.alive: set[str] = set()
        self.events: list[Event] = []
        for parts in subscriptions:
            self.bus.subscribe(*parts)
        self.bus.watch_liveliness()

    def _pump(self, timeout: float) -> None:
        event = self.bus.get(min(timeout, POLL))
        if event is None:
            return
        parts = self.bus.relative(event.key) or []
        if event.kind in ("alive", "gone") and parts[:1] == ["alive"]:
            name = "/".join(parts[1:])
            if event.kind == "alive":
                self.alive.add(name)
            else:
                self.alive.discard(name)
        else:
            self.events.append(event)

    def wait_for(self, ready: Callable[[], bool], timeout: float) -> bool:
        """Receive until ``ready()`` or the timeout; returns ``ready()``."""
        deadline = time.monotonic() + timeout
        while not ready():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return ready()
            self._pump(remaining)
        return True

    def wait_alive(self, names: Sequence[str], timeout: float) -> bool:
        """Wait until every ``alive/<name>`` token is present."""
        return self.wait_for(lambda: set(names) <= self.alive, timeout)

    def put(self, payload: bytes, *parts: object) -> None:
        """Publish raw bytes on ``<run prefix>/<parts>``."""
        self.bus.put(payload, *parts)

    def close(self) -> None:
        """Close the session."""
        self.bus.close()

"""Child processes of a launcher: starting them with their own signal set-up, waiting
for them, stopping them (shared by :mod:`services.launch` and :mod:`services.ros2.demo`)."""

from __future__ import annotations

import ctypes
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable

__all__ = ["SIGNAL_READY", "Child", "free_ports", "stop_children", "wait_all"]

log = logging.getLogger("services.launch")

SIGNAL_READY = 5.0


def free_ports(count: int, host: str = "127.0.0.1") -> list[int]:
    """``count`` distinct TCP ports free on ``host`` right now."""
    socks = []
    try:
        for _ in range(count):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind((host, 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def _child_setup(cpu: int | None) -> Callable[[], None]:
    """``preexec_fn`` of a child: die with the launcher (Linux), optionally pin to a CPU."""

    def setup() -> None:
        if sys.platform.startswith("linux"):
            try:
                libc = ctypes.CDLL("libc.so.6", use_errno=True)
                libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
            except OSError:
                pass
            if cpu is not None:
                os.sched_setaffinity(0, {cpu})

    return setup


class Child:
    """A service process in its own process group (same session as the launcher)."""

    def __init__(self, name: str, argv: list[str], cpu: int | None = None,
                 env: dict[str, str] | None = None, pass_fds: tuple[int, ...] = ()) -> None:
        self.name = name
        self.argv = argv
        self.reported = False
        self.proc = subprocess.Popen(argv, process_group=0, env=env, pass_fds=pass_fds,
                                     preexec_fn=_child_setup(cpu))
        log.info("started %s (pid %d)%s", name, self.proc.pid,
                 f" on CPU {cpu}" if cpu is not None else "")

    @property
    def pid(self) -> int:
        """Process id (also the process group id)."""
        return self.proc.pid

    def catches_signals(self, timeout: float = SIGNAL_READY) -> bool:
        """Wait (up to ``timeout`` s) until the child handles SIGTERM (Linux: its
        ``/proc/<pid>/status`` ``SigCgt``): a service does from its first lines on
        (:mod:`services.early`), so a signal sent then cannot hit the interpreter's start
        (a ``KeyboardInterrupt`` traceback, or an end that writes nothing)."""
        deadline = time.monotonic() + timeout
        while self.proc.poll() is None:
            try:
                with open(f"/proc/{self.proc.pid}/status") as fh:
                    caught = next(int(ln.split()[1], 16) for ln in fh
                                  if ln.startswith("SigCgt:"))
            except (OSError, StopIteration, ValueError):
                return False  # not Linux: no way to tell
            if caught & (1 << (signal.SIGTERM - 1)) or time.monotonic() >= deadline:
                return bool(caught & (1 << (signal.SIGTERM - 1)))
            time.sleep(0.01)
        return False

    def signal(self, sig: int) -> None:
        """Send ``sig`` to the child's process group (if it has not been reaped), once it
        handles signals (:meth:`catches_signals`, a few seconds at most)."""
        if sig != signal.SIGKILL:
            self.catches_signals()
        if self.proc.returncode is None:
            try:
                os.killpg(self.proc.pid, sig)
            except (ProcessLookupError, PermissionError):
                pass

    def poll(self) -> int | None:
        """Exit status, or ``None`` while running."""
        return self.proc.poll()


def wait_all(children: list[Child], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while any(c.poll() is None for c in children):
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.05)
    return True


def stop_children(children: list[Child], first: dict[str, int], grace: float) -> None:
    """Signal every running child (``first[name]`` or SIGTERM), then SIGKILL after ``grace``.

    Returns when every child has been reaped.
    """
    for c in children:
        c.signal(first.get(c.name, signal.SIGTERM))
    if not wait_all(children, grace):
        for c in children:
            if c.poll() is None:
                log.warning("%s did not exit in %.0f s: killing it", c.name, grace)
                c.signal(signal.SIGKILL)
        wait_all(children, 10.0)
    for c in children:  # reap
        try:
            c.proc.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            log.error("%s (pid %d) could not be reaped", c.name, c.pid)

"""Hand each process of a launched run its own credentials, and nothing on disk.

:mod:`services.launch` issues the run's certificates in memory
(:func:`services.credentials.issue`) and gives every child one end of a Unix
socket pair (``--credentials-fd FD``). The child first makes itself
non-dumpable (:func:`make_private`: another process of the same user can then
neither ``ptrace`` it nor read its ``/proc/<pid>/mem``, ``environ`` or file
descriptors), then asks for its credentials with one byte; only then does the
launcher send them: a JSON object with the run's ``meta`` and, per identity
the process serves, its Zenoh configuration holding its certificate and
private key inline. The key is never written to a file nor put on a command
line or in the environment, so a process holding robot 2's key has no way to
read another identity's key.
"""

from __future__ import annotations

import ctypes
import json
import socket
import sys
import threading
from typing import Any

from sqpmpc.errors import ProblemError

__all__ = ["PR_SET_DUMPABLE", "Handover", "make_private", "received"]

PR_SET_DUMPABLE = 4
"""``prctl`` option (Linux)."""
ASK = b"?"
"""What a child sends once it is private, to receive its credentials."""
_RECEIVED: dict[int, tuple[dict[str, Any], dict[str, Any]]] = {}


def make_private() -> bool:
    """Make this process non-dumpable (Linux ``prctl(PR_SET_DUMPABLE, 0)``): no core dump,
    and no other unprivileged process of the same user may trace it or read its memory or
    descriptors. Returns whether it was done (``False`` elsewhere than Linux)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_DUMPABLE, 0, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def received(fd: int, timeout: float = 120.0) -> tuple[dict[str, Any], dict[str, Any]]:
    """The ``(meta, configs by identity)`` handed over on socket ``fd`` (read once, then
    kept for this process's other sessions).

    Raises
    ------
    ProblemError
        ``fd`` is not such a socket, or what came is not a handover.
    """
    if fd in _RECEIVED:
        return _RECEIVED[fd]
    make_private()
    try:
        with socket.socket(fileno=fd) as sock:
            sock.settimeout(timeout)
            sock.sendall(ASK)
            chunks = []
            while chunk := sock.recv(1 << 16):
                chunks.append(chunk)
        body = json.loads(b"".join(chunks))
    except (OSError, ValueError) as exc:
        raise ProblemError(f"--credentials-fd {fd}: no credentials handed over ({exc}); "
                           "this option is for services.launch") from None
    if not (isinstance(body, dict) and isinstance(body.get("meta"), dict)
            and isinstance(body.get("configs"), dict)):
        raise ProblemError(f"--credentials-fd {fd}: not a credentials handover")
    _RECEIVED[fd] = (body["meta"], body["configs"])
    return _RECEIVED[fd]


class Handover:
    """The launcher's side: one socket pair per child, served by a thread each.

    Parameters
    ----------
    meta
        The run's credentials metadata (run, identities, ...).
    timeout
        Longest wait for a child to ask, s (then its end is closed: the child
        gets nothing and says so).
    """

    def __init__(self, meta: dict[str, Any], timeout: float = 300.0) -> None:
        self.meta = meta
        self.timeout = timeout
        self.threads: list[threading.Thread] = []
        self._pending: socket.socket | None = None

    def child_end(self, configs: dict[str, Any]) -> int:
        """A new socket pair for a child serving ``configs`` (identity -> Zenoh config):
        returns the child's descriptor (inheritable; close it in the parent once the child
        is started, :meth:`started`); a thread answers the child's request."""
        ours, theirs = socket.socketpair()
        theirs.set_inheritable(True)
        payload = json.dumps({"meta": self.meta, "configs": configs}).encode()
        thread = threading.Thread(target=self._serve, args=(ours, payload), daemon=True,
                                  name="handover")
        thread.start()
        self.threads.append(thread)
        self._pending = theirs
        return theirs.fileno()

    def started(self) -> None:
        """The child of the last :meth:`child_end` was started (or failed to): close the
        parent's copy of its end."""
        if self._pending is not None:
            self._pending.close()
            self._pending = None

    def _serve(self, sock: socket.socket, payload: bytes) -> None:
        with sock:
            sock.settimeout(self.timeout)
            try:
                if sock.recv(1) == ASK:
                    sock.sendall(payload)
            except OSError:
                pass  # the child died or never asked: it has nothing

"""Signals that arrive while a service is still starting (importing its modules).

A service module calls :func:`catch_signals` before its slow imports (numpy,
Zenoh, the compiled kernels: seconds on a busy machine) when it runs as
``__main__``: SIGINT and SIGTERM are then recorded instead of raising
``KeyboardInterrupt`` in the middle of an import (a traceback) or ending the
process before it wrote anything. :func:`services.node.install_signal_handlers`
takes over and honours a signal recorded here: the service stops at once, the
plant writing its (possibly empty) run.

Before this first line, a signal takes its default action: the process ends
before anything exists (no traceback, no child, no run folder). A parent that
must have every stop honoured (a supervisor, :mod:`benchmarks.lifecycle`)
starts the service with SIGINT and SIGTERM blocked (``pthread_sigmask`` in the
child before ``exec``): the kernel then holds a signal sent that early, and
:func:`catch_signals` unblocks both once its handlers are in place, so the
held signal is recorded like any other.
"""

from __future__ import annotations

import signal

__all__ = ["RECEIVED", "catch_signals"]

RECEIVED: dict[str, int] = {}
"""``{"signal": number}`` once a SIGINT or SIGTERM arrived during start-up."""


def catch_signals() -> None:
    """Record SIGINT and SIGTERM in :data:`RECEIVED` from now on."""

    def handler(signum: int, _frame: object) -> None:
        RECEIVED.setdefault("signal", signum)

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    if hasattr(signal, "pthread_sigmask"):  # one held since before exec arrives now
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})

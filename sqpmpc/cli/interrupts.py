"""A Ctrl-C that is never lost inside a QP solve.

OSQP installs its own SIGINT handler for the length of every solve (``osqp_solve``
starts an *interrupt listener* and restores the previous handler when it returns) and
looks at it between iterations. A Ctrl-C that lands after the solver's last look is
taken by OSQP's handler and forgotten: the run goes on (measured: 1 of 30 Ctrl-Cs
lost during ``sqpmpc run``). Blocking SIGINT in the solving thread alone does not
help: the kernel then hands the signal to another thread that does not block it
(numpy's BLAS pool, started at import), where OSQP's handler, installed for the whole
process, takes it just the same.

:func:`forward_interrupts`, called first thing in the process (before numpy, numba or
Zenoh start a thread), blocks SIGINT in the main thread; every thread started later
inherits the mask. One thread, the only one that accepts SIGINT, waits for it with
``sigwait`` and hands it to the main thread as Python's own SIGINT
(:func:`_thread.interrupt_main`): the main thread's handler runs at its next bytecode,
``KeyboardInterrupt`` by default, so a Ctrl-C during a solve takes effect when the solve
returns (a millisecond), and one during Python code at once. OSQP's handler never sees
a signal, so it cannot lose one.

If SIGINT's handler is the default action (``signal.SIG_DFL``) when it arrives, the
process ends at once, without clean-up, as the default action would, with the status a
shell gives a process ended by SIGINT (130; the signal is not re-raised, because during a
solve OSQP's handler would take it); if it is ignored (``signal.SIG_IGN``), nothing
happens.
"""

from __future__ import annotations

import _thread
import os
import signal
import threading

__all__ = ["forward_interrupts", "forwarding"]

_THREAD_NAME = "sqpmpc-sigint"


def forwarding() -> bool:
    """True when this process's SIGINT goes through :func:`forward_interrupts`' thread."""
    return any(t.name == _THREAD_NAME and t.is_alive() for t in threading.enumerate())


def _wait_and_forward() -> None:
    while True:
        signal.sigwait({signal.SIGINT})
        handler = signal.getsignal(signal.SIGINT)
        if handler == signal.SIG_IGN:
            continue
        if handler == signal.SIG_DFL:  # the default action: end now, without clean-up
            # (re-raising the signal could land in OSQP's handler, installed process-wide
            # during a solve, and be lost again)
            os._exit(128 + signal.SIGINT)
        _thread.interrupt_main(signal.SIGINT)


def forward_interrupts() -> bool:
    """Take SIGINT in one waiting thread and hand it to the main thread from now on.

    Call it first thing in a process's entry point, in the main thread, before any
    module that starts threads is imported: a thread started earlier keeps SIGINT
    unblocked and could still receive it. Child processes started later inherit the
    blocked SIGINT (a signal mask survives ``exec``); the project's services unblock
    it themselves (:mod:`services.early`).

    Returns
    -------
    bool
        False, doing nothing, where it cannot work: no ``pthread_sigmask`` (Windows),
        not the main thread, or already forwarding.
    """
    if (not hasattr(signal, "pthread_sigmask") or not hasattr(signal, "sigwait")
            or threading.current_thread() is not threading.main_thread() or forwarding()):
        return False
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    threading.Thread(target=_wait_and_forward, name=_THREAD_NAME, daemon=True).start()
    return True

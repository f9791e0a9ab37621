"""Layer 10, the ``sqpmpc`` command (:mod:`.main`) and the options every command shares
(:mod:`.options`).

:func:`console` is the command's entry point (``sqpmpc``, ``python -m sqpmpc``). This
package's ``__init__`` imports nothing heavy, so that :func:`console` can set up the
process (:mod:`.interrupts`) before numpy, numba or a solver starts a thread.
"""

from __future__ import annotations

import sys

from sqpmpc.cli.interrupts import forward_interrupts

__all__ = ["console"]

# commands that solve QPs in this process, where a Ctrl-C must not be lost in OSQP
_SOLVING_COMMANDS = frozenset({"run"})


def console(argv: list[str] | None = None) -> int:
    """The ``sqpmpc`` command: :func:`sqpmpc.cli.main.main` on ``argv`` (default: the
    process's arguments), with Ctrl-C taken by :func:`.interrupts.forward_interrupts` for
    the commands that solve QPs in this process."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] and argv[0] in _SOLVING_COMMANDS:
        forward_interrupts()
    from sqpmpc.cli.main import main  # the command itself: numpy, the solvers, ...

    return int(main(argv))

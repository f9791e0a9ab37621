"""The test suite. Waits are guarded against hangs only, never budgeted.

A test waits for what it checks (a process's end, a file, a message) however long a busy
machine makes it take; :data:`HANG` is the one limit on such a wait (a subprocess, a
``communicate``, a polling loop), far above what any right run needs at load 20 on 2
cores, so that it only ever catches a hang. pytest-timeout's limit per test (pyproject)
is the same kind of guard.
"""

HANG = 600.0
"""Seconds after which a wait is taken for a hang (not a budget: see the module's doc)."""

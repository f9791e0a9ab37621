"""A Ctrl-C reaches a process that spends its time inside OSQP solves (sqpmpc.cli.interrupts).

OSQP installs its own SIGINT handler during each solve and forgets a signal that lands after
its last look; in a loop of solves that is most Ctrl-Cs (25 of 40 in a stress run without
:func:`forward_interrupts`). Real OSQP solves in a real child process, a real signal.
"""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from tests import HANG

LOOP = """
import sys
from sqpmpc.cli.interrupts import forward_interrupts
assert forward_interrupts()
import signal
import numpy as np, osqp, scipy.sparse as sp
if sys.argv[1] == "default":
    signal.signal(signal.SIGINT, signal.SIG_DFL)
n = 300
M = sp.random(n, n, density=0.05, random_state=1)
P = (M @ M.T + sp.eye(n)).tocsc()
A = sp.vstack([sp.eye(n), sp.random(n, n, density=0.05, random_state=2)]).tocsc()
solver = osqp.OSQP()
solver.setup(P, np.linspace(-1.0, 1.0, n), A, -np.ones(2 * n), np.ones(2 * n), verbose=False)
print("solving", flush=True)
try:
    while True:
        if solver.solve().info.status_val == osqp.SolverStatus.OSQP_SIGINT:
            sys.exit(3)  # OSQP's handler saw it: the forwarding thread should have
except KeyboardInterrupt:
    sys.exit(130)
"""


def _sigint_default() -> None:
    """In the child: SIGINT at its default, as from a terminal (a background job of a
    shell, CI's perhaps, starts with it ignored, and an ignored Ctrl-C stays ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize(("handler", "status"), [("python", 130), ("default", 128 + signal.SIGINT)])
def test_every_ctrl_c_during_solves_reaches_the_main_thread(handler: str, status: int) -> None:
    for _ in range(3):
        proc = subprocess.Popen([sys.executable, "-c", LOOP, handler], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True, preexec_fn=_sigint_default)
        assert proc.stdout is not None and proc.stdout.readline() == "solving\n"
        proc.send_signal(signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=HANG)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            pytest.fail("the Ctrl-C was lost: the process went on solving")
        assert proc.returncode == status, err


def test_forwarding_is_off_where_it_cannot_work() -> None:
    code = ("import threading\nfrom sqpmpc.cli.interrupts import forward_interrupts, forwarding\n"
            "out = []\nt = threading.Thread(target=lambda: out.append(forward_interrupts()))\n"
            "t.start(); t.join()\nprint(out[0], forwarding(), forward_interrupts(), forwarding(),"
            " forward_interrupts())")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=HANG)
    # not from another thread; once from the main thread; not twice
    assert proc.stdout.split() == ["False", "False", "True", "True", "False"], proc.stderr

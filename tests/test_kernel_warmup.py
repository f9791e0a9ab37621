"""``python -m sqpmpc.kernels`` compiles every kernel signature a closed loop uses.

The README promises that no sample, the first one of a service included,
pays for a compilation. A fresh interpreter runs :func:`warm_up`, notes every
kernel's compiled signatures, then runs short closed loops of both schemes
over built-ins that reach every kernel family (paper robots, circle
obstacles, polygons, a door, a swap's roundabout ring, acceleration limits) and the services' input
types (read-only measured states, as decoded from a message): no kernel may
gain a signature. Found by a fresh clone's ``make demo``, where robot
processes spent 2 s of their first sample compiling ``clip_and_roll_out``
for the models' read-only input bounds.
"""

from __future__ import annotations

import json
import subprocess
import sys

PROBE = r"""
import importlib, json, pkgutil
from dataclasses import replace
import numpy as np
from numba.core.registry import CPUDispatcher
import sqpmpc
import sqpmpc.kernels as package
from sqpmpc.kernels.warmup import warm_up

warm_up()
modules = [importlib.import_module(f"sqpmpc.kernels.{m.name}")
           for m in pkgutil.iter_modules(package.__path__)]
kernels = {id(d): (f"{m.__name__}.{n}", d) for m in modules for n, d in vars(m).items()
           if isinstance(d, CPUDispatcher)}
before = {key: len(d.signatures) for key, (_, d) in kernels.items()}


def short(sc):
    return sc.with_changes(t_end=min(sc.t_end, 12 * sc.sample_time))


def limited(sc):
    return sc.with_changes(bounds=replace(sc.bounds, acceleration=(-1.0, 1.0),
                                          angular_acceleration=(-3.0, 3.0)))


for name in ("paper-s2", "corridor", "warehouse", "room-door", "swap-6"):
    for sc in (short(sqpmpc.load_scenario(name)), limited(short(sqpmpc.load_scenario(name)))):
        for scheme in ("centralized", "decentralized"):
            sqpmpc.ClosedLoopSimulation(sc, scheme).run()
# a service's controller: read-only states as a message decoder leaves them
sc = short(sqpmpc.load_scenario("paper-s2"))
ctrl = sqpmpc.DecentralizedController(sc, sc.robots[0].id)
x = np.array(sc.initial_states(), dtype=float)
for k in range(3):
    x.setflags(write=False)
    out = ctrl.step(k, k * sc.sample_time, x)
    x = x.copy()
new = {name: [str(s) for s in d.signatures[before[key]:]]
       for key, (name, d) in kernels.items() if len(d.signatures) > before[key]}
print(json.dumps(new))
"""


def test_no_kernel_compiles_after_the_warm_up() -> None:
    done = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True,
                          timeout=600, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    compiled = json.loads(done.stdout.strip().splitlines()[-1])
    assert compiled == {}, f"kernels compiled after warm_up(): {compiled}"

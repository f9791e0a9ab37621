"""Layer 1, the compiled kernels (numba): the OCP's dynamics and QP helpers (:mod:`.ocp`),
the collision geometry (:mod:`.collision`), the active-set QP backend's
sparse LDL factorization and iteration (:mod:`.kkt`), the rules' kernels (:mod:`.rules`), the
references' (:mod:`.references`), the roadmap planners' (:mod:`.mapf`, LaCAM's
:mod:`.lacam`), a schedule's execution (:mod:`.execution`), the motion along a roadmap
path (:mod:`.motion`), the roundabout's rings
(:mod:`.rings`) and the warm-up (:mod:`.warmup`).

Imports nothing of sqpmpc but :mod:`sqpmpc.errors`.
"""

from __future__ import annotations

__all__: list[str] = []

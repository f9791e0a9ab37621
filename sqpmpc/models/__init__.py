"""Layer 2, robot models: the state and input dimensions, the discrete dynamics and their
Jacobians, the footprint, the bounds (:mod:`.base`, the seam the OCP is written against). The
paper's unicycle is :mod:`.paper` (on the functions of :mod:`.unicycle`); the unicycle with
velocity states and acceleration inputs is :mod:`.acceleration`.
"""

from __future__ import annotations

__all__: list[str] = []

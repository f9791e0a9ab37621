"""Layer 2, robot models: the state and input dimensions, the discrete dynamics and their
Jacobians, the footprint. The paper's unicycle is :mod:`.unicycle`.
"""

from __future__ import annotations

__all__: list[str] = []

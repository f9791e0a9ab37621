"""How the collision rows are shaped: the geometry the rules configure once per controller.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["RowGeometry"]



@dataclass
class RowGeometry:
    r"""How the compiled kernels shape the collision rows (configured by rules once).

    Attributes
    ----------
    rotation
        ``(N, 2)``: :math:`(\cos\theta_i, \sin\theta_i)` of the rotation of the
        stage-``i`` normals (1..N); no rotation by default.
    max_turn
        Largest turn of a pair's normal between consecutive stages, rad, or
        ``None`` (no limit).
    hold_touching
        Decentralized shared rows: pairs inside the margin band repeat their
        stage-1 row on stage 2.
    """

    rotation: np.ndarray
    max_turn: float | None = None
    hold_touching: bool = False

    @classmethod
    def plain(cls, horizon: int) -> RowGeometry:
        """Unrotated Taylor normals, no turn limit, no holding."""
        return cls(np.tile([1.0, 0.0], (horizon, 1)))

    @property
    def kernel_max_turn(self) -> float:
        """``max_turn`` as the kernels take it (``-1`` for no limit)."""
        return -1.0 if self.max_turn is None else float(self.max_turn)

"""The optional ``[roadmap]`` section of a scenario: the grid a map was drawn on.

A scenario written from a grid map (``sqpmpc generate mapf``) declares the cell
size and the centre of one cell; the coordination layer's roadmap
(:mod:`sqpmpc.coordination.roadmap`) then uses exactly those cells.

.. code-block:: toml

    [roadmap]
    cell = 0.5            # m, the grid spacing
    origin = [0.25, 0.25] # m, the centre of one cell
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sqpmpc.errors import ProblemError

__all__ = ["ROADMAP_KEYS", "GridSpec", "grid_edges"]

ROADMAP_KEYS = ("cell", "origin")
"""The keys of the ``[roadmap]`` table."""


@dataclass(frozen=True)
class GridSpec:
    """A declared grid: the cell size and the centre of one cell.

    Parameters
    ----------
    cell
        :math:`h > 0`, m.
    origin
        ``(x, y)`` of a cell centre (a roadmap vertex), m.

    Raises
    ------
    ProblemError
        A cell that is not a finite positive number, an origin that is not two finite
        numbers (messages name the key).
    """

    cell: float
    origin: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        if isinstance(self.cell, bool) or not isinstance(self.cell, int | float) or not (
                math.isfinite(self.cell) and self.cell > 0):
            raise ProblemError(f"cell: expected a finite number > 0 (m), got {self.cell!r}")
        origin = tuple(self.origin) if isinstance(self.origin, list | tuple) else ()
        if len(origin) != 2 or not all(
                isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
                for v in origin):
            raise ProblemError(f"origin: expected an array of 2 finite numbers [x, y] (m), got "
                               f"{self.origin!r}")
        object.__setattr__(self, "cell", float(self.cell))
        object.__setattr__(self, "origin", (float(origin[0]), float(origin[1])))

    def to_dict(self) -> dict[str, object]:
        """The ``[roadmap]`` table."""
        return {"cell": self.cell, "origin": list(self.origin)}


def grid_edges(shape: tuple[int, int]) -> np.ndarray:
    """``(E, 2)`` the 4-neighbour pairs of a ``shape`` grid, as flat (C-order) indices:
    neighbours along the first axis, then along the second."""
    rows, cols = shape
    index = np.arange(rows * cols).reshape(rows, cols)
    first = np.column_stack((index[:-1, :].ravel(), index[1:, :].ravel()))
    second = np.column_stack((index[:, :-1].ravel(), index[:, 1:].ravel()))
    return np.concatenate((first, second))

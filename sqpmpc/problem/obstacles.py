r"""Circular obstacles, static or moving at constant velocity (scenario ``[[obstacles]]``).

An obstacle :math:`o` with centre :math:`c_o(t) = c_o + t\,w_o` and diameter
:math:`d_o` must be kept at :math:`D_{jo} = (d_j + d_o)/2` by every robot
:math:`j`. Both schemes handle obstacles with the separating-hyperplane rows
of the robots' neighbours (:mod:`sqpmpc.ocp.collision_rows`): at stage :math:`i` the
row

.. math::

    n_i^\top p_{j,i} \ge n_i^\top c_o(t_{k+i}) + D_{jo} + \text{margin},
    \qquad n_i = \frac{\bar p_{j,i} - c_o(t_{k+i})}{\lVert\cdot\rVert},

is relinearized at the robot's iterate :math:`\bar p_{j,i}` (the kernel
:func:`sqpmpc.kernels.collision.obstacle_rows`, the row rotation of the rules
included). Stage 1 is hard (stages 2..N carry the L1 slacks of every
collision row); its normal falls back to the current direction when the
iterate's would cut the robot's current position off (``stage-one-override``)
and its right-hand side is capped so that the row stays feasible: at the
current projected gap for a static obstacle (standing still satisfies it),
and for a moving one at what the robot reaches along that normal by moving on
its current heading within its speed bounds (90 % of it, for the
linearization's error). The first input is then verified along the whole
sample: the robot's path (within :func:`sqpmpc.problem.plant.path_deviation` of the
predicted segment) against the obstacle's straight motion
(:func:`sqpmpc.kernels.collision.moving_points_keep_distance`), else a
fallback applies (:mod:`sqpmpc.control.pipeline`).

A static obstacle can therefore never be hit. An obstacle does not cooperate:
a moving one is kept at its one-sample travel more than :math:`D_{jo}`, and
its motion is known over the horizon, but a robot cornered by an obstacle
faster than it can turn away can be hit while it brakes (the braking fallback
is not checked against obstacles: nothing better is known then). Measured in
``docs/real-plants.md``: 48 encounters from 8 directions at up to 0.45 m/s
(75 % of the robots' top speed), both schemes, no collision.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sqpmpc.errors import ProblemError

__all__ = ["Obstacle", "obstacle_positions"]


def _vector(value: object, name: str) -> tuple[float, float]:
    if (not isinstance(value, list | tuple | np.ndarray) or len(value) != 2
            or any(isinstance(x, bool) or not isinstance(x, int | float | np.number)
                   or not math.isfinite(x) for x in value)):
        raise ProblemError(f"{name}: expected an array of 2 finite numbers (m or m/s), "
                           f"found {value!r}")
    return float(value[0]), float(value[1])


@dataclass(frozen=True)
class Obstacle:
    """One circular obstacle (the file's ``[[obstacles]]`` table).

    Parameters
    ----------
    position
        Centre :math:`(x, y)` at :math:`t = 0`, m.
    diameter
        :math:`d_o > 0`, m.
    velocity
        Constant velocity :math:`(w_x, w_y)`, m/s (default at rest).
    """

    position: tuple[float, float]
    diameter: float
    velocity: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", _vector(self.position, "position"))
        object.__setattr__(self, "velocity", _vector(self.velocity, "velocity"))
        d = self.diameter
        if (isinstance(d, bool) or not isinstance(d, int | float | np.number)
                or not math.isfinite(d) or d <= 0):
            raise ProblemError(f"diameter: expected a finite number > 0 (m), found {d!r}")
        object.__setattr__(self, "diameter", float(d))

    @property
    def moving(self) -> bool:
        """Whether the obstacle has a non-zero velocity."""
        return self.velocity != (0.0, 0.0)

    def position_at(self, t: float | np.ndarray) -> np.ndarray:
        """Centre at time(s) ``t``, shape ``np.shape(t) + (2,)``."""
        t = np.asarray(t, dtype=float)
        return np.asarray(self.position) + t[..., None] * np.asarray(self.velocity)

    def to_dict(self) -> dict[str, object]:
        """The ``[[obstacles]]`` table."""
        out: dict[str, object] = {"position": list(self.position), "diameter": self.diameter}
        if self.moving:
            out["velocity"] = list(self.velocity)
        return out


def obstacle_positions(obstacles: Sequence[Obstacle], t: float | np.ndarray) -> np.ndarray:
    """Centres of all obstacles at time(s) ``t``, shape ``np.shape(t) + (O, 2)``."""
    t = np.asarray(t, dtype=float)
    if not obstacles:
        return np.zeros(t.shape + (0, 2))
    return np.stack([o.position_at(t) for o in obstacles], axis=-2)



r"""Circular obstacles, static or moving at constant velocity (scenario ``[[obstacles]]``).

An obstacle :math:`o` with centre :math:`c_o(t) = c_o + t\,w_o` and diameter
:math:`d_o` must be kept at :math:`D_{jo} = (d_j + d_o)/2` by every robot
:math:`j`. Both schemes handle obstacles with the separating-hyperplane rows
of the robots' neighbours (:mod:`sqpmpc.collision`): at stage :math:`i` the
row

.. math::

    n_i^\top p_{j,i} \ge n_i^\top c_o(t_{k+i}) + D_{jo} + \text{margin},
    \qquad n_i = \frac{\bar p_{j,i} - c_o(t_{k+i})}{\lVert\cdot\rVert},

is relinearized at the robot's iterate :math:`\bar p_{j,i}` (the kernel
:func:`sqpmpc.collision_kernels.obstacle_rows`, the row rotation of the rules
included). Stage 1 is hard (stages 2..N carry the L1 slacks of every
collision row); its normal falls back to the current direction when the
iterate's would cut the robot's current position off (``stage-one-override``)
and its right-hand side is capped so that the row stays feasible: at the
current projected gap for a static obstacle (standing still satisfies it),
and for a moving one at what the robot reaches along that normal by moving on
its current heading within its speed bounds (90 % of it, for the
linearization's error). The first input is then verified along the whole
sample: the robot's path (within :func:`sqpmpc.plant.path_deviation` of the
predicted segment) against the obstacle's straight motion
(:func:`sqpmpc.collision_kernels.moving_points_keep_distance`), else a
fallback applies (:mod:`sqpmpc.pipeline`).

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

from .collision_kernels import moving_points_keep_distance, obstacle_rows
from .errors import ProblemError
from .rules import RowGeometry

__all__ = ["Obstacle", "ObstacleRows", "StackedRows", "obstacle_positions"]


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


class ObstacleRows:
    r"""The obstacle rows of ``m`` own robots (a :class:`sqpmpc.rti.CollisionRows`).

    Parameters
    ----------
    obstacles
        The scenario's obstacles (``O`` of them).
    diameters
        ``(m,)`` diameters of the own robots.
    horizon, sample_time
        :math:`N`, :math:`T_s`.
    geometry
        Row geometry from the rules (the rotation is applied, as for neighbours).
    margin
        Added to :math:`D_{jo}` in the QP rows, m.
    """

    needs_states = True

    def __init__(self, obstacles: Sequence[Obstacle], diameters: np.ndarray, horizon: int,
                 sample_time: float, geometry: RowGeometry, margin: float,
                 speed_bounds: tuple[float, float] = (0.0, 0.0)) -> None:
        self.obstacles = tuple(obstacles)
        d_o = np.array([o.diameter for o in self.obstacles])
        d = np.asarray(diameters, dtype=float)
        #: ``(m, O)`` true required distances
        self.safe_distance = 0.5 * (d[:, None] + d_o[None, :])
        # a moving obstacle is kept at its one-sample travel more: however it moves, a
        # robot that stands still for one sample is not caught (cf. missing neighbours)
        reach = float(sample_time) * np.array([math.hypot(*o.velocity) for o in self.obstacles])
        self.required = self.safe_distance + float(margin) + reach[None, :]
        self.horizon = int(horizon)
        self.sample_time = float(sample_time)
        self.geometry = geometry
        self.n_obstacles = len(self.obstacles)
        self._kinds = np.full(self.n_obstacles, 2, dtype=np.int8)  # obstacle slots
        self._stage_offsets = self.sample_time * np.arange(0, self.horizon + 1)
        self.now = np.zeros((self.n_obstacles, 2))
        self.predicted = np.zeros((self.n_obstacles, self.horizon, 2))
        self._next = np.zeros((self.n_obstacles, 2))
        self.current = np.zeros((d.size, 2))
        self._heading = np.zeros((d.size, 2))
        self._moving = np.array([o.moving for o in self.obstacles], dtype=bool)
        self._v_min, self._v_max = (float(v) for v in speed_bounds)
        self._reach = 0.9 * self.sample_time  # a tenth kept for the linearization's error
        self.stage_one_overrides = 0

    def set_sample(self, t: float, current_states: np.ndarray) -> None:
        """Obstacles at ``t`` and over the horizon; the own robots' states ``(m, 3)``."""
        track = obstacle_positions(self.obstacles, t + self._stage_offsets)  # (N+1, O, 2)
        self.now = np.ascontiguousarray(track[0])
        self.predicted = np.ascontiguousarray(np.swapaxes(track[1:], 0, 1))
        self._next = np.ascontiguousarray(track[1])
        self.current = np.ascontiguousarray(current_states[:, :2], dtype=float)
        self._heading = np.stack((np.cos(current_states[:, 2]), np.sin(current_states[:, 2])),
                                 axis=-1)

    def write_rows(self, states: np.ndarray, A_out: np.ndarray, lower_out: np.ndarray) -> None:
        """Rows at the iterate ``states (m, N+1, 3)`` into ``(m, O, N, 2)`` and ``(m, O, N)``."""
        overrides = 0
        for r in range(self.current.shape[0]):
            overrides += obstacle_rows(self.current[r], self.now, states[r, 1:], self.predicted,
                                       self._kinds, self.required[r], 0.0,
                                       self.geometry.rotation, True, A_out[r], lower_out[r])
            # stage 1 hard and feasible: capped at what moving along the current heading
            # can reach (standing still, for a static obstacle: always feasible)
            n1 = A_out[r, :, 0, :]
            along = n1 @ self._heading[r]
            reach = self._reach * np.maximum(self._v_max * along, self._v_min * along)
            cap = n1 @ self.current[r] + np.where(self._moving, np.maximum(reach, 0.0), 0.0)
            np.minimum(lower_out[r, :, 0], cap, out=lower_out[r, :, 0])
        self.stage_one_overrides = overrides

    def first_input_safe(self, now: np.ndarray, nxt: np.ndarray, growth: np.ndarray) -> bool:
        """Every own robot's path ``now (m, 2) -> nxt (m, 2)`` keeps its distance to every
        obstacle over the sample (its path may stray ``growth[r] * s`` from the segment)."""
        for r in range(now.shape[0]):
            if not moving_points_keep_distance(float(now[r, 0]), float(now[r, 1]),
                                               float(nxt[r, 0]), float(nxt[r, 1]), self.now,
                                               self._next, self.safe_distance[r],
                                               float(growth[r])):
                return False
        return True


class StackedRows:
    """Two external row models side by side: ``first``'s ``E1`` slots, then ``second``'s.

    A decentralized robot's neighbour slots followed by the obstacle slots;
    each model writes into its own contiguous scratch (the compiled kernels'
    signatures stay those of the warm-up), copied into the QP's block.
    """

    needs_states = True

    def __init__(self, first: object, second: ObstacleRows, first_slots: int,
                 horizon: int) -> None:
        self.first = first
        self.second = second
        self.first_slots = int(first_slots)
        m = second.current.shape[0]
        self._A1 = np.zeros((m, self.first_slots, horizon, 2))
        self._l1 = np.zeros((m, self.first_slots, horizon))
        self._A2 = np.zeros((m, second.n_obstacles, horizon, 2))
        self._l2 = np.zeros((m, second.n_obstacles, horizon))
        self.stage_one_overrides = 0

    def write_rows(self, states: np.ndarray, A_out: np.ndarray, lower_out: np.ndarray) -> None:
        """Both models' rows into ``A_out (m, E1 + O, N, 2)``, ``lower_out (m, E1 + O, N)``."""
        E1 = self.first_slots
        self.first.write_rows(states, self._A1, self._l1)  # type: ignore[attr-defined]
        self.second.write_rows(states, self._A2, self._l2)
        A_out[:, :E1] = self._A1
        A_out[:, E1:] = self._A2
        lower_out[:, :E1] = self._l1
        lower_out[:, E1:] = self._l2
        self.stage_one_overrides = (self.first.stage_one_overrides  # type: ignore[attr-defined]
                                    + self.second.stage_one_overrides)

"""The obstacle rows of the OCP: circles of :class:`sqpmpc.problem.obstacles.Obstacle`
kept by separating half-planes (:class:`ObstacleRows`), stacked beside other collision
models (:class:`StackedRows`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from sqpmpc.kernels.acceleration import moving_points_keep_bulging_distance
from sqpmpc.kernels.collision import moving_points_keep_distance, obstacle_rows
from sqpmpc.ocp.geometry import RowGeometry
from sqpmpc.problem.obstacles import Obstacle, obstacle_positions

__all__ = ["ObstacleRows", "StackedRows"]



class ObstacleRows:
    r"""The obstacle rows of ``m`` own robots (a :class:`sqpmpc.ocp.report.CollisionRows`).

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
    speed_bounds
        :math:`(v_{\min}, v_{\max})`.
    recovery
        Tolerance of the ``overlap-recovery`` rule, m
        (:func:`sqpmpc.kernels.collision.moving_points_keep_distance`); negative: off.
    """

    needs_states = True

    def __init__(self, obstacles: Sequence[Obstacle], diameters: np.ndarray, horizon: int,
                 sample_time: float, geometry: RowGeometry, margin: float,
                 speed_bounds: tuple[float, float] = (0.0, 0.0),
                 recovery: float = -1.0) -> None:
        self.recovery = float(recovery)
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
        self._t = 0.0
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
        self._t = float(t)
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

    def braking_safe(self, paths: np.ndarray, alpha: np.ndarray, beta: np.ndarray) -> bool:
        """Every own robot's braking path ``paths (m, B+1, 2)`` (stage 1 on, one point a
        sample) keeps its distance to every obstacle as they move on: segment ``j`` against
        the obstacles' motion from stage ``1 + j`` to ``2 + j``; the path may stray
        ``alpha[r, j] s + beta[r, j] s (1 - s)`` from segment ``j`` (``(m, B)`` each)."""
        B = paths.shape[1] - 1
        if B < 1 or not self.n_obstacles:
            return True
        track = obstacle_positions(self.obstacles,
                                   self._t + self.sample_time * np.arange(1, B + 2))
        for j in range(B):
            start = np.ascontiguousarray(track[j])
            end = np.ascontiguousarray(track[j + 1])
            for r in range(paths.shape[0]):
                if not moving_points_keep_bulging_distance(
                        float(paths[r, j, 0]), float(paths[r, j, 1]), float(paths[r, j + 1, 0]),
                        float(paths[r, j + 1, 1]), start, end, self.safe_distance[r],
                        float(alpha[r, j]), float(beta[r, j])):
                    return False
        return True

    def first_input_safe(self, now: np.ndarray, nxt: np.ndarray, growth: np.ndarray,
                         beta: np.ndarray | None = None) -> bool:
        """Every own robot's path ``now (m, 2) -> nxt (m, 2)`` keeps its distance to every
        obstacle over the sample (its path may stray ``growth[r] * s`` from the segment; with
        ``beta``, ``growth[r] s + beta[r] s (1 - s)``); without ``beta``, a robot already
        inside an obstacle's distance comes no closer to it (``overlap-recovery``, if on)."""
        if beta is not None:
            for r in range(now.shape[0]):
                if not moving_points_keep_bulging_distance(
                        float(now[r, 0]), float(now[r, 1]), float(nxt[r, 0]), float(nxt[r, 1]),
                        self.now, self._next, self.safe_distance[r], float(growth[r]),
                        float(beta[r])):
                    return False
            return True
        for r in range(now.shape[0]):
            if not moving_points_keep_distance(float(now[r, 0]), float(now[r, 1]),
                                               float(nxt[r, 0]), float(nxt[r, 1]), self.now,
                                               self._next, self.safe_distance[r],
                                               float(growth[r]), self.recovery):
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

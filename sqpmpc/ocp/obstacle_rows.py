"""The obstacle rows of the OCP: circles of :class:`sqpmpc.problem.obstacles.Obstacle`
kept by separating half-planes (:class:`ObstacleRows`), stacked beside other collision
models (:class:`StackedRows`).

Rows by reach. A map with more than :data:`OBSTACLE_SLOTS` circles (or convex
polygon pieces, :mod:`sqpmpc.ocp.polygon_rows`) gives each robot that many
slots, filled every sample with the obstacles its horizon can reach: those
whose distance from the robot's measured position, less the distance the
robot can travel by each stage (``max_speed`` times the stage's time, one
sample more for the linearization), comes within the required distance,
nearest first (:func:`assign_slots`). The QP's size, and so the cost of a
sample, then depends on the slots, not on the map's size. An obstacle out of
reach cannot be touched by a plan within the speed bound; the first input is
still verified against every obstacle (:meth:`ObstacleRows.first_input_safe`),
so an obstacle within reach left without a slot (more than the slots nearby)
can stop a plan, never be hit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from sqpmpc.kernels.acceleration import moving_points_keep_bulging_distance
from sqpmpc.kernels.collision import moving_points_keep_distance, obstacle_rows
from sqpmpc.ocp.geometry import RowGeometry
from sqpmpc.problem.obstacles import Obstacle, obstacle_positions

__all__ = ["OBSTACLE_SLOTS", "ObstacleRows", "StackedRows", "assign_slots", "map_slots",
           "scenario_map_slots"]

#: Slots per robot for circles, and for polygon pieces, on maps with more of them
#: (``None``: one per circle and per piece). Measured on a 64-box maze with 0.5 m
#: corridors (``docs/speed.md``): 16 slots cost 3.2 times the CPU per robot of the
#: same robots without obstacles, 8 slots 2.6 times (before: 5 times).
OBSTACLE_SLOTS: int | None = 8


def map_slots(n_circles: int, n_pieces: int, slots: int | None = OBSTACLE_SLOTS
              ) -> tuple[int, int]:
    """``(circle slots, piece slots)`` per robot: at most ``slots`` of each (``None``: one
    per circle and per piece, every sample)."""
    if slots is None:
        return int(n_circles), int(n_pieces)
    return min(int(n_circles), int(slots)), min(int(n_pieces), int(slots))


def scenario_map_slots(scenario: object) -> tuple[int, int]:
    """:func:`map_slots` of a :class:`~sqpmpc.problem.scenario.Scenario`'s circles and
    convex polygon pieces."""
    return map_slots(len(scenario.obstacles),  # type: ignore[attr-defined]
                     sum(len(p.pieces) for p in scenario.polygons),  # type: ignore[attr-defined]
                     OBSTACLE_SLOTS)


def assign_slots(gaps: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """The obstacles of ``gaps (O,) <= 0`` in ``K = previous.size`` slots, nearest first.

    An obstacle chosen again keeps its slot of ``previous (K,)`` (warm starts stay
    with their rows); the others fill the empty slots in order of their gap; ``-1``
    marks an empty slot.
    """
    K = previous.size
    within = np.flatnonzero(gaps <= 0.0)
    if within.size > K:
        within = within[np.argpartition(gaps[within], K - 1)[:K]]
    out = np.where(np.isin(previous, within), previous, -1)
    new = within[~np.isin(within, out)]
    new = new[np.argsort(gaps[new], kind="stable")]
    out[np.flatnonzero(out < 0)[:new.size]] = new
    return out



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
    slots
        Rows per robot: fewer than the obstacles fills them every sample with the
        obstacles within reach (module docstring); ``None``: one per obstacle.
    max_speed
        The robots' largest speed, m/s, for the reach (default: the larger speed bound).
    """

    needs_states = True

    def __init__(self, obstacles: Sequence[Obstacle], diameters: np.ndarray, horizon: int,
                 sample_time: float, geometry: RowGeometry, margin: float,
                 speed_bounds: tuple[float, float] = (0.0, 0.0),
                 recovery: float = -1.0, slots: int | None = None,
                 max_speed: float | None = None) -> None:
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
        self.n_all = len(self.obstacles)
        #: rows per robot (slots)
        self.n_obstacles = self.n_all if slots is None else min(int(slots), self.n_all)
        self.selecting = self.n_obstacles < self.n_all
        speed = max(abs(float(v)) for v in speed_bounds) if max_speed is None else float(
            max_speed)
        # travel by stage 0..N, one sample more for the linearization's error
        self._travel = speed * self.sample_time * np.arange(1, self.horizon + 2)
        #: ``(m, K)`` the obstacle in each robot's slot (-1: empty)
        self.slot_obstacles = np.tile(np.arange(self.n_obstacles), (d.size, 1))
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
        if self.selecting:
            # (m, N+1, O): distance to each obstacle at stage k less the travel by then
            distance = np.hypot(track[None, :, :, 0] - self.current[:, None, None, 0],
                                track[None, :, :, 1] - self.current[:, None, None, 1])
            gap = (distance - self._travel[None, :, None]).min(axis=1) - self.required
            for r in range(self.current.shape[0]):
                self.slot_obstacles[r] = assign_slots(gap[r], self.slot_obstacles[r])

    def write_rows(self, states: np.ndarray, A_out: np.ndarray, lower_out: np.ndarray) -> None:
        """Rows at the iterate ``states (m, N+1, 3)`` into ``(m, K, N, 2)`` and ``(m, K, N)``
        (``K`` slots; an empty slot's row is off: zero, lower bound ``-inf``)."""
        overrides = 0
        for r in range(self.current.shape[0]):
            if self.selecting:
                slot = self.slot_obstacles[r]
                empty = slot < 0
                idx = np.where(empty, 0, slot)
                now, predicted, required = self.now[idx], self.predicted[idx], self.required[
                    r, idx]
                kinds = np.where(empty, 0, 2).astype(np.int8)
                moving = self._moving[idx]
            else:
                now, predicted, required = self.now, self.predicted, self.required[r]
                kinds, moving, empty = self._kinds, self._moving, None
            overrides += obstacle_rows(self.current[r], now, states[r, 1:], predicted,
                                       kinds, required, np.zeros(kinds.size),
                                       self.geometry.rotation, True, A_out[r], lower_out[r])
            if empty is not None:
                A_out[r, empty] = 0.0
                lower_out[r, empty] = -np.inf
            # stage 1 hard and feasible: capped at what moving along the current heading
            # can reach (standing still, for a static obstacle: always feasible)
            n1 = A_out[r, :, 0, :]
            along = n1 @ self._heading[r]
            reach = self._reach * np.maximum(self._v_max * along, self._v_min * along)
            cap = n1 @ self.current[r] + np.where(moving, np.maximum(reach, 0.0), 0.0)
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

r"""The polygon-obstacle rows of the OCP (:class:`PolygonRows`) and the obstacle rows of a
map: circles and polygons side by side (:class:`MapRows`).

Each convex piece of every static polygon (:mod:`sqpmpc.problem.polygons`) is one
obstacle slot per robot and stage: the separating line
:math:`n_i^\top p_{j,i} \ge h(n_i) + d_j/2 + \text{margin}` with the closest-point
normal at the iterate and the piece's support value :math:`h`
(:func:`sqpmpc.kernels.polygons.polygon_rows`). Stage 1 is hard and always
feasible (capped at the measured position's value: standing still satisfies
it), and the first input is verified along the whole sample against the true
distance to every piece (:func:`sqpmpc.kernels.polygons.path_keeps_pieces`), as
for circles (:mod:`sqpmpc.ocp.obstacle_rows`). A static polygon can therefore
never be hit. A map of more pieces than the slots gets rows for the pieces
within reach only, as circles do (:mod:`sqpmpc.ocp.obstacle_rows`, *rows by
reach*).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sqpmpc.kernels.polygons import path_keeps_pieces, piece_distances, polygon_rows
from sqpmpc.ocp.geometry import RowGeometry
from sqpmpc.ocp.obstacle_rows import ObstacleRows, assign_slots
from sqpmpc.problem.polygons import PolygonObstacle, pack_pieces

__all__ = ["MapRows", "PolygonRows"]


class PolygonRows:
    """The polygon rows of ``m`` own robots (a :class:`sqpmpc.ocp.report.CollisionRows`).

    Parameters
    ----------
    polygons
        The scenario's polygon obstacles (``P`` convex pieces in all).
    diameters
        ``(m,)`` diameters of the own robots.
    horizon
        :math:`N`.
    geometry
        Row geometry from the rules (kept for the interface; the rotation is not
        applied to walls: tilting a long piece's normal moves its support point
        along it).
    margin
        Added to the radius in the QP rows, m.
    slots
        Rows per robot: fewer than the pieces fills them every sample with the pieces
        within reach; ``None``: one per piece.
    reach
        How far a robot can travel in one sample, m (the selection's: a piece is
        within reach over the horizon and one sample more; only used with ``slots``).
    """

    needs_states = True

    def __init__(self, polygons: Sequence[PolygonObstacle], diameters: np.ndarray,
                 horizon: int, geometry: RowGeometry, margin: float,
                 slots: int | None = None, reach: float = np.inf) -> None:
        self.vertices, self.counts, self.owner = pack_pieces(polygons)
        self.n_all = int(self.counts.size)
        #: rows per robot (slots)
        self.n_obstacles = self.n_all if slots is None else min(int(slots), self.n_all)
        self.selecting = self.n_obstacles < self.n_all
        self._select_reach = float(reach) * (int(horizon) + 1)
        #: ``(m, K)`` the piece in each robot's slot (-1: empty)
        self.slot_pieces = np.tile(np.arange(self.n_obstacles), (np.size(diameters), 1))
        self._distances = np.zeros(self.n_all)
        radius = 0.5 * np.asarray(diameters, dtype=float)
        #: ``(m, P)`` true required distances (the radius)
        self.safe_distance = np.ascontiguousarray(
            np.broadcast_to(radius[:, None], (radius.size, self.n_all)))
        self.required = self.safe_distance + float(margin)
        self.horizon = int(horizon)
        self.geometry = geometry
        # the rules' tilt is for symmetric encounters between robots: tilting a long
        # wall's normal moves its support point metres along the wall, so walls keep
        # the closest-point normal
        self._plain = RowGeometry.plain(self.horizon).rotation
        self.current = np.zeros((radius.size, 2))
        self.stage_one_overrides = 0

    def set_sample(self, t: float, current_states: np.ndarray) -> None:
        """The own robots' measured states ``(m, 3)`` (the polygons do not move); with
        slots, the pieces within reach of each robot into them."""
        self.current = np.ascontiguousarray(current_states[:, :2], dtype=float)
        if self.selecting:
            for r in range(self.current.shape[0]):
                piece_distances(float(self.current[r, 0]), float(self.current[r, 1]),
                                self.vertices, self.counts, self._distances)
                gap = self._distances - self.required[r] - self._select_reach
                self.slot_pieces[r] = assign_slots(gap, self.slot_pieces[r])

    def write_rows(self, states: np.ndarray, A_out: np.ndarray, lower_out: np.ndarray) -> None:
        """Rows at the iterate ``states (m, N+1, 3)`` into ``(m, K, N, 2)``, ``(m, K, N)``
        (``K`` slots; an empty slot's row is off: zero, lower bound ``-inf``)."""
        overrides = 0
        for r in range(self.current.shape[0]):
            if not self.selecting:
                overrides += polygon_rows(self.current[r], states[r, 1:], self.vertices,
                                          self.counts, self.required[r], self._plain,
                                          A_out[r], lower_out[r])
                continue
            slot = self.slot_pieces[r]
            full = np.flatnonzero(slot >= 0)
            idx = slot[full]
            A = np.empty((full.size,) + A_out.shape[2:])
            lower = np.empty((full.size, lower_out.shape[2]))
            overrides += polygon_rows(self.current[r], states[r, 1:], self.vertices[idx],
                                      self.counts[idx], self.required[r, idx], self._plain,
                                      A, lower)
            A_out[r] = 0.0
            lower_out[r] = -np.inf
            A_out[r, full] = A
            lower_out[r, full] = lower
        self.stage_one_overrides = overrides

    def first_input_safe(self, now: np.ndarray, nxt: np.ndarray, growth: np.ndarray,
                         beta: np.ndarray | None = None) -> bool:
        """Every own robot's path ``now (m, 2) -> nxt (m, 2)`` keeps its radius from every
        piece over the sample (straying at most ``growth[r] * s`` from the segment; with
        ``beta``, ``growth[r] s + beta[r] s (1 - s)``, bounded by ``(growth[r] + beta[r]) s``)."""
        if beta is not None:
            growth = np.asarray(growth, dtype=float) + np.maximum(beta, 0.0)
        for r in range(now.shape[0]):
            if not path_keeps_pieces(float(now[r, 0]), float(now[r, 1]), float(nxt[r, 0]),
                                     float(nxt[r, 1]), self.vertices, self.counts,
                                     self.safe_distance[r], float(growth[r])):
                return False
        return True


    def braking_safe(self, paths: np.ndarray, alpha: np.ndarray, beta: np.ndarray) -> bool:
        """Every own robot's braking path ``paths (m, B+1, 2)`` keeps its radius from every
        piece, segment ``j`` straying at most ``(alpha[r, j] + beta[r, j]) s``."""
        for j in range(paths.shape[1] - 1):
            growth = np.asarray(alpha[:, j], dtype=float) + np.maximum(beta[:, j], 0.0)
            if not self.first_input_safe(paths[:, j], paths[:, j + 1], growth):
                return False
        return True


class MapRows:
    """Circle rows (:class:`ObstacleRows`, optional) then polygon rows, as one model.

    Parameters
    ----------
    circles
        The circles' rows, or ``None`` without circular obstacles.
    polygons
        The polygons' rows.
    """

    needs_states = True

    def __init__(self, circles: ObstacleRows | None, polygons: PolygonRows) -> None:
        self.circles = circles
        self.polygons = polygons
        self.first = 0 if circles is None else circles.n_obstacles
        self.n_obstacles = self.first + polygons.n_obstacles
        self.stage_one_overrides = 0

    @property
    def current(self) -> np.ndarray:
        """``(m, 2)`` the own robots' measured positions."""
        return self.polygons.current

    def set_sample(self, t: float, current_states: np.ndarray) -> None:
        """Both models' sample data."""
        if self.circles is not None:
            self.circles.set_sample(t, current_states)
        self.polygons.set_sample(t, current_states)

    def write_rows(self, states: np.ndarray, A_out: np.ndarray, lower_out: np.ndarray) -> None:
        """Circle slots first, then the polygon pieces (contiguous scratch for each)."""
        c = self.first
        overrides = 0
        if self.circles is not None:
            A1 = np.ascontiguousarray(A_out[:, :c])
            l1 = np.ascontiguousarray(lower_out[:, :c])
            self.circles.write_rows(states, A1, l1)
            A_out[:, :c] = A1
            lower_out[:, :c] = l1
            overrides += self.circles.stage_one_overrides
        A2 = np.ascontiguousarray(A_out[:, c:])
        l2 = np.ascontiguousarray(lower_out[:, c:])
        self.polygons.write_rows(states, A2, l2)
        A_out[:, c:] = A2
        lower_out[:, c:] = l2
        self.stage_one_overrides = overrides + self.polygons.stage_one_overrides

    def first_input_safe(self, now: np.ndarray, nxt: np.ndarray, growth: np.ndarray,
                         beta: np.ndarray | None = None) -> bool:
        """Both models' checks of the first input."""
        if self.circles is not None and not self.circles.first_input_safe(now, nxt, growth,
                                                                          beta):
            return False
        return self.polygons.first_input_safe(now, nxt, growth, beta)

    def braking_safe(self, paths: np.ndarray, alpha: np.ndarray, beta: np.ndarray) -> bool:
        """Both models' checks of a braking path."""
        if self.circles is not None and not self.circles.braking_safe(paths, alpha, beta):
            return False
        return self.polygons.braking_safe(paths, alpha, beta)

r"""The polygon-obstacle rows of the OCP (:class:`PolygonRows`) and the obstacle rows of a
map: circles and polygons side by side (:class:`MapRows`).

Each convex piece of every static polygon (:mod:`sqpmpc.problem.polygons`) is kept
by separating lines: at stage :math:`i` of own robot :math:`j`

.. math::

    n_i^\top p_{j,i} \ge h(n_i) + d_j/2 + \text{margin}, \qquad
    h(n) = \max_{v \in \text{piece}} n^\top v,

with the closest-point normal at the iterate and the piece's support value
:math:`h` (:func:`sqpmpc.kernels.polygons.polygon_rows`). Stage 1 is hard and
always feasible (capped at the measured position's value: standing still
satisfies it), and the first input is verified along the whole sample against
the true distance to the pieces (:func:`sqpmpc.kernels.polygons.path_keeps_pieces`),
as for circles (:mod:`sqpmpc.ocp.obstacle_rows`). A static polygon can
therefore never be hit.

Rows by reach
-------------
A map with more pieces than the ``K`` slots per robot (``slots``) gives each
robot ``K`` rows per stage, whose pattern is fixed (a slot's row is a line in
that stage's position whatever piece it holds); they are filled every sample
so that no piece the horizon can reach is left unguarded:

1. **Reach.** With :math:`|v| \le v_{\max}` the robot is at most
   :math:`v_{\max} i T_s` from its measured position :math:`p_0` at stage
   :math:`i`. A piece of signed distance :math:`\delta` from :math:`p_0` with
   :math:`\delta - d > \rho_i = v_{\max} T_s (i + 1)` (``d`` the row's distance,
   one sample more than the travel for the linearization) cannot be touched at
   stage :math:`i`; the others are the stage's *candidates* (a piece beyond
   :math:`\rho_N` is no candidate at all, found with a k-d tree of the pieces'
   centres on large maps, so a sample's cost depends on what is near).
2. **Shadows.** At each stage the candidates are taken by their row's gap at
   the iterate (the most violated first); one whose support lies behind a
   chosen row, :math:`h_c(n) + d \le l` for a chosen :math:`n^\top p \ge l`,
   needs no row: every :math:`p` that keeps the chosen row has
   :math:`\operatorname{dist}(p, c) \ge n^\top p - h_c(n) \ge d`
   (:func:`sqpmpc.kernels.polygons.shadow_select`). In corridors the nearest
   piece on each side shadows the rest of its wall, so a few slots hold a stage.
3. **Overflow.** More unshadowed candidates than slots raise the chosen row
   that needs the least to shadow them all (conservative, never a dropped
   piece), and are counted in :attr:`PolygonRows.overflows` with a warning.

So every candidate is kept by its own row or by a chosen row that implies it,
exactly as the full set of rows would keep it. The checks of the first input
and of braking paths look at the candidates only when the path stays within
:math:`\rho_N` of :math:`p_0` (triangle inequality: every other piece is then
more than its distance away), else at every piece.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
from scipy.spatial import cKDTree

from sqpmpc.errors import ProblemError
from sqpmpc.kernels.polygons import (
    candidate_rows,
    path_keeps_pieces,
    piece_distances,
    polygon_rows,
    shadow_select,
)
from sqpmpc.ocp.geometry import RowGeometry
from sqpmpc.ocp.obstacle_rows import ObstacleRows
from sqpmpc.problem.polygons import PolygonObstacle, pack_pieces

__all__ = ["TREE_PIECES", "MapRows", "PolygonRows"]

_log = logging.getLogger(__name__)

#: Maps of more pieces than this find each robot's candidates with a k-d tree of the
#: pieces' centres instead of measuring the distance to every piece.
TREE_PIECES = 128


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
        Rows per robot and stage ``K``: fewer than the pieces fills them every
        sample by reach and shadows (module docstring); ``None``: one per piece.
    reach
        How far a robot can travel in one sample, m (:math:`v_{\\max} T_s`; only used
        with ``slots``).

    Raises
    ------
    ProblemError
        ``slots`` below 1, or ``reach`` negative or not finite while selecting.
    """

    needs_states = True

    def __init__(self, polygons: Sequence[PolygonObstacle], diameters: np.ndarray,
                 horizon: int, geometry: RowGeometry, margin: float,
                 slots: int | None = None, reach: float = np.inf) -> None:
        self.vertices, self.counts, self.owner = pack_pieces(polygons)
        self.n_all = int(self.counts.size)
        if slots is not None and int(slots) < 1:
            raise ProblemError(f"PolygonRows: slots must be >= 1 or None, got {slots}")
        #: rows per robot and stage (slots)
        self.n_obstacles = self.n_all if slots is None else min(int(slots), self.n_all)
        self.selecting = self.n_obstacles < self.n_all
        self.horizon = int(horizon)
        if self.selecting and not (np.isfinite(reach) and reach >= 0.0):
            raise ProblemError(f"PolygonRows: reach must be finite and >= 0 m, got {reach}")
        #: ``(N,)`` :math:`\\rho_i`: a piece farther than this plus its distance from the
        #: measured position has no row at stage ``i``
        self.stage_reach = float(reach) * np.arange(2, self.horizon + 2) if self.selecting \
            else np.full(self.horizon, np.inf)
        m = int(np.size(diameters))
        #: ``(m, K, N)`` the piece in each robot's slot per stage (-1: empty)
        self.slot_pieces = np.tile(np.arange(self.n_obstacles)[:, None], (m, 1, self.horizon))
        self._distances = np.zeros(self.n_all)
        radius = 0.5 * np.asarray(diameters, dtype=float)
        #: ``(m, P)`` true required distances (the radius)
        self.safe_distance = np.ascontiguousarray(
            np.broadcast_to(radius[:, None], (radius.size, self.n_all)))
        self.required = np.ascontiguousarray(self.safe_distance + float(margin))
        self.geometry = geometry
        # the rules' tilt is for symmetric encounters between robots: tilting a long
        # wall's normal moves its support point metres along the wall, so walls keep
        # the closest-point normal
        self._plain = RowGeometry.plain(self.horizon).rotation
        self.current = np.zeros((m, 2))
        self.stage_one_overrides = 0
        #: stages whose unshadowed candidates outnumbered the slots (a row raised), so far
        self.overflows = 0
        #: per robot: the candidate pieces of the sample (indices)
        self.candidates: list[np.ndarray] = [np.arange(self.n_all)] * m
        self._offsets = np.zeros((0, self.horizon, 2))
        self._gaps: list[np.ndarray] = [np.zeros(self.n_all)] * m
        self._tree = None
        if self.selecting and self.n_all > TREE_PIECES:
            centres = np.array([self.vertices[e, :c].mean(axis=0)
                                for e, c in enumerate(self.counts)])
            self._tree = cKDTree(centres)
            self._spread = float(max(
                np.hypot(*(self.vertices[e, :c] - centres[e]).T).max()
                for e, c in enumerate(self.counts)))

    @property
    def indexed(self) -> bool:
        """Whether the candidates come from the k-d tree (more than :data:`TREE_PIECES`
        pieces, selecting)."""
        return self._tree is not None

    def _nearby(self, r: int) -> tuple[np.ndarray, np.ndarray]:
        """Robot ``r``'s candidates (pieces within :math:`\\rho_N` plus their distance)
        and their gaps :math:`\\delta - d`."""
        px, py = float(self.current[r, 0]), float(self.current[r, 1])
        limit = float(self.stage_reach[-1])
        if self._tree is None:
            piece_distances(px, py, self.vertices, self.counts, self._distances)
            gap = self._distances - self.required[r]
            cand = np.flatnonzero(gap <= limit)
            return cand, gap[cand]
        # the centre of a piece within reach is within reach + distance + its spread
        near = np.asarray(self._tree.query_ball_point(
            (px, py), limit + float(self.required[r].max()) + self._spread), dtype=np.int64)
        near.sort()
        out = np.empty(near.size)
        piece_distances(px, py, self.vertices[near], self.counts[near], out)
        gap = out - self.required[r, near]
        keep = gap <= limit
        return near[keep], gap[keep]

    def set_sample(self, t: float, current_states: np.ndarray) -> None:
        """The own robots' measured states ``(m, 3)`` (the polygons do not move); with
        slots, each robot's candidate pieces."""
        self.current = np.ascontiguousarray(current_states[:, :2], dtype=float)
        if self.selecting:
            self._gaps = []
            for r in range(self.current.shape[0]):
                cand, gap = self._nearby(r)
                self.candidates[r] = cand
                self._gaps.append(gap)

    def write_rows(self, states: np.ndarray, A_out: np.ndarray, lower_out: np.ndarray) -> None:
        """Rows at the iterate ``states (m, N+1, 3)`` into ``(m, K, N, 2)``, ``(m, K, N)``
        (``K`` slots; an empty slot's row is off: zero, lower bound ``-inf``)."""
        overrides = 0
        N = self.horizon
        for r in range(self.current.shape[0]):
            if not self.selecting:
                overrides += polygon_rows(self.current[r], states[r, 1:], self.vertices,
                                          self.counts, self.required[r], self._plain,
                                          A_out[r], lower_out[r])
                continue
            cand = self.candidates[r]
            C = cand.size
            A_all = np.empty((C, N, 2))
            l_all = np.empty((C, N))
            flags = np.zeros(C, dtype=np.bool_)
            candidate_rows(self.current[r], states[r, 1:], self.vertices, self.counts, cand,
                           self.required[r], self._plain, A_all, l_all, flags)
            if self._offsets.shape[0] < C:
                self._offsets = np.zeros((C, N, 2))
            active = self._gaps[r][:, None] <= self.stage_reach[None, :]
            overflows = shadow_select(A_all, l_all, self.vertices[cand], self.counts[cand],
                                      self._offsets[:C], self.required[r, cand],
                                      states[r, 1:], active, cand, A_out[r], lower_out[r],
                                      self.slot_pieces[r])
            if overflows:
                if not self.overflows:
                    _log.warning(
                        "obstacle rows by reach: %d stage(s) of robot slot %d had more "
                        "unshadowed pieces within reach than its %d slots; a row was raised "
                        "to keep them all (conservative)", overflows, r, self.n_obstacles)
                self.overflows += overflows
            if flags.any():
                overrides += int(np.isin(self.slot_pieces[r, :, 0], cand[flags]).sum())
        self.stage_one_overrides = overrides

    def _pieces_for(self, r: int, extent: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pieces, counts and radii to check for robot ``r``'s path within ``extent`` of its
        measured position: the candidates when the path stays within :math:`\\rho_N`."""
        if self.selecting and extent <= float(self.stage_reach[-1]):
            cand = self.candidates[r]
            return self.vertices[cand], self.counts[cand], self.safe_distance[r, cand]
        return self.vertices, self.counts, self.safe_distance[r]

    def first_input_safe(self, now: np.ndarray, nxt: np.ndarray, growth: np.ndarray,
                         beta: np.ndarray | None = None) -> bool:
        """Every own robot's path ``now (m, 2) -> nxt (m, 2)`` keeps its radius from every
        piece over the sample (straying at most ``growth[r] * s`` from the segment; with
        ``beta``, ``growth[r] s + beta[r] s (1 - s)``, bounded by ``(growth[r] + beta[r]) s``).

        A piece that is no candidate is more than :math:`\\rho_N` plus its distance from
        the measured position :math:`p_0`; a path within ``extent`` of :math:`p_0`
        (:math:`\\max(|now - p_0|, |nxt - p_0|)` plus the growth) keeps it when
        ``extent`` :math:`\\le \\rho_N`, so only the candidates are checked then.
        """
        if beta is not None:
            growth = np.asarray(growth, dtype=float) + np.maximum(beta, 0.0)
        for r in range(now.shape[0]):
            extent = max(float(np.hypot(*(now[r, :2] - self.current[r]))),
                         float(np.hypot(*(nxt[r, :2] - self.current[r])))) + max(
                float(growth[r]), 0.0)
            vertices, counts, keep = self._pieces_for(r, extent)
            if not path_keeps_pieces(float(now[r, 0]), float(now[r, 1]), float(nxt[r, 0]),
                                     float(nxt[r, 1]), vertices, counts, keep,
                                     float(growth[r])):
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

r"""Static polygon obstacles: walls and shelves (scenario ``[[obstacles]]`` with ``points``).

A polygon obstacle is a simple polygon (at least 3 vertices, either
orientation, edges that do not cross). A robot :math:`j` keeps its radius
:math:`d_j / 2` from the polygon's boundary and never enters it. The
controllers keep it with separating lines, one per *convex piece* of the
polygon (:attr:`PolygonObstacle.pieces`: the polygon itself when convex, else
a decomposition of its constrained Delaunay triangulation into convex parts):
at stage :math:`i`

.. math::

    n_i^\top p_{j,i} \ge h_P(n_i) + \frac{d_j}{2} + \text{margin},
    \qquad h_P(n) = \max_{v \in P} n^\top v,

with :math:`n_i` the unit direction from the piece's closest point to the
predicted position (the rules' rotation applied) and :math:`h_P` the piece's
support value, so the line separates the whole piece whatever the normal
(:mod:`sqpmpc.ocp.polygon_rows`, kernels :mod:`sqpmpc.kernels.polygons`).
Metrics measure the true distance (:func:`polygon_clearances`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import Polygon

from sqpmpc.errors import ProblemError

__all__ = ["MAX_VERTICES", "PolygonObstacle", "pack_pieces", "polygon_clearances"]

_AREA_RTOL = 1e-9
#: Most vertices a polygon obstacle may have (its convex pieces are rows of every QP).
MAX_VERTICES = 128


def _points(value: object) -> tuple[tuple[float, float], ...]:
    what = (f"an array of 3 to {MAX_VERTICES} vertices [x, y] of finite numbers (m)")
    if (not isinstance(value, list | tuple | np.ndarray) or len(value) < 3
            or len(value) > MAX_VERTICES):
        raise ProblemError(f"points: expected {what}, found {value!r}")
    out = []
    for v in value:
        if (not isinstance(v, list | tuple | np.ndarray) or len(v) != 2
                or any(isinstance(x, bool) or not isinstance(x, int | float | np.number)
                       or not math.isfinite(x) for x in v)):
            raise ProblemError(f"points: expected {what}, found vertex {v!r}")
        out.append((float(v[0]), float(v[1])))
    return tuple(out)


def _convex(poly: Polygon) -> bool:
    return poly.convex_hull.area <= poly.area * (1.0 + _AREA_RTOL) + 1e-12


def _ccw(poly: Polygon) -> np.ndarray:
    """Exterior vertices counter-clockwise, without the closing repeat, ``(V, 2)``."""
    ring = shapely.geometry.polygon.orient(poly, 1.0).exterior
    return np.asarray(ring.coords, dtype=float)[:-1]


def _decompose(poly: Polygon) -> list[Polygon]:
    """Convex pieces covering ``poly`` (greedy merge of its constrained triangulation)."""
    if _convex(poly):
        return [poly]
    tris = [t for t in shapely.constrained_delaunay_triangles(poly).geoms if t.area > 0.0]
    pieces = list(tris)
    merged = True
    while merged:  # grow each piece by its neighbours while the union stays convex
        merged = False
        a = 0
        while a < len(pieces):
            b = a + 1
            while b < len(pieces):
                union = None
                if pieces[a].intersection(pieces[b]).length > 1e-12:  # a shared edge
                    union = shapely.union(pieces[a], pieces[b]).simplify(0.0)
                if isinstance(union, Polygon) and _convex(union):
                    pieces[a] = union
                    del pieces[b]
                    merged = True
                else:
                    b += 1
            a += 1
    return pieces


@dataclass(frozen=True)
class PolygonObstacle:
    """One static polygon obstacle (an ``[[obstacles]]`` table with ``points``).

    Parameters
    ----------
    points
        Vertices :math:`(x, y)`, m, 3 to :data:`MAX_VERTICES`, in either
        orientation, forming a simple polygon of positive area.

    Raises
    ------
    ProblemError
        Too few or non-finite vertices, zero area, or crossing edges (named
        ``points: ...`` so that the scenario loader names the key).
    """

    points: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        pts = _points(self.points)
        object.__setattr__(self, "points", pts)
        ring = shapely.geometry.LinearRing(pts)
        if not ring.is_simple:
            reason = shapely.is_valid_reason(Polygon(pts))
            at = reason.partition("[")[2].rstrip("]").split()
            where = f" near ({float(at[0]):.6g}, {float(at[1]):.6g})" if len(at) == 2 else ""
            raise ProblemError("points: expected a simple polygon (edges that do not cross "
                               f"or touch), found a self-intersecting one{where}")
        if Polygon(pts).area <= 1e-12:
            raise ProblemError("points: expected a polygon of positive area, found area 0")

    @functools.cached_property
    def shape(self) -> Polygon:
        """The polygon as a shapely geometry."""
        return Polygon(self.points)

    @functools.cached_property
    def pieces(self) -> tuple[np.ndarray, ...]:
        """Convex pieces covering the polygon, each ``(V, 2)`` counter-clockwise."""
        return tuple(_ccw(p) for p in _decompose(self.shape))

    def signed_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance of ``points (..., 2)`` to the boundary, negative inside, m."""
        pts = np.asarray(points, dtype=float)
        flat = pts.reshape(-1, 2)
        dist = shapely.distance(self.shape.exterior, shapely.points(flat))
        inside = shapely.contains_xy(self.shape, flat[:, 0], flat[:, 1])
        return np.where(inside, -dist, dist).reshape(pts.shape[:-1])

    def to_dict(self) -> dict[str, object]:
        """The ``[[obstacles]]`` table."""
        return {"points": [list(p) for p in self.points]}


def pack_pieces(polygons: Sequence[PolygonObstacle]) -> tuple[np.ndarray, np.ndarray,
                                                              np.ndarray]:
    """Every polygon's convex pieces in padded arrays for the kernels.

    Returns
    -------
    tuple of np.ndarray
        ``vertices (P, V, 2)`` (counter-clockwise, padded with the last vertex),
        ``counts (P,)`` int64 and ``owner (P,)`` int64: the polygon of each piece.
    """
    pieces = [(o, piece) for o, poly in enumerate(polygons) for piece in poly.pieces]
    width = max((p.shape[0] for _, p in pieces), default=3)
    vertices = np.zeros((len(pieces), width, 2))
    counts = np.zeros(len(pieces), dtype=np.int64)
    owner = np.zeros(len(pieces), dtype=np.int64)
    for e, (o, p) in enumerate(pieces):
        vertices[e, :p.shape[0]] = p
        vertices[e, p.shape[0]:] = p[-1]
        counts[e] = p.shape[0]
        owner[e] = o
    return vertices, counts, owner


def polygon_clearances(polygons: Sequence[PolygonObstacle], radii: np.ndarray,
                       positions: np.ndarray, path_positions: np.ndarray | None,
                       tolerance: float) -> tuple[int, float | None, float | None]:
    """Collisions and clearances of robots against polygons, at samples and between.

    Parameters
    ----------
    polygons
        The obstacles.
    radii
        ``(n,)`` robot radii.
    positions
        ``(k+1, n, 2)`` at the samples.
    path_positions
        ``(S, n, 2)`` along the true paths (consecutive points move straight), or
        ``None``.
    tolerance
        A clearance below ``-tolerance`` is a collision.

    Returns
    -------
    tuple
        ``(collisions, min clearance at samples, min clearance between samples)``
        over (sample, robot, polygon) and (interval, robot, polygon) entries;
        the intervals are the path pieces of one sample taken together.
    """
    if not polygons:
        return 0, None, None
    radii = np.asarray(radii, dtype=float)
    collisions = 0
    at_best = math.inf
    between_best = math.inf
    k1 = positions.shape[0]
    for poly in polygons:
        clearance = poly.signed_distance(positions) - radii[None, :]
        collisions += int(np.count_nonzero(clearance < -tolerance))
        at_best = min(at_best, float(clearance.min()))
        if path_positions is None or k1 < 2:
            continue
        a, b = path_positions[:-1], path_positions[1:]  # (S-1, n, 2)
        per_sample = (path_positions.shape[0] - 1) // (k1 - 1)
        # only the pieces near the polygon are measured exactly
        x0, y0, x1, y1 = poly.shape.bounds
        reach = float(radii.max()) + 1.0
        lo = np.minimum(a, b)
        hi = np.maximum(a, b)
        near = ((hi[..., 0] >= x0 - reach) & (lo[..., 0] <= x1 + reach)
                & (hi[..., 1] >= y0 - reach) & (lo[..., 1] <= y1 + reach))
        piece = np.full(a.shape[:2], math.inf)
        if near.any():
            lines = shapely.linestrings(np.stack((a[near], b[near]), axis=1))
            dist = shapely.distance(poly.shape, lines)  # 0 when the piece enters
            piece[near] = dist - np.broadcast_to(radii, a.shape[:2])[near]
        per_interval = piece.reshape((k1 - 1, per_sample) + piece.shape[1:]).min(axis=1)
        collisions += int(np.count_nonzero(per_interval < -tolerance))
        between_best = min(between_best, float(per_interval.min()))
    if path_positions is None or k1 < 2:
        return collisions, at_best, None
    # every path piece farther than a radius + 1 m from every polygon's box: no closer
    # than at the samples' nearest
    return collisions, at_best, between_best if math.isfinite(between_best) else at_best

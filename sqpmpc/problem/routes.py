r"""Routes through the static map: shortest collision-free paths around walls and pillars.

A :class:`RoadMap` inflates every static obstacle (polygons, and circles at
rest) by a robot's clearance (its radius plus a margin) with shapely, merges
them, and builds the *visibility graph* of the merged outlines' vertices
(networkx): two vertices are joined when the straight segment between them
stays outside the inflated map. A route from a start to a goal adds both
points to the graph and takes the shortest path (Dijkstra), so it is the
shortest path among the inflated obstacles (up to the outlines: polygons are
inflated with mitred corners, circles by circumscribed octagons). A start or a
goal inside the inflation band (closer than the margin, not the radius) is
joined to its nearest outline point first. There is no route when the goal
is nearer an obstacle than the radius or no path connects the two.

A scenario's ``[bounds]`` ``x``/``y`` box (it bounds the robot's centre) is part
of the map: the routes stay inside it (a frame around the box, not inflated by
the radius), so a route never leads where the NMPC may not go; a goal outside
the box has no route.

:class:`Route` is the polyline with its arc length; the route rule
(:mod:`sqpmpc.rules.routes`) time-parametrizes it at the robot's speed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import LineString, Point, box
from shapely.ops import nearest_points, unary_union

from sqpmpc.problem.obstacles import Obstacle
from sqpmpc.problem.polygons import PolygonObstacle

__all__ = ["RoadMap", "Route", "route_lengths", "scenario_box"]

_SIDES = 8  # circles become circumscribed octagons
_EPS = 1e-6  # the outline itself counts as free


@dataclass(frozen=True)
class Route:
    """A polyline route.

    Attributes
    ----------
    points
        ``(K, 2)`` vertices from the start to the goal, m.
    """

    points: np.ndarray

    @property
    def cumulative(self) -> np.ndarray:
        """``(K,)`` arc length at each vertex, m."""
        steps = np.hypot(*np.diff(self.points, axis=0).T)
        return np.concatenate(([0.0], np.cumsum(steps)))

    @property
    def length(self) -> float:
        """Total length, m."""
        return float(self.cumulative[-1])

    def position_at(self, s: float | np.ndarray) -> np.ndarray:
        """Points at arc length(s) ``s`` (clipped to the route), shape ``np.shape(s) + (2,)``."""
        cum = self.cumulative
        s = np.clip(np.asarray(s, dtype=float), 0.0, cum[-1])
        x = np.interp(s, cum, self.points[:, 0])
        y = np.interp(s, cum, self.points[:, 1])
        return np.stack((x, y), axis=-1)

    def project(self, point: np.ndarray, lower: float = 0.0) -> tuple[float, float]:
        """Arc length of the route point nearest ``point`` (at least ``lower``) and the
        distance to it, m."""
        cum = self.cumulative
        a, b = self.points[:-1], self.points[1:]
        d = b - a
        den = np.maximum((d * d).sum(axis=1), 1e-18)
        s = np.clip(((point - a) * d).sum(axis=1) / den, 0.0, 1.0)
        along = cum[:-1] + s * np.sqrt(den)
        along = np.maximum(along, lower)
        closest = self.position_at(along)
        dist = np.hypot(*(closest - point).T)
        k = int(np.argmin(dist))
        return float(along[k]), float(dist[k])


class RoadMap:
    """The visibility graph of the static map for one clearance.

    Parameters
    ----------
    polygons
        Polygon obstacles.
    circles
        Circular obstacles; only those at rest are part of the map.
    radius
        The robot's radius: nearer than this to an obstacle nothing can go, m.
    margin
        Added to ``radius`` for the inflation the routes keep, m.
    bounds
        ``(lower, upper)``, each ``(x, y)``, of the robot centre's position
        (``-inf``/``inf`` where unbounded; ``None``: no box): the routes stay
        inside it.
    """

    def __init__(self, polygons: Sequence[PolygonObstacle], circles: Sequence[Obstacle],
                 radius: float, margin: float,
                 bounds: tuple[Sequence[float], Sequence[float]] | None = None) -> None:
        self.radius = float(radius)
        self.clearance = float(radius) + float(margin)
        c = self.clearance
        shapes = [p.shape.buffer(c, join_style="mitre", mitre_limit=2.0) for p in polygons]
        grow = 1.0 / math.cos(math.pi / _SIDES)
        shapes += [Point(o.position).buffer((0.5 * o.diameter + c) * grow, quad_segs=_SIDES // 4)
                   for o in circles if not o.moving]
        self.bare = unary_union([p.shape for p in polygons]
                                + [Point(o.position).buffer(0.5 * o.diameter, quad_segs=16)
                                   for o in circles if not o.moving])
        outside = _outside(self.bare, bounds)
        self._outside = outside
        if outside is not None:  # the centre's box: not inflated by the radius
            shapes.append(outside)
        self.inflated = unary_union(shapes)
        hard = self.bare.buffer(self.radius)
        if outside is not None:
            hard = hard.union(outside)
        self._hard = hard.buffer(-_EPS)
        shapely.prepare(self._hard)
        self.empty = self.inflated.is_empty
        self._inner = self.inflated.buffer(-_EPS)
        shapely.prepare(self._inner)
        import networkx as nx  # here: ~0.1 s of every process's start, for maps only

        self.graph = nx.Graph()
        nodes: list[tuple[float, float]] = []
        if not self.empty:
            for poly in getattr(self.inflated, "geoms", [self.inflated]):
                for ring in (poly.exterior, *poly.interiors):
                    nodes += [tuple(map(float, p)) for p in np.asarray(ring.coords)[:-1]]
        self.nodes = np.array(nodes, dtype=float).reshape(-1, 2)
        for i, p in enumerate(self.nodes):
            self.graph.add_node(i, pos=p)
        n = len(self.nodes)
        if n > 1:
            i, j = np.triu_indices(n, 1)
            lines = shapely.linestrings(np.stack((self.nodes[i], self.nodes[j]), axis=1))
            free = ~shapely.intersects(self._inner, lines)
            for a, b in zip(i[free], j[free], strict=True):
                self.graph.add_edge(int(a), int(b),
                                    weight=float(np.hypot(*(self.nodes[a] - self.nodes[b]))))

    def free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Whether the straight segment ``a -> b`` stays outside the inflated map."""
        if self.empty:
            return True
        if np.allclose(a, b):
            return not self._inner.contains(Point(a))
        return not self._inner.intersects(LineString([tuple(a), tuple(b)]))

    def sees(self, p: np.ndarray, points: np.ndarray, keep: float = 0.0) -> np.ndarray:
        """Whether the robot's centre at ``p`` can go straight to each of ``points (K, 2)``
        without coming nearer an obstacle than its radius plus ``keep`` (the room the
        collision rows keep; a robot standing nearer than that: than it stands now),
        ``(K,)`` bool. A robot whose rows hold it farther off a corner than a line grazes
        it stays pinned against the corner, tracking a point it sees only by its radius."""
        if self.empty:
            return np.ones(len(points), dtype=bool)
        lines = shapely.linestrings(np.stack((np.broadcast_to(p, points.shape), points),
                                             axis=1))
        seen = ~shapely.intersects(self._hard, lines)
        if keep > 0.0 and not self.bare.is_empty:
            now = float(self.bare.distance(Point(p)))
            need = min(self.radius + float(keep), now) - _EPS
            seen &= shapely.distance(self.bare, lines) >= need
        return seen

    def away_from_walls(self, p: np.ndarray) -> tuple[float, np.ndarray]:
        """Clearance of a robot centred at ``p`` (distance to the static map minus the
        radius, m) and the unit direction from the nearest obstacle point to ``p``."""
        if self.bare.is_empty:
            return math.inf, np.array([1.0, 0.0])
        point = Point(p)
        q = np.asarray(nearest_points(self.bare, point)[0].coords[0])
        d = np.asarray(p, dtype=float) - q
        norm = float(np.hypot(*d))
        away = d / norm if norm > 1e-12 else np.array([1.0, 0.0])
        return norm - self.radius, away

    def _entry(self, p: np.ndarray) -> list[np.ndarray] | None:
        """``[p]``, or ``[p, nearest outline point]`` inside the band; ``None`` if too near."""
        point = Point(p)
        if self.empty or not self._inner.contains(point):
            return [np.asarray(p, dtype=float)]
        if self.bare.distance(point) < self.radius or (
                self._outside is not None and self._outside.contains(point)):
            return None
        q = np.asarray(nearest_points(self.inflated.boundary, point)[0].coords[0])
        out = q - np.asarray(p)
        norm = float(np.hypot(*out))
        if norm > 0.0:
            q = q + out / norm * 2.0 * _EPS
        return [np.asarray(p, dtype=float), q]

    def route(self, start: np.ndarray, goal: np.ndarray) -> Route | None:
        """The shortest route ``start -> goal`` around the inflated map, or ``None``."""
        start = np.asarray(start, dtype=float)
        goal = np.asarray(goal, dtype=float)
        head, tail = self._entry(start), self._entry(goal)
        if head is None or tail is None:
            return None
        a, b = head[-1], tail[-1]
        if self.free(a, b):
            return Route(np.array(head + tail[::-1]))
        import networkx as nx

        g = self.graph.copy()
        n = len(self.nodes)
        for name, p in ((n, a), (n + 1, b)):
            g.add_node(name, pos=p)
            if n:
                lines = shapely.linestrings(
                    np.stack((np.broadcast_to(p, self.nodes.shape), self.nodes), axis=1))
                free = ~shapely.intersects(self._inner, lines)
                for k in np.flatnonzero(free):
                    g.add_edge(name, int(k), weight=float(np.hypot(*(self.nodes[k] - p))))
        try:
            path = nx.dijkstra_path(g, n, n + 1, weight="weight")
        except nx.NetworkXNoPath:
            return None
        middle = [self.nodes[k] for k in path[1:-1]]
        return Route(np.array(head + middle + tail[::-1]))


def _outside(bare: object, bounds: tuple[Sequence[float], Sequence[float]] | None
             ) -> object | None:
    """The frame outside the box ``bounds`` (``None``: no box), as wide as the map and
    the box together plus a metre, so every vertex stays finite."""
    if bounds is None:
        return None
    lo, hi = np.asarray(bounds[0], dtype=float), np.asarray(bounds[1], dtype=float)
    if not (np.isfinite(lo).any() or np.isfinite(hi).any()):
        return None
    finite = np.concatenate((lo[np.isfinite(lo)], hi[np.isfinite(hi)]))
    extent = float(np.abs(finite).max()) + 1.0
    if not bare.is_empty:  # type: ignore[attr-defined]
        extent = max(extent, float(np.abs(bare.bounds).max()) + 1.0)  # type: ignore[attr-defined]
    far = 2.0 * extent
    a = np.where(np.isfinite(lo), lo, -far)
    b = np.where(np.isfinite(hi), hi, far)
    inner = box(float(a[0]), float(a[1]), float(max(b[0], a[0])), float(max(b[1], a[1])))
    return box(-2.0 * far, -2.0 * far, 2.0 * far, 2.0 * far).difference(inner)


def scenario_box(scenario: object) -> tuple[np.ndarray, np.ndarray] | None:
    """The ``[bounds]`` ``x``/``y`` box of a scenario's robot centres, or ``None``."""
    bounds = getattr(scenario, "bounds", None)
    if bounds is None or (bounds.x is None and bounds.y is None):
        return None
    return bounds.position_lower(), bounds.position_upper()


def route_lengths(scenario: object, goals: np.ndarray, margin: float = 0.0
                  ) -> list[float | None]:
    """Length of every robot's shortest route from its initial position to ``goals (n, 2)``
    (``None``: no route), with ``margin`` beyond its radius, inside the scenario's
    ``[bounds]`` box."""
    polygons = tuple(getattr(scenario, "polygons", ()))
    circles = tuple(getattr(scenario, "obstacles", ()))
    frame = scenario_box(scenario)
    starts = scenario.initial_states()[:, :2]  # type: ignore[attr-defined]
    radii = 0.5 * scenario.diameters()  # type: ignore[attr-defined]
    maps: dict[float, RoadMap] = {}
    out: list[float | None] = []
    for p, g, r in zip(starts, goals, radii, strict=True):
        road = maps.setdefault(float(r), RoadMap(polygons, circles, float(r), margin, frame))
        route = road.route(p, g)
        out.append(None if route is None else route.length)
    return out

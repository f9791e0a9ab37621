r"""The roadmap: a grid graph of the free space at the robots' own footprint.

Vertices are the points of a square grid of spacing :math:`h` that lie farther
than the robots' *clearance* :math:`c` (the largest radius plus the margin the
obstacle rows keep) from every static obstacle (polygons, circles at rest) and
inside the scenario's ``[bounds]`` box; two vertices are joined when they are grid
neighbours (4-connected) and the segment between them keeps the same clearance.
The robots' own starts and goals are vertices too: a start or goal point within
:math:`\rho` of a grid vertex *is* that vertex (its robot still ends on its own
point), any other one replaces the grid vertices nearer than :math:`h` and joins
every vertex within :math:`\sqrt{5/2}\, h` that it sees with clearance (the
farthest its nearest kept grid vertex can be: from the centre of a cell, whose
corners it removed), else the nearest vertex it sees; points nearer than
:math:`h` to each other are one vertex. Where no grid tried (below) joins every robot's
start to its goal (off-grid goals crowding an aisle remove the grid vertices between
them, and their rings may not reach each other), the one that joins the most is
*bridged*: the smaller of a robot's two components is joined to the rest by its
shortest segment that keeps the clearance :math:`c` (not the tube: a bridge is where the
map leaves no room for it), until every robot's start and goal are joined
or no free segment is left (each bridge joins two components, so there are fewer
bridges than components).

**The tube keeps the clearance.** A robot is anywhere within :math:`\rho` of its way
(its reach, below), and its motion rounds corners within :math:`\rho`
(:mod:`sqpmpc.coordination.motion`). Without a declared grid the grid's vertices and
edges therefore keep :math:`c + \rho` from the obstacles and :math:`\rho` inside the
``[bounds]`` box, so that the whole tube keeps :math:`c`: with :math:`c` alone a
robot's way along a shelf kept 3 cm to spare, its corner arc 1 cm, and the robot,
pressed into the obstacle row at the shelf's corner and heading into it, stood for the
rest of the run (warehouse family, 8 robots, seed 1). The narrower free space can make
the plan harder to find (warehouse family, 64 robots, seeds 1 and 2: LaCAM ran over
90 s on their tube roadmaps in pure Python; compiled, with the swap technique, it plans the
tube roadmaps of seeds 0-5 in 0.004-0.02 s), so the fleet
(:mod:`sqpmpc.coordination.fleet`) takes the tube roadmap where prioritized planning
solves it and otherwise the thinner roadmap whose vertices and edges keep :math:`c` alone
(``tube=False``), prioritized planning and then LaCAM on it. LaCAM on the tube first
would find a plan there too, but a longer one (warehouse family, 64 robots, seed 5: 174
steps, against 47 on the thinner roadmap by prioritized planning).
A declared grid's reach is at
most :math:`h/2 - c` (below), so its free cells' centres and the segments between them
keep :math:`c + \rho` already.

Why this graph
--------------
Let :math:`s` be the largest distance the collision rows keep between two robots
(the required distance plus the solver's and the plant's margins). The grid is
built with

.. math::

    h \ge s + 2 \rho, \qquad \rho > 0,

so that **two robots each within** :math:`\rho` **of distinct vertices keep**
:math:`s`: the plans on the graph (:mod:`sqpmpc.coordination.mapf`) never put
two robots on one vertex, and the execution (:mod:`sqpmpc.coordination.schedule`)
lets a robot head for a vertex only when the robot that held it before is within
:math:`\rho` of its next one. :math:`\rho` is also how close a robot must come
to a vertex to have *reached* it. A scenario written from a grid map
(``sqpmpc generate mapf``) declares its cell size and origin (``[roadmap]``),
which are then the grid's: :math:`\rho = (h - s) / 2` must be positive, i.e. a
cell wider than the robots' kept distance, and it is at most :math:`h/2 - c`, the room a
robot has beside its path in a one-cell corridor (a wider tube lets its motion cut a
corner into the walls' margin, where the obstacle rows pin it: room-32-32-4, random-1,
64 robots, one robot stood at a wall's corner from 42 s on). Without a declared grid,
:math:`\rho = d_{\max}/4` and :math:`h = s + 2\rho`; of the nine grid origins
offset by :math:`0, h/3, 2h/3` in each axis the one that joins the most robots'
starts to their goals is taken. Before those, a grid *fitted* to the robots' own
points is tried: its spacing is the most common offset along an axis between
nearest start or goal points divided by the largest whole number that keeps it
at least :math:`h` (a formation 1 m apart gets 0.5 m for :math:`h` = 0.45 m), its
reach :math:`(h' - s)/2`, its origin a point; it is taken when it puts more of the
points on vertices than the finest grid does and joins every robot. A point that
is not a vertex is joined to the grid by new edges (below), around which the
robots' paths bend: on the 5 x 5 grid formation the fitted grid's plan is 24
steps, the finest grid's 36.

Diagonals
---------
Where no grid is declared (open space, built-in maps), the diagonal of every grid
square whose four vertices are free grid vertices is an edge too, when it keeps the
clearance (:attr:`Roadmap.diagonals`, not in the adjacency: LaCAM plans on the
4-connected grid). A robot on a diagonal passes the square's two other vertices
(its *corners*) at :math:`h/\sqrt 2 < s + 2\rho`: a plan that moves along a
diagonal keeps both corners free from the step before the move to the step after
it (:mod:`sqpmpc.coordination.mapf`), and the schedule orders the corner passes as
visits (:mod:`sqpmpc.coordination.schedule`); every vertex nearer than :math:`h` to
a diagonal is one of its square's four. The fleet plans with and without the
diagonals and keeps the plan of fewer steps (:mod:`sqpmpc.coordination.fleet`):
on antipodal swaps of 16 and 64 robots 26 and 56 steps instead of 30 and 64, on
grid formations the 4-connected plans are shorter. MovingAI maps stay 4-connected,
as in their benchmark.

Maps drawn on a grid
--------------------
A map need not declare the grid it was drawn on: when every wall is an
axis-aligned polygon whose corners lie on one square lattice, the free space is a
union of the lattice's cells, and of those of every subdivision of it. :func:`drawn_grid` takes the
coarsest subdivision whose cell is at least :math:`s + d_{\max}/2` (the finest
grid a roadmap takes without one) and uses it as a declared grid: the cells'
centres are the vertices, so a corridor :math:`k` cells wide holds :math:`k`
lines of vertices, the one-cell corridor's at its centre. A hand-drawn maze of
0.5 m corridors (the test maze's walls without its ``[roadmap]``) gets its own
0.5 m cells: with the grid fitted to the robots' points instead (0.47 m, off
the corridors' centres) LaCAM searched without end, and the liveness rules
brought 0 of 6 robots home.

Lanes
-----
Without a declared grid, a corridor off the grid's lines (narrower than :math:`h`
beside them, or in no axis's direction) gets no grid vertex where its free band is
narrower than the spacing. Such corridors get *lanes* (:func:`_lanes`): vertices on the
medial axis of the free space (the box less the map inflated by the clearance),
the line along every corridor's middle, taken wherever the axis is :math:`h` or more
from every vertex so far, and joined along it. Junctions of narrow corridors (the
axis nearer than :math:`h/2` to the free space's edge) are vertices first and replace
the grid vertices within :math:`h` of them: where two narrow corridors meet only a
vertex at the junction joins them by straight segments that keep the clearance.
Every two vertices keep the spacing :math:`h`, and an edge of a lane keeps it from
every third vertex, so the separation argument above holds on lanes too. In open
space the axis is within :math:`h` of grid vertices everywhere and adds nothing. The
test maze turned by 17, 30 and 45 degrees (0.5 m corridors in no axis's direction,
robots of 0.3 m): 6 of 6 home with lanes.

Completeness assumption (stated, not checked beyond the graph): without a declared
grid, a corridor is passable when its free band at the clearance is not empty, i.e.
when it is wider than :math:`2c` (the largest diameter plus twice the obstacle rows'
margin): its middle line carries a lane or grid vertices, unless it runs nearer than
:math:`h` to the vertices of another corridor across a wall thinner than
:math:`h - 2c` (the spacing is measured through walls), where it may have none; for
maps drawn on the grid (MovingAI maps at cell :math:`h`, free cells whose centres keep
:math:`c`) every free cell is a vertex, so every corridor of free cells is passable.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import shapely
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree
from shapely.geometry import Point
from shapely.geometry import box as rectangle
from shapely.ops import linemerge, unary_union

from sqpmpc.errors import ProblemError
from sqpmpc.problem.grid import GridSpec, grid_edges
from sqpmpc.problem.obstacles import Obstacle
from sqpmpc.problem.polygons import PolygonObstacle

__all__ = ["Roadmap", "build_roadmap", "drawn_grid", "on_one_lattice"]

_OFFSETS = (0.0, 1.0 / 3.0, 2.0 / 3.0)
_FIT_MAX_POINTS = 1024  # a grid is fitted to at most this many starts and goals (k^2 pairs)


@dataclass(frozen=True, eq=False)
class Roadmap:
    """An undirected graph of free positions.

    Attributes
    ----------
    positions
        ``(V, 2)`` vertex positions, m.
    indptr, indices
        The adjacency in CSR form: the neighbours of ``v`` are
        ``indices[indptr[v]:indptr[v + 1]]``.
    spacing
        :math:`h`, m: distinct vertices are at least this far apart.
    reach
        :math:`\\rho`, m: a robot within this of a vertex has reached it.
    starts, goals
        ``(n,)`` the vertex of each robot's start and goal (scenario order;
        -1 for a robot without a goal at rest).
    diagonals
        ``(D, 4)`` the diagonal edges ``(a, d)`` of grid squares and the square's two
        other vertices ``(b, c)`` (its *corners*, which a robot on the diagonal passes
        :math:`h/\\sqrt 2` from): ``a, d, b, c`` per row, each edge once. They are not in
        the adjacency (:meth:`neighbours`): a plan that uses one keeps its corners free
        (:mod:`sqpmpc.coordination.mapf`).
    """

    positions: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    spacing: float
    reach: float
    starts: np.ndarray
    goals: np.ndarray
    diagonals: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), dtype=np.int64))

    @property
    def size(self) -> int:
        """Number of vertices."""
        return int(self.positions.shape[0])

    def neighbours(self, vertex: int) -> np.ndarray:
        """The vertices joined to ``vertex``."""
        return self.indices[self.indptr[vertex]:self.indptr[vertex + 1]]

    def adjacency(self) -> csr_matrix:
        """The ``(V, V)`` adjacency matrix (ones)."""
        data = np.ones(self.indices.size)
        return csr_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))

    def diagonal_lists(self) -> list[list[tuple[int, int, int]]]:
        """Every vertex's diagonal neighbours ``(u, b, c)`` with the corners of the square."""
        out: list[list[tuple[int, int, int]]] = [[] for _ in range(self.size)]
        for a, d, b, c in self.diagonals.tolist():
            out[a].append((d, b, c))
            out[d].append((a, b, c))
        return out

    def corners(self) -> dict[tuple[int, int], tuple[int, int]]:
        """``(a, d) -> (b, c)`` for every diagonal edge, both ways."""
        out: dict[tuple[int, int], tuple[int, int]] = {}
        for a, d, b, c in self.diagonals.tolist():
            out[(a, d)] = out[(d, a)] = (b, c)
        return out

    def isolated(self, vertices: np.ndarray) -> Roadmap:
        """The roadmap with ``vertices`` cut off: no edge or diagonal ends at one of them
        and no diagonal passes one as a corner, so a plan enters none of them and a robot
        on one stays there (a robot whose controller left: it stands)."""
        cut = np.zeros(self.size, dtype=bool)
        cut[np.asarray(vertices, dtype=np.int64)] = True
        rows = np.repeat(np.arange(self.size), np.diff(self.indptr))
        keep = ~(cut[rows] | cut[self.indices])
        indptr = np.concatenate(([0], np.cumsum(np.bincount(rows[keep], minlength=self.size))))
        diagonals = self.diagonals[~cut[self.diagonals].any(axis=1)] if self.diagonals.size \
            else self.diagonals
        return replace(self, indptr=indptr.astype(self.indptr.dtype),
                       indices=self.indices[keep], diagonals=diagonals)

    def neighbour_lists(self) -> list[list[int]]:
        """The neighbours of every vertex as Python lists (for the planners' inner loops)."""
        ptr, idx = self.indptr.tolist(), self.indices.tolist()
        return [idx[ptr[v]:ptr[v + 1]] for v in range(self.size)]


def _inflated(polygons: Sequence[PolygonObstacle], circles: Sequence[Obstacle],
              clearance: float) -> shapely.Geometry | None:
    shapes = [p.shape.buffer(clearance, join_style="mitre") for p in polygons]
    shapes += [Point(o.position).buffer(0.5 * o.diameter + clearance, quad_segs=8)
               for o in circles if not any(o.velocity)]
    if not shapes:
        return None
    merged = unary_union(shapes)
    shapely.prepare(merged)
    return merged


def _free_points(points: np.ndarray, inflated: shapely.Geometry | None,
                 low: np.ndarray, high: np.ndarray) -> np.ndarray:
    inside = np.all((points >= low - 1e-9) & (points <= high + 1e-9), axis=1)
    if inflated is None or not inside.any():
        return inside
    blocked = shapely.intersects_xy(inflated, points[:, 0], points[:, 1])
    return inside & ~blocked


def _free_segments(a: np.ndarray, b: np.ndarray, inflated: shapely.Geometry | None
                   ) -> np.ndarray:
    if inflated is None or a.shape[0] == 0:
        return np.ones(a.shape[0], dtype=bool)
    lines = shapely.linestrings(np.stack((a, b), axis=1))
    return ~shapely.intersects(inflated, lines)


def _grid(low: np.ndarray, high: np.ndarray, h: float, origin: np.ndarray
          ) -> tuple[np.ndarray, tuple[int, int], np.ndarray]:
    """Grid points covering ``[low, high]`` through ``origin``: points ``(V, 2)``, the shape
    ``(rows, cols)`` and the ``(2,)`` first point."""
    first = origin + np.ceil((low - origin) / h - 1e-9) * h
    counts = np.floor((high - first) / h + 1e-9).astype(int) + 1
    counts = np.maximum(counts, 0)
    if counts.prod() > 4_000_000:
        raise ProblemError(f"roadmap: a grid of {counts[0]} x {counts[1]} vertices at spacing "
                           f"{h:.3g} m is larger than 4,000,000; bound the scenario "
                           "([bounds] x, y) or declare a coarser [roadmap] cell")
    xs = first[0] + h * np.arange(counts[0])
    ys = first[1] + h * np.arange(counts[1])
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.column_stack((gx.ravel(), gy.ravel())), (int(counts[0]), int(counts[1])), first


def _attach(points: np.ndarray, reach: float, h: float, grid: np.ndarray,
            keep: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Where each start/goal point goes: ``(P,)`` a grid vertex (>= 0) within ``reach`` or a
    new vertex ``-(1 + k)`` (points nearer than ``h`` to a new vertex join it); ``keep``
    with the grid vertices nearer than ``h`` to a new vertex removed; the new vertices'
    points (indices into ``points``). Repeated until no point needs a new vertex (a
    removal can take a grid vertex an earlier point was given)."""
    where = np.zeros(points.shape[0], dtype=np.int64)
    new: list[int] = []
    tree = shapely.STRtree(shapely.points(grid))
    added = True
    while added:
        added = False
        for p, point in enumerate(points):
            if new:
                gaps = np.hypot(*(points[new] - point).T)
                k = int(np.argmin(gaps))
                if gaps[k] < h - 1e-9:
                    where[p] = -(1 + k)
                    continue
            near = [v for v in tree.query(Point(point), predicate="dwithin", distance=reach)
                    if keep[v]]
            if near:
                where[p] = min(near, key=lambda v: math.hypot(*(grid[v] - point)))
                continue
            new.append(p)
            where[p] = -len(new)
            keep[tree.query(Point(point), predicate="dwithin", distance=h - 1e-9)] = False
            added = True
    return where, keep, new


def build_roadmap(polygons: Sequence[PolygonObstacle], circles: Sequence[Obstacle],
                  bounds: tuple[np.ndarray, np.ndarray] | None, starts: np.ndarray,
                  goals: np.ndarray, has_goal: np.ndarray, clearance: float,
                  separation: float, diameter: float, grid: GridSpec | None = None,
                  diagonal: bool = False, tube: bool = True) -> Roadmap:
    """The roadmap of a static map for robots keeping ``clearance`` from obstacles and
    ``separation`` between them (module docstring).

    Parameters
    ----------
    polygons, circles
        The static map (moving circles are ignored: they are the NMPC's business).
    bounds
        ``(low (2,), high (2,))`` box of the robots' centres, or ``None``.
    starts, goals
        ``(n, 2)`` each robot's start and goal point.
    has_goal
        ``(n,)`` bool: the robots that have a goal at rest (only they are planned).
    clearance
        :math:`c`, m.
    separation
        :math:`s`, m.
    diameter
        The largest robot diameter, m (:math:`\\rho = d/4` without a declared grid).
    grid
        A declared grid, or ``None``.
    diagonal
        Whether the diagonals of grid squares whose four vertices are free grid vertices
        (and whose diagonal keeps the clearance) are edges too (:attr:`Roadmap.diagonals`).
    tube
        Without a declared grid: whether the grid's vertices and edges keep the clearance
        plus the reach (the tube, module docstring) or the clearance alone.

    Raises
    ------
    ProblemError
        A declared cell no wider than ``separation``, or a grid too large.
    """
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    goals = np.asarray(goals, dtype=float).reshape(-1, 2)
    has_goal = np.asarray(has_goal, dtype=bool)
    inflated = _inflated(polygons, circles, clearance)
    footprint = _inflated(polygons, circles, 0.5 * diameter)
    if grid is not None:
        h = grid.cell
        reach = 0.5 * (h - separation)
        if reach <= 0.0:
            raise ProblemError(
                f"roadmap: the declared cell {h:.6g} m is not wider than the distance the "
                f"robots keep, {separation:.6g} m (their diameter plus the margins): robots on "
                "neighbouring cells would touch; use a larger cell or smaller robots")
        if 0.5 * h > clearance:  # the tube fits a one-cell corridor's room
            reach = min(reach, 0.5 * h - clearance)
        grids = [(h, reach, np.asarray(grid.origin))]
    else:
        reach = 0.25 * diameter
        h = separation + 2.0 * reach
        base = starts[has_goal][0] if has_goal.any() else np.zeros(2)
        grids = [(h, reach, base + h * np.array([a, b])) for a in _OFFSETS for b in _OFFSETS]
        fitted = _fitted_grid(np.concatenate((starts[has_goal], goals[has_goal])), h,
                              separation, min(_closest(starts[has_goal]),
                                              _closest(goals[has_goal])))
        if fitted is not None:  # tried first; the finest grid stays the fallback
            grids.insert(0, fitted)
    ends = np.concatenate((starts[has_goal], goals[has_goal]))
    if bounds is not None and np.all(np.isfinite(bounds[0])) and np.all(np.isfinite(bounds[1])):
        low, high = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    else:
        parts = [ends] if ends.size else [np.zeros((1, 2))]
        if inflated is not None:
            x0, y0, x1, y1 = inflated.bounds
            parts.append(np.array([[x0, y0], [x1, y1]]))
        every = np.concatenate(parts)
        low, high = every.min(axis=0) - 2.0 * h, every.max(axis=0) + 2.0 * h
        if bounds is not None:
            low = np.where(np.isfinite(bounds[0]), bounds[0], low)
            high = np.where(np.isfinite(bounds[1]), bounds[1], high)
    best: Roadmap | None = None
    best_score = -1
    chosen: tuple = ()
    # without a declared grid the grid's vertices and edges keep the clearance over their
    # tube (module docstring), unless ``tube`` is off (a thinner roadmap)
    tries: list[tuple] = []
    axes: dict[tuple, _Axis] = {}  # the medial axis of each free space tried (lanes)
    if grid is None and tube:
        tubes = {reach: _inflated(polygons, circles, clearance + reach) for _, reach, _ in grids}
        tries += [(tubes[reach], (low + reach, high - reach), h, reach, origin)
                  for h, reach, origin in grids]
    else:
        tries += [(inflated, (low, high), h, reach, origin) for h, reach, origin in grids]
    for free, box, h, reach, origin in tries:
        arguments = (free, footprint, box[0], box[1], h, origin, reach, starts, goals,
                     has_goal, diagonal)
        candidate = _roadmap_at(*arguments, lanes=grid is None, axes=axes)
        score = _joined(candidate, has_goal)
        if score > best_score:
            best, best_score, chosen = candidate, score, arguments
        if score == int(has_goal.sum()):
            break
    assert best is not None  # at least one origin
    if best_score < int(has_goal.sum()):  # the grid that joins the most, bridged
        best = _roadmap_at(*chosen, bridge=True, clear=inflated, lanes=grid is None,
                           axes=axes)
    return best


def _aligned(points: np.ndarray, h: float, reach: float) -> tuple[int, np.ndarray]:
    """The most ``points (k, 2)`` within ``reach`` of one square lattice of spacing ``h``
    through one of them, and that lattice's origin."""
    folded = np.mod(points - points[0], h)
    gap = np.abs(folded[:, None, :] - folded[None, :, :])
    gap = np.minimum(gap, h - gap)
    near = np.hypot(gap[..., 0], gap[..., 1]) <= reach + 1e-9
    best = int(np.argmax(near.sum(axis=1)))
    return int(near[best].sum()), points[best]


def _pair_gaps(points: np.ndarray) -> np.ndarray:
    """``(k, k)`` distances between ``points (k, 2)``, inf on the diagonal."""
    gaps = np.hypot(*(points[:, None, :] - points[None, :, :]).transpose(2, 0, 1))
    gaps[np.diag_indices_from(gaps)] = math.inf
    return gaps


def _closest(points: np.ndarray) -> float:
    """The smallest distance between two of ``points (k, 2)`` (inf for fewer than two)."""
    return float(_pair_gaps(points).min()) if points.shape[0] >= 2 else math.inf


def _fitted_grid(points: np.ndarray, h_min: float, separation: float, closest: float
                 ) -> tuple[float, float, np.ndarray] | None:
    """A grid on which more of the robots' ``points`` are vertices than on the finest one:
    spacing the most common offset along an axis between nearest points divided by the
    largest whole number that keeps it at least ``h_min``, its reach half its spacing
    beyond ``separation``, its origin one of the points; ``(h, reach, origin)`` or ``None``
    when it puts no more points on vertices, or when two starts (or two goals) are nearer
    than its spacing (``closest``: they would be one vertex)."""
    if points.shape[0] < 2 or points.shape[0] > _FIT_MAX_POINTS:
        return None
    nearest = np.argmin(_pair_gaps(points), axis=1)
    offsets = np.abs(points - points[nearest]).ravel()
    offsets = np.round(offsets[offsets >= h_min], 6)
    if offsets.size == 0:
        return None
    values, counts = np.unique(offsets, return_counts=True)
    span = float(values[np.argmax(counts)])
    h = span / math.floor(span / h_min + 1e-9)
    if h <= h_min + 1e-9 or h > closest - 1e-9:
        return None
    reach = 0.5 * (h - separation)
    count, origin = _aligned(points, h, reach)
    if count <= _aligned(points, h_min, 0.5 * (h_min - separation))[0]:
        return None
    return h, reach, origin


def drawn_grid(polygons: Sequence[PolygonObstacle], separation: float, diameter: float
               ) -> GridSpec | None:
    r"""The grid a map was drawn on, read from its walls (module docstring, "Maps drawn on
    a grid"), or ``None``.

    The lattice spacing :math:`L` is the greatest common divisor (to 1 micrometre) of
    the offsets between the polygons' corner coordinates, along both axes (the
    ``[bounds]`` box of the robots' centres is left out: it is the map's edge moved in
    by a radius); the cell is :math:`L / \lfloor L / h_{\min} \rfloor` with
    :math:`h_{\min} = s + d/2`, its centres offset by half a cell from a corner.

    Parameters
    ----------
    polygons
        The static walls; ``None`` is returned without any, or when an edge is not
        axis-aligned.
    separation, diameter
        :math:`s` and :math:`d`, m.

    Returns
    -------
    GridSpec or None
        ``None`` also when :math:`L < h_{\min}` (a finer drawing, e.g. an occupancy
        grid's pixels: no cell of it holds the robots).
    """
    if not polygons:
        return None
    every = []
    for polygon in polygons:
        corners = np.asarray(polygon.points, dtype=float)
        edges = np.roll(corners, -1, axis=0) - corners
        if np.any((np.abs(edges[:, 0]) > 1e-9) & (np.abs(edges[:, 1]) > 1e-9)):
            return None  # a slanted wall: not drawn on a lattice
        every.append(corners)
    x, y = np.concatenate(every).T
    steps = np.concatenate((x - x[0], y - y[0])) * 1e6
    whole = np.round(steps)
    if np.any(np.abs(steps - whole) > 1e-3):  # not on a micrometre lattice
        return None
    lattice = float(np.gcd.reduce(np.abs(whole).astype(np.int64))) * 1e-6
    h_min = separation + 0.5 * diameter
    if lattice < h_min:  # also 0: one point, no offset
        return None
    cell = lattice / math.floor(lattice / h_min + 1e-9)
    return GridSpec(cell, (float(x[0]) + 0.5 * cell, float(y[0]) + 0.5 * cell))


def on_one_lattice(starts: np.ndarray, goals: np.ndarray, separation: float,
                   diameter: float) -> bool:
    r"""Whether every one of a fleet's ``starts`` and ``goals`` (``(k, 2)`` each) lies
    within the reach of a vertex of one grid fitted to them: the grid that
    :func:`build_roadmap` tries first without a declared one (spacing
    :math:`h \ge s + 2\rho` with :math:`\rho = d/4`, from the points' most common nearest
    offset; reach :math:`(h - s)/2`), or the finest grid when none is fitted. On such a
    fleet the roadmap is exact, every start and goal a vertex, as on a declared grid
    (``sqpmpc generate mapf``). Above 1024 points no grid is fitted (the pairs of points
    are compared: :math:`k^2` memory), here as in :func:`build_roadmap`.

    Parameters
    ----------
    starts, goals
        ``(k, 2)`` positions of the robots with goals, ``k >= 1``.
    separation
        :math:`s`, the distance two robots keep, m.
    diameter
        :math:`d`, the largest robot's diameter, m.
    """
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    goals = np.asarray(goals, dtype=float).reshape(-1, 2)
    points = np.concatenate((starts, goals))
    if points.shape[0] > _FIT_MAX_POINTS:  # build_roadmap fits no grid to them either
        return False
    h_min = separation + 0.5 * diameter
    fitted = _fitted_grid(points, h_min, separation, min(_closest(starts), _closest(goals)))
    h, reach = (fitted[0], fitted[1]) if fitted is not None else (
        h_min, 0.5 * (h_min - separation))
    return _aligned(points, h, reach)[0] == points.shape[0]


def _roadmap_at(inflated: shapely.Geometry | None, footprint: shapely.Geometry | None,
                low: np.ndarray, high: np.ndarray, h: float, origin: np.ndarray,
                reach: float, starts: np.ndarray, goals: np.ndarray, has_goal: np.ndarray,
                diagonal: bool = False, bridge: bool = False,
                clear: shapely.Geometry | None = None, lanes: bool = False,
                axes: dict[tuple, _Axis] | None = None) -> Roadmap:
    points, shape, _ = _grid(low, high, h, origin)
    keep = _free_points(points, inflated, low, high)
    planned = np.flatnonzero(has_goal)
    ends = np.concatenate((starts[planned], goals[planned]))
    where, keep, new = _attach(ends, reach, h, points, keep)
    axis = None
    junctions = np.zeros((0, 2))
    if lanes and inflated is not None:  # the corridors no grid line passes (_lanes)
        key = (id(inflated), *np.asarray(low).tolist(), *np.asarray(high).tolist(), h)
        axis = None if axes is None else axes.get(key)
        if axis is None:  # the same free space for every grid origin tried: once
            axis = _axis(rectangle(*low, *high).difference(inflated), h)
            if axes is not None:
                axes[key] = axis
        junctions = _narrow_junctions(axis, ends[new].reshape(-1, 2), h)
        if junctions.size:  # they replace the grid vertices within h
            gone = cKDTree(junctions).query(points)[0] < h - 1e-9
            keep &= ~gone
    edges = grid_edges(shape)
    edges = edges[keep[edges[:, 0]] & keep[edges[:, 1]]]
    edges = edges[_free_segments(points[edges[:, 0]], points[edges[:, 1]], inflated)]
    # renumber: kept grid vertices, then the new ones
    number = np.full(points.shape[0], -1, dtype=np.int64)
    number[keep] = np.arange(int(keep.sum()))
    positions = np.concatenate((points[keep], ends[new].reshape(-1, 2)))
    base = int(keep.sum())
    pairs = [number[edges]]
    if axis is not None:  # lanes first: a robot's own point joins its lane's vertices
        if junctions.size:
            positions = np.concatenate((positions, junctions))
        extra_points, extra_edges = _lanes(positions, axis, inflated, h)
        if extra_points.size or extra_edges.size:
            positions = np.concatenate((positions, extra_points))
            pairs.append(extra_edges)
    if new:
        tree = shapely.STRtree(shapely.points(positions))
        extra: list[tuple[int, int]] = []
        for k, p in enumerate(new):
            v = base + k
            near = tree.query(Point(ends[p]), predicate="dwithin",
                              distance=math.sqrt(2.5) * h + 1e-9)
            near = np.asarray([u for u in near if u != v], dtype=np.int64)
            ok = _free_segments(np.repeat(positions[v][None], near.size, axis=0),
                                positions[near], footprint) if near.size else near.astype(bool)
            if not ok.any():  # others' points took its ring: the nearest vertex it sees
                order = np.argsort(np.hypot(*(positions - positions[v]).T))[1:]
                free = _free_segments(np.repeat(positions[v][None], order.size, axis=0),
                                      positions[order], footprint)
                near, ok = order[free][:1], np.ones(min(1, int(free.sum())), dtype=bool)
            extra += [(v, int(u)) for u in near[ok]]
        if extra:
            pairs.append(np.asarray(extra, dtype=np.int64))
    edges = np.concatenate(pairs) if pairs else np.zeros((0, 2), dtype=np.int64)
    vertex = np.where(where >= 0, number[np.maximum(where, 0)], base - 1 - where)
    ends_v = vertex.reshape(2, -1).T  # (planned, 2): each planned robot's start and goal
    if bridge:  # bridges free at the clearance (``clear``: the map inflated by it)
        edges = _bridged(positions, edges, ends_v, clear)
    edges = np.unique(np.sort(edges, axis=1), axis=0) if edges.size else edges
    adjacency = _adjacency(edges, positions.shape[0])
    n = has_goal.size
    start_v = np.full(n, -1, dtype=np.int64)
    goal_v = np.full(n, -1, dtype=np.int64)
    start_v[planned] = vertex[:planned.size]
    goal_v[planned] = vertex[planned.size:]
    diagonals = np.zeros((0, 4), dtype=np.int64)
    if diagonal:
        diagonals = _diagonals(shape, keep, points, inflated, number)
    return Roadmap(positions, adjacency.indptr.astype(np.int64),
                   adjacency.indices.astype(np.int64), h, reach, start_v, goal_v, diagonals)


def _medial_lines(free: shapely.Geometry, step: float) -> list[np.ndarray]:
    """The medial axis of the region ``free`` as polylines ``(K, 2)``: the edges of the
    Voronoi diagram of its boundary sampled every ``step`` that lie inside it, merged
    into lines (the classical approximation; every point of it is as far as possible
    from the boundary across the region's width)."""
    boundary = shapely.segmentize(free.boundary, step)
    points = shapely.multipoints(shapely.get_coordinates(boundary))
    edges = shapely.get_parts(shapely.voronoi_polygons(points, only_edges=True))
    if edges.size == 0:
        return []
    shapely.prepare(free)
    inside = edges[shapely.contains(free, edges)]
    if inside.size == 0:
        return []
    merged = linemerge(unary_union(inside))
    return [shapely.get_coordinates(line) for line in shapely.get_parts(merged)]


@dataclass(frozen=True, eq=False)
class _Axis:
    """The medial axis of the free space as a fine graph (:func:`_axis`): nodes ``(M, 2)``,
    links ``(E, 2)`` between them, and which nodes are junctions and which narrow
    ``(M,)`` each."""

    nodes: np.ndarray
    links: np.ndarray
    junction: np.ndarray
    narrow: np.ndarray


def _axis(free: shapely.Geometry, h: float) -> _Axis:
    r"""The medial axis of ``free`` sampled every :math:`h/8` (:func:`_fine_axis`), with
    which nodes are junctions and which are *narrow*: nearer than :math:`h/2` to the
    boundary of ``free``, where a corridor's room is narrower than the grid's spacing and
    a grid line may miss it."""
    nodes, links, junction = _fine_axis(_medial_lines(free, 0.125 * h), 0.125 * h)
    if nodes.shape[0] == 0:
        return _Axis(nodes, links, junction, junction.copy())
    room = shapely.distance(free.boundary, shapely.points(nodes))
    return _Axis(nodes, links, junction, room < 0.5 * h)


def _narrow_junctions(axis: _Axis, fixed: np.ndarray, h: float) -> np.ndarray:
    r"""``(J, 2)`` the narrow junctions of ``axis`` taken as vertices: at least :math:`h`
    from each other and from the ``fixed (F, 2)`` vertices (the robots' own points).
    Where narrow corridors meet, only a vertex at the junction joins their lanes by
    straight segments that keep the clearance (a segment between vertices on two of
    them cuts the corner), so these are placed before the grid's (which they
    replace within :math:`h`)."""
    chosen: list[np.ndarray] = []
    for k in np.flatnonzero(axis.junction & axis.narrow):
        p = axis.nodes[k]
        if fixed.size and float(np.hypot(*(fixed - p).T).min()) < h - 1e-9:
            continue
        if chosen and float(np.hypot(*(np.asarray(chosen) - p).T).min()) < h - 1e-9:
            continue
        chosen.append(p)
    return np.asarray(chosen, dtype=float).reshape(-1, 2)


def _lanes(positions: np.ndarray, axis: _Axis, inflated: shapely.Geometry, h: float
           ) -> tuple[np.ndarray, np.ndarray]:
    r"""Lane vertices along the corridors that no vertex of ``positions (V, 2)`` lies in,
    and the edges that join them: new vertices ``(L, 2)`` and edges ``(E, 2)`` (indices
    into ``positions`` followed by the new vertices), each touching a new vertex or a
    narrow junction among ``positions`` (:func:`_narrow_junctions`).

    The lanes follow the medial axis of the free space (the box less the map inflated
    by the clearance): a corridor of any direction that leaves room for a robot has one
    along its middle, the line farthest from both walls. The axis's nodes (every
    :math:`h/8`) are taken as vertices in turn when they are at least :math:`h` from
    every vertex so far (the grid's spacing, so the separation argument holds for every
    two vertices); every node then lies within :math:`h` of a vertex. Each node stands
    for the nearest vertex within :math:`h` that it sees with the clearance, and two
    vertices whose nodes are neighbours on the axis are joined when the segment between
    them keeps the clearance and no third vertex is nearer than :math:`h` to it (as on
    the grid, a robot on an edge keeps the kept distance from robots on every other
    vertex). In open space every node is within :math:`h` of a grid vertex and nothing
    is added."""
    nodes, links = axis.nodes, axis.links
    if nodes.shape[0] == 0:
        return np.zeros((0, 2)), np.zeros((0, 2), dtype=np.int64)
    base = positions.shape[0]
    tree = cKDTree(positions) if base else None
    new: list[int] = []
    for k in range(nodes.shape[0]):
        if tree is not None and tree.query(nodes[k])[0] < h - 1e-9:
            continue
        if new and float(np.hypot(*(nodes[new] - nodes[k]).T).min()) < h - 1e-9:
            continue
        new.append(k)
    every = np.concatenate((positions.reshape(-1, 2), nodes[new]))
    # each node's vertex: the nearest within h that it sees with the clearance (every
    # node's candidates in one query and one segment test)
    near = cKDTree(every).query_ball_point(nodes, h + 1e-9)
    node = np.repeat(np.arange(nodes.shape[0]), [len(c) for c in near])
    vertex = np.fromiter((v for c in near for v in c), dtype=np.int64, count=node.size)
    gap = np.hypot(*(every[vertex] - nodes[node]).T)
    order = np.lexsort((gap, node))  # by node, nearest first
    node, vertex = node[order], vertex[order]
    seen = _free_segments(nodes[node], every[vertex], inflated)
    node, vertex = node[seen], vertex[seen]
    first = np.r_[True, node[1:] != node[:-1]] if node.size else np.zeros(0, dtype=bool)
    stand = np.full(nodes.shape[0], -1, dtype=np.int64)
    stand[node[first]] = vertex[first]
    a, b = stand[links[:, 0]], stand[links[:, 1]]
    lane = np.zeros(every.shape[0], dtype=bool)
    lane[base:] = True
    junctions = np.flatnonzero(axis.junction & axis.narrow)
    if junctions.size:  # the narrow junctions placed among positions
        lane[stand[junctions][stand[junctions] >= 0]] = True
    ok = (a >= 0) & (b >= 0) & (a != b)
    ok[ok] &= lane[a[ok]] | lane[b[ok]]
    pairs = np.column_stack((a, b))[ok]
    if pairs.size == 0:
        return every[base:], np.zeros((0, 2), dtype=np.int64)
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    pairs = pairs[_free_segments(every[pairs[:, 0]], every[pairs[:, 1]], inflated)]
    keep = np.array([_clear_of_others(every, int(u), int(v), h) for u, v in pairs], dtype=bool)
    return every[base:], pairs[keep].reshape(-1, 2).astype(np.int64)


def _fine_axis(lines: list[np.ndarray], step: float
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The polylines ``lines`` as one graph of points at most ``step`` apart along them:
    nodes ``(M, 2)``, links ``(E, 2)`` and which nodes are junctions (three lines or more
    meet there) ``(M,)``. Lines meet where their ends coincide."""
    index: dict[tuple[float, float], int] = {}
    points: list[np.ndarray] = []
    links: list[tuple[int, int]] = []
    degree: dict[int, int] = {}

    def end(p: np.ndarray) -> int:
        key = (round(float(p[0]), 9), round(float(p[1]), 9))
        if key not in index:
            index[key] = len(points)
            points.append(np.asarray(p, dtype=float))
        return index[key]

    for line in lines:
        if line.shape[0] < 2:
            continue
        samples = _samples(line, step)
        first, last = end(samples[0]), end(samples[-1])
        degree[first] = degree.get(first, 0) + 1
        degree[last] = degree.get(last, 0) + 1
        previous = first
        for p in samples[1:-1]:
            points.append(p)
            links.append((previous, len(points) - 1))
            previous = len(points) - 1
        links.append((previous, last))
    nodes = np.asarray(points).reshape(-1, 2)
    junction = np.zeros(nodes.shape[0], dtype=bool)
    junction[[k for k, d in degree.items() if d >= 3]] = True
    return nodes, np.asarray(links, dtype=np.int64).reshape(-1, 2), junction


def _samples(line: np.ndarray, step: float) -> np.ndarray:
    """Points of the polyline ``line (K, 2)`` evenly spaced along its length, at most
    ``step`` apart, both ends included."""
    arc = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(line, axis=0).T))))
    at = np.linspace(0.0, arc[-1], max(1, math.ceil(arc[-1] / step)) + 1)
    return np.column_stack((np.interp(at, arc, line[:, 0]), np.interp(at, arc, line[:, 1])))


def _clear_of_others(points: np.ndarray, a: int, b: int, h: float) -> bool:
    """Whether every point but ``a`` and ``b`` is at least ``h`` from the segment between
    them."""
    p, q = points[a], points[b]
    d = q - p
    f = np.clip((points - p) @ d / max(float(d @ d), 1e-18), 0.0, 1.0)
    gap = np.hypot(*(points - p - f[:, None] * d).T)
    gap[[a, b]] = np.inf
    return bool(gap.min() >= h - 1e-9)


def _adjacency(edges: np.ndarray, size: int) -> csr_matrix:
    """The symmetric ``(size, size)`` adjacency of ``(E, 2)`` edges, indices sorted."""
    adjacency = csr_matrix((np.ones(2 * edges.shape[0]),
                            (np.concatenate((edges[:, 0], edges[:, 1])),
                             np.concatenate((edges[:, 1], edges[:, 0])))), shape=(size, size))
    adjacency.sort_indices()
    return adjacency


def _bridged(positions: np.ndarray, edges: np.ndarray, ends: np.ndarray,
             clear: shapely.Geometry | None) -> np.ndarray:
    """``edges`` plus the bridges that join each robot's start to its goal where the graph
    leaves them apart and the free space does not: while some robot's ``ends`` row
    (start, goal vertex) lies in two components, the smaller of the two is joined to
    the rest of the graph by its shortest segment that ``clear`` (the map inflated by the
    clearance) leaves free (off-grid starts and goals crowded in an aisle remove the grid
    vertices between them, and their rings may not reach each other). Each bridge joins
    two components, so there are fewer bridges than components; a robot whose component
    no free segment leaves is passed over (the planner then names it)."""
    size = positions.shape[0]
    edges = edges.reshape(-1, 2)
    failed: set[int] = set()  # the robots whose components no free segment joins
    for _ in range(size + ends.shape[0]):  # each pass adds a bridge or a failed robot
        _, label = connected_components(_adjacency(edges, size), directed=False)
        apart = [r for r in np.flatnonzero(label[ends[:, 0]] != label[ends[:, 1]])
                 if r not in failed]
        if not apart:
            return edges
        counts = np.bincount(label)
        a, b = label[ends[apart[0]]]
        part = a if counts[a] <= counts[b] else b
        inside = np.flatnonzero(label == part)
        outside = np.flatnonzero(label != part)
        tree = cKDTree(positions[outside])
        bridge = None
        k = 8
        while bridge is None:
            k = min(2 * k, outside.size)
            gaps, near = tree.query(positions[inside], k=k)
            gaps, near = gaps.reshape(inside.size, -1), near.reshape(inside.size, -1)
            order = np.argsort(gaps, axis=None)
            i, o = np.unravel_index(order, gaps.shape)
            free = _free_segments(positions[inside[i]], positions[outside[near[i, o]]], clear)
            if free.any():
                j = int(np.argmax(free))
                bridge = (int(inside[i[j]]), int(outside[near[i[j], o[j]]]))
            elif k == outside.size:
                break
        if bridge is None:
            failed.add(int(apart[0]))
            continue
        edges = np.concatenate((edges, np.asarray([bridge], dtype=np.int64)))
    return edges


def _diagonals(shape: tuple[int, int], keep: np.ndarray, points: np.ndarray,
               inflated: shapely.Geometry | None, number: np.ndarray) -> np.ndarray:
    """``(D, 4)`` ``a, d, b, c`` (renumbered) of the diagonals of grid squares whose four
    vertices are kept, whose diagonal keeps the clearance."""
    rows, cols = shape
    index = np.arange(rows * cols).reshape(rows, cols)
    p, q = index[:-1, :-1].ravel(), index[1:, 1:].ravel()  # (i, j) and (i+1, j+1)
    r, t = index[1:, :-1].ravel(), index[:-1, 1:].ravel()  # (i+1, j) and (i, j+1)
    whole = keep[p] & keep[q] & keep[r] & keep[t]
    p, q, r, t = p[whole], q[whole], r[whole], t[whole]
    both = np.concatenate((np.column_stack((p, q, r, t)), np.column_stack((r, t, p, q))))
    free = _free_segments(points[both[:, 0]], points[both[:, 1]], inflated)
    return number[both[free]]


def _joined(roadmap: Roadmap, has_goal: np.ndarray) -> int:
    """How many planned robots have their start and goal on free, connected vertices."""
    if roadmap.size == 0:
        return 0
    _, label = connected_components(roadmap.adjacency(), directed=False)
    s, g = roadmap.starts[has_goal], roadmap.goals[has_goal]
    return int(np.sum((s >= 0) & (g >= 0) & (label[np.maximum(s, 0)] == label[np.maximum(g, 0)])))

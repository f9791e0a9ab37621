r"""Conflict-free multi-robot plans on a roadmap: prioritized planning, else LaCAM with PIBT.

A *configuration* gives every robot a vertex, no two the same. A plan is a
sequence of configurations :math:`Q_0, Q_1, \dots, Q_T` from the starts to the
goals in which every robot stays or moves to a neighbour from one to the next,
never onto a vertex another robot holds in the next configuration (vertex
conflict), never along an edge another robot takes the other way (swap
conflict) and never round a cycle of robots each moving onto the vertex the next
one leaves (rotation: valid in MAPF, but its robots would have to move at once,
and executed in order, :mod:`sqpmpc.coordination.schedule`, each would wait for
the next). Robots that reach their goals stay in the plan: moving off a goal to
let another robot by and back is part of it, so a robot that has finished is
never in another's way in the final configuration.

A plan is first sought by *prioritized planning* (Silver, *Cooperative
Pathfinding*, 2005): robots with farther goals first, each one's path a search
around the paths of the robots before it (their vertices, their moves the other
way, their goals from their arrival on; a robot may follow one planned before it
onto the vertex it leaves, never the other way round, so the following never closes
a cycle): a safe-interval A* (Phillips and Likhachev, *SIPP*, 2011; compiled,
:func:`sqpmpc.kernels.mapf.safe_interval_search`, whose docstring has the argument)
over a vertex, a safe interval of it (a maximal run of steps at which the robots
planned before leave it free) and the robot's heading, which arrives as early as any
path, with the turns' steps, and among the paths it finds that arrive as early takes
one with the fewest turns (a unicycle slows down at every corner), each search bounded
by 10,000 times its robot's distance plus one expansions; when a robot finds no path,
the planning starts again with that robot first (each robot moved to the front at
most once, so at most :math:`n + 1` attempts). Its plans are short (on the MovingAI
maps with 32 robots, 20 of 20 plans at the lower bound, the longest distance of a
robot alone) and cheap, but it is not complete: where the last attempt fails, the
plan is LaCAM's.

LaCAM (Okumura, *LaCAM: Search-Based Algorithm for Quick
Multi-Agent Pathfinding*, AAAI 2023): a depth-first search over configurations
whose successors are generated lazily. Every search node keeps a queue of
*constraints* (some robots told where to go next, built up one robot at a time
over all of its neighbours and itself), and each time the node is visited the
next constraint is handed to PIBT (Okumura et al., *Priority Inheritance with
Backtracking*, AIJ 2022), which completes it to a successor configuration: each
robot in priority order takes its best free neighbour by distance to its goal,
asking a robot standing there to move first (priority inheritance) and trying its
next choice when that one cannot. Where two robots must pass each other in a
corridor (no branch to step aside into before they would meet, one on either
side of a branch behind) PIBT alone pushes back and forth for ever: with the *swap
technique* of LaCAM2 (Okumura, *Improving LaCAM for Scalable Eventually Optimal
Multi-Agent Pathfinding*, IJCAI 2023) the robot steps back first, away from its
goal, and pulls the other one onto the vertex it leaves, until the branch lets
them pass. A configuration met before is not expanded again (its node goes back on
the stack). The search is compiled
(:func:`sqpmpc.kernels.lacam.lacam_search`, whose module docstring has the details:
configurations in arrays, found again by a hash table; constraints a tree of
robot-vertex pairs; PIBT's recursion on an explicit stack).

On a roadmap with diagonals (:attr:`~sqpmpc.coordination.roadmap.Roadmap.diagonals`)
prioritized planning may move along them: a diagonal move from :math:`t` to
:math:`t+1` needs both other corners of its square free of the robots planned
before from :math:`t-1` to :math:`t+1`, not entered at :math:`t+2`, not parked on,
and not a start of a robot not planned yet at :math:`t = 0`; it then holds them over
the move. LaCAM plans on the 4-connected grid only.

**Completeness** (LaCAM's theorem 1): the constraints of a node enumerate, over
the visits, every assignment of next vertices to the robots, so every
configuration reachable in one step (no vertex or swap conflict, no rotation: a
completion with one is dropped) is eventually generated from every visited node
(whatever PIBT's policy, the swap technique included: a constraint that fixes every
robot leaves it nothing to choose); the search is a depth-first search of the finite
graph of configurations, which therefore reaches the goal configuration whenever it is
reachable and ends otherwise, so together with the prioritized attempt the planner is
complete.
Among equally near vertices PIBT goes straight on (a unicycle turns at corners,
not on lines), except when it steps back to swap. ``max_nodes`` bounds the work; a
search stopped by it raises :class:`PlanningError` (never a partial plan). In practice
PIBT finds the plan on the first descent or nearly (the warehouse family with 64
robots, seed 0, where prioritized planning fails: 111 search nodes, 0.02 s; without
the swap technique 200,000 nodes found none), and the search only backtracks in narrow
places.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix

from sqpmpc.coordination.roadmap import Roadmap
from sqpmpc.errors import ProblemError
from sqpmpc.kernels.lacam import EXHAUSTED, OVER_BUDGET, lacam_search
from sqpmpc.kernels.mapf import (
    FIELDS,
    FOUND,
    LIMIT,
    SCRATCH,
    UNBOUNDED,
    bfs_distances,
    reserve_path,
    safe_interval_search,
    straight_moves,
    turn_tables,
)

__all__ = ["PLANNERS", "Moves", "PlanningError", "distance_tables", "plan_moves", "plan_paths",
           "straight_on"]

#: The ``method`` names of :func:`plan_paths`.
PLANNERS = ("auto", "prioritized", "lacam")


class PlanningError(ProblemError):
    """No conflict-free plan: a goal that cannot be reached, or the search's budget spent."""


def distance_tables(roadmap: Roadmap, goals: np.ndarray, diagonal: bool = False
                    ) -> np.ndarray:
    """``(n, V)`` hop distances from every vertex to each robot's goal (``inf`` where the goal
    cannot be reached), along the roadmap's diagonals too when ``diagonal``."""
    unique, inverse = np.unique(np.asarray(goals, dtype=np.int64), return_inverse=True)
    graph = _graph(roadmap, diagonal)
    table = np.empty((unique.size, roadmap.size))
    bfs_distances(graph.indptr.astype(np.int64), graph.indices.astype(np.int64), unique,
                  table)
    return table[inverse]


def _graph(roadmap: Roadmap, diagonal: bool) -> csr_matrix:
    """The roadmap's adjacency, with its diagonal edges when ``diagonal``."""
    adjacency = roadmap.adjacency()
    if not diagonal or not roadmap.diagonals.size:
        return adjacency
    a, d = roadmap.diagonals[:, 0], roadmap.diagonals[:, 1]
    extra = csr_matrix((np.ones(2 * a.size), (np.concatenate((a, d)), np.concatenate((d, a)))),
                       shape=adjacency.shape)
    out = (adjacency + extra).tocsr()
    out.sort_indices()
    return out


def plan_paths(roadmap: Roadmap, starts: np.ndarray, goals: np.ndarray, *, seed: int = 0,
               max_nodes: int = 200_000, names: list[str] | None = None,
               method: str = "auto", shorter_than: int | None = None,
               turn_step: float = 0.0, headings: np.ndarray | None = None) -> np.ndarray:
    r"""A conflict-free plan from ``starts`` to ``goals`` (module docstring).

    Parameters
    ----------
    roadmap
        The graph.
    starts, goals
        ``(n,)`` distinct vertices each.
    seed
        Seed of PIBT's tie-breaking (the plan is a function of the inputs and the seed).
    max_nodes
        Largest number of search nodes.
    names
        How to name robot ``i`` in errors (default ``robot index i``).
    method
        ``"auto"`` (prioritized planning, else LaCAM), ``"prioritized"`` (a
        :class:`PlanningError` when it finds no plan) or ``"lacam"``.
    shorter_than
        Prioritized planning seeks only plans of fewer steps (each robot's search stops
        at arrivals later than ``shorter_than - 1``): a plan no shorter than one in hand
        is not worth its work. LaCAM's plan is not bounded.
    turn_step
        The largest turn in place of a robot per step, rad (:math:`\omega_{\max} h /
        v_{\max}`): prioritized planning gives a robot the steps it needs to turn at a
        vertex before a move in a new direction (``0``: turns take no time). LaCAM's
        moves do not turn.
    headings
        ``(n,)`` the robots' headings at the start, rad (default: unknown; their first
        move's turn takes no time).

    Returns
    -------
    numpy.ndarray
        ``(T + 1, n)`` vertices of every robot at steps ``0..T``; row 0 the starts, row T
        the goals.

    Raises
    ------
    PlanningError
        Starts or goals not distinct, a goal unreachable from its start, or no plan within
        ``max_nodes`` nodes.
    """
    if method not in PLANNERS:
        raise PlanningError(f"unknown planning method {method!r}; expected one of {PLANNERS}")
    starts = np.asarray(starts, dtype=np.int64)
    goals = np.asarray(goals, dtype=np.int64)
    n = starts.size
    label = names or [f"robot index {i}" for i in range(n)]
    for what, vs in (("start", starts), ("goal", goals)):
        values, counts = np.unique(vs, return_counts=True)
        if (counts > 1).any():
            v = int(values[np.argmax(counts > 1)])
            who = [label[i] for i in np.flatnonzero(vs == v)]
            raise PlanningError(f"roadmap: {' and '.join(who)} share the {what} vertex {v} "
                                f"at {roadmap.positions[v].round(3).tolist()}: their {what}s "
                                "are nearer than the roadmap spacing")
    if n == 0:
        return np.zeros((1, 0), dtype=np.int64)
    # the hop distances (over the diagonals too, for prioritized planning: its heuristic
    # counts diagonal steps; a diagonal joins two vertices its corners join, so the goals
    # are reachable or not as on the grid alone)
    diagonal = method != "lacam" and roadmap.diagonals.size > 0
    table = distance_tables(roadmap, goals, diagonal=diagonal)
    far = ~np.isfinite(table[np.arange(n), starts])
    if far.any():
        i = int(np.argmax(far))
        raise PlanningError(f"roadmap: {label[i]} cannot reach its goal "
                            f"{roadmap.positions[goals[i]].round(3).tolist()} from "
                            f"{roadmap.positions[starts[i]].round(3).tolist()}: no path of free "
                            "roadmap vertices joins them at the robots' footprint")
    if method != "lacam":
        moves = plan_moves(roadmap)
        facing = np.full(n, np.nan) if headings is None else np.asarray(headings, dtype=float)
        bound = -1 if shorter_than is None else shorter_than - 1
        first = _prioritized(moves, table, starts.tolist(), goals.tolist(), bound,
                             float(turn_step), facing)
        if first is None and turn_step > 0.0:  # the turns' steps left out
            first = _prioritized(moves, table, starts.tolist(), goals.tolist(), bound, 0.0,
                                 facing)
        if first is not None:
            return first
        if method == "prioritized":
            within = "" if shorter_than is None else f" of fewer than {shorter_than} steps"
            raise PlanningError(f"roadmap: prioritized planning found no plan{within} for "
                                f"{n} robots (in {n + 1} orders at most)")
        if diagonal:  # LaCAM's distances: on the grid alone
            table = distance_tables(roadmap, goals)
    return _lacam(roadmap, table, starts, goals, seed, max_nodes)


def _lacam(roadmap: Roadmap, table: np.ndarray, starts: np.ndarray, goals: np.ndarray,
           seed: int, max_nodes: int) -> np.ndarray:
    """LaCAM with PIBT (module docstring; compiled, :func:`sqpmpc.kernels.lacam.lacam_search`)
    within ``max_nodes`` search nodes, on the 4-connected grid; ``table`` the ``(n, V)``
    hop distances to the goals on it."""
    n = starts.size
    ptr, idx = roadmap.indptr.astype(np.int64), roadmap.indices.astype(np.int64)
    straight = np.empty(idx.size, dtype=np.int64)
    pos = roadmap.positions
    straight_moves(ptr, idx, np.ascontiguousarray(pos[:, 0], dtype=float),
                   np.ascontiguousarray(pos[:, 1], dtype=float), straight)
    dist = np.where(np.isfinite(table), table, roadmap.size + 1).astype(np.int64)
    # copies: contiguous and writable, the types the kernel is warmed up for
    status, _, plan = lacam_search(ptr, idx, straight, dist, np.array(starts, dtype=np.int64),
                                   np.array(goals, dtype=np.int64), int(seed), int(max_nodes))
    if status == OVER_BUDGET:
        raise PlanningError(f"roadmap: no conflict-free plan for {n} robots within "
                            f"{max_nodes} search nodes")
    if status == EXHAUSTED:
        raise PlanningError(f"roadmap: the goals of the {n} robots cannot be reached together "
                            "(every configuration reachable from the starts was explored)")
    return plan


@dataclass
class Moves:
    """The moves of prioritized planning in CSR form: out of ``v``, ``targets[ptr[v]:ptr[v +
    1]]`` (its grid neighbours, ``v`` itself: the wait, then its diagonals), the corners
    ``b, c`` of a diagonal (-1 otherwise), the vertex ``straight`` on after each move
    (-1 where none), its direction ``angle`` and the move ``back`` (out of its end; a
    wait's itself); the vertices' coordinates ``x, y``."""

    ptr: np.ndarray
    targets: np.ndarray
    b: np.ndarray
    c: np.ndarray
    straight: np.ndarray
    angle: np.ndarray
    back: np.ndarray
    x: np.ndarray
    y: np.ndarray
    offsets: np.ndarray = field(default_factory=lambda: np.zeros(1, dtype=np.int64))
    depart: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    turn: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    turn_step: float = 0.0

    def turning(self, turn_step: float) -> None:
        """The tables of the steps turns take at ``turn_step`` (:func:`turn_tables`)."""
        if turn_step <= 0.0 or turn_step == self.turn_step:
            return
        width = np.diff(self.ptr)
        self.offsets = np.concatenate(([0], np.cumsum(width * width))).astype(np.int64)
        self.depart = np.empty(int(self.offsets[-1]), dtype=np.int64)
        self.turn = np.empty(int(self.offsets[-1]), dtype=np.int64)
        turn_tables(self.ptr, self.back, self.angle, turn_step, self.offsets, self.depart,
                    self.turn)
        self.turn_step = turn_step


def plan_moves(roadmap: Roadmap) -> Moves:
    """The moves of ``roadmap`` (:class:`Moves`): out of every vertex its neighbours in
    the roadmap's order, the wait, then its diagonals in their order."""
    size = roadmap.size
    ptr, idx = roadmap.indptr.astype(np.int64), roadmap.indices.astype(np.int64)
    diag = roadmap.diagonals.astype(np.int64).reshape(-1, 4)
    vertices = np.arange(size, dtype=np.int64)
    # (tail, kind, order) sorts them: grid edges (0), the wait (1), diagonals both ways (2)
    tail = np.concatenate((np.repeat(vertices, np.diff(ptr)), vertices, diag[:, 0], diag[:, 1]))
    head = np.concatenate((idx, vertices, diag[:, 1], diag[:, 0]))
    b = np.concatenate((np.full(idx.size + size, -1), diag[:, 2], diag[:, 2]))
    c = np.concatenate((np.full(idx.size + size, -1), diag[:, 3], diag[:, 3]))
    kind = np.concatenate((np.zeros(idx.size), np.ones(size), np.full(2 * diag.shape[0], 2)))
    # the diagonals of a vertex in the order of the roadmap's rows
    rank = np.concatenate((np.arange(idx.size), np.zeros(size), np.arange(diag.shape[0]),
                           np.arange(diag.shape[0])))
    order = np.lexsort((rank, kind, tail))
    tail, head, b, c = tail[order], head[order], b[order], c[order]
    starts = np.searchsorted(tail, np.arange(size + 1))
    # the move back (the same move, ends swapped), and the vertex straight on
    key = tail * size + head
    sort = np.argsort(key, kind="stable")
    back = sort[np.searchsorted(key[sort], head * size + tail)]
    pos = roadmap.positions
    x = np.ascontiguousarray(pos[:, 0], dtype=float)
    y = np.ascontiguousarray(pos[:, 1], dtype=float)
    straight = np.empty(tail.size, dtype=np.int64)
    straight_moves(starts, head, x, y, straight)
    return Moves(starts, head, b, c, straight,
                  np.arctan2(y[head] - y[tail], x[head] - x[tail]), back, x, y)


class _Tables:
    """The reservations (:mod:`sqpmpc.kernels.mapf`): the ``(H, V)`` table, grown by
    doubling ``H``, every vertex's blocked runs (``(V, H // 2 + 1, 2)``), and the
    searches' scratch states and heap."""

    def __init__(self, size: int, rows: int) -> None:
        self.size = size
        self.res = np.zeros((rows, size), dtype=np.int64)
        self.runs = np.zeros((size, rows // 2 + 1, 2), dtype=np.int64)
        self.count = np.zeros(size, dtype=np.int64)
        self.states = np.zeros((4 * size, FIELDS), dtype=np.int32)
        self.heap = np.zeros((1 << 15, 3), dtype=np.int64)
        self.search = 0

    def clear(self) -> None:
        """No reservation."""
        self.res[:] = 0
        self.count[:] = 0

    def fit(self, rows: int) -> None:
        """At least ``rows`` rows (new rows empty)."""
        have = self.res.shape[0]
        if rows <= have:
            return
        more = max(rows, 2 * have) - have
        self.res = np.concatenate((self.res, np.zeros((more, self.size), dtype=np.int64)))
        room = self.res.shape[0] // 2 + 1 - self.runs.shape[1]
        self.runs = np.concatenate((self.runs, np.zeros((self.size, room, 2), dtype=np.int64)),
                                   axis=1)

    def scratch(self, need: int) -> None:
        """At least ``need`` scratch states (marks below every search's), or when ``need``
        is negative at least ``-need`` heap entries."""
        if need < 0:
            self.heap = np.zeros((-need, 3), dtype=np.int64)
        elif need > self.states.shape[0]:
            self.states = np.zeros((max(need, 2 * self.states.shape[0]), FIELDS),
                                   dtype=np.int32)


def _prioritized(moves: Moves, table: np.ndarray, starts: list[int], goals: list[int],
                 bound: int, turn_step: float, headings: np.ndarray, effort: int = 10_000,
                 total: int = 300) -> np.ndarray | None:
    """Prioritized planning (:func:`_prioritized_once`), first in the order of farther goals
    first; when a robot finds no path, again with that robot moved to the front of the
    order (each robot at most once: at most ``n + 1`` attempts); ``None`` when the last
    attempt fails too, or when the attempts together expand more than ``total`` times the
    sum of the robots' distances + 1 states (with the turns' steps, on the MovingAI maps
    with 32 and 64 robots they expand 5 to 11 times it, antipodal swaps of 64 to 256
    robots 15 to 42 times on the 4-connected grid and 29 to 120 times over the
    diagonals).
    ``bound`` (>= 0) is the largest makespan sought; ``turn_step`` and ``headings``
    (``(n,)``, NaN where unknown) as :func:`plan_paths`'s."""
    n = len(starts)
    order = sorted(range(n), key=lambda i: (-table[i, starts[i]], i))
    moved: set[int] = set()
    budget = [int(total * sum(int(table[i, starts[i]]) + 1 for i in range(n)))]
    # room for plans twice as long as the longest distance (grown if longer)
    tables = _Tables(table.shape[1], 2 * (2 + int(table[np.arange(n), starts].max())))
    while True:
        plan, failed = _prioritized_once(moves, table, starts, goals, order, effort, bound,
                                         tables, budget, turn_step, headings)
        if plan is not None:
            return plan
        if failed < 0 or failed in moved:
            return None
        moved.add(failed)
        order = [failed] + [i for i in order if i != failed]


def _prioritized_once(moves: Moves, table: np.ndarray, starts: list[int], goals: list[int],
                      order: list[int], effort: int, bound: int, tables: _Tables,
                      budget: list[int], turn_step: float, headings: np.ndarray
                      ) -> tuple[np.ndarray | None, int]:
    """One prioritized planning in ``order``: each robot's path a safe-interval A*
    (:func:`sqpmpc.kernels.mapf.safe_interval_search`) around the robots planned before
    it (their vertices, their edges the other way, and their goals from their arrival
    on); it may follow one of them onto the vertex it leaves, never be followed by one
    (so no cycle of following: no rotation); it arrives as early as any path, and among
    the paths found arriving as early takes the one with the fewest turns, since a
    unicycle slows down at every corner. Returns the plan and -1,
    or ``None`` and the robot whose search found no path (arriving by ``bound`` when
    ``bound >= 0``) or expanded more than ``effort`` times (its distance + 1) states;
    ``None`` and -1 once the attempts' shared ``budget`` (expansions left) is spent."""
    n, size = len(starts), tables.size
    tables.clear()
    parked = np.full(size, UNBOUNDED, dtype=np.int64)  # vertex -> step a robot stays from
    last_use = np.full(size, -1, dtype=np.int64)  # vertex -> last step a robot is there
    others = np.zeros(size, dtype=np.uint8)  # starts of the robots not planned yet
    others[starts] = 1
    empty = 0  # the first step from which every reservation row is empty
    paths: list[np.ndarray] = [np.zeros(0, dtype=np.int64)] * n
    # the most steps a robot takes to leave a vertex: a half-turn, then the move; a robot
    # not planned yet keeps its start that long (it may have to turn before it leaves)
    hold = 1 + (int(np.ceil(np.pi / turn_step)) if turn_step > 0.0 else 0)
    moves.turning(turn_step)
    for i in order:
        others[starts[i]] = 0
        own = effort * (int(table[i, starts[i]]) + 1)
        limit = min(own, budget[0])
        # with the turns' steps first; where that finds no path (a robot that must dodge
        # the robots before it as fast as the grid allows), without them: the plan stays
        # conflict-free, only its timing of that robot's turns is not the unicycle's
        for step in ((float(turn_step), 0.0) if turn_step > 0.0 else (0.0,)):
            while True:
                tables.search += 1
                status, length, spent, path = safe_interval_search(
                    moves.ptr, moves.targets, moves.b, moves.c, moves.straight, moves.angle,
                    moves.back, moves.offsets, moves.depart, moves.turn, step,
                    float(headings[i]), hold, table[i], moves.x, moves.y,
                    starts[i], goals[i], int(last_use[goals[i]]) + 1, bound, limit,
                    tables.runs, tables.count, parked, others, tables.search, tables.states,
                    tables.heap)
                if status != SCRATCH:
                    break
                tables.scratch(length)
            budget[0] -= spent
            limit = min(own, budget[0])
            if status == FOUND or limit <= 0:
                break
        if status == LIMIT:
            return None, (i if own <= limit else -1)  # its own effort, or the attempts'
        if status != FOUND:
            return None, i
        tables.fit(length + 2)
        last = reserve_path(path, length, moves.ptr, moves.targets, moves.b, moves.c,
                            tables.res, parked, last_use, tables.runs, tables.count, empty)
        empty = max(empty, last + 1)  # rows up to last hold the reservations
        paths[i] = path
    horizon = max(p.size for p in paths)
    return np.array([np.concatenate((p, np.full(horizon - p.size, p[-1]))) for p in paths],
                    dtype=np.int64).T, -1


def straight_on(roadmap: Roadmap, diagonal: bool = False) -> dict[tuple[int, int], int]:
    """``(u, v) -> w``: the first neighbour ``w`` of ``v`` straight on from the edge
    ``u -> v`` (``w - v`` parallel to ``v - u``, same way), where there is one (over the
    diagonals too when ``diagonal``)."""
    graph = _graph(roadmap, diagonal)
    ptr, idx, pos = graph.indptr, graph.indices, roadmap.positions
    degree = np.diff(ptr)
    u = np.repeat(np.arange(roadmap.size), degree)  # the directed edges u -> v
    v = idx
    # every continuation v -> w of every edge, in v's neighbour order
    count = degree[v]
    edge = np.repeat(np.arange(v.size), count)
    offset = np.arange(edge.size) - np.repeat(np.cumsum(count) - count, count)
    w = idx[np.repeat(ptr[v], count) + offset]
    back = (pos[v] - pos[u])[edge]
    step = pos[w] - pos[v][edge]
    cross = np.abs(back[:, 0] * step[:, 1] - back[:, 1] * step[:, 0])
    ok = (w != u[edge]) & (cross <= 1e-9 * (1.0 + np.einsum("ij,ij->i", back, back))) & (
        np.einsum("ij,ij->i", back, step) > 0.0)
    first = np.unique(edge[ok], return_index=True)[1]  # the first straight one per edge
    chosen = np.flatnonzero(ok)[first]
    e = edge[chosen]
    return dict(zip(zip(u[e].tolist(), v[e].tolist(), strict=True), w[chosen].tolist(),
                    strict=True))

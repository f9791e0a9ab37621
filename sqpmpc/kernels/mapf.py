r"""Compiled kernels of the roadmap planners (:mod:`sqpmpc.coordination.mapf`).

:func:`bfs_distances` gives the hop distances to the robots' goals (the
heuristic of the space-time search and PIBT's preferences);
:func:`space_time_search` is one robot's search of prioritized planning around
the robots planned before it, whose paths :func:`reserve_path` writes into
the reservation tables.

Reservation tables are ``(H, V)`` arrays indexed by step and vertex, with
``H`` larger than every step reserved: a row at or beyond the last reserved step
is empty, so a step past ``H - 1`` reads row ``H - 1``. Let :math:`R` be the first
step from which every row is empty. From step :math:`R + 1` on, every condition a
move must meet is the same at every step (the rows it reads, at :math:`t - 1`
to :math:`t + 2`, are empty, the parked robots park before :math:`R`), so the
search identifies the nodes :math:`(v, t)`, :math:`t \ge R + 1` with the one node
:math:`(v, R + 1)`, kept with its earliest step: the space-time graph searched is
finite, :math:`V (R + 2)` nodes, and a robot that no path brings to its goal is
found out when its search runs out of nodes.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["bfs_distances", "reserve_path", "space_time_search", "warm_up_mapf"]

_jit = numba.njit(cache=True, nogil=True)

#: :func:`space_time_search`'s outcomes
FOUND, NO_PATH, LIMIT = 0, 1, 2

_T_BITS = 20  # steps below 2**20
_K_BITS = 20  # turns below 2**20


@_jit
def bfs_distances(indptr: np.ndarray, indices: np.ndarray, sources: np.ndarray,
                  out: np.ndarray) -> None:
    """``out[k, v]``: the fewest edges from ``sources[k]`` to ``v`` (``inf`` where none)
    on the undirected graph in CSR form ``indptr, indices``; breadth-first."""
    size = indptr.size - 1
    queue = np.empty(size, dtype=np.int64)
    for k in range(sources.size):
        row = out[k]
        row[:] = np.inf
        s = sources[k]
        row[s] = 0.0
        queue[0] = s
        head, tail = 0, 1
        while head < tail:
            v = queue[head]
            head += 1
            dv = row[v] + 1.0
            for e in range(indptr[v], indptr[v + 1]):
                u = indices[e]
                if row[u] == np.inf:
                    row[u] = dv
                    queue[tail] = u
                    tail += 1


@_jit
def _less(keys: np.ndarray, ties: np.ndarray, a: int, b: int) -> bool:
    return keys[a] < keys[b] or (keys[a] == keys[b] and ties[a] < ties[b])


@_jit
def _swap(keys: np.ndarray, ties: np.ndarray, verts: np.ndarray, a: int, b: int) -> None:
    keys[a], keys[b] = keys[b], keys[a]
    ties[a], ties[b] = ties[b], ties[a]
    verts[a], verts[b] = verts[b], verts[a]


@_jit
def _sift_up(keys: np.ndarray, ties: np.ndarray, verts: np.ndarray, i: int) -> None:
    while i > 0:
        p = (i - 1) >> 1
        if not _less(keys, ties, i, p):
            return
        _swap(keys, ties, verts, i, p)
        i = p


@_jit
def _sift_down(keys: np.ndarray, ties: np.ndarray, verts: np.ndarray, size: int) -> None:
    i = 0
    while True:
        left = 2 * i + 1
        if left >= size:
            return
        best = left
        if left + 1 < size and _less(keys, ties, left + 1, left):
            best = left + 1
        if not _less(keys, ties, best, i):
            return
        _swap(keys, ties, verts, i, best)
        i = best


@_jit
def _row(t: int, rows: int) -> int:
    return t if t < rows else rows - 1


# the reservation table's bits: occupied, entered, then the vertex the occupant came from + 1
_OCC, _ENTER, _FROM = 1, 2, 2
# the fields of a node in the scratch array
_MARK, _TURNS, _PARENT, _CAME, _EARLY, _WAITS = 0, 1, 2, 3, 4, 5
FIELDS = 6


@_jit
def _corner_free(x: int, t: int, res: np.ndarray, parked: np.ndarray, others: np.ndarray,
                 hold: int) -> bool:
    """Whether corner ``x`` of a diagonal move from ``t`` to ``t + 1`` is free: no robot
    planned before is there from ``t - 1`` to ``t + 1``, enters it at ``t + 2`` or is parked
    on it by then, and no robot not planned yet stands there at ``t = 0``."""
    rows = res.shape[0]
    for s in range(max(t - 1, 0), t + 2):
        if res[_row(s, rows), x] & _OCC:
            return False
    if res[_row(t + 2, rows), x] & _ENTER or parked[x] <= t + 1:
        return False
    return not (t < hold and others[x])


@_jit
def space_time_search(cptr: np.ndarray, cidx: np.ndarray, cb: np.ndarray, cc: np.ndarray,
                      straight: np.ndarray, angle: np.ndarray, turn_step: float,
                      heading: float, hold: int, dist: np.ndarray, start: int, goal: int,
                      free_at: int, bound: int, limit: int, res: np.ndarray,
                      parked: np.ndarray, others: np.ndarray, collapse: int, search: int,
                      nodes: np.ndarray, path: np.ndarray) -> tuple[int, int, int]:
    r"""One robot's space-time A* around the robots planned before it.

    A node :math:`(v, t)` is the robot at ``v`` at step ``t``; its successors are the
    moves ``cidx[cptr[v]:cptr[v + 1]]`` (``v`` itself: the wait; a diagonal where
    ``cb >= 0``, passing the corners ``cb, cc``). A move to ``u`` at
    :math:`t + 1` is allowed when ``u`` is not occupied then nor parked on by then
    (``res``, ``parked``), no robot comes from ``u`` to ``v``, no robot enters
    ``u`` at :math:`t + 2` (it would follow this one: no rotation), at :math:`t = 0`
    no robot not planned yet stands on ``u`` (``others``), and a diagonal's corners are
    free (:func:`_corner_free`). The key is lexicographic,
    :math:`(t + \max(d(v), t_{\text{free}} - t),\ \text{turns},\ -t)`, then the order of
    the pushes: the first node popped at the goal at or after ``free_at`` arrives as
    early as any path, with the fewest turns among those (a move is a turn when it is
    not the edge straight on, ``straight``, from the last move; a wait keeps the last
    move). Nodes with :math:`t \ge` ``collapse`` are one node per vertex (module
    docstring), kept with the earliest step, then the fewest turns.

    **Turns take time** (``turn_step > 0``): a unicycle turns in place by at most
    ``turn_step`` radians per step (:math:`\omega_{\max} h / v_{\max}`), so a move whose
    direction differs by :math:`\Delta` from the robot's heading (the last move's, at
    the start ``heading``) is made after :math:`\lceil \Delta / \text{turn\_step}
    \rceil` steps turning at its vertex, each kept free as a wait is. The node
    reached keeps its label (fewest turns) as any other: the search is exact in time
    for the heading of that label.

    Parameters
    ----------
    cptr, cidx, cb, cc
        The moves in CSR form: ``cidx[e]`` the end of move ``e`` out of its vertex,
        ``cb[e], cc[e]`` its corners (-1 for a grid edge).
    straight
        ``(E,)`` the vertex straight on after move ``e``, -1 where none.
    angle
        ``(E,)`` the direction of move ``e``, rad (any value for a wait).
    turn_step
        Largest turn in place per step, rad (``<= 0``: turns take no time).
    heading
        The robot's heading at the start, rad (NaN: unknown, its first turn takes no time).
    hold
        The robots not planned yet keep their starts up to step ``hold`` (1: they leave
        at the first step; with turns, they may have to turn before).
    dist
        ``(V,)`` hop distances to ``goal`` (the heuristic).
    start, goal, free_at
        The robot's start and goal vertices, and the step from which its goal is free.
    bound
        Largest arrival step searched (-1: none).
    limit
        Largest number of expansions.
    res
        ``(H, V)`` the reservations: bit 0 occupied, bit 1 entered, the bits from 2 on
        one more than the vertex the occupant came from (0: none).
    parked, others
        ``(V,)`` the step from which a robot stays on each vertex, and the starts of the
        robots not planned yet.
    collapse
        :math:`R + 1`, the first step searched as one node per vertex;
        ``collapse < nodes.shape[0]``.
    search
        A number above every earlier search's on ``nodes``.
    nodes
        Scratch ``(H, V, FIELDS)``: per node ``2 search`` (seen) or ``2 search + 1``
        (expanded), its turns, parent vertex, last move and (collapsed) step.
    path
        Output, at least ``collapse + V + 1`` long (a path is at most that long: past
        ``collapse`` it visits distinct vertices): the path's vertices at steps ``0..T``.

    Returns
    -------
    tuple
        The outcome (:data:`FOUND`, :data:`NO_PATH` or :data:`LIMIT`), ``T + 1`` (the
        path's length, when found) and the expansions made.
    """
    rows = res.shape[0]
    seen_mark, closed_mark = 2 * search, 2 * search + 1
    capacity = 1024
    keys = np.empty(capacity, dtype=np.int64)
    ties = np.empty(capacity, dtype=np.int64)
    verts = np.empty(capacity, dtype=np.int64)
    t_top = (1 << _T_BITS) - 1
    h0 = max(dist[start], float(free_at))
    if h0 == np.inf or (bound >= 0 and h0 > bound):
        return NO_PATH, 0, 0
    node = nodes[0, start]
    node[_MARK] = seen_mark
    node[_TURNS] = 0
    node[_CAME] = -1
    node[_PARENT] = -1
    node[_EARLY] = 0
    node[_WAITS] = 0
    keys[0] = ((int(h0) << _K_BITS) << _T_BITS) | t_top
    ties[0] = 0
    verts[0] = start
    heap = 1
    pushes = 0
    expanded = 0
    while heap > 0:
        key, v = keys[0], verts[0]
        heap -= 1
        if heap > 0:
            keys[0], ties[0], verts[0] = keys[heap], ties[heap], verts[heap]
            _sift_down(keys, ties, verts, heap)
        t = t_top - (key & t_top)
        k = (key >> _T_BITS) & ((1 << _K_BITS) - 1)
        layer = min(t, collapse)
        node = nodes[layer, v]
        if node[_MARK] == closed_mark or k > node[_TURNS]:
            continue  # expanded already, or reached with fewer turns since
        if layer == collapse and t > node[_EARLY]:
            continue  # reached earlier since
        node[_MARK] = closed_mark
        expanded += 1
        if expanded > limit:
            return LIMIT, 0, expanded
        if v == goal and t >= free_at:
            w, s = v, t
            while s >= 0:
                path[s] = w
                entry = nodes[min(s, collapse), w]
                parent, waits = entry[_PARENT], entry[_WAITS]
                for _ in range(waits):  # turning at the vertex before
                    s -= 1
                    path[s] = parent
                w = parent
                s -= 1
            return FOUND, t + 1, expanded
        last = node[_CAME]
        facing = heading if last < 0 else angle[last]
        for e in range(cptr[v], cptr[v + 1]):
            u = cidx[e]  # v itself: the wait
            waits = 0
            if turn_step > 0.0 and u != v and not np.isnan(facing):
                bend = abs((angle[e] - facing + np.pi) % (2.0 * np.pi) - np.pi)
                waits = int(np.ceil(bend / turn_step - 1e-9))
            if waits > 0:  # turning at v first: each step kept free as a wait is
                blocked = False
                for s2 in range(t + 1, t + waits + 1):
                    if (res[_row(s2, rows), v] & _OCC or parked[v] <= s2
                            or res[_row(s2 + 1, rows), v] & _ENTER):
                        blocked = True
                        break
                if blocked:
                    continue
            t0 = t + waits  # the step the move starts from
            t2 = t0 + 1
            layer2 = min(t2, collapse)
            here = res[_row(t2, rows)]
            ahead = res[_row(t2 + 1, rows)]
            nxt = nodes[layer2, u]
            if nxt[_MARK] == closed_mark or here[u] & _OCC or parked[u] <= t2:
                continue
            if u != v and (here[v] >> _FROM) == u + 1:
                continue  # a robot comes the other way
            if ahead[u] & _ENTER:  # it would be followed by a robot planned before
                continue
            if t2 <= hold and u != v and others[u]:
                continue  # a robot not planned yet still stands there
            if cb[e] >= 0 and not (_corner_free(cb[e], t0, res, parked, others, hold)
                                   and _corner_free(cc[e], t0, res, parked, others, hold)):
                continue  # a diagonal passes the square's other corners: kept free
            move = last if u == v else e
            bend = 1 if (u != v and last >= 0 and straight[last] != u) else 0
            count = k + bend
            h = max(dist[u], float(free_at - t2))
            if h == np.inf:
                continue
            f = t2 + int(h)
            if bound >= 0 and f > bound:
                continue
            if nxt[_MARK] == seen_mark:
                if layer2 == collapse:
                    if t2 > nxt[_EARLY] or (t2 == nxt[_EARLY] and count >= nxt[_TURNS]):
                        continue
                elif count >= nxt[_TURNS]:
                    continue
            nxt[_MARK] = seen_mark
            nxt[_PARENT] = v
            nxt[_TURNS] = count
            nxt[_CAME] = move
            nxt[_EARLY] = t2
            nxt[_WAITS] = waits
            pushes += 1
            if heap == capacity:
                capacity *= 2
                keys2 = np.empty(capacity, dtype=np.int64)
                ties2 = np.empty(capacity, dtype=np.int64)
                verts2 = np.empty(capacity, dtype=np.int64)
                keys2[:heap] = keys[:heap]
                ties2[:heap] = ties[:heap]
                verts2[:heap] = verts[:heap]
                keys, ties, verts = keys2, ties2, verts2
            keys[heap] = (((f << _K_BITS) | count) << _T_BITS) | (t_top - t2)
            ties[heap] = pushes
            verts[heap] = u
            heap += 1
            _sift_up(keys, ties, verts, heap - 1)
    return NO_PATH, 0, expanded


@_jit
def reserve_path(path: np.ndarray, length: int, cptr: np.ndarray, cidx: np.ndarray,
                 cb: np.ndarray, cc: np.ndarray, res: np.ndarray, parked: np.ndarray,
                 last_use: np.ndarray) -> int:
    """Write a path of ``length`` vertices into the reservations ``res`` (its vertices, its
    entries, the vertex it comes from, a diagonal's corners held from the step before it
    to the step after, its goal parked from its arrival); ``res.shape[0]`` must exceed
    ``length``. Returns the last step reserved."""
    last = length - 1
    for t in range(length):
        v = path[t]
        res[t, v] |= _OCC
        if last_use[v] < t:
            last_use[v] = t
        if t + 1 < length:
            w = path[t + 1]
            res[t + 1, w] |= (v + 1) << _FROM
            if w != v:
                res[t + 1, w] |= _ENTER
                for e in range(cptr[v], cptr[v + 1]):
                    if cidx[e] == w and cb[e] >= 0:  # held over the diagonal move
                        for x in (cb[e], cc[e]):
                            res[t, x] |= _OCC | _ENTER
                            res[t + 1, x] |= _OCC
                            if last_use[x] < t + 1:
                                last_use[x] = t + 1
    parked[path[last]] = last
    return last


def warm_up_mapf() -> None:
    """Compile or load the kernels for the argument types the planners pass."""
    indptr = np.array([0, 1, 2], dtype=np.int64)
    indices = np.array([1, 0], dtype=np.int64)
    out = np.empty((1, 2))
    bfs_distances(indptr, indices, np.array([0], dtype=np.int64), out)
    minus = np.full(2, -1, dtype=np.int64)
    rows, size = 4, 2
    res = np.zeros((rows, size), dtype=np.int64)
    parked = np.full(size, 1 << 40, dtype=np.int64)
    nodes = np.zeros((rows, size, FIELDS), dtype=np.int32)
    path = np.zeros(rows * size, dtype=np.int64)
    status, length, _ = space_time_search(
        indptr, indices, minus, minus, minus, np.zeros(2), 1.0, np.nan, 1, out[0], 1, 0, 0, -1,
        100, res, parked,
        np.zeros(size, dtype=np.uint8), 1, 1, nodes, path)
    if status == FOUND:
        reserve_path(path, length, indptr, indices, minus, minus, res, parked,
                     np.full(size, -1, dtype=np.int64))

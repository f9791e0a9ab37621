r"""Compiled kernels of the roadmap planners (:mod:`sqpmpc.coordination.mapf`).

:func:`bfs_distances` gives the hop distances to the robots' goals (the
heuristic of the robots' searches and PIBT's preferences);
:func:`safe_interval_search` is one robot's search of prioritized planning around
the robots planned before it, whose paths :func:`reserve_path` writes into the
reservations; :func:`straight_moves` and :func:`turn_tables` prepare the moves.

Reservations and safe intervals
-------------------------------
The reservation table is an ``(H, V)`` array indexed by step and vertex, with
``H`` larger than every step reserved: per step and vertex, whether a robot is
there (*occupied*), whether it moved in at that step (*entered*) and the vertex it
came from. A robot may stand on :math:`x` at step :math:`s` when no robot planned
before is there, none enters :math:`x` at :math:`s + 1` (it would follow this one,
which only robots planned *after* may do: no cycle of following, no rotation), none
is parked on :math:`x` by then and, for :math:`s \le` ``hold``, :math:`x` is no start
of a robot not planned yet. The steps at which it may not are the *blocked* steps
:math:`B(x)`, and the maximal runs of steps outside :math:`B(x)` are the *safe
intervals* of :math:`x` (Phillips and Likhachev, *SIPP: Safe Interval Path Planning
for Dynamic Environments*, ICRA 2011). :func:`reserve_path` keeps every vertex's
blocked runs of the table (``runs``, ``count``); interval :math:`j` of :math:`x` is the
gap before its run :math:`j`, the last one unbounded, cut short where a robot parks
on :math:`x` and, up to ``hold``, at the starts of the robots not planned yet.

A move :math:`x \to u` leaving at :math:`t_0` (on :math:`x` at :math:`t_0`, on
:math:`u` at :math:`t_0 + 1`) needs :math:`t_0 \notin B(x)`, :math:`t_0 + 1 \notin
B(u)`, no robot going :math:`u \to x` at the same time (a swap: such a robot enters
:math:`x` at :math:`t_0 + 1`, so :math:`t_0 \in B(x)`, which the first condition
already excludes) and, for a diagonal, the square's two other corners free: no robot
on them from :math:`t_0 - 1` to :math:`t_0 + 1`, entering them at :math:`t_0 + 2` or
parked on them by :math:`t_0 + 1` (steps :math:`t_0 - 1 .. t_0 + 1` in one safe
interval of the corner), nor, for :math:`t_0 <` ``hold``, a robot not planned yet.
**Turns take time**: a move in a direction :math:`\Delta` away from the robot's
heading (its last move's, at the start its own) is made after :math:`w =
\lceil \Delta / \text{turn\_step} \rceil` steps standing on :math:`x` (turning): with
arrival :math:`t_a` on :math:`x`, :math:`t_0 \ge t_a + w`. Waits and turns are steps
on :math:`x` inside its interval. The robot's start at step 0 is its own even where a
robot planned before holds it from step 1 (as a corner of a diagonal, which may pass a
start from that step): the robot then leaves it at once.

The search
----------
A state :math:`\sigma = (x, j, \theta)` is a vertex, one of its safe intervals and the
robot's heading there (the move it came by; one state for every heading when turns
take no time); its *label* is the step :math:`t` it arrives and the turns of the path.

1. *Dominance.* Of two arrivals :math:`t \le t'` at one state, every continuation of
   the later is one of the earlier: the robot stands on :math:`x` from :math:`t` to
   :math:`t'` (the interval's steps are free), keeping its heading, and the steps a
   turn needs are counted from :math:`t`. So a state keeps its earliest arrival (then
   its fewest turns). Likewise :math:`(x, j, \theta_1)` at :math:`t_1` dominates
   :math:`(x, j, \theta_2)` at :math:`t_2 \ge t_1 + w(\theta_1, \theta_2)`: it turns
   to :math:`\theta_2` standing by then, and :math:`w(\theta_1, \theta') \le
   w(\theta_1, \theta_2) + w(\theta_2, \theta')` for every later direction
   :math:`\theta'` (angles obey the triangle inequality, and :math:`\lceil a + b
   \rceil \le \lceil a \rceil + \lceil b \rceil`); a dominated label is dropped.
2. *Successors.* From :math:`(\sigma, t)`, for every move :math:`x \to u` and every
   interval :math:`[l, h]` of :math:`u` that meets :math:`[t + w + 1, \text{end}(j) +
   1]`, the successor arrives at the first step of that overlap at which the move is
   allowed (a grid move: its first step; a diagonal: the first step at which both
   corners are free, found from the corners' intervals). Any later arrival in that
   interval is dominated (1).
3. *Order.* A* with :math:`f = \max(t + d(u) + \lceil \alpha / \text{turn\_step}
   \rceil, F)`: :math:`d` the hop distance to the goal, :math:`\alpha` the angle
   between the heading and the straight line to the goal, :math:`F` the step from
   which the goal is free. Every path on from the label takes :math:`d` more moves and
   parks no earlier than :math:`F`; its moves add up to the line to the goal, so
   (positive combinations of directions lying within the arc they span) its heading
   turns at least by :math:`\alpha`, which takes at least :math:`\lceil \alpha /
   \text{turn\_step} \rceil` steps standing. So :math:`f` is a lower bound of every
   arrival through the label (admissible). A state reached again *strictly earlier*
   after its expansion is opened again. Then the first goal label popped arrives as
   early as any path (A* with an admissible heuristic and re-opening: until then,
   some label on an optimal path, arriving there no later than that path, is open,
   and its :math:`f` is at most the optimal arrival, below every later goal label's).
   The goal is reached in its last interval, unbounded: free from :math:`F` on for
   good, where the robot parks. Among labels of one :math:`f` the fewer turns go
   first, then the later arrival (deeper): among equally early arrivals the one
   returned has the fewest turns of the labels kept (each state keeps one).
4. *Termination and completeness.* The states are finite (:math:`\sum_x
   (\text{runs}(x) + 1)` intervals times the headings) and a label is pushed only when
   it improves its state's (arrival, turns) lexicographically, so finitely many
   labels are expanded: a robot that no path brings home is found out when the heap
   runs empty, and one that a path does gets the earliest (a smallest integer).

The search replaced a space-time A* over :math:`(x, t)` nodes, exact in time only for
the heading of each node's label, whose waits made plateaus of nodes; on a 256-robot
antipodal swap with turns it expanded about 14,000 nodes per robot.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["FIELDS", "FOUND", "LIMIT", "NO_PATH", "SCRATCH", "UNBOUNDED", "bfs_distances",
           "reserve_path", "safe_interval_search", "straight_moves", "turn_tables",
           "warm_up_mapf"]

_jit = numba.njit(cache=True, nogil=True)

#: :func:`safe_interval_search`'s outcomes; ``SCRATCH``: a scratch array is too small
FOUND, NO_PATH, LIMIT, SCRATCH = 0, 1, 2, 3
#: an unbounded interval's end; a vertex nobody parks on has ``parked`` at least this
UNBOUNDED = 1 << 40
#: the fields of a search state (:func:`safe_interval_search`'s ``states``)
FIELDS = 8
_MARK, _TIME, _TURNS, _PARENT, _CAME, _VERTEX, _INTERVAL = 0, 1, 2, 3, 4, 5, 6
# the reservation table's bits: occupied, entered, then the vertex the occupant came from + 1
_OCC, _ENTER, _FROM = 1, 2, 2
# the heap's first key packs f and the turns, _BITS bits for the turns; the second is
# _MASK minus the arrival (steps below 2 ** _BITS)
_BITS = 20
_MASK = (1 << _BITS) - 1


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


@numba.njit(cache=True, nogil=True, inline="always")
def _dominated(states: np.ndarray, row: int, width: int, sid: int, t: int, seen: int,
               turn: np.ndarray, offset: int, facing: float, heading: float,
               turn_step: float) -> bool:
    """Whether state ``sid`` (arrival ``t``, reached by a move in direction ``facing``) is
    dominated by a sibling: a state of the same vertex and interval, ``states[row:row +
    width]``, seen in this search and reached earlier by at least the turn from its
    heading to this one's (``turn[offset + (sid - row) + (sib - row) width]``; from the
    start, the turn from ``heading``, free when it is unknown)."""
    table = offset + sid - row
    for sib in range(row, row + width):
        if sib == sid or states[sib, _MARK] < seen or states[sib, _TIME] >= t:
            continue
        if states[sib, _CAME] >= 0:
            if states[sib, _TIME] + turn[table + (sib - row) * width] <= t:
                return True
        elif np.isnan(heading):  # the start, its heading unknown: turns free
            return True
        else:
            bend = abs((facing - heading + np.pi) % (2.0 * np.pi) - np.pi)
            if states[sib, _TIME] + int(np.ceil(bend / turn_step - 1e-9)) <= t:
                return True
    return False


@_jit
def safe_interval_search(cptr: np.ndarray, cidx: np.ndarray, cb: np.ndarray, cc: np.ndarray,
                         straight: np.ndarray, angle: np.ndarray, back: np.ndarray,
                         offsets: np.ndarray, depart: np.ndarray, turn: np.ndarray,
                         turn_step: float, heading: float, hold: int, dist: np.ndarray,
                         px: np.ndarray, py: np.ndarray, start: int, goal: int,
                         free_at: int, bound: int, limit: int, runs: np.ndarray,
                         count: np.ndarray, parked: np.ndarray, others: np.ndarray,
                         search: int, states: np.ndarray, heap: np.ndarray
                         ) -> tuple[int, int, int, np.ndarray]:
    r"""One robot's safe-interval A* around the robots planned before it (module
    docstring): the path arriving as early as any at the goal, to stay there, among
    those found so the one with the fewest turns.

    A move to ``u`` arriving at :math:`t + 1` is allowed when ``u`` is not occupied then,
    nor parked on by then, no robot enters ``u`` at :math:`t + 2` (it would follow this
    one: no rotation), the robot was on its vertex at :math:`t` under the same conditions
    (which rules out a robot coming the other way), up to ``hold`` no robot not planned
    yet stands on ``u`` (``others``), and a diagonal's corners are free: no robot
    planned before on them from :math:`t - 1` to :math:`t + 1`, entering them at
    :math:`t + 2` or parked on them by :math:`t + 1`, and, for :math:`t <` ``hold``, no
    robot not planned yet. A move turning the robot's heading by :math:`\Delta` is made
    after :math:`\lceil \Delta / \text{turn\_step} \rceil` steps standing (turning) on
    its vertex (``turn_step > 0``: a unicycle turns in place by at most
    :math:`\omega_{\max} h / v_{\max}` per step), each kept free as a wait is.

    Parameters
    ----------
    cptr, cidx, cb, cc
        The moves in CSR form: ``cidx[e]`` the end of move ``e`` out of its vertex (one
        of them the vertex itself: the wait, implicit here), ``cb[e], cc[e]`` its corners
        (-1 for a grid edge).
    straight
        ``(E,)`` the vertex straight on after move ``e``, -1 where none.
    angle
        ``(E,)`` the direction of move ``e``, rad (any value for a wait).
    back
        ``(E,)`` the move back of move ``e`` (out of its end; a wait's itself): its
        place among its end's moves is the heading of the state it reaches.
    offsets, depart, turn
        :func:`turn_tables` at ``turn_step`` (read only when ``turn_step > 0``).
    turn_step
        Largest turn in place per step, rad (``<= 0``: turns take no time).
    heading
        The robot's heading at the start, rad (NaN: unknown, its first turn takes no time).
    hold
        The robots not planned yet keep their starts up to step ``hold`` (1: they leave
        at the first step; with turns, they may have to turn before).
    dist
        ``(V,)`` hop distances to ``goal`` (the heuristic).
    px, py
        ``(V,)`` the vertices' positions (the heuristic's turn towards the goal).
    start, goal, free_at
        The robot's start and goal vertices, and the step from which its goal is free.
    bound
        Largest arrival step searched (-1: none).
    limit
        Largest number of expansions.
    runs, count
        ``(V, K, 2)`` and ``(V,)``: every vertex's blocked runs (first and last step),
        in order, and how many (:func:`reserve_path`).
    parked, others
        ``(V,)`` the step from which a robot stays on each vertex (at least
        :data:`UNBOUNDED`: none), and the starts of the robots not planned yet.
    search
        A number above every earlier search's on ``states``.
    states
        Scratch ``(S, FIELDS)`` int32: per state ``2 search`` (seen) or ``2 search + 1``
        (expanded), its arrival, turns, parent state, last move, vertex and interval.
    heap
        Scratch ``(C, 3)`` int64: the open labels (two keys and the state).

    Returns
    -------
    tuple
        The outcome (:data:`FOUND`, :data:`NO_PATH`, :data:`LIMIT` or :data:`SCRATCH`:
        ``states`` needs the number of rows returned next or, when it is negative, the
        heap ``-number`` rows), ``T + 1`` (the path's length, when found), the
        expansions made and the path's vertices at steps ``0..T``.
    """
    # the bodies of small helpers are written out here: a call passing arrays costs their
    # reference counts (atomic), a third of the time when they were calls
    size = cptr.size - 1
    timed = turn_step > 0.0
    none = np.zeros(0, dtype=np.int64)
    # the states of every vertex in one block: (runs + 1) intervals times its headings
    # (one when turns take no time)
    base = np.empty(size + 1, dtype=np.int64)
    total = 0
    for x in range(size):
        base[x] = total
        total += (count[x] + 1) * (cptr[x + 1] - cptr[x] if timed else 1)
    base[size] = total
    if total > states.shape[0]:
        return SCRATCH, total, 0, none
    if dist[start] == np.inf or (bound >= 0 and max(int(dist[start]), free_at) > bound):
        return NO_PATH, 0, 0, none
    seen, closed = 2 * search, 2 * search + 1
    slot = 0
    if timed:  # the start's heading: the wait's slot
        for e in range(cptr[start], cptr[start + 1]):
            if cidx[e] == start:
                slot = e - cptr[start]
    sid = base[start] + slot
    states[sid, _MARK] = seen
    states[sid, _TIME] = 0
    states[sid, _TURNS] = 0
    states[sid, _PARENT] = -1
    states[sid, _CAME] = -1
    states[sid, _VERTEX] = start
    states[sid, _INTERVAL] = 0
    capacity = heap.shape[0]
    heap[0, 0] = max(int(dist[start]), free_at) << _BITS  # f, then the turns
    heap[0, 1] = _MASK  # then the later arrival
    heap[0, 2] = sid
    n_heap = 1
    expanded = 0
    gx, gy = px[goal], py[goal]
    # cos(k turn_step), k = 0, 1, ...: the turn towards the goal takes the least k steps
    # whose cosine is at most the angle's (a hair lower: the bound stays a lower bound)
    cosines = np.full(2 + int(np.pi / turn_step) if timed else 1, -2.0)
    for step in range(cosines.size - 1):
        cosines[step] = np.cos(step * turn_step) - 1e-12
    while n_heap > 0:
        key, tie, sid = heap[0, 0], heap[0, 1], heap[0, 2]
        n_heap -= 1
        if n_heap > 0:  # the last entry sifted down from the root
            for c in range(3):
                heap[0, c] = heap[n_heap, c]
            i = 0
            while True:
                a = 2 * i + 1
                if a >= n_heap:
                    break
                if a + 1 < n_heap and (heap[a + 1, 0] < heap[a, 0] or (
                        heap[a + 1, 0] == heap[a, 0] and heap[a + 1, 1] < heap[a, 1])):
                    a += 1
                if not (heap[a, 0] < heap[i, 0] or (
                        heap[a, 0] == heap[i, 0] and heap[a, 1] < heap[i, 1])):
                    break
                for c in range(3):
                    heap[i, c], heap[a, c] = heap[a, c], heap[i, c]
                i = a
        t, k = _MASK - tie, key & _MASK
        if (states[sid, _MARK] == closed or t != states[sid, _TIME]
                or k != states[sid, _TURNS]):
            continue  # expanded already, or a better label since
        v, j, last = states[sid, _VERTEX], states[sid, _INTERVAL], states[sid, _CAME]
        width = cptr[v + 1] - cptr[v]
        if timed and last >= 0 and _dominated(  # by a sibling reached since (1)
                states, base[v] + j * width, width, sid, t, seen, turn, offsets[v],
                angle[last], heading, turn_step):
            states[sid, _MARK] = closed
            continue
        states[sid, _MARK] = closed
        expanded += 1
        if expanded > limit:
            return LIMIT, 0, expanded, none
        last_v = UNBOUNDED if j == count[v] else runs[v, j, 0] - 1  # the interval's end
        if parked[v] < UNBOUNDED and parked[v] - 1 < last_v:
            last_v = parked[v] - 1
        if last_v < t:  # the start, taken from step 1 (a robot planned before holds it as
            last_v = t  # the corner of a diagonal, the start's robot to leave at once)
        if v == goal and last_v == UNBOUNDED:  # parked from t on, free for good
            path = np.empty(t + 1, dtype=np.int64)
            path[t] = v
            child = sid
            while states[child, _PARENT] >= 0:
                parent = states[child, _PARENT]
                for s in range(states[parent, _TIME], states[child, _TIME]):
                    path[s] = states[parent, _VERTEX]  # waiting or turning there
                child = parent
            return FOUND, t + 1, expanded, path
        here = offsets[v] + (back[last] - cptr[v]) * width if timed and last >= 0 else 0
        for e in range(cptr[v], cptr[v + 1]):
            u = cidx[e]
            if u == v or dist[u] == np.inf:
                continue  # the wait: inside the interval, implicit
            waits = 0
            if timed and last >= 0:  # the heading's row of the table
                waits = depart[here + e - cptr[v]]
            elif timed and not np.isnan(heading):
                bend = abs((angle[e] - heading + np.pi) % (2.0 * np.pi) - np.pi)
                waits = int(np.ceil(bend / turn_step - 1e-9))
            if t + waits > last_v:
                continue  # the interval ends before the turn does
            early = t + waits + 1  # the first and last steps it may arrive at u
            late = last_v + 1 if last_v < UNBOUNDED else UNBOUNDED
            turns = k + (1 if (last >= 0 and straight[last] != u) else 0)
            # the heuristic: the hops left, and the turn towards the goal (3)
            h = int(dist[u])
            if timed and u != goal:  # the least k with cos(angle) >= cos(k turn_step)
                ax, ay = px[u] - px[v], py[u] - py[v]
                bx, by = gx - px[u], gy - py[u]
                cosine = (ax * bx + ay * by) / np.sqrt((ax * ax + ay * ay) * (bx * bx + by * by))
                step = 0
                while cosine < cosines[step]:
                    step += 1
                h += step
            slot = back[e] - cptr[u] if timed else 0
            across = cptr[u + 1] - cptr[u] if timed else 1
            # u's first interval ending at or after `early`: the first run starting after
            # it (bisection)
            lo, hi = 0, count[u]
            while lo < hi:
                m = (lo + hi) >> 1
                if runs[u, m, 0] > early:
                    hi = m
                else:
                    lo = m + 1
            for ju in range(lo, count[u] + 1):
                first_u = 0 if ju == 0 else runs[u, ju - 1, 1] + 1
                if others[u] and first_u <= hold:
                    first_u = hold + 1
                if first_u > late:
                    break
                last_u = UNBOUNDED if ju == count[u] else runs[u, ju, 0] - 1
                if parked[u] < UNBOUNDED and parked[u] - 1 < last_u:
                    last_u = parked[u] - 1
                t2 = max(first_u, early)
                top = min(last_u, late)
                if t2 > top:
                    continue
                if cb[e] >= 0:  # a diagonal: the first step t0 from t2 - 1 on at which
                    # both corners are free, each one's found in turn until both agree
                    t0 = t2 - 1
                    x = cb[e]
                    agreed = 0
                    while agreed < 2 and t0 < top:
                        # corner x from t1 on: steps t1 - 1 .. t1 + 1 in one of its safe
                        # intervals (as reserved; a start of a robot not planned yet only
                        # while t1 < hold)
                        t1 = hold if (others[x] and t0 < hold) else t0
                        while True:
                            s0 = max(t1 - 1, 0)
                            lo, hi = 0, count[x]
                            while lo < hi:
                                m = (lo + hi) >> 1
                                if runs[x, m, 0] > s0:
                                    hi = m
                                else:
                                    lo = m + 1
                            first_x = 0 if lo == 0 else runs[x, lo - 1, 1] + 1
                            if first_x > s0:
                                t1 = first_x + 1
                                continue
                            last_x = UNBOUNDED if lo == count[x] else runs[x, lo, 0] - 1
                            if parked[x] < UNBOUNDED and parked[x] - 1 < last_x:
                                last_x = parked[x] - 1
                            if t1 + 1 <= last_x:
                                break
                            if lo == count[x]:
                                t1 = UNBOUNDED  # parked on for good
                                break
                            t1 = runs[x, lo, 1] + 2
                        agreed = agreed + 1 if t1 == t0 else 1
                        t0 = t1
                        x = cc[e] if x == cb[e] else cb[e]
                    if t0 >= top:
                        continue
                    t2 = t0 + 1
                f = max(t2 + h, free_at)
                if (bound >= 0 and f > bound) or t2 > _MASK:
                    break  # later intervals arrive later still
                row = base[u] + ju * across
                sid2 = row + slot
                # dominated by this interval reached earlier with another heading, by
                # more than the turn between them (1)
                if timed and _dominated(states, row, across, sid2, t2, seen, turn,
                                        offsets[u], angle[e], heading, turn_step):
                    continue
                mark = states[sid2, _MARK]
                if mark >= seen:  # seen in this search
                    if t2 > states[sid2, _TIME] or (t2 == states[sid2, _TIME] and (
                            turns >= states[sid2, _TURNS] or mark == closed)):
                        continue  # no better: expanded ones are opened again only earlier
                states[sid2, _MARK] = seen
                states[sid2, _TIME] = t2
                states[sid2, _TURNS] = turns
                states[sid2, _PARENT] = sid
                states[sid2, _CAME] = e
                states[sid2, _VERTEX] = u
                states[sid2, _INTERVAL] = ju
                if n_heap == capacity:
                    return SCRATCH, -2 * capacity, expanded, none  # a larger heap
                i = n_heap  # sifted up from the end: f, the turns, the later arrival
                n_heap += 1
                heap[i, 0] = (f << _BITS) | turns
                heap[i, 1] = _MASK - t2
                heap[i, 2] = sid2
                while i > 0:
                    p = (i - 1) >> 1
                    if not (heap[i, 0] < heap[p, 0] or (
                            heap[i, 0] == heap[p, 0] and heap[i, 1] < heap[p, 1])):
                        break
                    for c in range(3):
                        heap[i, c], heap[p, c] = heap[p, c], heap[i, c]
                    i = p
    return NO_PATH, 0, expanded, none


@_jit
def straight_moves(ptr: np.ndarray, head: np.ndarray, px: np.ndarray, py: np.ndarray,
                   out: np.ndarray) -> None:
    """``out[e]``: for move ``e`` (in CSR form ``ptr, head``; a wait's end is its start)
    the end's neighbour of least index straight on from it (the way parallel to the move's
    and the same way, not back), -1 where none or for a wait."""
    size = ptr.size - 1
    for v in range(size):
        for e in range(ptr[v], ptr[v + 1]):
            u = head[e]
            out[e] = -1
            if u == v:
                continue
            ax, ay = px[u] - px[v], py[u] - py[v]
            scale = 1e-9 * (1.0 + ax * ax + ay * ay)
            for e2 in range(ptr[u], ptr[u + 1]):
                w = head[e2]
                if w == u or w == v or (out[e] >= 0 and w >= out[e]):
                    continue
                bx, by = px[w] - px[u], py[w] - py[u]
                if abs(ax * by - ay * bx) <= scale and ax * bx + ay * by > 0.0:
                    out[e] = w


@_jit
def turn_tables(ptr: np.ndarray, back: np.ndarray, angle: np.ndarray, turn_step: float,
                offsets: np.ndarray, depart: np.ndarray, turn: np.ndarray) -> None:
    r"""The steps a robot turns in place at every vertex ``u`` (``D`` moves out of it, in
    CSR form ``ptr``): heading as it arrives by the move back of its move ``a`` (from that
    neighbour), before it leaves by its move ``b``, ``depart[offsets[u] + a D + b]``, and
    until it heads as one arriving by the move back of ``b``, ``turn[offsets[u] + a D +
    b]``: :math:`\lceil \Delta / \text{turn\_step} \rceil` for a turn by
    :math:`\Delta`."""
    for u in range(ptr.size - 1):
        width = ptr[u + 1] - ptr[u]
        for a in range(width):
            arrived = angle[back[ptr[u] + a]]
            for b in range(width):
                e = ptr[u] + b
                k = offsets[u] + a * width + b
                bend = abs((angle[e] - arrived + np.pi) % (2.0 * np.pi) - np.pi)
                depart[k] = int(np.ceil(bend / turn_step - 1e-9))
                bend = abs((angle[back[e]] - arrived + np.pi) % (2.0 * np.pi) - np.pi)
                turn[k] = int(np.ceil(bend / turn_step - 1e-9))


@_jit
def _runs(x: int, reach: int, res: np.ndarray, runs: np.ndarray, count: np.ndarray) -> None:
    """The blocked runs of vertex ``x`` over steps ``0..reach - 1`` of ``res``: a step on
    which a robot is there, or one before a robot enters."""
    rows = res.shape[0]
    n = 0
    for s in range(min(reach, rows)):
        if res[s, x] & _OCC or (s + 1 < rows and res[s + 1, x] & _ENTER):
            if n > 0 and runs[x, n - 1, 1] == s - 1:
                runs[x, n - 1, 1] = s
            else:
                runs[x, n, 0] = s
                runs[x, n, 1] = s
                n += 1
    count[x] = n


@_jit
def reserve_path(path: np.ndarray, length: int, cptr: np.ndarray, cidx: np.ndarray,
                 cb: np.ndarray, cc: np.ndarray, res: np.ndarray, parked: np.ndarray,
                 last_use: np.ndarray, runs: np.ndarray, count: np.ndarray, reach: int
                 ) -> int:
    """Write a path of ``length`` vertices into the reservations ``res`` (its vertices, its
    entries, the vertex it comes from, a diagonal's corners held from the step before it
    to the step after, its goal parked from its arrival) and the blocked runs ``runs,
    count`` of the vertices it touches. ``res.shape[0]`` must exceed ``length``, ``runs``
    have room for ``res.shape[0] // 2 + 1`` runs, and every row of ``res`` from ``reach``
    on be empty. Returns the last step reserved."""
    last = length - 1
    touched = np.zeros(res.shape[1], dtype=np.bool_)
    for t in range(length):
        v = path[t]
        res[t, v] |= _OCC
        touched[v] = True
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
                            touched[x] = True
                            if last_use[x] < t + 1:
                                last_use[x] = t + 1
    parked[path[last]] = last
    span = max(reach, last + 2)
    for x in np.flatnonzero(touched):
        _runs(x, span, res, runs, count)
    return last


def warm_up_mapf() -> None:
    """Compile or load the kernels for the argument types the planners pass."""
    indptr = np.array([0, 1, 2], dtype=np.int64)
    indices = np.array([1, 0], dtype=np.int64)
    out = np.empty((1, 2))
    bfs_distances(indptr, indices, np.array([0], dtype=np.int64), out)
    straight_moves(indptr, indices, np.zeros(2), np.zeros(2), np.empty(2, dtype=np.int64))
    back = np.array([1, 0], dtype=np.int64)
    offsets = np.array([0, 1, 2], dtype=np.int64)
    depart = np.zeros(2, dtype=np.int64)
    turn = np.zeros(2, dtype=np.int64)
    turn_tables(indptr, back, np.zeros(2), 1.0, offsets, depart, turn)
    minus = np.full(2, -1, dtype=np.int64)
    rows, size = 4, 2
    res = np.zeros((rows, size), dtype=np.int64)
    runs = np.zeros((size, rows // 2 + 1, 2), dtype=np.int64)
    count = np.zeros(size, dtype=np.int64)
    parked = np.full(size, UNBOUNDED, dtype=np.int64)
    states = np.zeros((8, FIELDS), dtype=np.int32)
    status, length, _, path = safe_interval_search(
        indptr, indices, minus, minus, minus, np.zeros(2), back, offsets, depart, turn,
        1.0, np.nan, 1, out[0], np.zeros(2), np.zeros(2), 1, 0, 0, -1, 100, runs, count,
        parked, np.zeros(size, dtype=np.uint8), 1, states, np.zeros((8, 3), dtype=np.int64))
    if status == FOUND:
        reserve_path(path, length, indptr, indices, minus, minus, res, parked,
                     np.full(size, -1, dtype=np.int64), runs, count, 0)

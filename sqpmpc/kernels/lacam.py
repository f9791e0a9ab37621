r"""Compiled LaCAM with PIBT (:mod:`sqpmpc.coordination.mapf`, its module docstring has
the algorithm and its completeness argument).

:func:`lacam_search` is the whole search, in arrays: the roadmap in CSR form, the robots'
hop distances to their goals as an ``(n, V)`` integer table, the vertex straight on after
every directed edge; no Python object is made per search node or per step.

The search
----------
A *high-level node* :math:`h` holds a configuration :math:`Q_h \in V^n`, its parent,
the robots' priorities and their order (highest first), and a FIFO queue of
*constraints*. The priority of robot :math:`i` is :math:`p_i = c_i + d_i(s_i) / (|V| +
1)`: :math:`c_i` counts the steps since it last stood on its goal (0 at the start), so
robots long away from their goals go first, ties broken by their distances at the start
(then by index). A constraint is a low-level node: robots :math:`(i_1, \dots, i_m)`, the
first :math:`m` of :math:`h`'s order, told to go to :math:`(v_1, \dots, v_m)`; it is
stored as a tree (parent, robot, vertex, depth :math:`m`) so each is :math:`O(1)` memory.
Visiting :math:`h` pops the next constraint :math:`L`; if :math:`m < n` it first queues
:math:`L`'s children, robot :math:`i_{m+1}` told to go to each of its neighbours and its
own vertex (in a random order). PIBT completes :math:`L` to a successor configuration (or
fails); a configuration already in the table of explored ones (open addressing on a
64-bit FNV-1a hash of the configuration, compared in full on equal hashes) puts its node
back on the depth-first stack, a new one becomes a child of :math:`h`. Every
configuration reachable in one step from :math:`Q_h` is the completion of exactly the
constraint that fixes all :math:`n` robots to it, which the queue reaches after finitely
many visits: the search is complete over the configurations (LaCAM's theorem 1).

PIBT
----
Robots are taken in :math:`h`'s order; a robot :math:`i` not yet assigned tries its
neighbours and its own vertex by increasing :math:`d_i(u)`, among equals the vertex
straight on from its last move first (from the parent configuration: a unicycle turns at
a corner, not on a line), then in a random order (splitmix64, seeded). A candidate
:math:`u` is skipped when a robot already goes there (vertex conflict), when the robot
:math:`k` standing on it goes to :math:`i`'s vertex (swap) or when :math:`i` moving onto
:math:`k`'s vertex closes a cycle of robots each moving onto the vertex the next leaves (a
rotation). When :math:`k` is not assigned yet it inherits the priority: PIBT runs for
:math:`k` (depth first, an explicit stack of at most :math:`n` frames: a robot on it is
assigned, so it is never asked again), and if :math:`k` cannot move, :math:`i` tries its
next candidate. A robot with no candidate left stays (and fails). A successor is
accepted only if no robot of it (the constraint's included) closes a rotation.

*Swap technique* (LaCAM2, Okumura, IJCAI 2023). Let :math:`u^*` be :math:`i`'s best
candidate. Walking from a robot's vertex :math:`x` to a neighbour :math:`y`, the ways on
from :math:`y` are its neighbours but :math:`x` and dead ends where a robot stands on its
goal. A swap is *required* of :math:`i` and the robot :math:`j` on :math:`u^*` (not yet
assigned) when, walking from :math:`i`'s vertex through :math:`u^*` along vertices with
one way on while :math:`d_i` decreases, no vertex with two ways comes (no place for
:math:`j` to step aside), and at the end each is nearer its goal from the other's side;
it is *possible* when walking from :math:`u^*` through :math:`i`'s vertex, away, a vertex
with two ways comes before a dead end (and before the walk comes round to :math:`u^*`):
there they can pass. Likewise with a robot beside :math:`i` that must come through
:math:`i`'s vertex towards :math:`u^*`. Then :math:`i` tries its candidates in reverse
(steps back) and, when it moves to its first one, pulls that robot onto the vertex it
leaves, if nobody claims it and the pull closes no rotation; the pair so walks back to
the branch, where the ordinary rule lets them pass.

Every ``after[v] = r`` written has ``nxt[r] = v`` until the step ends (a robot that fails
overwrites the claim of its caller on its own vertex, whose caller moves on; a pull writes
both), so the claims are cleared through ``nxt``.
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["EXHAUSTED", "FOUND", "OVER_BUDGET", "lacam_search", "warm_up_lacam"]

_jit = numba.njit(cache=True, nogil=True)
_inline = numba.njit(cache=True, nogil=True, inline="always")

#: :func:`lacam_search`'s outcomes: a plan, no plan (every reachable configuration
#: explored), the node budget spent
FOUND, EXHAUSTED, OVER_BUDGET = 0, 1, 2

_FNV_OFFSET = np.uint64(14695981039346656037)
_FNV_PRIME = np.uint64(1099511628211)
_MIX = np.uint64(0xFF51AFD7ED558CCD)
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


@_jit
def _hash(config: np.ndarray) -> np.uint64:
    r"""The hash of a configuration: 64-bit FNV-1a over its vertices, each one word,
    :math:`h \leftarrow (h \oplus v_r)\, p \bmod 2^{64}`, then MurmurHash3's finalizer
    (:math:`h \leftarrow h \oplus (h \gg 33)`, times a constant, again), so that the low
    bits (the table's slot) depend on every bit of every vertex."""
    h = _FNV_OFFSET
    for r in range(config.size):
        h = (h ^ np.uint64(config[r])) * _FNV_PRIME
    h ^= h >> np.uint64(33)
    h *= _MIX
    h ^= h >> np.uint64(33)
    return h


@_inline
def _below(state: np.ndarray, bound: int) -> int:
    """A pseudo-random integer in ``[0, bound)`` from the splitmix64 generator whose state
    is ``state[0]`` (advanced)."""
    state[0] += _GOLDEN
    z = state[0]
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z ^= z >> np.uint64(31)
    return np.int64(z % np.uint64(bound))


@_jit
def _grown2(a: np.ndarray, rows: int) -> np.ndarray:
    """``a`` with at least ``rows`` rows (doubling), the first ``a.shape[0]`` kept."""
    out = np.empty((max(rows, 2 * a.shape[0]), a.shape[1]), dtype=a.dtype)
    out[:a.shape[0]] = a
    return out


@_jit
def _grown1(a: np.ndarray, size: int) -> np.ndarray:
    """``a`` with at least ``size`` entries (doubling), the first ``a.size`` kept."""
    out = np.empty(max(size, 2 * a.size), dtype=a.dtype)
    out[:a.size] = a
    return out


@_inline
def _closes_cycle(i: int, k: int, nxt: np.ndarray, now: np.ndarray) -> bool:
    """Whether robot ``i`` moving onto robot ``k``'s vertex closes a rotation: ``k`` moves
    onto a vertex whose robot moves on, and so on, round to ``i``'s own vertex."""
    j = k
    for _ in range(nxt.size):
        if nxt[j] < 0:
            return False
        o = now[nxt[j]]
        if o < 0 or o == j:
            return False
        if o == i:
            return True
        j = o
    return False


@_inline
def _candidates(i: int, config: np.ndarray, previous: np.ndarray, ptr: np.ndarray,
                idx: np.ndarray, straight: np.ndarray, dist: np.ndarray, state: np.ndarray,
                out: np.ndarray) -> int:
    """Robot ``i``'s next vertices in PIBT's order into ``out``: its neighbours and its own
    vertex by distance to its goal, among equals the vertex straight on from its last move
    first, then at random (``state``: :func:`_below`'s). Returns how many."""
    here = config[i]
    count = 0
    for e in range(ptr[here], ptr[here + 1]):
        out[count] = idx[e]
        count += 1
    out[count] = here
    count += 1
    for a in range(count - 1, 0, -1):  # Fisher-Yates
        b = _below(state, a + 1)
        out[a], out[b] = out[b], out[a]
    ahead = -1
    back = previous[i]
    if back != here:
        for e in range(ptr[back], ptr[back + 1]):
            if idx[e] == here:
                ahead = straight[e]
                break
    row = dist[i]
    for a in range(1, count):  # stable insertion sort by (distance, not straight on)
        u = out[a]
        du, su = row[u], 1 if u != ahead else 0
        b = a - 1
        while b >= 0 and (row[out[b]] > du or (row[out[b]] == du
                                                and (1 if out[b] != ahead else 0) > su)):
            out[b + 1] = out[b]
            b -= 1
        out[b + 1] = u
    return count


@_inline
def _blocked(u: int, pusher_at: int, ptr: np.ndarray, idx: np.ndarray, now: np.ndarray,
             goals: np.ndarray) -> bool:
    """Whether a robot cannot be pulled to ``u`` (a neighbour of the puller's vertex): it is
    where the pusher comes from, or a dead end a robot stands on as its goal."""
    if u == pusher_at:
        return True
    a = now[u]
    return ptr[u + 1] - ptr[u] == 1 and a >= 0 and goals[a] == u


@_inline
def _ways_on(ahead: int, back: int, ptr: np.ndarray, idx: np.ndarray, now: np.ndarray,
             goals: np.ndarray) -> tuple[int, int]:
    """The ways on from ``ahead`` (coming from ``back``) that are not blocked, and the last
    of them (``-1``: none): one step of a walk along a corridor."""
    ways = 0
    on = -1
    for e in range(ptr[ahead], ptr[ahead + 1]):
        u = idx[e]
        if not _blocked(u, back, ptr, idx, now, goals):
            ways += 1
            on = u
    return ways, on


@_inline
def _swap_required(pusher: int, puller: int, pusher_at: int, puller_at: int,
                   ptr: np.ndarray, idx: np.ndarray, dist: np.ndarray, now: np.ndarray,
                   goals: np.ndarray) -> bool:
    """Whether ``pusher`` (on ``pusher_at``) and ``puller`` (on its neighbour
    ``puller_at``) must swap: walking the corridor ahead of the puller (vertices with one
    way on) towards the pusher's goal, no place to step aside comes before the pusher
    would pass the puller, and each is then nearer its goal on the other's side."""
    back, ahead = pusher_at, puller_at
    while dist[pusher, ahead] < dist[pusher, back]:
        ways, on = _ways_on(ahead, back, ptr, idx, now, goals)
        if ways >= 2:  # a branch: the puller can step aside there
            return False
        if ways == 0:
            break
        back, ahead = ahead, on
    return (dist[puller, back] < dist[puller, ahead]
            and (dist[pusher, back] == 0 or dist[pusher, ahead] < dist[pusher, back]))


@_inline
def _swap_possible(pusher_at: int, puller_at: int, ptr: np.ndarray, idx: np.ndarray,
                   now: np.ndarray, goals: np.ndarray) -> bool:
    """Whether the corridor behind ``puller_at`` (away from ``pusher_at``) reaches a branch,
    where the two robots can pass each other."""
    back, ahead = pusher_at, puller_at
    while ahead != pusher_at:  # round a loop: no
        ways, on = _ways_on(ahead, back, ptr, idx, now, goals)
        if ways >= 2:
            return True
        if ways == 0:
            return False
        back, ahead = ahead, on
    return False


@_inline
def _swapper(i: int, best: int, config: np.ndarray, ptr: np.ndarray, idx: np.ndarray,
             dist: np.ndarray, now: np.ndarray, nxt: np.ndarray, goals: np.ndarray) -> int:
    """The robot ``i`` must swap with, going the other way through a corridor, to reach
    its best vertex ``best`` (LaCAM2's swap technique), -1 when none: the robot on
    ``best`` when neither can otherwise pass, or a robot beside ``i`` coming through
    ``i``'s vertex towards ``best``."""
    here = config[i]
    if best == here:
        return -1
    j = now[best]
    if (j >= 0 and nxt[j] < 0 and _swap_required(i, j, here, best, ptr, idx, dist, now, goals)
            and _swap_possible(best, here, ptr, idx, now, goals)):
        return j
    for e in range(ptr[here], ptr[here + 1]):
        u = idx[e]
        k = now[u]
        if k < 0 or u == best:
            continue
        if (_swap_required(k, i, here, best, ptr, idx, dist, now, goals)
                and _swap_possible(best, here, ptr, idx, now, goals)):
            return k
    return -1


@_inline
def _enter(top: int, i: int, config: np.ndarray, previous: np.ndarray, ptr: np.ndarray,
           idx: np.ndarray, straight: np.ndarray, dist: np.ndarray, state: np.ndarray,
           now: np.ndarray, nxt: np.ndarray, goals: np.ndarray, frame: np.ndarray,
           cand: np.ndarray, ncand: np.ndarray, tried: np.ndarray, swap: np.ndarray
           ) -> None:
    """Frame ``top`` of PIBT's stack for robot ``i``: its candidates in order, reversed when
    it must swap (it steps back first, to pull the other robot after it)."""
    frame[top] = i
    count = _candidates(i, config, previous, ptr, idx, straight, dist, state, cand[top])
    ncand[top] = count
    tried[top] = 0
    swap[top] = _swapper(i, cand[top, 0], config, ptr, idx, dist, now, nxt, goals)
    if swap[top] >= 0:
        row = cand[top]
        for a in range(count // 2):
            row[a], row[count - 1 - a] = row[count - 1 - a], row[a]


@_jit
def _pibt(root: int, config: np.ndarray, previous: np.ndarray, ptr: np.ndarray,
          idx: np.ndarray, straight: np.ndarray, dist: np.ndarray, goals: np.ndarray,
          state: np.ndarray, now: np.ndarray, after: np.ndarray, nxt: np.ndarray,
          frame: np.ndarray, cand: np.ndarray, ncand: np.ndarray, tried: np.ndarray,
          swap: np.ndarray) -> bool:
    """PIBT from robot ``root`` (module docstring), the recursion on an explicit stack:
    ``frame`` its robots, ``cand``/``ncand`` their candidates, ``tried`` how many each
    has tried and ``swap`` the robot each pulls after it (-1: none). Returns whether
    ``root`` found a vertex."""
    top = 0
    _enter(0, root, config, previous, ptr, idx, straight, dist, state, now, nxt, goals,
           frame, cand, ncand, tried, swap)
    result = False
    returning = False
    while top >= 0:
        i = frame[top]
        here = config[i]
        done = False
        if returning:
            returning = False
            done = result  # the robot asked to move did: so does this one
        pushed = False
        while not done and tried[top] < ncand[top]:
            u = cand[top, tried[top]]
            tried[top] += 1
            if after[u] >= 0:
                continue
            k = now[u]
            if k >= 0 and k != i and (nxt[k] == here or _closes_cycle(i, k, nxt, now)):
                continue  # k comes here (a swap) or round to here (a rotation)
            after[u] = i
            nxt[i] = u
            if k < 0 or k == i or nxt[k] >= 0:
                done = True
                break
            top += 1  # k inherits the priority
            _enter(top, k, config, previous, ptr, idx, straight, dist, state, now, nxt,
                   goals, frame, cand, ncand, tried, swap)
            pushed = True
            break
        if pushed:
            continue
        if done:
            j = swap[top]  # stepped back first: pull the robot to swap with after it
            if (tried[top] == 1 and j >= 0 and nxt[j] < 0 and after[here] < 0
                    and not _closes_cycle(j, i, nxt, now)):
                after[here] = j
                nxt[j] = here
        else:
            after[here] = i
            nxt[i] = here
        result = done
        top -= 1
        returning = True
    return result


@_jit
def _step(config: np.ndarray, previous: np.ndarray, order: np.ndarray, who: np.ndarray,
          where: np.ndarray, m: int, ptr: np.ndarray, idx: np.ndarray,
          straight: np.ndarray, dist: np.ndarray, goals: np.ndarray, state: np.ndarray,
          now: np.ndarray, after: np.ndarray, nxt: np.ndarray, frame: np.ndarray,
          cand: np.ndarray, ncand: np.ndarray, tried: np.ndarray, swap: np.ndarray) -> bool:
    """PIBT's successor of ``config`` (reached from ``previous``) under the constraint
    ``who[:m] -> where[:m]``, into ``nxt``; whether there is one. ``now`` and ``after``
    (``(V,)``, -1) are left as they came."""
    n = config.size
    for r in range(n):
        now[config[r]] = r
        nxt[r] = -1
    ok = True
    for c in range(m):
        i, v = who[c], where[c]
        if after[v] >= 0:  # vertex conflict among the constraints
            ok = False
            break
        j = now[v]
        if j >= 0 and j != i and nxt[j] == config[i]:  # swap conflict
            ok = False
            break
        after[v] = i
        nxt[i] = v
    if ok:
        for c in range(n):
            i = order[c]
            if nxt[i] < 0 and not _pibt(i, config, previous, ptr, idx, straight, dist, goals,
                                        state, now, after, nxt, frame, cand, ncand, tried,
                                        swap):
                ok = False
                break
    if ok:  # the constraints' robots too: nobody follows round a cycle
        for i in range(n):
            k = now[nxt[i]]
            if k >= 0 and k != i and _closes_cycle(i, k, nxt, now):
                ok = False
                break
    for r in range(n):
        if nxt[r] >= 0:
            after[nxt[r]] = -1
        now[config[r]] = -1
    return ok


@_jit
def _order(count: np.ndarray, start_share: np.ndarray, out: np.ndarray) -> None:
    """The robots by decreasing priority ``count + start_share`` (ties by index)."""
    out[:] = np.argsort(-(count + start_share), kind="mergesort")


@_jit
def lacam_search(ptr: np.ndarray, idx: np.ndarray, straight: np.ndarray, dist: np.ndarray,
                 starts: np.ndarray, goals: np.ndarray, seed: int, max_nodes: int
                 ) -> tuple[int, int, np.ndarray]:
    r"""LaCAM with PIBT from ``starts`` to ``goals`` (module docstring).

    Parameters
    ----------
    ptr, idx
        The roadmap in CSR form (no self-loops).
    straight
        ``(E,)`` for every directed edge ``e`` (out of its vertex to ``idx[e]``) the vertex
        straight on after it, -1 where none.
    dist
        ``(n, V)`` hop distances from every vertex to each robot's goal, integers (a
        vertex that cannot reach the goal: any value above every finite one).
    starts, goals
        ``(n,)`` distinct vertices each, every goal reachable from its start.
    seed
        Seed of the tie-breaking (the search is a function of its inputs and the seed).
    max_nodes
        Largest number of search nodes besides the root.

    Returns
    -------
    tuple
        The outcome (:data:`FOUND`, :data:`EXHAUSTED` or :data:`OVER_BUDGET`), the
        search nodes made and, when found, the plan's ``(T + 1, n)`` configurations
        (otherwise ``(0, n)``).
    """
    state = np.empty(1, dtype=np.uint64)
    state[0] = np.uint64(seed)
    n, size = starts.size, ptr.size - 1
    degree = 0
    for v in range(size):
        degree = max(degree, ptr[v + 1] - ptr[v])
    share = np.empty(n)
    for i in range(n):
        share[i] = dist[i, starts[i]] / (size + 1.0)
    # the search nodes: configuration, parent, steps away from the goal, order, constraints
    cap = 1024
    conf = np.empty((cap, n), dtype=np.int32)
    count = np.zeros((cap, n), dtype=np.int32)
    order = np.empty((cap, n), dtype=np.int32)
    parent = np.empty(cap, dtype=np.int64)
    hashes = np.empty(cap, dtype=np.uint64)
    head = np.empty(cap, dtype=np.int64)  # the constraint queue: first and last
    tail = np.empty(cap, dtype=np.int64)
    # the constraints: parent, robot, vertex, depth, next in its node's queue
    lcap = 8192
    lparent = np.empty(lcap, dtype=np.int64)
    lwho = np.empty(lcap, dtype=np.int32)
    lwhere = np.empty(lcap, dtype=np.int32)
    ldepth = np.empty(lcap, dtype=np.int32)
    lnext = np.empty(lcap, dtype=np.int64)
    # the explored configurations: open addressing, node ids (-1: empty)
    table = np.full(4 * cap, -1, dtype=np.int64)
    stack = np.empty(cap, dtype=np.int64)
    # PIBT's scratch
    now = np.full(size, -1, dtype=np.int64)
    after = np.full(size, -1, dtype=np.int64)
    nxt = np.empty(n, dtype=np.int64)
    frame = np.empty(n, dtype=np.int64)
    cand = np.empty((n, degree + 1), dtype=np.int64)
    ncand = np.empty(n, dtype=np.int64)
    tried = np.empty(n, dtype=np.int64)
    swap = np.empty(n, dtype=np.int64)
    who = np.empty(n, dtype=np.int64)
    where = np.empty(n, dtype=np.int64)
    choices = np.empty(degree + 1, dtype=np.int64)
    config = np.empty(n, dtype=np.int32)
    empty = np.zeros((0, n), dtype=np.int64)

    conf[0] = starts
    count[0] = 0
    _order(count[0].astype(np.float64), share, order[0])
    parent[0] = -1
    hashes[0] = _hash(conf[0])
    lparent[0], lwho[0], lwhere[0], ldepth[0], lnext[0] = -1, -1, -1, 0, -1
    head[0] = 0
    tail[0] = 0
    lows = 1
    mask = table.size - 1
    table[np.int64(hashes[0] & np.uint64(mask))] = 0
    nodes = 1
    stack[0] = 0
    sp = 1
    found = -1
    at_goal = True
    for i in range(n):
        if starts[i] != goals[i]:
            at_goal = False
    if at_goal:
        found = 0
    while sp > 0 and found < 0:
        h = stack[sp - 1]
        low = head[h]
        if low < 0:  # every constraint of this node tried
            sp -= 1
            continue
        head[h] = lnext[low]
        if head[h] < 0:
            tail[h] = -1
        depth = ldepth[low]
        if depth < n:  # the next robot's choices extend this constraint
            i = order[h, depth]
            here = conf[h, i]
            k = 0
            for e in range(ptr[here], ptr[here + 1]):
                choices[k] = idx[e]
                k += 1
            choices[k] = here
            k += 1
            for a in range(k - 1, 0, -1):
                b = _below(state, a + 1)
                choices[a], choices[b] = choices[b], choices[a]
            if lows + k > lparent.size:
                lparent = _grown1(lparent, lows + k)
                lwho = _grown1(lwho, lows + k)
                lwhere = _grown1(lwhere, lows + k)
                ldepth = _grown1(ldepth, lows + k)
                lnext = _grown1(lnext, lows + k)
            for a in range(k):
                lparent[lows], lwho[lows], lwhere[lows] = low, i, choices[a]
                ldepth[lows], lnext[lows] = depth + 1, -1
                if tail[h] < 0:
                    head[h] = lows
                else:
                    lnext[tail[h]] = lows
                tail[h] = lows
                lows += 1
        walk = low  # the constraint, root first
        for c in range(depth - 1, -1, -1):
            who[c], where[c] = lwho[walk], lwhere[walk]
            walk = lparent[walk]
        up = parent[h] if parent[h] >= 0 else h
        if not _step(conf[h], conf[up], order[h], who, where, depth, ptr, idx, straight,
                     dist, goals, state, now, after, nxt, frame, cand, ncand, tried, swap):
            continue
        for r in range(n):
            config[r] = nxt[r]
        key = _hash(config)
        slot = np.int64(key & np.uint64(mask))
        seen = -1
        while table[slot] >= 0:
            o = table[slot]
            if hashes[o] == key:
                same = True
                for r in range(n):
                    if conf[o, r] != config[r]:
                        same = False
                        break
                if same:
                    seen = o
                    break
            slot = (slot + 1) & mask
        if seen < 0 and nodes > max_nodes:
            return OVER_BUDGET, nodes - 1, empty
        if sp >= stack.size:
            stack = _grown1(stack, sp + 1)
        if seen >= 0:  # met before: its node goes back on the stack
            stack[sp] = seen
            sp += 1
            continue
        if nodes >= conf.shape[0]:
            conf = _grown2(conf, nodes + 1)
            count = _grown2(count, nodes + 1)
            order = _grown2(order, nodes + 1)
            parent = _grown1(parent, nodes + 1)
            hashes = _grown1(hashes, nodes + 1)
            head = _grown1(head, nodes + 1)
            tail = _grown1(tail, nodes + 1)
        c = nodes
        nodes += 1
        conf[c] = config
        at_goal = True
        for r in range(n):
            if config[r] != goals[r]:
                count[c, r] = count[h, r] + 1
                at_goal = False
            else:
                count[c, r] = 0
        _order(count[c].astype(np.float64), share, order[c])
        parent[c] = h
        hashes[c] = key
        if lows >= lparent.size:
            lparent = _grown1(lparent, lows + 1)
            lwho = _grown1(lwho, lows + 1)
            lwhere = _grown1(lwhere, lows + 1)
            ldepth = _grown1(ldepth, lows + 1)
            lnext = _grown1(lnext, lows + 1)
        lparent[lows], lwho[lows], lwhere[lows], ldepth[lows], lnext[lows] = -1, -1, -1, 0, -1
        head[c] = lows
        tail[c] = lows
        lows += 1
        table[slot] = c
        if 2 * nodes > table.size:  # rehash at half full
            table = np.full(2 * table.size, -1, dtype=np.int64)
            mask = table.size - 1
            for o in range(nodes):
                s = np.int64(hashes[o] & np.uint64(mask))
                while table[s] >= 0:
                    s = (s + 1) & mask
                table[s] = o
        stack[sp] = c
        sp += 1
        if at_goal:
            found = c
    if found < 0:
        return EXHAUSTED, nodes - 1, empty
    length = 0
    walk = found
    while walk >= 0:
        length += 1
        walk = parent[walk]
    plan = np.empty((length, n), dtype=np.int64)
    walk = found
    for t in range(length - 1, -1, -1):
        plan[t] = conf[walk]
        walk = parent[walk]
    return FOUND, nodes - 1, plan


def warm_up_lacam() -> None:
    """Compile or load the kernel for the argument types the planner passes."""
    ptr = np.array([0, 1, 3, 4], dtype=np.int64)
    idx = np.array([1, 0, 2, 1], dtype=np.int64)
    straight = np.array([2, -1, -1, 0], dtype=np.int64)
    dist = np.array([[2, 1, 0]], dtype=np.int64)
    lacam_search(ptr, idx, straight, dist, np.array([0], dtype=np.int64),
                 np.array([2], dtype=np.int64), 0, 10)

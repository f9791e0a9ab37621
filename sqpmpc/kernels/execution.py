r"""Compiled kernels of a schedule's execution (:class:`sqpmpc.coordination.schedule.Execution`).

A robot may head for its path vertex :math:`k` only when every dependency on it is
met: :math:`\text{permitted}_i = \min(L_i - 1, \min\{k_e - 1 : e \text{ unmet}\})`
over the dependencies :math:`e` owned by robot :math:`i` (vertex :math:`k_e`, waiting
for robot :math:`r_e` to reach progress :math:`m_e`), unmet while
:math:`k_e > p_i` and :math:`p_{r_e} < m_e`. Progress never decreases, so a
dependency once passed (:math:`k_e \le p_i`) or met (:math:`p_{r_e} \ge m_e`) stays
so: sorted by owner and vertex, each owner's first unmet dependency gives its
minimum, and a pointer per owner moves past the others once, not at every sample
(a 256-robot swap's plan has tens of thousands of dependencies).

Every controller counts every robot's progress (:func:`advance`: a window of vertices
per robot), but decides the holds and waits (:func:`clear`) only for its own robots:
a robot's hold depends on the robots near its next vertex, its wait on the robots
pushed off their paths onto its way and, for a cycle of waiting, on those they wait
for in turn; the numpy form looked at every robot's (a k-d tree of all, a strongly
connected components pass over the free ones).
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["advance", "clear", "permitted", "warm_up_execution"]

_jit = numba.njit(cache=True, nogil=True)


@_jit
def permitted(progress: np.ndarray, last: np.ndarray, owners: np.ndarray, ends: np.ndarray,
              index: np.ndarray, robot: np.ndarray, need: np.ndarray, pointer: np.ndarray,
              starts: np.ndarray, seen: np.ndarray, out: np.ndarray) -> None:
    """The last path index each robot may head for, into ``out (n,)``.

    Parameters
    ----------
    progress, last
        ``(n,)`` every robot's progress and last path index.
    owners, ends
        ``(g,)`` the owner of each group of dependencies and the end of its group (the
        dependencies sorted by owner, then vertex; a group starts where the previous
        ends).
    index, robot, need
        ``(D,)`` the sorted dependencies: vertex, the robot waited for, its progress
        needed.
    pointer, starts
        ``(g,)`` each group's first dependency not yet passed or met (updated here) and
        the group's start (where the pointers go back to when a progress went down).
    seen
        ``(n,)`` the progress the pointers were moved for (updated here).
    out
        ``(n,)`` output.
    """
    for i in range(progress.size):
        if progress[i] < seen[i]:  # a progress went down (a resume): afresh
            pointer[:] = starts
            break
    seen[:] = progress
    out[:] = last
    for g in range(owners.size):
        o = owners[g]
        p = pointer[g]
        while p < ends[g] and (index[p] <= progress[o] or progress[robot[p]] >= need[p]):
            p += 1
        pointer[g] = p
        if p < ends[g] and index[p] - 1 < out[o]:
            out[o] = index[p] - 1


@_jit
def advance(progress: np.ndarray, last: np.ndarray, permit: np.ndarray, points: np.ndarray,
            now: np.ndarray, robots: np.ndarray, window: int) -> None:
    r"""Count every robot's progress from the measured positions (updated in place).

    Robot :math:`i` is at the path vertex nearest to it among
    :math:`p_i, \dots, p_i + W` (not past its path's end nor past ``permit[i]``, the
    last it may enter; ties: the later one), and its progress never decreases
    (:meth:`sqpmpc.coordination.schedule.Execution.advance`).

    Parameters
    ----------
    progress, last, permit
        ``(n,)`` the progress (updated), last path index, last permitted index.
    points
        ``(n, L, 2)`` the paths' vertex positions.
    now, robots
        ``(N, 2)`` all robots' positions (scenario order) and ``(n,)`` each scheduled
        robot's index there.
    window
        :math:`W`.
    """
    width = points.shape[1]
    for i in range(progress.size):
        x, y = now[robots[i], 0], now[robots[i], 1]
        p = progress[i]
        best, least = -1, 0.0
        # numpy's argmin over the reversed window: the first minimum (or NaN) from the end
        for w in range(window, -1, -1):
            at = p + w
            valid = at <= last[i]
            at = min(at, width - 1)
            gap = math.hypot(points[i, at, 0] - x, points[i, at, 1] - y) \
                if valid and at <= permit[i] else np.inf
            if best < 0 or (not math.isnan(least) and (gap < least or math.isnan(gap))):
                best, least = at, gap
        if best > p:
            progress[i] = best


@_jit
def _free(j: int, now: np.ndarray, robots: np.ndarray, points: np.ndarray,
          progress: np.ndarray, permit: np.ndarray, half: float, state: np.ndarray) -> bool:
    """Whether robot ``j`` may head for its next vertex and no other robot is within
    ``half`` of it (memo in ``state``: 0 not known, 1 free, 2 not)."""
    if state[j] == 0:
        state[j] = 2
        if permit[j] > progress[j]:
            nx, ny = points[j, progress[j] + 1, 0], points[j, progress[j] + 1, 1]
            me = robots[j]
            state[j] = 1
            for k in range(now.shape[0]):  # the distance as the k-d tree takes it
                dx, dy = now[k, 0] - nx, now[k, 1] - ny
                if k != me and math.sqrt(dx * dx + dy * dy) < half:
                    state[j] = 2
                    break
    return state[j] == 1


@_jit
def _off(j: int, now: np.ndarray, robots: np.ndarray, points: np.ndarray,
         progress: np.ndarray, reach: float) -> bool:
    """Whether robot ``j`` (heading for its next vertex) is farther than ``reach`` from
    the edge from its progress vertex to it."""
    ax, ay = now[robots[j], 0], now[robots[j], 1]
    p = progress[j]
    vx, vy = points[j, p, 0], points[j, p, 1]
    ex, ey = points[j, p + 1, 0] - vx, points[j, p + 1, 1] - vy
    length = max(ex * ex + ey * ey, 1e-12)
    g = min(max(((ax - vx) * ex + (ay - vy) * ey) / length, 0.0), 1.0)
    return math.hypot(ax - vx - g * ex, ay - vy - g * ey) > reach


@_jit
def _in_way(r: int, j: int, now: np.ndarray, robots: np.ndarray, points: np.ndarray,
            progress: np.ndarray, sep: float) -> bool:
    """Whether robot ``j`` stands within ``sep`` of robot ``r``'s straight way from where
    it is to its next vertex."""
    ax, ay = now[robots[r], 0], now[robots[r], 1]
    dx = points[r, progress[r] + 1, 0] - ax
    dy = points[r, progress[r] + 1, 1] - ay
    dd = max(dx * dx + dy * dy, 1e-12)
    rx, ry = now[robots[j], 0] - ax, now[robots[j], 1] - ay
    f = min(max((rx * dx + ry * dy) / dd, 0.0), 1.0)
    return math.hypot(rx - f * dx, ry - f * dy) < sep


@_jit
def _follows(r: int, j: int, progress: np.ndarray, dep_key: np.ndarray,
             dep_robot: np.ndarray, key_base: int) -> bool:
    """Whether robot ``r`` depends on robot ``j`` for its next vertex (the plan has ``j``
    there before it)."""
    key = r * key_base + progress[r] + 1
    e = np.searchsorted(dep_key, key)
    while e < dep_key.size and dep_key[e] == key:
        if dep_robot[e] == j:
            return True
        e += 1
    return False


@_jit
def _waits_for(r: int, j: int, now: np.ndarray, robots: np.ndarray, points: np.ndarray,
               progress: np.ndarray, permit: np.ndarray, off: np.ndarray, sep: float,
               half: float, dep_key: np.ndarray, dep_robot: np.ndarray, key_base: int,
               state: np.ndarray) -> bool:
    """Whether free robot ``r`` gives way to robot ``j`` (heading for its next vertex and
    pushed off its path: ``off[j]``): ``j`` is free and on ``r``'s way, not one ``r``
    follows, and ``r`` is not on ``j``'s way in the same sense (the edge ``r -> j`` of the
    graph of waiting)."""
    if j == r or not _in_way(r, j, now, robots, points, progress, sep) or \
            _follows(r, j, progress, dep_key, dep_robot, key_base):
        return False
    if off[r] and _in_way(j, r, now, robots, points, progress, sep) and \
            not _follows(j, r, progress, dep_key, dep_robot, key_base):
        return False  # each on the other's way: neither gives way
    return _free(j, now, robots, points, progress, permit, half, state)


@_jit
def clear(now: np.ndarray, robots: np.ndarray, points: np.ndarray, progress: np.ndarray,
          permit: np.ndarray, spacing: float, reach: float, dep_key: np.ndarray,
          dep_robot: np.ndarray, key_base: int, rows: np.ndarray, out: np.ndarray) -> None:
    r"""The last path index robots ``rows (m,)`` may head for, into ``out (m,)``:
    :meth:`sqpmpc.coordination.schedule.Execution.clear_all` for these robots only.

    A robot permitted beyond its progress holds at its progress vertex when another
    robot is within half the spacing :math:`h` of its next vertex; a robot still free
    gives way when it has an edge in the graph of waiting and is on no cycle of it. The
    edge :math:`r 	o j` (both free): :math:`j` is farther than :math:`
ho` from the
    edge it is on, within :math:`s = h - 2
ho` of :math:`r`'s straight way to its next
    vertex, not a robot the plan has on that vertex before :math:`r`, and :math:`r` is
    not so on :math:`j`'s way. Only what these robots' decisions depend on is looked at:
    the robots they may wait for and, for the cycle, the robots those wait for in turn
    (a search from each robot for a way back to it).

    Parameters
    ----------
    now, robots
        ``(N, 2)`` all robots' positions (scenario order) and ``(n,)`` each scheduled
        robot's index there.
    points, progress, permit
        ``(n, L, 2)`` the paths' vertex positions, ``(n,)`` the progress and
        :func:`permitted`'s output.
    spacing, reach
        :math:`h` and :math:`
ho`.
    dep_key, dep_robot, key_base
        ``(D,)`` the dependencies sorted by owner and vertex: ``owner * key_base +
        vertex``, and the robot waited for.
    rows, out
        ``(m,)`` the robots asked about (schedule indices) and the output.
    """
    n = progress.size
    half = 0.5 * spacing
    sep = spacing - 2.0 * reach
    state = np.zeros(n, dtype=np.int8)
    off = np.zeros(n, dtype=np.bool_)  # heading for its next vertex, pushed off its path
    pushed = np.empty(n, dtype=np.int64)  # those robots (the only ones waited for)
    count = -1  # not yet found
    seen = np.zeros(n, dtype=np.int64)  # the search a robot was last reached by (+1)
    stack = np.empty(n, dtype=np.int64)
    for k in range(rows.size):
        r = rows[k]
        out[k] = permit[r]
        if permit[r] <= progress[r] or now.shape[0] < 2:
            continue
        if not _free(r, now, robots, points, progress, permit, half, state):
            out[k] = progress[r]  # held: another robot on its next vertex
            continue
        if count < 0:
            count = 0
            for j in range(n):
                if permit[j] > progress[j] and _off(j, now, robots, points, progress, reach):
                    off[j] = True
                    pushed[count] = j
                    count += 1
        # gives way when it waits for a robot and no chain of waiting leads back to it
        size = 0
        for c in range(count):
            j = pushed[c]
            if _waits_for(r, j, now, robots, points, progress, permit, off, sep, half,
                          dep_key, dep_robot, key_base, state):
                stack[size] = j
                size += 1
                seen[j] = k + 1
        if size == 0:
            continue
        cyclic = False
        while size > 0 and not cyclic:
            size -= 1
            u = stack[size]
            for c in range(count):
                j = pushed[c]
                if (j == r or seen[j] != k + 1) and _waits_for(
                        u, j, now, robots, points, progress, permit, off, sep, half,
                        dep_key, dep_robot, key_base, state):
                    if j == r:
                        cyclic = True
                        break
                    stack[size] = j
                    size += 1
                    seen[j] = k + 1
        if not cyclic:
            out[k] = progress[r]


def warm_up_execution() -> None:
    """Compile or load the kernels with the array layouts the execution passes."""
    one = np.ones(2, dtype=np.int64)
    permitted(np.zeros(2, dtype=np.int64), one, np.zeros(1, dtype=np.int64), one[:1],
              one[:1], one[:1], one[:1], np.zeros(1, dtype=np.int64),
              np.zeros(1, dtype=np.int64), np.zeros(2, dtype=np.int64), np.empty(2, np.int64))
    progress, robots = np.zeros(2, dtype=np.int64), np.arange(2)
    points = np.zeros((2, 3, 2))
    points[:, :, 0] = np.arange(3)
    now = np.array([[0.1, 0.0], [0.0, 1.0]])
    frozen = now.copy()
    frozen.flags.writeable = False  # the rules' sample view's positions
    for positions in (now, frozen):
        advance(progress, one * 2, one * 2, points, positions, robots, 2)
        clear(positions, robots, points, progress, one * 2, 1.0, 0.1, np.array([1, 4]),
              robots, 3, robots, np.empty(2, dtype=np.int64))

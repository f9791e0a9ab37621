r"""Compiled kernels of the roundabout's fixed rings (:mod:`sqpmpc.rules.roundabout`).

A *ring* is a disc at a point where the straight ways (position to goal at
rest) of several robots cross at about the same time, as in an antipodal
swap. :func:`ring_zones` finds them from one snapshot of positions and goals;
:func:`segment_distance` and :func:`ring_path` serve the rule at every sample:
whether a way still crosses a ring, and the references around it.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["ring_busy", "ring_path", "ring_zones", "segment_distance", "warm_up_rings"]

_jit = numba.njit(cache=True, nogil=True)


@_jit
def segment_distance(ax: float, ay: float, bx: float, by: float, cx: float, cy: float
                     ) -> float:
    """Distance from ``(cx, cy)`` to the segment from ``(ax, ay)`` to ``(bx, by)``."""
    dx, dy = bx - ax, by - ay
    length2 = dx * dx + dy * dy
    s = 0.0 if length2 == 0.0 else min(1.0, max(0.0, ((cx - ax) * dx + (cy - ay) * dy)
                                                 / length2))
    return math.hypot(ax + s * dx - cx, ay + s * dy - cy)


@_jit
def _meeting_points(positions: np.ndarray, goals: np.ndarray, travelling: np.ndarray,
                    window: float, cos_along: float, cluster: float,
                    points: np.ndarray, pairs: np.ndarray) -> int:
    """The meeting points of every pair of travelling robots' straight ways (see
    :func:`ring_zones`) into ``points`` and the pair into ``pairs``; their number."""
    n = positions.shape[0]
    m = 0
    # each travelling robot's straight way: unit direction and length, once
    ux, uy, length = np.zeros(n), np.zeros(n), np.zeros(n)
    for i in range(n):
        if travelling[i]:
            dx, dy = goals[i, 0] - positions[i, 0], goals[i, 1] - positions[i, 1]
            length[i] = math.hypot(dx, dy)
            ux[i], uy[i] = dx / length[i], dy / length[i]
    for i in range(n):
        if not travelling[i]:
            continue
        pix, piy, uix, uiy, li = positions[i, 0], positions[i, 1], ux[i], uy[i], length[i]
        for j in range(i + 1, n):
            if not travelling[j]:
                continue
            pjx, pjy, ujx, ujy, lj = positions[j, 0], positions[j, 1], ux[j], uy[j], length[j]
            cos = uix * ujx + uiy * ujy
            if cos > cos_along:
                continue
            cross = uix * ujy - uiy * ujx
            rx, ry = pjx - pix, pjy - piy
            if abs(cross) < 0.05:  # (nearly) one line, opposite ways: meet half-way
                if abs(rx * uiy - ry * uix) > cluster or rx * uix + ry * uiy <= 0.0:
                    continue
                a = b = 0.5 * math.hypot(rx, ry)
                if a > li or b > lj:
                    continue
                x, y = 0.5 * (pix + pjx), 0.5 * (piy + pjy)
            else:
                a = (rx * ujy - ry * ujx) / cross
                b = (rx * uiy - ry * uix) / cross
                if a <= 0.0 or b <= 0.0 or a > li or b > lj or abs(a - b) > window:
                    continue
                x, y = pix + a * uix, piy + a * uiy
            points[m, 0], points[m, 1] = x, y
            pairs[m, 0], pairs[m, 1] = i, j
            m += 1
    return m


@_jit
def _heap_push(keys: np.ndarray, items: np.ndarray, size: int, key: int, item: int) -> int:
    """Push ``(key, item)`` on the max-heap held in ``keys``/``items``; the new size."""
    k = size
    keys[k], items[k] = key, item
    while k > 0:
        parent = (k - 1) // 2
        if keys[parent] >= keys[k]:
            break
        keys[parent], keys[k] = keys[k], keys[parent]
        items[parent], items[k] = items[k], items[parent]
        k = parent
    return size + 1


@_jit
def _heap_pop(keys: np.ndarray, items: np.ndarray, size: int) -> int:
    """Remove the top of the max-heap; the new size."""
    size -= 1
    keys[0], items[0] = keys[size], items[size]
    k = 0
    while True:
        left, top = 2 * k + 1, k
        if left < size and keys[left] > keys[top]:
            top = left
        if left + 1 < size and keys[left + 1] > keys[top]:
            top = left + 1
        if top == k:
            return size
        keys[top], keys[k] = keys[k], keys[top]
        items[top], items[k] = items[k], items[top]
        k = top


@_jit
def ring_zones(positions: np.ndarray, goals: np.ndarray, travelling: np.ndarray,
               window: float, cos_along: float, cluster: float, min_members: int,
               max_resultant: float, zone_of: np.ndarray, centres: np.ndarray) -> int:
    r"""Group robots whose straight ways cross near one point at about the same time.

    Two travelling robots' ways (segments from position to goal) *meet* where
    they cross, when the distances of both robots to that point differ by at
    most ``window`` (equal speeds reach it about together) and their directions
    differ by more than ``along`` (a robot going the same way is traffic); ways
    on one line in opposite directions meet half-way. Greedily, the meeting
    point with the most others within ``cluster`` (the first such point in
    pair order on a tie) makes a zone of the robots meeting there (at least
    ``min_members`` robots not yet in a zone, coming from all sides: the mean
    of their unit directions is at most ``max_resultant`` long, so a group
    meeting one robot head-on is not a zone), centred at the mean of those
    meeting points; repeated until no such point is left.

    The :math:`m \le n(n-1)/2` meeting points are binned in square cells of
    side :math:`g = \text{cluster}/2`: two points of one cell are within
    ``cluster`` of each other, and a point's neighbours within ``cluster`` lie
    in the :math:`5 \times 5` cells around its own. So the number of unused
    points in those cells bounds a point's count from above, and the greedy
    step visits cells from the largest bound down (a max-heap, keys lowered
    lazily as points are used), counting points exactly only in cells whose
    bound can still beat the best count: the same zones as counting every
    point against every other (:math:`O(m^2)` per zone, 8 s for an antipodal
    swap of 256 robots, whose :math:`m = 32{,}640` points all lie at the
    centre) in about :math:`O(m \log m)` plus the exact counts of the
    densest cells.

    Parameters
    ----------
    positions, goals
        ``(n, 2)`` positions and goals at rest (NaN: none) of all robots.
    travelling
        ``(n,)`` bool: robots with a goal at rest that are not there yet.
    window, cos_along, cluster, min_members, max_resultant
        See above (``cos_along`` is the cosine of ``along``).
    zone_of
        ``(n,)`` int output: the zone of each robot, ``-1`` for none.
    centres
        ``(n, 2)`` output: the centres of the zones (first rows).

    Returns
    -------
    int
        The number of zones.
    """
    n = positions.shape[0]
    for i in range(n):
        zone_of[i] = -1
    points = np.zeros((n * (n - 1) // 2, 2))
    pairs = np.zeros((n * (n - 1) // 2, 2), dtype=np.int64)
    m = _meeting_points(positions, goals, travelling, window, cos_along, cluster, points,
                        pairs)
    if m == 0:
        return 0
    cells, order, first, cell_of, around = _cells(points, m, 0.5 * cluster)
    # per cell: unused points, the unused points of the 5 x 5 cells around (a bound on
    # the count of each of its points) and its first unused point (in pair order)
    unused = np.empty(cells, dtype=np.int64)
    bound = np.zeros(cells, dtype=np.int64)
    head = first[:cells].copy()
    for c in range(cells):
        unused[c] = first[c + 1] - first[c]
    for c in range(cells):
        for s in range(25):
            if around[c, s] < 0:
                break
            bound[c] += unused[around[c, s]]
    # max-heap of cells by (bound, earliest first unused point): both only drop, so a
    # popped key that is no longer the cell's own is stale and pushed again lowered
    heap_keys = np.empty(2 * cells + m + 1, dtype=np.int64)
    heap_items = np.empty(2 * cells + m + 1, dtype=np.int64)
    size = 0
    for c in range(cells):
        size = _heap_push(heap_keys, heap_items, size,
                          _cell_key(c, bound, head, order, unused, m), c)
    used = np.zeros(m, dtype=np.bool_)
    seen = np.zeros(n, dtype=np.bool_)
    seen_list = np.empty(n, dtype=np.int64)
    visited = np.empty(cells, dtype=np.int64)
    near = np.empty(m, dtype=np.int64)
    take = np.zeros(m, dtype=np.bool_)
    dropped = np.zeros(cells, dtype=np.int64)
    touched = np.empty(cells, dtype=np.int64)
    zones = 0
    while True:
        best, best_count, examined = -1, 0, 0
        while size > 0:
            c = heap_items[0]
            current = _cell_key(c, bound, head, order, unused, m)
            if heap_keys[0] != current:  # stale key: lowered since pushed
                size = _heap_pop(heap_keys, heap_items, size)
                if unused[c] > 0:
                    size = _heap_push(heap_keys, heap_items, size, current, c)
                continue
            if bound[c] < best_count or (bound[c] == best_count
                                         and order[head[c]] > best):
                break  # no cell left can beat the best or tie it with an earlier point
            size = _heap_pop(heap_keys, heap_items, size)
            visited[examined] = c
            examined += 1
            for r in range(head[c], first[c + 1]):
                k = order[r]
                if used[k]:
                    continue
                if bound[c] == best_count and k > best:
                    break  # this cell holds no earlier point that ties
                count = _within(k, c, points, cluster, around, head, first, order, used,
                                near)
                if count > best_count or (count == best_count and k < best):
                    best, best_count = k, count
        for e in range(examined):  # back on the heap (their keys may drop below)
            c = visited[e]
            if unused[c] > 0:
                size = _heap_push(heap_keys, heap_items, size,
                                  _cell_key(c, bound, head, order, unused, m), c)
        if best < 0:
            return zones
        # the unused points within cluster of the best
        found = _within(best, cell_of[best], points, cluster, around, head, first, order,
                        used, near)
        if 16 * found > m:  # in pair order (the centre's sum as counted one by one)
            for e in range(found):
                take[near[e]] = True
            found = 0
            for q in range(m):
                if take[q]:
                    take[q] = False
                    near[found] = q
                    found += 1
        else:
            near[:found] = np.sort(near[:found])
        members, seen_count, sx, sy = 0, 0, 0.0, 0.0
        for e in range(found):
            q = near[e]
            used[q] = True
            sx += points[q, 0]
            sy += points[q, 1]
            for end in range(2):
                r = pairs[q, end]
                if zone_of[r] < 0 and not seen[r]:
                    seen[r] = True
                    seen_list[seen_count] = r
                    seen_count += 1
                    members += 1
        _use(near, found, cell_of, around, order, used, unused, bound, head, first, dropped,
             touched)
        ux, uy = 0.0, 0.0
        seen_list[:seen_count] = np.sort(seen_list[:seen_count])  # summed in robot order
        for e in range(seen_count):
            i = seen_list[e]
            dx, dy = goals[i, 0] - positions[i, 0], goals[i, 1] - positions[i, 1]
            length = math.hypot(dx, dy)
            ux += dx / length
            uy += dy / length
        if members < min_members or math.hypot(ux, uy) > max_resultant * members:
            for e in range(seen_count):
                seen[seen_list[e]] = False
            continue  # these meeting points make no zone; the next densest may
        centres[zones, 0], centres[zones, 1] = sx / found, sy / found
        for e in range(seen_count):
            zone_of[seen_list[e]] = zones
            seen[seen_list[e]] = False
        found = 0
        for q in range(m):  # a robot belongs to one zone
            if not used[q] and (zone_of[pairs[q, 0]] >= 0 or zone_of[pairs[q, 1]] >= 0):
                used[q] = True
                near[found] = q
                found += 1
        _use(near, found, cell_of, around, order, used, unused, bound, head, first, dropped,
             touched)
        zones += 1


@_jit
def _within(k: int, c: int, points: np.ndarray, cluster: float, around: np.ndarray,
            head: np.ndarray, first: np.ndarray, order: np.ndarray, used: np.ndarray,
            out: np.ndarray) -> int:
    """The unused points within ``cluster`` of point ``k`` (in cell ``c``: they are in the
    5 x 5 cells around it) into ``out``; their number."""
    found = 0
    for s in range(25):
        a = around[c, s]
        if a < 0:
            break
        for t in range(head[a], first[a + 1]):
            q = order[t]
            if not used[q] and math.hypot(points[q, 0] - points[k, 0],
                                          points[q, 1] - points[k, 1]) <= cluster:
                out[found] = q
                found += 1
    return found


@_jit
def _cell_key(c: int, bound: np.ndarray, head: np.ndarray, order: np.ndarray,
              unused: np.ndarray, m: int) -> int:
    """A cell's heap key: its bound, then the earlier its first unused point the higher;
    0 for a cell with no unused point (nothing in it to count)."""
    return bound[c] * (m + 1) + m - order[head[c]] if unused[c] > 0 else 0


@_jit
def _cells(points: np.ndarray, m: int, side: float
           ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Bin the first ``m`` points in square cells of ``side``.

    Returns the number of cells, the points ordered by cell (within a cell in
    their own order), each cell's first position in that order (and ``m`` after
    the last), each point's cell and, per cell, the cells of the ``5 x 5``
    block around it (``-1`` after the last).
    """
    x0, y0 = points[0, 0], points[0, 1]
    for q in range(m):
        x0, y0 = min(x0, points[q, 0]), min(y0, points[q, 1])
    ix = np.empty(m, dtype=np.int64)
    iy = np.empty(m, dtype=np.int64)
    width, height = 0, 0
    for q in range(m):  # two cells of margin on every side
        ix[q] = int((points[q, 0] - x0) / side) + 2
        iy[q] = int((points[q, 1] - y0) / side) + 2
        width, height = max(width, ix[q] + 3), max(height, iy[q] + 3)
    key = iy * width + ix
    dense = width * height <= max(4 * m, 1 << 20)
    if dense:  # a counting sort: stable, O(m + width height)
        counts = np.zeros(width * height + 1, dtype=np.int64)
        for q in range(m):
            counts[key[q] + 1] += 1
        for k in range(width * height):
            counts[k + 1] += counts[k]
        order = np.empty(m, dtype=np.int64)
        for q in range(m):
            order[counts[key[q]]] = q
            counts[key[q]] += 1
    else:
        order = np.argsort(key, kind="mergesort")
    cell_keys = np.empty(m, dtype=np.int64)
    first = np.empty(m + 1, dtype=np.int64)
    cell_of = np.empty(m, dtype=np.int64)
    cells = 0
    for r in range(m):
        q = order[r]
        if cells == 0 or key[q] != cell_keys[cells - 1]:
            cell_keys[cells] = key[q]
            first[cells] = r
            cells += 1
        cell_of[q] = cells - 1
    first[cells] = m
    cell_keys = cell_keys[:cells]
    if dense:  # the cell at each key, -1 for none
        cell_at = np.full(width * height, -1, dtype=np.int64)
        for c in range(cells):
            cell_at[cell_keys[c]] = c
    around = np.full((cells, 25), -1, dtype=np.int64)
    for c in range(cells):
        s = 0
        for dy in range(-2, 3):
            for dx in range(-2, 3):
                k = cell_keys[c] + dy * width + dx
                if dense:
                    t = cell_at[k]
                else:
                    t = np.searchsorted(cell_keys, k)
                    t = t if t < cells and cell_keys[t] == k else -1
                if t >= 0:
                    around[c, s] = t
                    s += 1
    return cells, order, first[:cells + 1], cell_of, around


@_jit
def _use(points: np.ndarray, count: int, cell_of: np.ndarray, around: np.ndarray,
         order: np.ndarray, used: np.ndarray, unused: np.ndarray, bound: np.ndarray,
         head: np.ndarray, first: np.ndarray, dropped: np.ndarray, touched: np.ndarray
         ) -> None:
    """The first ``count`` of ``points`` (already marked ``used``) leave their cells'
    counts, the bounds of the cells around them (the block is symmetric) and the
    cells' first unused points."""
    cells = 0
    for e in range(count):
        c = cell_of[points[e]]
        if dropped[c] == 0:
            touched[cells] = c
            cells += 1
        dropped[c] += 1
    for e in range(cells):
        c = touched[e]
        unused[c] -= dropped[c]
        for s in range(25):
            a = around[c, s]
            if a < 0:
                break
            bound[a] -= dropped[c]
        dropped[c] = 0
        while head[c] < first[c + 1] - 1 and used[order[head[c]]]:
            head[c] += 1


@_jit
def ring_busy(positions: np.ndarray, goals: np.ndarray, zone_of: np.ndarray, zone: int,
              me: int, cx: float, cy: float, radius: float, goal_distance: float) -> int:
    """How many other robots of ``zone`` still have to pass its ring: not within
    ``goal_distance`` of their goals, and inside the ring or with a straight way
    through it; ``-1`` when a robot that has arrived stands in the ring."""
    busy = 0
    for j in range(positions.shape[0]):
        arrived = math.hypot(positions[j, 0] - goals[j, 0],
                             positions[j, 1] - goals[j, 1]) <= goal_distance
        inside = math.hypot(positions[j, 0] - cx, positions[j, 1] - cy) < radius
        if arrived and inside:
            return -1
        if j != me and zone_of[j] == zone and not arrived and (inside or segment_distance(
                positions[j, 0], positions[j, 1], goals[j, 0], goals[j, 1], cx, cy) < radius):
            busy += 1
    return busy


@_jit
def ring_path(px: float, py: float, gx: float, gy: float, cx: float, cy: float,
              radius: float, step: float, out: np.ndarray) -> None:
    """References ``out (N, 2)`` ``step`` apart from ``(px, py)`` around the ring.

    Outside the ring the point heads for the tangent point that passes it
    counter-clockwise (the ring on its left); on the ring it moves along it
    counter-clockwise, and inside it it spirals out to it; as soon as the
    straight way to the goal ``(gx, gy)`` clears the ring, it heads for the goal
    (and stays there).
    """
    qx, qy = px, py
    for s in range(out.shape[0]):
        left = step
        for _ in range(8):
            if left <= 1e-9:
                break
            rx, ry = qx - cx, qy - cy
            dist = math.hypot(rx, ry)
            to_goal = math.hypot(gx - qx, gy - qy)
            outward = (gx - qx) * rx + (gy - qy) * ry >= 0.0
            if to_goal <= 1e-9:
                break
            if (dist >= radius and outward) or segment_distance(qx, qy, gx, gy, cx, cy) >= radius:
                move = min(left, to_goal)
                qx += move * (gx - qx) / to_goal
                qy += move * (gy - qy) / to_goal
                left -= move
            elif dist > radius * (1.0 + 1e-9):  # towards the counter-clockwise tangent point
                alpha = math.acos(radius / dist)
                ca, sa = math.cos(alpha), math.sin(alpha)
                tx = cx + radius * (ca * rx - sa * ry) / dist
                ty = cy + radius * (sa * rx + ca * ry) / dist
                length = math.hypot(tx - qx, ty - qy)
                move = min(left, length)
                if length > 1e-12:
                    qx += move * (tx - qx) / length
                    qy += move * (ty - qy) / length
                if move >= length:
                    qx, qy = tx, ty
                left -= move
            else:  # on or inside the ring: a quarter of the step outwards, the rest around
                if dist < 1e-9:
                    rx, ry, dist = -(gy - qy), gx - qx, to_goal
                out_step = min(radius - dist, 0.25 * left) if dist < radius else 0.0
                arc = min(left - out_step, 0.25 * radius)
                angle = arc / radius
                new = dist + out_step
                c, sn = math.cos(angle), math.sin(angle)
                qx = cx + new * (c * rx - sn * ry) / dist
                qy = cy + new * (sn * rx + c * ry) / dist
                left -= out_step + arc
        out[s, 0], out[s, 1] = qx, qy


def warm_up_rings() -> None:
    """Compile or load the kernels with the array layouts the rule passes."""
    positions = np.array([[-2.0, 0.0], [2.0, 0.0], [0.0, -2.0], [0.0, 2.0]])
    zone_of = np.zeros(4, dtype=np.int64)
    ring_zones(positions, -positions, np.ones(4, dtype=np.bool_), 1.5, 0.7, 0.5, 4, 0.5,
               zone_of, np.zeros((4, 2)))
    ring_busy(positions, -positions, zone_of, 0, 0, 0.0, 0.0, 1.0, 1.0)
    positions.setflags(write=False)  # as the rule passes the measured positions
    ring_busy(positions, -positions, zone_of, 0, 0, 0.0, 0.0, 1.0, 1.0)
    ring_path(-2.0, 0.0, 2.0, 0.0, 0.0, 0.0, 1.0, 0.3, np.zeros((8, 2)))
    segment_distance(-2.0, 0.0, 2.0, 0.0, 0.0, 0.5)  # the rule also calls it itself

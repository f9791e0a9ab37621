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
def ring_zones(positions: np.ndarray, goals: np.ndarray, travelling: np.ndarray,
               window: float, cos_along: float, cluster: float, min_members: int,
               max_resultant: float, zone_of: np.ndarray, centres: np.ndarray) -> int:
    """Group robots whose straight ways cross near one point at about the same time.

    Two travelling robots' ways (segments from position to goal) *meet* where
    they cross, when the distances of both robots to that point differ by at
    most ``window`` (equal speeds reach it about together) and their directions
    differ by more than ``along`` (a robot going the same way is traffic); ways
    on one line in opposite directions meet half-way. Greedily, the meeting
    point with the most others within ``cluster`` makes a zone of the robots
    meeting there (at least ``min_members`` robots not yet in a zone, coming from
    all sides: the mean of their unit directions is at most ``max_resultant``
    long, so a group meeting one robot head-on is not a zone), centred at the
    mean of those meeting points; repeated until no such point is left.

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
    points = np.zeros((n * (n - 1) // 2, 2))
    pairs = np.zeros((n * (n - 1) // 2, 2), dtype=np.int64)
    m = 0
    # each travelling robot's straight way: unit direction and length, once
    ux, uy, length = np.zeros(n), np.zeros(n), np.zeros(n)
    for i in range(n):
        zone_of[i] = -1
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
    used = np.zeros(m, dtype=np.bool_)
    seen = np.zeros(n, dtype=np.bool_)
    zones = 0
    while True:
        best, best_count = -1, 0
        for k in range(m):
            if used[k]:
                continue
            count = 0
            for q in range(m):
                if not used[q] and math.hypot(points[q, 0] - points[k, 0],
                                              points[q, 1] - points[k, 1]) <= cluster:
                    count += 1
            if count > best_count:
                best, best_count = k, count
        if best < 0:
            return zones
        for i in range(n):
            seen[i] = False
        members, sx, sy, count = 0, 0.0, 0.0, 0
        for q in range(m):
            if not used[q] and math.hypot(points[q, 0] - points[best, 0],
                                          points[q, 1] - points[best, 1]) <= cluster:
                used[q] = True
                sx += points[q, 0]
                sy += points[q, 1]
                count += 1
                for e in range(2):
                    r = pairs[q, e]
                    if zone_of[r] < 0 and not seen[r]:
                        seen[r] = True
                        members += 1
        ux, uy = 0.0, 0.0
        for i in range(n):
            if seen[i]:
                dx, dy = goals[i, 0] - positions[i, 0], goals[i, 1] - positions[i, 1]
                length = math.hypot(dx, dy)
                ux += dx / length
                uy += dy / length
        if members < min_members or math.hypot(ux, uy) > max_resultant * members:
            continue  # these meeting points make no zone; the next densest may
        centres[zones, 0], centres[zones, 1] = sx / count, sy / count
        for i in range(n):
            if seen[i]:
                zone_of[i] = zones
        for q in range(m):  # a robot belongs to one zone
            if zone_of[pairs[q, 0]] >= 0 or zone_of[pairs[q, 1]] >= 0:
                used[q] = True
        zones += 1


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

r"""Compiled kernels of the polygon-obstacle rows and checks (numba, cached on disk).

Convex pieces come as padded arrays ``vertices (P, V, 2)`` (counter-clockwise)
and ``counts (P,)`` (:func:`sqpmpc.problem.polygons.pack_pieces`). The rows
are separating lines :math:`n^\top p \ge h(n) + d` with :math:`h` the piece's
support value, so a row implies the distance to the whole piece whatever
:math:`n` is; the check of the first input measures the exact distance of the
robot's path to every piece's boundary.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["candidate_rows", "closest_point", "path_keeps_pieces", "piece_distances",
           "polygon_rows", "shadow_select", "support"]

_jit = numba.njit(cache=True, nogil=True)


@_jit
def closest_point(px: float, py: float, vertices: np.ndarray,
                  count: int) -> tuple[float, float, float]:
    """Closest boundary point of a convex counter-clockwise piece to ``(px, py)`` and the
    signed distance (negative inside)."""
    best = math.inf
    qx, qy = vertices[0, 0], vertices[0, 1]
    inside = True
    for k in range(count):
        ax, ay = vertices[k, 0], vertices[k, 1]
        b = (k + 1) % count
        bx, by = vertices[b, 0], vertices[b, 1]
        ex, ey = bx - ax, by - ay
        if ex * (py - ay) - ey * (px - ax) < 0.0:
            inside = False
        den = ex * ex + ey * ey
        s = 0.0 if den <= 0.0 else min(max(((px - ax) * ex + (py - ay) * ey) / den, 0.0), 1.0)
        cx, cy = ax + s * ex, ay + s * ey
        d = math.hypot(px - cx, py - cy)
        if d < best:
            best, qx, qy = d, cx, cy
    return qx, qy, -best if inside else best


@_jit
def support(nx: float, ny: float, vertices: np.ndarray, count: int) -> float:
    r""":math:`\max_v n^\top v` over the piece's vertices."""
    best = -math.inf
    for k in range(count):
        best = max(best, nx * vertices[k, 0] + ny * vertices[k, 1])
    return best


@_jit
def _normal(px: float, py: float, vertices: np.ndarray, count: int, fx: float,
            fy: float) -> tuple[float, float]:
    """Unit direction from the piece to the point (outward when inside), else ``(fx, fy)``."""
    qx, qy, sd = closest_point(px, py, vertices, count)
    dx, dy = px - qx, py - qy
    if sd < 0.0:
        dx, dy = -dx, -dy
    d = math.hypot(dx, dy)
    if d > 1e-9:
        return dx / d, dy / d
    return fx, fy


@_jit
def polygon_rows(me: np.ndarray, own: np.ndarray, vertices: np.ndarray, counts: np.ndarray,
                 required: np.ndarray, rotation: np.ndarray, A_out: np.ndarray,
                 lower_out: np.ndarray) -> int:
    r"""Rows :math:`n_i^\top p_i \ge h(n_i) + d` of every piece at the own iterate.

    Parameters
    ----------
    me
        ``(2,)`` the robot's measured position.
    own
        ``(N, 2+)`` its predicted stages 1..N.
    vertices, counts
        The convex pieces.
    required
        ``(P,)`` distance plus margin per piece.
    rotation
        ``(N, 2)`` the rules' per-stage rotation of the normals.
    A_out, lower_out
        ``(P, N, 2)`` and ``(P, N)`` outputs.

    A stage normal that turns by more than 90 degrees from the previous stage's (from
    the current one for stage 1) is the prediction tunnelling through the piece: the
    previous normal is kept. Stage 1 is the hard row: its normal falls back to the
    current one when the measured position violates it (``stage-one-override``), and its right-hand
    side is capped at the measured position's value, so standing still always
    satisfies it. Returns the number of overrides.
    """
    overrides = 0
    for e in range(counts.shape[0]):
        if _piece_rows(me[0], me[1], own, vertices[e], counts[e], required[e], rotation,
                       A_out[e], lower_out[e]):
            overrides += 1
    return overrides


@_jit
def _piece_rows(mx: float, my: float, own: np.ndarray, verts: np.ndarray, c_count: int,
                d: float, rotation: np.ndarray, A: np.ndarray, lower: np.ndarray) -> bool:
    """One piece's rows of :func:`polygon_rows` into ``A (N, 2)``, ``lower (N,)``; whether
    stage 1 was overridden."""
    N = A.shape[0]
    n0x, n0y = _normal(mx, my, verts, c_count, 1.0, 0.0)
    px, py = n0x, n0y
    for i in range(N):
        nx, ny = _normal(own[i, 0], own[i, 1], verts, c_count, px, py)
        if nx * px + ny * py < 0.0:
            # the prediction tunnelled through the piece between two stages (a thin
            # wall): keep the side it came from, or the plan stays locked beyond it
            nx, ny = px, py
        px, py = nx, ny
        c, sn = rotation[i, 0], rotation[i, 1]
        ax, ay = nx * c - ny * sn, nx * sn + ny * c
        A[i, 0], A[i, 1] = ax, ay
        lower[i] = support(ax, ay, verts, c_count) + d
    # stage one: keep the current normal when the iterate's cuts the robot off
    overridden = False
    gap = A[0, 0] * mx + A[0, 1] * my - support(A[0, 0], A[0, 1], verts, c_count)
    if gap < d:
        overridden = True
        A[0, 0], A[0, 1] = n0x, n0y
        lower[0] = support(n0x, n0y, verts, c_count) + d
    lower[0] = min(lower[0], A[0, 0] * mx + A[0, 1] * my)
    return overridden


@_jit
def _growing_point_distance(rx: float, ry: float, dx: float, dy: float,
                            growth: float) -> float:
    r"""Smallest :math:`\lVert r + s\Delta\rVert - G s` over :math:`s \in [0, 1]` (convex:
    ternary search, 60 steps)."""
    lo, hi = 0.0, 1.0
    for _ in range(60):
        a = lo + (hi - lo) / 3.0
        b = hi - (hi - lo) / 3.0
        fa = math.hypot(rx + a * dx, ry + a * dy) - growth * a
        fb = math.hypot(rx + b * dx, ry + b * dy) - growth * b
        if fa <= fb:
            hi = b
        else:
            lo = a
    s = 0.5 * (lo + hi)
    best = math.hypot(rx + s * dx, ry + s * dy) - growth * s
    return min(best, math.hypot(rx, ry), math.hypot(rx + dx, ry + dy) - growth)


@_jit
def path_keeps_pieces(x0: float, y0: float, x1: float, y1: float, vertices: np.ndarray,
                      counts: np.ndarray, keep: np.ndarray, growth: float) -> bool:
    r"""Whether a path near the segment :math:`p_0 \to p_1` keeps ``keep[e]`` from every
    piece's boundary (and stays outside), straying at most ``growth`` :math:`\cdot s`.

    The distance to an edge is the smaller of the distances to its end points and,
    where the projection falls inside the edge, to its line; each is minimized
    exactly over the path (the path starts outside, so it cannot enter a piece
    without crossing an edge). A piece at least ``keep[e]`` plus the path's reach
    (:math:`|p_1 - p_0| +` ``growth``) from :math:`p_0` is kept by every point of
    the path (triangle inequality) and needs no edge test.
    """
    dx, dy = x1 - x0, y1 - y0
    reach = math.hypot(dx, dy) + max(growth, 0.0)
    for e in range(counts.shape[0]):
        count = counts[e]
        need = keep[e]
        start = closest_point(x0, y0, vertices[e], count)[2]
        if start < need:
            return False
        if start >= need + reach:
            continue
        for k in range(count):
            ax, ay = vertices[e, k, 0], vertices[e, k, 1]
            b = (k + 1) % count
            bx, by = vertices[e, b, 0], vertices[e, b, 1]
            if _growing_point_distance(x0 - ax, y0 - ay, dx, dy, growth) < need:
                return False
            ex, ey = bx - ax, by - ay
            length = math.hypot(ex, ey)
            if length <= 0.0:
                continue
            ux, uy = ex / length, ey / length
            # along-edge coordinate u(s) = u0 + s du, line distance |h0 + s dh|
            u0 = (x0 - ax) * ux + (y0 - ay) * uy
            du = dx * ux + dy * uy
            h0 = (x0 - ax) * uy - (y0 - ay) * ux
            dh = dx * uy - dy * ux
            s_lo, s_hi = 0.0, 1.0
            if abs(du) > 1e-15:
                s_a, s_b = (0.0 - u0) / du, (length - u0) / du
                s_lo = max(s_lo, min(s_a, s_b))
                s_hi = min(s_hi, max(s_a, s_b))
            elif u0 < 0.0 or u0 > length:
                continue
            if s_lo > s_hi:
                continue
            # |h0 + s dh| - G s is piecewise linear: its minimum is at an end or a root
            for s in (s_lo, s_hi):
                if abs(h0 + s * dh) - growth * s < need:
                    return False
            if abs(dh) > 1e-15:
                root = -h0 / dh
                if s_lo <= root <= s_hi and -growth * root < need:
                    return False
    return True


@_jit
def piece_distances(px: float, py: float, vertices: np.ndarray, counts: np.ndarray,
                    out: np.ndarray) -> None:
    """Signed distance of ``(px, py)`` to every piece's boundary into ``out (P,)`` (negative
    inside)."""
    for p in range(counts.shape[0]):
        out[p] = closest_point(px, py, vertices[p], counts[p])[2]


@_jit
def _shifted_support(nx: float, ny: float, verts: np.ndarray, count: int, ox: float,
                     oy: float) -> float:
    """:func:`support` of the piece moved by ``(ox, oy)``."""
    return support(nx, ny, verts, count) + nx * ox + ny * oy


@_jit
def shadow_select(A_all: np.ndarray, lower_all: np.ndarray, verts: np.ndarray,
                  counts: np.ndarray, offsets: np.ndarray, required: np.ndarray,
                  points: np.ndarray, active: np.ndarray, ids: np.ndarray,
                  A_out: np.ndarray, lower_out: np.ndarray, slot_out: np.ndarray) -> int:
    r"""Each stage's rows of the candidates in ``K`` slots, none of them dropped.

    Parameters
    ----------
    A_all, lower_all
        ``(C, N, 2)``, ``(C, N)``: every candidate's rows :math:`a^\top p \ge l` at the
        iterate (:math:`\lVert a \rVert \le 1`).
    verts, counts, offsets
        ``(C, V, 2)``, ``(C,)``, ``(C, N, 2)``: candidate ``c`` at stage ``i`` is the
        convex hull of ``verts[c, :counts[c]] + offsets[c, i]`` (a circle: its centre).
    required
        ``(C,)`` the distance each candidate's row keeps (radius and margins).
    points
        ``(N, 2+)`` the iterate's positions, stages 1..N (the order of the candidates).
    active
        ``(C, N)`` whether candidate ``c`` is within reach at stage ``i`` (others have
        no row).
    ids
        ``(C,)`` the candidates' obstacle numbers.
    A_out, lower_out, slot_out
        ``(K, N, 2)``, ``(K, N)``, ``(K, N)``: the slots' rows and their obstacles;
        the slots hold the chosen rows in the order chosen, so they depend on the
        sample's data alone (slots kept from the sample before permuted the QP's rows
        and its round-off between otherwise equal runs), ``-1`` for an empty slot (row
        off: zero, ``-inf``).

    At each stage the active candidates are taken in the order of their row's gap
    at the iterate (the most violated first). A candidate is *shadowed* by a chosen
    row :math:`(a, l)` when :math:`h_c(a) + d_c \le l`, with :math:`h_c` its support
    value: every :math:`p` with :math:`a^\top p \ge l` then keeps
    :math:`\operatorname{dist}(p, c) \ge \min_{q \in c} a^\top (p - q) \ge l - h_c(a)
    \ge d_c` (a soft row with slack :math:`s`: :math:`d_c - s`, as the candidate's own
    row would), so it needs no row of its own. Candidates neither shadowed nor
    given one of the ``K`` slots (more than ``K`` unshadowed) are not dropped: the
    chosen row that needs the smallest raise to shadow all of them is raised,
    :math:`l \leftarrow \max(l, \max_c h_c(a) + d_c)` (conservative: it may cut the
    iterate, the QP's slack or a fallback takes it). Returns how many stages needed
    such a raise (the overflows).
    """
    C, N = A_all.shape[0], A_all.shape[1]
    K = A_out.shape[0]
    overflows = 0
    order = np.empty(C, dtype=np.int64)
    gaps = np.empty(C)
    chosen = np.empty(K, dtype=np.int64)
    lows = np.empty(K)
    rest = np.empty(C, dtype=np.int64)
    for i in range(N):
        px, py = points[i, 0], points[i, 1]
        n_active = 0
        for c in range(C):
            if active[c, i]:
                order[n_active] = c
                gaps[n_active] = A_all[c, i, 0] * px + A_all[c, i, 1] * py - lower_all[c, i]
                n_active += 1
        ranked = order[:n_active][np.argsort(gaps[:n_active], kind="mergesort")]
        n_chosen = 0
        n_rest = 0
        for c in ranked:
            shadowed = False
            for s in range(n_chosen):
                a = chosen[s]
                if _shifted_support(A_all[a, i, 0], A_all[a, i, 1], verts[c], counts[c],
                                    offsets[c, i, 0], offsets[c, i, 1]) + required[c] \
                        <= lows[s]:
                    shadowed = True
                    break
            if shadowed:
                continue
            if n_chosen < K:
                chosen[n_chosen] = c
                lows[n_chosen] = lower_all[c, i]
                n_chosen += 1
            else:
                rest[n_rest] = c
                n_rest += 1
        if n_rest:
            overflows += 1
            best, best_raise = 0, math.inf
            for s in range(n_chosen):
                a = chosen[s]
                need = -math.inf
                for q in range(n_rest):
                    c = rest[q]
                    need = max(need, _shifted_support(A_all[a, i, 0], A_all[a, i, 1],
                                                      verts[c], counts[c], offsets[c, i, 0],
                                                      offsets[c, i, 1]) + required[c])
                if need - lows[s] < best_raise:
                    best, best_raise = s, need - lows[s]
            lows[best] = max(lows[best], lows[best] + best_raise)
        # the slots in the order chosen (a function of this sample's data alone)
        for t in range(K):
            if t >= n_chosen:
                A_out[t, i, 0] = 0.0
                A_out[t, i, 1] = 0.0
                lower_out[t, i] = -np.inf
                slot_out[t, i] = -1
            else:
                a = chosen[t]
                A_out[t, i, 0] = A_all[a, i, 0]
                A_out[t, i, 1] = A_all[a, i, 1]
                lower_out[t, i] = lows[t]
                slot_out[t, i] = ids[a]
    return overflows


@_jit
def candidate_rows(me: np.ndarray, own: np.ndarray, vertices: np.ndarray, counts: np.ndarray,
                   candidates: np.ndarray, required: np.ndarray, rotation: np.ndarray,
                   A_all: np.ndarray, lower_all: np.ndarray, overridden: np.ndarray) -> None:
    """:func:`polygon_rows` of the pieces ``candidates (C,)`` into ``A_all (C, N, 2)``,
    ``lower_all (C, N)`` (``required (P,)`` per piece) and whether each one's stage 1 was
    overridden into ``overridden (C,)``."""
    for c in range(candidates.shape[0]):
        e = candidates[c]
        overridden[c] = _piece_rows(me[0], me[1], own, vertices[e], counts[e], required[e],
                                    rotation, A_all[c], lower_all[c])

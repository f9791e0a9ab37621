r"""Compiled kernels of the collision rows and checks (numba, cached on disk).

The geometry half of the hot path (:mod:`sqpmpc.kernels.ocp` holds the model and
QP half, and :func:`sqpmpc.kernels.warmup.warm_up` compiles or loads both): the
separating-hyperplane rows of both schemes (centralized pairs,
shared-responsibility and obstacle slots) with the stage-one override, the
checks of the first input (half-planes, segments against points and pairs),
and the neighbour selection (nearest within reach, pair slots). Same
conventions as :mod:`sqpmpc.kernels.ocp`; the arithmetic is that of
:mod:`sqpmpc.ocp.collision_rows`'s NumPy reference functions (tested against them).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sqpmpc.kernels.rules import limit_turning

__all__ = [
    "growing_segment_distance", "halfplanes_hold", "halfplanes_hold_path",
    "moving_points_keep_distance", "nearest_within", "obstacle_rows", "pair_rows",
    "pairs_keep_distance", "segment_keeps_distance", "select_pairs", "shared_rows",
    "stage_one_override"
]

_jit = numba.njit(cache=True, nogil=True)


@_jit
def halfplanes_hold(normals: np.ndarray, rhs: np.ndarray, x: float, y: float,
                    tolerance: float) -> bool:
    """Whether the point ``(x, y)`` satisfies every ``normals[e] . p >= rhs[e] - tolerance``."""
    for e in range(normals.shape[0]):
        if normals[e, 0] * x + normals[e, 1] * y < rhs[e] - tolerance:
            return False
    return True


@_jit
def halfplanes_hold_path(normals: np.ndarray, rhs: np.ndarray, x0: float, y0: float,
                         x1: float, y1: float, alpha: float, beta: float,
                         tolerance: float) -> bool:
    r"""Whether a path near the segment :math:`p_0 \to p_1` stays in every half-plane.

    The path is within :math:`\alpha s + \beta s(1-s)` of :math:`(1-s)p_0 + s p_1`
    (:func:`sqpmpc.problem.plant.path_deviation`); :math:`p_0` satisfies the half-planes.
    Along the path :math:`n^\top p - c \ge A + (B - A - \alpha - \beta) s + \beta s^2`
    with :math:`A, B` the end points' values, whose minimum on :math:`(0, 1]` is at
    :math:`s = 1` or at the vertex. With :math:`\alpha = \beta = 0` this is
    :func:`halfplanes_hold` at :math:`p_1`.
    """
    for e in range(normals.shape[0]):
        a = normals[e, 0] * x0 + normals[e, 1] * y0 - rhs[e]
        b = normals[e, 0] * x1 + normals[e, 1] * y1 - rhs[e]
        if b - alpha < -tolerance:
            return False
        if beta > 0.0:
            slope = b - a - alpha - beta
            s = -slope / (2.0 * beta)
            if 0.0 < s < 1.0 and a + slope * s + beta * s * s < -tolerance:
                return False
    return True


@_jit
def growing_segment_distance(r0x: float, r0y: float, dx: float, dy: float,
                             growth: float) -> float:
    r"""Smallest :math:`\lVert r_0 + s\Delta \rVert - G s` over :math:`s \in [0, 1]`.

    The smallest distance of a relative segment when the true path may stray
    :math:`G s` from it (:func:`sqpmpc.problem.plant.linear_growth`). The function is
    convex; its minimizer solves :math:`(a + b s) = G \lVert r_0 + s \Delta\rVert`
    (:math:`a = r_0^\top\Delta`, :math:`b = \lVert\Delta\rVert^2`,
    :math:`c = \lVert r_0\rVert^2`):
    :math:`s^* = (-a + G\sqrt{(bc - a^2)/(b - G^2)})/b` when :math:`G^2 < b`,
    else it decreases to :math:`s = 1`. :math:`G = 0` gives the segment distance.
    """
    b = dx * dx + dy * dy
    a = r0x * dx + r0y * dy
    c = r0x * r0x + r0y * r0y
    if b <= 0.0 or growth * growth >= b:
        s = 1.0
    else:
        s = (-a + growth * math.sqrt(max(b * c - a * a, 0.0) / (b - growth * growth))) / b
        s = min(max(s, 0.0), 1.0)
    best = math.hypot(r0x + s * dx, r0y + s * dy) - growth * s
    end = math.hypot(r0x + dx, r0y + dy) - growth
    return min(best, end, math.sqrt(c))


@_jit
def segment_keeps_distance(x0: float, y0: float, x1: float, y1: float, points: np.ndarray,
                           keep: np.ndarray, tolerance: float, growth: float = 0.0) -> bool:
    r"""Whether the segment :math:`(x_0, y_0) \to (x_1, y_1)` keeps ``keep[u] - tolerance``
    from every ``points[u]`` (the point-segment distance, as
    :func:`sqpmpc.problem.paths.segment_distances`), when the true path may stray
    ``growth`` :math:`\cdot s` from it (:func:`growing_segment_distance`)."""
    dx, dy = x1 - x0, y1 - y0
    for u in range(points.shape[0]):
        rx, ry = x0 - points[u, 0], y0 - points[u, 1]
        if growing_segment_distance(rx, ry, dx, dy, growth) < keep[u] - tolerance:
            return False
    return True


@_jit
def _keeps(rx: float, ry: float, dx: float, dy: float, growth: float, keep: float,
           recovery: float) -> bool:
    """The relative path keeps ``keep``; inside it already, with ``recovery >= 0``: no closer."""
    d0 = math.hypot(rx, ry)
    if recovery >= 0.0 and d0 < keep:
        return growing_segment_distance(rx, ry, dx, dy, 0.0) >= d0 - recovery
    return growing_segment_distance(rx, ry, dx, dy, growth) >= keep


@_jit
def moving_points_keep_distance(x0: float, y0: float, x1: float, y1: float,
                                start: np.ndarray, end: np.ndarray, keep: np.ndarray,
                                growth: float, recovery: float = -1.0) -> bool:
    r"""Whether the path near :math:`p_0 \to p_1` keeps ``keep[o]`` from points moving
    straight from ``start[o]`` to ``end[o]`` over the same sample (obstacles).

    ``recovery >= 0``: the ``overlap-recovery`` rule of :func:`pairs_keep_distance`."""
    for o in range(start.shape[0]):
        rx, ry = x0 - start[o, 0], y0 - start[o, 1]
        dx = (x1 - end[o, 0]) - rx
        dy = (y1 - end[o, 1]) - ry
        if not _keeps(rx, ry, dx, dy, growth, keep[o], recovery):
            return False
    return True


@_jit
def _unit(dx: float, dy: float, fx: float, fy: float) -> tuple[float, float]:
    """``(dx, dy) / |(dx, dy)|``, or the fallback ``(fx, fy)`` below 1e-9 m."""
    d = math.hypot(dx, dy)
    if d > 1e-9:
        return dx / d, dy / d
    return fx, fy


@_jit
def _stage_normals(gx: float, gy: float, a_pred: np.ndarray, b_pred: np.ndarray,
                   rotation: np.ndarray, max_turn: float, normals: np.ndarray
                   ) -> tuple[float, float]:
    """Stage normals ``(N, 2)`` of a pair: Taylor normals, turn limit, rotation.

    ``(gx, gy)`` is the current offset (this robot minus the other),
    ``a_pred``/``b_pred`` ``(N, 2+)`` the predicted positions of stages 1..N,
    ``rotation (N, 2)`` the per-stage ``(cos, sin)`` of the keep-right tilt
    and ``max_turn < 0`` skips the turn limit. Returns the current unit normal.
    """
    n0x, n0y = _unit(gx, gy, 1.0, 0.0)
    N = normals.shape[0]
    for i in range(N):
        nx, ny = _unit(a_pred[i, 0] - b_pred[i, 0], a_pred[i, 1] - b_pred[i, 1], n0x, n0y)
        normals[i, 0], normals[i, 1] = nx, ny
    if max_turn >= 0.0:
        limit_turning(n0x, n0y, normals, max_turn)
    for i in range(N):
        c, s = rotation[i, 0], rotation[i, 1]
        x, y = normals[i, 0], normals[i, 1]
        normals[i, 0] = x * c + y * (-s)
        normals[i, 1] = x * s + y * c
    return n0x, n0y


@_jit
def stage_one_override(normals: np.ndarray, n0x: float, n0y: float, gx: float, gy: float,
                       d: float) -> tuple[float, int]:
    r"""The ``stage-one-override`` safety row, in place on ``normals (N, 2)``.

    If the stage-1 normal does not keep the current offset ``(gx, gy)`` at
    ``d`` (:math:`n_1^\top g < d`), it is replaced by the current unit normal
    ``(n0x, n0y)``, so that standing still satisfies stage 1. Returns the
    projected current gap :math:`n_1^\top g` and 1 if the row was overridden.
    """
    gap = normals[0, 0] * gx + normals[0, 1] * gy
    if gap >= d:
        return gap, 0
    normals[0, 0], normals[0, 1] = n0x, n0y
    return n0x * gx + n0y * gy, 1


@_jit
def pair_rows(pairs: np.ndarray, now: np.ndarray, states: np.ndarray, required: np.ndarray,
              rotation: np.ndarray, max_turn: float, A_out: np.ndarray,
              lower_out: np.ndarray, normals: np.ndarray, stages: np.ndarray) -> int:
    r"""Centralized pair rows :math:`n^\top(p_a - p_b) \ge d` into the QP (stages 1..N).

    Parameters
    ----------
    pairs
        ``(P, 2)`` local robot indices.
    now
        ``(m, 2)`` measured positions (the stage-1 safety rule).
    states
        ``(m, N+1, 3)`` linearization point.
    required
        ``(P,)`` required distances plus margin.
    rotation, max_turn
        Keep-right ``(N, 2)`` (cos, sin) per stage; turn limit (``< 0``: none).
    A_out, lower_out
        ``(P, N, 4)`` values ``(n, -n)`` and ``(P, N)`` right-hand sides.
    normals
        ``(N, 2)`` scratch.
    stages
        ``(P,)`` how many stages of each pair get a row (``N``: all, ``1``: the
        first only, ``0``: none); the other rows are off (zero normal, ``-inf``).

    Returns
    -------
    int
        Rows whose stage-1 normal was replaced by the current one (stage-1 rule).
    """
    overrides = 0
    N = normals.shape[0]
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        for i in range(stages[p], N):
            A_out[p, i, 0] = A_out[p, i, 1] = A_out[p, i, 2] = A_out[p, i, 3] = 0.0
            lower_out[p, i] = -np.inf
        if stages[p] == 0:
            continue
        gx, gy = now[a, 0] - now[b, 0], now[a, 1] - now[b, 1]
        n0x, n0y = _stage_normals(gx, gy, states[a, 1:], states[b, 1:], rotation, max_turn,
                                  normals)
        d = required[p]
        gap, overridden = stage_one_override(normals, n0x, n0y, gx, gy, d)
        overrides += overridden
        for i in range(stages[p]):
            nx, ny = normals[i, 0], normals[i, 1]
            A_out[p, i, 0], A_out[p, i, 1] = nx, ny
            A_out[p, i, 2], A_out[p, i, 3] = -nx, -ny
            lower_out[p, i] = d
        lower_out[p, 0] = min(d, gap)
    return overrides


@_jit
def select_pairs(pairs: np.ndarray, positions: np.ndarray, radius: np.ndarray, slots: int,
                 horizon: int, stages_out: np.ndarray) -> tuple[int, int]:
    r"""The centralized form of the neighbour slots: how many stages each pair gets.

    A pair farther apart than its ``radius`` (required distance plus margin
    plus :math:`2 v_{max} N T_s`) cannot come within its distance over the
    horizon: no row (0). Each robot's ``slots`` nearest pairs within the radius
    get every stage (``horizon``); a pair within the radius that neither robot
    chose keeps its stage-1 row (1), so the next sample keeps its distance
    whatever the plan after it (the first-input check covers every pair).

    Parameters
    ----------
    pairs
        ``(P, 2)`` robot indices.
    positions
        ``(m, 2)`` measured positions.
    radius
        ``(P,)`` interaction radii.
    slots, horizon
        The budget per robot and ``N``.
    stages_out
        ``(P,)`` output.

    Returns
    -------
    tuple of int
        Pairs with every stage, pairs with stage 1 only.
    """
    P = pairs.shape[0]
    m = positions.shape[0]
    dist = np.empty(P)
    degree = np.zeros(m, dtype=np.int64)
    for p in range(P):
        a, b = pairs[p, 0], pairs[p, 1]
        dist[p] = math.hypot(positions[a, 0] - positions[b, 0], positions[a, 1] - positions[b, 1])
        near = dist[p] <= radius[p]
        stages_out[p] = 1 if near else 0
        if near:
            degree[a] += 1
            degree[b] += 1
    start = np.zeros(m + 1, dtype=np.int64)
    for r in range(m):
        start[r + 1] = start[r] + degree[r]
    members = np.empty(start[m], dtype=np.int64)
    fill = start[:m].copy()
    for p in range(P):
        if stages_out[p]:
            for r in (pairs[p, 0], pairs[p, 1]):
                members[fill[r]] = p
                fill[r] += 1
    for r in range(m):
        mine = members[start[r]:start[r + 1]]
        order = np.argsort(dist[mine], kind="mergesort")
        for s in range(min(slots, mine.shape[0])):
            stages_out[mine[order[s]]] = horizon
    full = 0
    first = 0
    for p in range(P):
        full += stages_out[p] == horizon
        first += stages_out[p] == 1
    return full, first


@_jit
def shared_rows(me: np.ndarray, others_now: np.ndarray, own_pred: np.ndarray,
                other_pred: np.ndarray, shared: np.ndarray, required: np.ndarray,
                true_distance: np.ndarray, rotation: np.ndarray, max_turn: float,
                A_out: np.ndarray, lower_out: np.ndarray, check_normals: np.ndarray,
                check_rhs: np.ndarray, touching: np.ndarray) -> int:
    r"""Shared-responsibility rows of one robot against its neighbours (decentralized).

    For every slot ``e`` with ``shared[e]``: the common hyperplane of the two
    exchanged predictions, half the distance each (see
    :class:`sqpmpc.ocp.collision_rows.ExternalCollisionModel`), with the stage-1 offset
    clipped so that both current positions stay on their sides. Other slots
    get zero normals and ``-inf`` bounds (no constraint).

    Parameters
    ----------
    me, others_now
        ``(2,)`` and ``(E, 2)`` measured positions.
    own_pred, other_pred
        ``(E, N, 2+)`` predicted positions of stages 1..N: per slot, this
        robot's and the neighbour's, from the pair's common plans.
    shared
        ``(E,)`` bool.
    required, true_distance
        ``(E,)`` distances with and without the margin.
    rotation, max_turn
        As in :func:`pair_rows`.
    A_out, lower_out
        ``(E, N, 2)`` normals and ``(E, N)`` right-hand sides of the rows.
    check_normals, check_rhs
        ``(E, 2)``, ``(E,)``: the first-stage check of the true distance
        (``n^T p >= rhs``); ``-inf`` for slots that are not shared.
    touching
        ``(E,)`` bool out: the pair is inside the margin band.

    Returns
    -------
    int
        Stage-1 normals replaced by the current one.
    """
    overrides = 0
    E, N = shared.shape[0], A_out.shape[1]
    mx, my = me[0], me[1]
    for e in range(E):
        touching[e] = False
        if not shared[e]:
            for i in range(N):
                A_out[e, i, 0] = 0.0
                A_out[e, i, 1] = 0.0
                lower_out[e, i] = -np.inf
            check_normals[e, 0] = 0.0
            check_normals[e, 1] = 0.0
            check_rhs[e] = -np.inf
            continue
        ox, oy = others_now[e, 0], others_now[e, 1]
        gx, gy = mx - ox, my - oy
        n = A_out[e]
        n0x, n0y = _stage_normals(gx, gy, own_pred[e], other_pred[e], rotation, max_turn, n)
        d = required[e]
        half = 0.5 * d
        gap, overridden = stage_one_override(n, n0x, n0y, gx, gy, d)
        overrides += overridden
        for i in range(N):
            cx = 0.5 * (own_pred[e, i, 0] + other_pred[e, i, 0])
            cy = 0.5 * (own_pred[e, i, 1] + other_pred[e, i, 1])
            lower_out[e, i] = n[i, 0] * cx + n[i, 1] * cy
        n1x, n1y = n[0, 0], n[0, 1]
        lo = (n1x * ox + n1y * oy) + half
        n1_me = n1x * mx + n1y * my
        hi = n1_me - half
        c0 = min(max(lower_out[e, 0], lo), max(lo, hi))
        lower_out[e, 0] = c0
        for i in range(N):
            lower_out[e, i] = lower_out[e, i] + half
        lower_out[e, 0] = min(lower_out[e, 0], n1_me)
        touching[e] = gap < d
        D = true_distance[e]
        check_normals[e, 0], check_normals[e, 1] = n1x, n1y
        if gap >= d:
            check_rhs[e] = c0 + 0.5 * D
        else:
            mid = n1x * (0.5 * (mx + ox)) + n1y * (0.5 * (my + oy))
            check_rhs[e] = mid + 0.5 * min(D, gap)
    return overrides


@_jit
def obstacle_rows(me: np.ndarray, others_now: np.ndarray, own: np.ndarray,
                  obstacles: np.ndarray, kinds: np.ndarray, required: np.ndarray,
                  reach: np.ndarray, rotation: np.ndarray, stage_one_rule: bool,
                  A_out: np.ndarray, lower_out: np.ndarray) -> int:
    r"""Rows of the obstacle (kind 2) and missing (kind 3) slots at the own iterate.

    Each such neighbour's prediction is a moving obstacle: the full distance
    :math:`n^\top p \ge n^\top o + d` with :math:`n` the rotated unit direction
    from the obstacle to the own predicted position (``own (N, 2+)``, stages
    1..N). With ``stage_one_rule`` a stage-1 normal that the current positions
    violate is replaced by the current one (``stage-one-override``). Missing
    slots then get the ``missing-neighbour-reach`` stage-1 row: keep
    :math:`d + r_e` (``reach (E,)``, the neighbour's one-sample reach) from the
    neighbour's current position if the current gap allows, else do not approach.
    Other slots are left as they are. Returns the number of stage-1 overrides.
    """
    overrides = 0
    N = A_out.shape[1]
    mx, my = me[0], me[1]
    for e in range(kinds.shape[0]):
        if kinds[e] != 2 and kinds[e] != 3:
            continue
        gx, gy = mx - others_now[e, 0], my - others_now[e, 1]
        n0x, n0y = _unit(gx, gy, 1.0, 0.0)
        d = required[e]
        for i in range(N):
            nx, ny = _unit(own[i, 0] - obstacles[e, i, 0], own[i, 1] - obstacles[e, i, 1],
                           n0x, n0y)
            c, sn = rotation[i, 0], rotation[i, 1]
            A_out[e, i, 0] = nx * c - ny * sn
            A_out[e, i, 1] = nx * sn + ny * c
        if stage_one_rule:
            overrides += stage_one_override(A_out[e], n0x, n0y, gx, gy, d)[1]
        for i in range(N):
            lower_out[e, i] = (A_out[e, i, 0] * obstacles[e, i, 0]
                               + A_out[e, i, 1] * obstacles[e, i, 1]) + d
        if kinds[e] == 3:
            keep = d + reach[e]
            A_out[e, 0, 0], A_out[e, 0, 1] = n0x, n0y
            if n0x * gx + n0y * gy >= keep:
                lower_out[e, 0] = (n0x * others_now[e, 0] + n0y * others_now[e, 1]) + keep
            else:
                lower_out[e, 0] = n0x * mx + n0y * my
    return overrides


@_jit
def pairs_keep_distance(pairs: np.ndarray, now: np.ndarray, nxt: np.ndarray,
                        required: np.ndarray, growth: np.ndarray,
                        recovery: float = -1.0) -> bool:
    r"""Whether every pair keeps ``required`` along the straight segments of one sample.

    With both robots moving on straight segments at constant speed, the
    relative position is :math:`r(s) = r_0 + s(r_1 - r_0)`, whose smallest norm
    on :math:`s\in[0,1]` is at :math:`s^* = \mathrm{clip}(-r_0^\top\Delta/\|\Delta\|^2)`.
    A robot whose true path may stray ``growth[j]`` :math:`\cdot s` from its
    segment (a plant unlike the prediction) adds it: the pair's relative path
    strays at most :math:`(G_j + G_l) s` (:func:`growing_segment_distance`).

    ``recovery >= 0`` turns on the ``overlap-recovery`` rule: a pair that is
    already inside its distance at the start (:math:`\|r_0\| <` ``required``: a
    push, a slip) cannot keep it; it passes when its relative segment comes no
    closer than :math:`\|r_0\|` less ``recovery`` (the solver's tolerance), so
    that inputs which separate it are applied instead of a brake that never
    ends. Pairs that are apart are checked as without it.
    """
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        r0x, r0y = now[a, 0] - now[b, 0], now[a, 1] - now[b, 1]
        dx = (nxt[a, 0] - nxt[b, 0]) - r0x
        dy = (nxt[a, 1] - nxt[b, 1]) - r0y
        if not _keeps(r0x, r0y, dx, dy, growth[a] + growth[b], required[p], recovery):
            return False
    return True


@_jit
def nearest_within(me: np.ndarray, positions: np.ndarray, others: np.ndarray,
                   radius: np.ndarray, chosen_out: np.ndarray, rest_out: np.ndarray
                   ) -> tuple[int, int]:
    r"""The robots ``others`` within ``radius`` of ``me``, nearest first (stable order).

    ``positions (n, 2)`` are everyone's, ``others (m,)`` the candidates'
    indices into them and ``radius (m,)`` their radii. The first
    ``len(chosen_out)`` of them, as indices into ``others``, go to
    ``chosen_out``, the rest to ``rest_out (m,)``. Returns both counts.
    """
    m = others.shape[0]
    dist = np.empty(m)
    near = np.empty(m, dtype=np.int64)
    count = 0
    for e in range(m):
        j = others[e]
        d = math.hypot(positions[j, 0] - me[0], positions[j, 1] - me[1])
        if d <= radius[e]:
            near[count] = e
            dist[count] = d
            count += 1
    order = np.argsort(dist[:count], kind="mergesort")
    used = min(chosen_out.shape[0], count)
    for s in range(used):
        chosen_out[s] = near[order[s]]
    for s in range(used, count):
        rest_out[s - used] = near[order[s]]
    return used, count - used

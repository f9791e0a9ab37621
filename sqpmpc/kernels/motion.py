r"""Compiled kernels of the motion along a roadmap path (:mod:`sqpmpc.coordination.motion`,
whose module docstring gives the geometry and the timing).

The arithmetic is the one of the numpy form the motion had (kept as the reference in
``tests/motion_reference.py``), step by step in the same order, so that the motion is
the same to the last bit but where numpy evaluates a sine, cosine or arctangent of an
array with its own vectorized routines (a unit in the last place at most). numpy's
helpers are written out as numpy computes them:

* ``linspace(a, b, n)[i]`` is :math:`a + i\,\frac{b - a}{n - 1}`, its last entry
  :math:`b` (:func:`_spaced`);
* ``interp(x, xp, fp)`` takes the last :math:`j` with :math:`x_j \le x`,
  :math:`f_j + \frac{f_{j+1} - f_j}{x_{j+1} - x_j}(x - x_j)`, :math:`f_j` where
  :math:`x = x_j` or :math:`j` is the last, the end values outside (:func:`_interp`);
* ``union1d(s, t)`` of two sorted arrays is their sorted distinct values (:func:`_union`).

A motion is written into the caller's arrays (:func:`path_motion_into`), so a
controller's sample allocates nothing for it but the kernel's scratch.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["ARC_STEP", "kept_steps", "path_motion_into", "smooth_path", "warm_up_motion"]

_jit = numba.njit(cache=True, nogil=True)

ARC_STEP = math.pi / 16
"""Arcs are sampled every 11.25 degrees (positions on the arc)."""


@_jit
def _wrap(a: float) -> float:
    """``a`` wrapped into :math:`[-\\pi, \\pi)` (Python's float remainder)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


@_jit
def _spaced(start: float, stop: float, num: int, i: int) -> float:
    """``numpy.linspace(start, stop, num)[i]`` (``num >= 2``), as numpy computes it."""
    if i == num - 1:
        return stop
    div = num - 1
    delta = stop - start
    step = delta / div
    if step == 0.0:  # numpy's branch for denormal steps
        return (i / div) * delta + start
    return i * step + start


@_jit
def _interp(x: float, xp: np.ndarray, fp: np.ndarray, size: int) -> float:
    """``numpy.interp(x, xp[:size], fp[:size])`` (``xp`` non-decreasing, ``size >= 2``)."""
    if math.isnan(x):
        return x
    if x < xp[0]:
        return fp[0]
    if x > xp[size - 1]:
        return fp[size - 1]
    lo, hi = 0, size  # the last j with xp[j] <= x
    while lo < hi:
        mid = lo + ((hi - lo) >> 1)
        if x >= xp[mid]:
            lo = mid + 1
        else:
            hi = mid
    j = lo - 1
    if j == size - 1 or xp[j] == x:
        return fp[j]
    slope = (fp[j + 1] - fp[j]) / (xp[j + 1] - xp[j])
    out = slope * (x - xp[j]) + fp[j]
    if math.isnan(out):
        out = slope * (x - xp[j + 1]) + fp[j + 1]
        if math.isnan(out) and fp[j] == fp[j + 1]:
            out = fp[j]
    return out


@_jit
def _union(s: np.ndarray, size: int, t: np.ndarray) -> np.ndarray:
    """``numpy.union1d(s[:size], t)`` of non-decreasing ``s`` and ``t``."""
    out = np.empty(size + t.size)
    m = 0
    a = b = 0
    while a < size or b < t.size:
        if b >= t.size or (a < size and s[a] <= t[b]):
            value = s[a]
            a += 1
        else:
            value = t[b]
            b += 1
        if m == 0 or value != out[m - 1]:
            out[m] = value
            m += 1
    return out[:m]


@_jit
def _kept(points: np.ndarray) -> tuple[np.ndarray, int]:
    """Each point's index among the kept ones (a point within 1e-9 of the one before it
    is dropped) and their number."""
    kept = np.empty(points.shape[0], dtype=np.int64)
    K = 0
    for k in range(points.shape[0]):
        if k == 0 or math.hypot(points[k, 0] - points[k - 1, 0],
                                points[k, 1] - points[k - 1, 1]) > 1e-9:
            K += 1
        kept[k] = K - 1
    return kept, K


@_jit
def kept_steps(points: np.ndarray) -> np.ndarray:
    """``(K - 1, 2)`` the steps between the kept points of ``points`` (a point within 1e-9
    of the one before it is dropped): their directions, numpy's ``arctan2`` of them, are
    :func:`smooth_path`'s ``headings``."""
    kept, K = _kept(points)
    steps = np.empty((max(K - 1, 0), 2))
    at = 0  # the last kept point
    for k in range(1, points.shape[0]):
        if kept[k] != kept[k - 1]:
            steps[kept[k] - 1, 0] = points[k, 0] - points[at, 0]
            steps[kept[k] - 1, 1] = points[k, 1] - points[at, 1]
            at = k
    return steps


@_jit
def smooth_path(points: np.ndarray, headings: np.ndarray, reach: float, step: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""The polyline ``points (K, 2)`` with its corners rounded within ``reach``:
    samples ``(S, 2)``, their headings ``(S,)`` and each point's last sample ``(K,)``
    (:func:`sqpmpc.coordination.motion.smooth_path`).

    ``headings`` are the directions of the :func:`kept_steps` as numpy's ``arctan2``
    gives them: its vectorized arctangent is not the C library's (a unit in the last
    place apart), and a corner of exactly 45 or 90 degrees gets its arc's number of
    samples from its deflection's ratio to :data:`ARC_STEP`, an integer that one unit
    more puts one sample further.

    A corner of deflection :math:`\varphi` becomes the arc of radius
    :math:`R = \rho / (\sec(\varphi/2) - 1)` whose tangent points,
    :math:`R\tan(\varphi/2)` from the vertex, are kept to half of each segment; a
    half-turn (or :math:`\rho \le 0`) is a turn in place, two samples at the vertex.
    """
    count_in = points.shape[0]
    kept, K = _kept(points)
    pts = np.empty((K, 2))
    for k in range(count_in):
        if k == 0 or kept[k] != kept[k - 1]:
            pts[kept[k], 0], pts[kept[k], 1] = points[k, 0], points[k, 1]
    if K < 2:
        return pts, np.zeros(K), np.zeros(count_in, dtype=np.int64)
    seg = np.empty((K - 1, 2))
    lengths = np.empty(K - 1)
    angles = np.empty(K - 1)
    for j in range(K - 1):
        seg[j, 0], seg[j, 1] = pts[j + 1, 0] - pts[j, 0], pts[j + 1, 1] - pts[j, 1]
        lengths[j] = math.hypot(seg[j, 0], seg[j, 1])
        angles[j] = headings[0] if j == 0 else \
            angles[j - 1] + _wrap(headings[j] - headings[j - 1])
    # tangent lengths and radii of the corners at pts[1..K-2]
    tangent = np.zeros(K)
    radius = np.zeros(K)
    size = 1 + 2 * (K - 1)  # the samples' bound: a line's two extra, an arc's at most 17
    for j in range(1, K):
        size += math.ceil(lengths[j - 1] / step) + 18
        if j == K - 1:
            break
        phi = abs(angles[j] - angles[j - 1])
        if phi < 1e-9:
            continue
        room = 0.5 * min(lengths[j - 1], lengths[j])
        half = 0.5 * phi
        if phi >= math.pi - 1e-9 or reach <= 0.0:
            continue  # a turn in place
        r = reach / (1.0 / math.cos(half) - 1.0)
        t = r * math.tan(half)
        if t > room:
            t, r = room, room / math.tan(half)
        tangent[j], radius[j] = t, r
    xy = np.empty((size, 2))
    psi = np.empty(size)
    xy[0, 0], xy[0, 1] = pts[0, 0], pts[0, 1]
    psi[0] = angles[0]
    marks = np.zeros(K, dtype=np.int64)
    count = 1
    for j in range(1, K):
        ux, uy = seg[j - 1, 0] / lengths[j - 1], seg[j - 1, 1] / lengths[j - 1]
        sx, sy = xy[count - 1, 0], xy[count - 1, 1]
        if j < K - 1:
            ex, ey = pts[j, 0] - tangent[j] * ux, pts[j, 1] - tangent[j] * uy
        else:
            ex, ey = pts[j, 0], pts[j, 1]
        bx, by = ex - sx, ey - sy
        n = max(1, math.ceil(math.hypot(bx, by) / step))
        for i in range(1, n + 1):
            f = _spaced(0.0, 1.0, n + 1, i)
            xy[count, 0], xy[count, 1] = sx + f * bx, sy + f * by
            psi[count] = angles[j - 1]
            count += 1
        marks[j] = count - 1
        if j == K - 1:
            break
        turn = angles[j] - angles[j - 1]
        if abs(turn) < 1e-9:
            continue
        if radius[j] <= 0.0:  # in place: the heading changes at the vertex
            xy[count, 0], xy[count, 1] = pts[j, 0], pts[j, 1]
            psi[count] = angles[j]
            count += 1
            marks[j] = count - 1
            continue
        sr = (1.0 if turn > 0 else -1.0) * radius[j]
        a_in = angles[j - 1]
        cx, cy = ex + sr * -math.sin(a_in), ey + sr * math.cos(a_in)
        n = max(2, math.ceil(abs(turn) / ARC_STEP))
        for i in range(1, n + 1):
            h = a_in + _spaced(0.0, turn, n + 1, i)
            xy[count, 0], xy[count, 1] = cx - sr * -math.sin(h), cy - sr * math.cos(h)
            psi[count] = h
            count += 1
        marks[j] = count - 1
    out = np.empty(count_in, dtype=np.int64)
    for k in range(count_in):
        out[k] = marks[kept[k]]
    return xy[:count].copy(), psi[:count].copy(), out


@_jit
def _nearest(xy: np.ndarray, size: int, hx: float, hy: float
             ) -> tuple[float, float, float, int]:
    """The distance from ``(hx, hy)`` to the polyline ``xy[:size]`` (``size >= 2``), the
    nearest point and its segment (the last of those within 1e-9 of the nearest)."""
    gaps = np.empty(size - 1)
    least = np.inf
    for k in range(size - 1):
        dx, dy = xy[k + 1, 0] - xy[k, 0], xy[k + 1, 1] - xy[k, 1]
        dd = dx * dx + dy * dy
        f = ((hx - xy[k, 0]) * dx + (hy - xy[k, 1]) * dy) / (dd if dd > 0 else 1.0)
        f = min(max(f, 0.0), 1.0)
        gaps[k] = math.hypot(xy[k, 0] + f * dx - hx, xy[k, 1] + f * dy - hy)
        least = min(least, gaps[k])
    i = size - 2
    while gaps[i] > least + 1e-9:
        i -= 1
    dx, dy = xy[i + 1, 0] - xy[i, 0], xy[i + 1, 1] - xy[i, 1]
    dd = dx * dx + dy * dy
    f = min(max(((hx - xy[i, 0]) * dx + (hy - xy[i, 1]) * dy) / (dd if dd > 0 else 1.0),
                0.0), 1.0)
    return gaps[i], xy[i, 0] + f * dx, xy[i, 1] + f * dy, i


@_jit
def _arc_lengths(xy: np.ndarray, ds: np.ndarray, s: np.ndarray) -> None:
    """``ds`` the lengths of the steps of ``xy (S, 2)``, ``s`` their running sum from 0."""
    s[0] = 0.0
    for k in range(xy.shape[0] - 1):
        ds[k] = math.hypot(xy[k + 1, 0] - xy[k, 0], xy[k + 1, 1] - xy[k, 1])
        s[k + 1] = s[k] + ds[k]


@_jit
def _forward(points: np.ndarray, headings: np.ndarray, hx: float, hy: float, theta0: float,
             speed: float, reach: float, T: float, v_max: float, w_max: float, limited: bool,
             acceleration: float, stop: bool, within: int, has_rate: bool, turn_rate: float,
             poses: np.ndarray, velocities: np.ndarray) -> None:
    """The motion driving forwards into ``poses (N+1, 3)``, ``velocities (N+1, 2)``."""
    N = poses.shape[0] - 1
    step = 0.25 * v_max * T
    xy, psi, marks = smooth_path(points, headings, reach, step)
    if xy.shape[0] < 2:  # a path of one point
        px, py = xy[0, 0], xy[0, 1]
        xy = np.empty((2, 2))
        xy[0, 0], xy[0, 1], xy[1, 0], xy[1, 1] = px, py, px, py
        psi = np.full(2, theta0)
        marks = np.ones(points.shape[0], dtype=np.int64)
    S = xy.shape[0]
    w = points.shape[0] - 1 if within < 0 else min(within, points.shape[0] - 1)
    last = max(marks[w], 1)
    # the robot's projection on the path (up to points[within]): the furthest of the
    # nearest points, so that a path that steps back is followed in its order
    gap, qx, qy, i = _nearest(xy, last + 1, hx, hy)
    ds = np.empty(S - 1)
    s = np.empty(S)
    _arc_lengths(xy, ds, s)
    s_q = s[i] + math.hypot(qx - xy[i, 0], qy - xy[i, 1])
    # straight to the path max(2 rho, gap) ahead (not past a turn in place or the end)
    end = s[S - 1]
    for k in range(i + 1, S - 1):
        if ds[k] <= 1e-12:
            end = s[k]
            break
    s_join = min(s_q + max(2.0 * reach, gap), end)
    j = 0
    while j < S and s[j] <= s_join:
        j += 1
    j = min(j - 1, S - 2)
    f = (s_join - s[j]) / ds[j] if ds[j] > 0 else 0.0
    tx = xy[j, 0] + f * (xy[j + 1, 0] - xy[j, 0])
    ty = xy[j, 1] + f * (xy[j + 1, 1] - xy[j, 1])
    psi_t = psi[j] + f * (psi[j + 1] - psi[j])
    span = math.hypot(tx - hx, ty - hy)
    lead = math.atan2(ty - hy, tx - hx) if span > 1e-9 else psi_t
    lead = psi_t + _wrap(lead - psi_t)
    n = max(1, math.ceil(span / step))
    span_line = span > 1e-9
    head = n + 1 if span_line else 1  # the line to the path, or the join alone
    M = head + S - (j + 1)
    path = np.empty((M + 1, 2))  # one more: the robot's own heading first (below)
    turn = np.empty(M + 1)
    if span_line:  # along the line, turning onto the path's heading on the way
        for k in range(n + 1):
            f = _spaced(0.0, 1.0, n + 1, k)
            path[k + 1, 0], path[k + 1, 1] = hx + f * (tx - hx), hy + f * (ty - hy)
            turn[k + 1] = lead + (psi_t - lead) * f
    else:
        path[1, 0], path[1, 1] = tx, ty
        turn[1] = psi_t
    for k in range(j + 1, S):
        path[head + k - j, 0], path[head + k - j, 1] = xy[k, 0], xy[k, 1]
        turn[head + k - j] = psi[k]
    # headings on the robot's branch, its error turned away at its speed (in place at rest)
    shift = theta0 + _wrap(turn[1] - theta0) - turn[1]
    for k in range(1, M + 1):
        turn[k] = turn[k] + shift
    error = theta0 - turn[1]
    ds = np.empty(M)
    s = np.empty(M + 1)
    _arc_lengths(path[1:], ds[1:], s[1:])
    first = 1  # the samples are path[first:], turn[first:], s[first:], ds[first:]
    if abs(error) > 1e-9:
        # the turn at the robot's speed: radius v0 / w_max (in place at rest)
        span = min(max(speed, 0.0) / w_max * abs(error), s[n + 1] if span_line else s[M])
        if span > 0:  # sampled as an arc is
            parts = max(2, math.ceil(abs(error) / ARC_STEP))
            fine = np.empty(parts + 1)
            for k in range(parts + 1):
                fine[k] = _spaced(0.0, span, parts + 1, k)
            grid = _union(s[1:], M, fine)
            G = grid.size
            fresh = np.empty((G + 1, 2))
            bent = np.empty(G + 1)
            for k in range(G):
                fresh[k + 1, 0] = _interp(grid[k], s[1:], path[1:, 0], M)
                fresh[k + 1, 1] = _interp(grid[k], s[1:], path[1:, 1], M)
                bent[k + 1] = _interp(grid[k], s[1:], turn[1:], M)
            path, turn, M = fresh, bent, G
            s = np.empty(M + 1)
            s[1:] = grid
            ds = np.empty(M)
            for k in range(M - 1):
                ds[k + 1] = grid[k + 1] - grid[k]
        for k in range(1, M + 1):
            weight = min(max(1.0 - s[k] / span, 0.0), 1.0) if span > 0 else 0.0
            turn[k] = turn[k] + error * weight
        # the robot's own heading first: a turn in place when nothing may drift
        path[0, 0], path[0, 1] = path[1, 0], path[1, 1]
        turn[0] = theta0
        s[0] = 0.0
        ds[0] = 0.0
        first = 0
    P = M + 1 - first  # samples
    X, H, L, D = path[first:], turn[first:], s[first:], ds[first:]
    # caps: |omega| <= w_max on every interval, v_max, a stop at the end
    dpsi = np.empty(P - 1)
    interval = np.empty(P - 1)
    cap = np.full(P, v_max)
    for k in range(P - 1):
        dpsi[k] = abs(H[k + 1] - H[k])
        interval[k] = w_max * D[k] / dpsi[k] if dpsi[k] > 1e-12 else np.inf
        cap[k] = min(cap[k], interval[k])
    for k in range(P - 1):
        cap[k + 1] = min(cap[k + 1], interval[k])
    if stop:
        cap[P - 1] = 0.0
    v0 = min(max(speed, 0.0), v_max)
    v = np.empty(P)
    if not limited:
        v[:] = cap
        v[0] = min(v0, cap[0])
    else:
        two_a = 2.0 * acceleration
        least = np.inf
        for k in range(P):  # forward pass
            square = cap[k] * cap[k]
            if k == 0:
                square = min(square, v0 * v0)
            least = min(least, square - two_a * L[k])
            v[k] = two_a * L[k] + least
        least = np.inf
        for k in range(P - 1, -1, -1):  # backward pass
            square = cap[k] * cap[k]
            if k == 0:
                square = min(square, v0 * v0)
            least = min(least, square + two_a * L[k])
            v[k] = math.sqrt(max(min(min(v[k], -two_a * L[k] + least), cap[k] * cap[k]),
                                 0.0))
    # the time of each interval: from v[k] to v[k+1] over D[k] at most its cap, |a| <= a_max
    t = np.empty(P)
    t[0] = 0.0
    for k in range(P - 1):
        if not limited:
            dt = D[k] / min(interval[k], v_max) if D[k] > 0 else 0.0
        else:
            a = acceleration
            va, vb = v[k], v[k + 1]
            top = min(math.sqrt(0.5 * (2.0 * a * D[k] + va * va + vb * vb)),
                      min(interval[k], v_max))
            ramps = (2.0 * (top * top) - va * va - vb * vb) / (2.0 * a)
            dt = (2.0 * top - va - vb) / a + ((D[k] - ramps) / top if top > 0 else 0.0)
        if not math.isfinite(dt):
            dt = 0.0
        t[k + 1] = t[k] + max(dt, dpsi[k] / w_max)
    for k in range(N + 1):
        stage = T * k
        poses[k, 0] = _interp(stage, t, X[:, 0], P)
        poses[k, 1] = _interp(stage, t, X[:, 1], P)
        poses[k, 2] = _interp(stage, t, H, P)
        velocities[k, 0] = _interp(stage, t, v, P)
    # turn rates: the mean of each sample's, at a stage the mean of the two around it
    for k in range(N + 1):
        before = (poses[k, 2] - poses[k - 1, 2]) / T if k > 0 else 0.0
        after = (poses[k + 1, 2] - poses[k, 2]) / T if k < N else 0.0
        velocities[k, 1] = after if k == 0 else before if k == N else 0.5 * (before + after)
    poses[0, 0], poses[0, 1], poses[0, 2] = hx, hy, theta0
    if has_rate:  # where the robot's velocities are
        velocities[0, 0], velocities[0, 1] = speed, turn_rate


@_jit
def path_motion_into(points: np.ndarray, headings: np.ndarray, hx: float, hy: float,
                     heading: float, speed: float, reach: float, sample_time: float,
                     max_speed: float, max_turn_rate: float, limited: bool,
                     acceleration: float, stop: bool, within: int, reverse: bool,
                     has_rate: bool, turn_rate: float, poses: np.ndarray,
                     velocities: np.ndarray) -> None:
    """The motion of :func:`sqpmpc.coordination.motion.path_motion` into ``poses (N+1, 3)``
    and ``velocities (N+1, 2)``; ``headings`` those of :func:`smooth_path`.

    ``limited`` says whether ``acceleration`` bounds the speed's change (else it may
    change at once), ``within < 0`` projects on the whole path, ``has_rate`` gives stage
    0 the robot's ``speed`` and ``turn_rate``. Backwards (``reverse``) the motion is the
    one of the robot turned by a half-turn, its speeds negated.
    """
    if reverse:  # backwards is forwards with the heading turned by a half-turn
        _forward(points, headings, hx, hy, heading + math.pi, -speed, reach, sample_time,
                 max_speed, max_turn_rate, limited, acceleration, stop, within, has_rate,
                 turn_rate, poses, velocities)
        for k in range(poses.shape[0]):
            poses[k, 2] -= math.pi
            velocities[k, 0] *= -1.0
    else:
        _forward(points, headings, hx, hy, heading, speed, reach, sample_time, max_speed,
                 max_turn_rate, limited, acceleration, stop, within, has_rate, turn_rate,
                 poses, velocities)


def warm_up_motion() -> None:
    """Compile or load the kernels with the array layouts the coordination passes: the
    path's points contiguous (a slice of the execution's paths, or a stacked copy), the
    motion into rows of the rule's arrays."""
    points = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    headings = np.array([0.0, 0.5 * math.pi])
    kept_steps(points)
    smooth_path(points, headings, 0.06, 0.05)
    poses, velocities = np.zeros((2, 5, 3)), np.zeros((2, 5, 2))
    for flag in (False, True):
        path_motion_into(points, headings, 0.1, 0.0, 0.0, 0.5, 0.06, 0.2, 1.0, 1.5, flag, 1.0, flag,
                         -1, flag, flag, 0.0, poses[0], velocities[0])

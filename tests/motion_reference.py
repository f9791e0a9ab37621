"""The numpy form of :mod:`sqpmpc.coordination.motion` as it was before its kernel
(:mod:`sqpmpc.kernels.motion`): the reference the compiled motion is compared to
(tests/test_motion_kernel.py). The arithmetic is the one the kernel repeats step by
step; the geometry is the module docstring of :mod:`sqpmpc.coordination.motion`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Motion", "nearest", "path_motion", "smooth_path"]

_ARC_STEP = math.pi / 16  # arcs are sampled every 11.25 degrees (positions on the arc)


@dataclass(frozen=True)
class Motion:
    """A timed motion along a path, at the stage times ``0, T, ..., N T``.

    Attributes
    ----------
    poses
        ``(N+1, 3)`` ``(x, y, psi)``; stage 0 is the robot's own pose.
    velocities
        ``(N+1, 2)`` ``(v, omega)`` at the stages (stage 0: the robot's own).
    """

    poses: np.ndarray
    velocities: np.ndarray


def _wrap(a: float) -> float:
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def smooth_path(points: np.ndarray, reach: float, step: float
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""The polyline ``points (K, 2)`` with its corners rounded within ``reach``.

    Returns samples ``(S, 2)`` of the path, their headings ``(S,)`` (continuous,
    starting at the first segment's direction) and, for every point, the index of the
    last sample of its corner ``(K,)``; lines are sampled at most ``step`` apart, arcs
    every :data:`_ARC_STEP`; a turn in place is two samples at the vertex. A point
    equal to the one before it is a corner of none (its mark is the one before's).
    """
    pts = np.asarray(points, dtype=float)
    keep = np.ones(len(pts), dtype=bool)
    keep[1:] = np.hypot(*np.diff(pts, axis=0).T) > 1e-9
    kept = np.cumsum(keep) - 1  # each point's index among the kept ones
    pts = pts[keep]
    if len(pts) < 2:
        return pts.copy(), np.zeros(len(pts)), np.zeros(len(points), dtype=np.int64)
    seg = np.diff(pts, axis=0)
    lengths = np.hypot(seg[:, 0], seg[:, 1])
    raw = np.arctan2(seg[:, 1], seg[:, 0])
    angles = np.empty_like(raw)
    angles[0] = raw[0]
    for j in range(1, raw.size):
        angles[j] = angles[j - 1] + _wrap(raw[j] - raw[j - 1])
    # tangent lengths and radii of the corners at pts[1..K-2]
    K = len(pts)
    tangent = np.zeros(K)
    radius = np.zeros(K)
    for j in range(1, K - 1):
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
    xy: list[np.ndarray] = []
    psi: list[np.ndarray] = []

    def line(a: np.ndarray, b: np.ndarray, heading: float) -> None:
        n = max(1, math.ceil(float(np.hypot(*(b - a))) / step))
        f = np.linspace(0.0, 1.0, n + 1)[1:]
        xy.append(a + f[:, None] * (b - a))
        psi.append(np.full(n, heading))

    xy.append(pts[:1].copy())
    psi.append(angles[:1].copy())
    marks = np.zeros(K, dtype=np.int64)
    count = 1
    for j in range(1, K):
        u = seg[j - 1] / lengths[j - 1]
        start = xy[-1][-1]
        end = pts[j] - tangent[j] * u if j < K - 1 else pts[j]
        line(start, end, angles[j - 1])
        count += len(xy[-1])
        marks[j] = count - 1
        if j == K - 1:
            break
        turn = angles[j] - angles[j - 1]
        if abs(turn) < 1e-9:
            continue
        if radius[j] <= 0.0:  # in place: the heading changes at the vertex
            xy.append(pts[j][None].copy())
            psi.append(np.array([angles[j]]))
            count += 1
            marks[j] = count - 1
            continue
        sign = 1.0 if turn > 0 else -1.0
        a_in = angles[j - 1]
        centre = end + sign * radius[j] * np.array([-math.sin(a_in), math.cos(a_in)])
        n = max(2, math.ceil(abs(turn) / _ARC_STEP))
        h = a_in + np.linspace(0.0, turn, n + 1)[1:]
        xy.append(centre - sign * radius[j] * np.column_stack((-np.sin(h), np.cos(h))))
        psi.append(h)
        count += n
        marks[j] = count - 1
    return np.concatenate(xy), np.concatenate(psi), marks[kept]


def nearest(points: np.ndarray, here: np.ndarray) -> tuple[float, np.ndarray, int]:
    """The distance from ``here`` to the polyline ``points (K >= 2, 2)``, the nearest point
    and its segment (the last of equally near ones)."""
    a, b = points[:-1], points[1:]
    d = b - a
    dd = np.einsum("ij,ij->i", d, d)
    f = np.clip(np.einsum("ij,ij->i", here - a, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    near = a + f[:, None] * d
    gaps = np.hypot(*(near - here).T)
    i = int(np.flatnonzero(gaps <= gaps.min() + 1e-9)[-1])
    return float(gaps[i]), near[i], i


def path_motion(points: np.ndarray, pose: np.ndarray, speed: float, reach: float,
                sample_time: float, horizon: int, max_speed: float, max_turn_rate: float,
                acceleration: float | None, stop: bool = True, within: int | None = None,
                reverse: bool = False, turn_rate: float | None = None) -> Motion:
    """The numpy :func:`sqpmpc.coordination.motion.path_motion` (its parameters)."""
    T, N = float(sample_time), int(horizon)
    v_max, w_max = float(max_speed), float(max_turn_rate)
    if reverse:  # backwards is forwards with the heading turned by a half-turn
        flipped = np.array([pose[0], pose[1], float(pose[2]) + math.pi])
        motion = path_motion(points, flipped, -float(speed), reach, sample_time, horizon,
                             max_speed, max_turn_rate, acceleration, stop=stop, within=within,
                             turn_rate=turn_rate)
        poses = motion.poses.copy()
        poses[:, 2] -= math.pi
        velocities = motion.velocities.copy()
        velocities[:, 0] *= -1.0
        return Motion(poses, velocities)
    step = 0.25 * v_max * T
    pts = np.asarray(points, dtype=float).reshape(-1, 2)
    here = np.asarray(pose[:2], dtype=float)
    theta0 = float(pose[2])
    xy, psi, marks = smooth_path(pts, reach, step)
    if xy.shape[0] < 2:  # a path of one point
        xy, psi = np.concatenate((xy, xy)), np.full(2, theta0)
        marks = np.ones(len(pts), dtype=np.int64)
    w = len(pts) - 1 if within is None else min(int(within), len(pts) - 1)
    last = max(int(marks[w]), 1)
    # the robot's projection on the path (up to points[within]): the furthest of the
    # nearest points, so that a path that steps back is followed in its order
    gap, q, i = nearest(xy[:last + 1], here)
    ds = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate(([0.0], np.cumsum(ds)))
    s_q = s[i] + float(np.hypot(*(q - xy[i])))
    # straight to the path max(2 rho, gap) ahead (not past a turn in place or the end): a
    # join of at most arctan(1/2) in the tube, at most 45 degrees out of it
    still = np.flatnonzero(ds[i + 1:] <= 1e-12)
    s_join = min(s_q + max(2.0 * reach, gap), s[i + 1 + still[0]] if still.size else s[-1])
    j = min(int(np.searchsorted(s, s_join, side="right")) - 1, xy.shape[0] - 2)
    f = (s_join - s[j]) / ds[j] if ds[j] > 0 else 0.0
    target = xy[j] + f * (xy[j + 1] - xy[j])
    psi_t = psi[j] + f * (psi[j + 1] - psi[j])
    span = float(np.hypot(*(target - here)))
    lead = math.atan2(target[1] - here[1], target[0] - here[0]) if span > 1e-9 else psi_t
    lead = psi_t + _wrap(lead - psi_t)
    n = max(1, math.ceil(span / step))
    line = here + np.linspace(0.0, 1.0, n + 1)[:, None] * (target - here)
    rest = slice(j + 1, None)
    span_line = span > 1e-9
    if span_line:  # along the line, turning onto the path's heading on the way
        xy = np.concatenate((line, xy[rest]))
        psi = np.concatenate((lead + (psi_t - lead) * np.linspace(0.0, 1.0, n + 1), psi[rest]))
    else:
        xy = np.concatenate((target[None], xy[rest]))
        psi = np.concatenate(([psi_t], psi[rest]))
    # headings on the robot's branch, its error turned away at its speed (in place at rest)
    psi = psi + (theta0 + _wrap(psi[0] - theta0) - psi[0])
    error = theta0 - psi[0]
    ds = np.hypot(*np.diff(xy, axis=0).T)
    s = np.concatenate(([0.0], np.cumsum(ds)))
    if abs(error) > 1e-9:
        # the turn at the robot's speed: radius v0 / w_max (in place at rest)
        span = min(max(float(speed), 0.0) / w_max * abs(error), s[n] if span_line else s[-1])
        if span > 0:  # sampled as an arc is
            fine = np.linspace(0.0, span, max(2, math.ceil(abs(error) / _ARC_STEP)) + 1)
            grid = np.union1d(s, fine)
            xy = np.column_stack((np.interp(grid, s, xy[:, 0]), np.interp(grid, s, xy[:, 1])))
            psi, s = np.interp(grid, s, psi), grid
            ds = np.diff(s)
        weight = np.clip(1.0 - s / span, 0.0, 1.0) if span > 0 else np.zeros_like(s)
        # the robot's own heading first: a turn in place when nothing may drift
        xy = np.concatenate((xy[:1], xy))
        psi = np.concatenate(([theta0], psi + error * weight))
        s = np.concatenate(([0.0], s))
        ds = np.concatenate(([0.0], ds))
    dpsi = np.abs(np.diff(psi))
    # caps: |omega| <= w_max on every interval, v_max, a stop at the end
    with np.errstate(divide="ignore", invalid="ignore"):
        interval = np.where(dpsi > 1e-12, w_max * ds / dpsi, np.inf)
    cap = np.full(s.size, v_max)
    np.minimum(cap[:-1], interval, out=cap[:-1])
    np.minimum(cap[1:], interval, out=cap[1:])
    if stop:
        cap[-1] = 0.0
    v0 = min(max(float(speed), 0.0), v_max)
    if acceleration is None:
        v = cap.copy()
        v[0] = min(v0, cap[0])
    else:
        two_a = 2.0 * float(acceleration)
        head = cap ** 2
        head[0] = min(head[0], v0 ** 2)
        forward = two_a * s + np.minimum.accumulate(head - two_a * s)
        backward = -two_a * s + np.minimum.accumulate((head + two_a * s)[::-1])[::-1]
        v = np.sqrt(np.clip(np.minimum(np.minimum(forward, backward), cap ** 2), 0.0, None))
    # the time of each interval: from v[i] to v[i+1] over ds at most its cap, |a| <= a_max
    with np.errstate(divide="ignore", invalid="ignore"):
        if acceleration is None:
            dt = np.where(ds > 0, ds / interval.clip(max=v_max), 0.0)
        else:
            a = float(acceleration)
            va, vb = v[:-1], v[1:]
            top = np.minimum(np.sqrt(0.5 * (2.0 * a * ds + va ** 2 + vb ** 2)),
                             np.minimum(interval, v_max))
            ramps = (2.0 * top ** 2 - va ** 2 - vb ** 2) / (2.0 * a)
            dt = (2.0 * top - va - vb) / a + np.where(top > 0, (ds - ramps) / top, 0.0)
    dt = np.maximum(np.where(np.isfinite(dt), dt, 0.0), dpsi / w_max)
    t = np.concatenate(([0.0], np.cumsum(dt)))
    stages = T * np.arange(N + 1)
    x = np.interp(stages, t, xy[:, 0])
    y = np.interp(stages, t, xy[:, 1])
    heading = np.interp(stages, t, psi)
    speeds = np.interp(stages, t, v)
    # turn rates: the mean of each sample's, at a stage the mean of the two around it
    mean_rate = np.diff(heading) / T
    rate = np.empty(N + 1)
    rate[0] = mean_rate[0]
    rate[1:-1] = 0.5 * (mean_rate[:-1] + mean_rate[1:])
    rate[-1] = mean_rate[-1]
    poses = np.column_stack((x, y, heading))
    poses[0] = (here[0], here[1], theta0)
    if turn_rate is not None:  # where the robot's velocities are
        speeds[0], rate[0] = float(speed), float(turn_rate)
    return Motion(poses, np.column_stack((speeds, rate)))

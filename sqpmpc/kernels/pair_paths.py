r"""Compiled check of a pair's exact relative path under constant accelerations.

A robot with acceleration limits (:class:`sqpmpc.models.acceleration.AccelerationUnicycle`)
that holds the linear acceleration :math:`a` over a sample, starting along the heading
:math:`\psi_0`, is at

.. math::

    p(s) = \big((1-s)p_0 + s\hat p_1\big) - s(1-s)\,B, \qquad
    B = \tfrac{a T_s^2}{2}\,(\cos\psi_0, \sin\psi_0),

up to the part of :func:`sqpmpc.problem.plant.acceleration_path_deviation` that does not come
from the ramp (the heading turning within the sample, the input noise): a residual
:math:`g(s) = \alpha' s + \beta' s(1-s)`, :math:`\alpha' = \alpha`,
:math:`\beta' = \beta - |a| T_s^2/2`. The ramp's part is thus a known vector along the
robot's heading, not a disc of radius :math:`|a|T_s^2 s(1-s)/2` around the segment point.

For a pair the relative path is the quadratic curve
:math:`r(s) = r_0 + s\Delta - s(1-s)(B_a - B_b)` and the pair keeps :math:`R` over the sample
when :math:`\lVert r(s)\rVert \ge R + g_a(s) + g_b(s)` on :math:`[0, 1]`; both sides are
non-negative, so this is :math:`h(s) = \lVert r(s)\rVert^2 - (R + g(s))^2 \ge 0`, a polynomial
of degree 4. :func:`quartic_nonnegative` proves it with Bernstein coefficients (all
non-negative: so is the polynomial) and halving by de Casteljau's algorithm; a negative value at
an interval's end, or 40 halvings without a proof, refuse it. Exact arithmetic aside the check is
therefore sound, and it accepts a robot at rest beside another turning away or moving along the
gap, which the disc bound refuses near the distance: the disc (the lag taken in every direction)
grows linearly from :math:`s = 0`, where sideways motion opens the gap only quadratically.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sqpmpc.kernels.acceleration import bulging_segment_distance

__all__ = ["pairs_keep_ramp_distance", "quartic_nonnegative", "ramp_vectors", "warm_up_pair_paths"]

_jit = numba.njit(cache=True, nogil=True)
_DEPTH = 40


@_jit
def quartic_nonnegative(c0: float, c1: float, c2: float, c3: float, c4: float) -> bool:
    """Whether :math:`c_0 + c_1 s + \\dots + c_4 s^4 \\ge 0` on :math:`[0, 1]` is proved
    (Bernstein coefficients, halving up to 40 times; ``False`` when not proved)."""
    stack = np.empty((_DEPTH + 2, 5))
    depth = np.empty(_DEPTH + 2, dtype=np.int64)
    stack[0, 0] = c0
    stack[0, 1] = c0 + c1 / 4.0
    stack[0, 2] = c0 + c1 / 2.0 + c2 / 6.0
    stack[0, 3] = c0 + 0.75 * c1 + c2 / 2.0 + c3 / 4.0
    stack[0, 4] = c0 + c1 + c2 + c3 + c4
    depth[0] = 0
    top = 1
    work = np.empty((5, 5))
    while top > 0:
        top -= 1
        b = stack[top].copy()
        level = depth[top]
        if b[0] < 0.0 or b[4] < 0.0:
            return False
        if b.min() >= 0.0:
            continue
        if level >= _DEPTH:
            return False
        # de Casteljau at 1/2: left half work[i, 0], right half work[4 - i, i]
        work[0] = b
        for r in range(1, 5):
            for i in range(5 - r):
                work[r, i] = 0.5 * (work[r - 1, i] + work[r - 1, i + 1])
        for i in range(5):
            stack[top, i] = work[4 - i, i]          # right half
            stack[top + 1, i] = work[i, 0]          # left half (popped first)
        depth[top] = level + 1
        depth[top + 1] = level + 1
        top += 2
    return True


@_jit
def _ramp_path_keeps(r0x: float, r0y: float, dx: float, dy: float, bx: float, by: float,
                     alpha: float, beta: float, required: float) -> bool:
    """``|r0 + s d - s(1-s) b| >= required + alpha s + beta s(1-s)`` on [0, 1]."""
    if alpha + min(beta, 0.0) < 0.0 or required < 0.0:
        return False  # the residual must be non-negative for the squared form
    p0x, p0y = r0x, r0y
    p1x, p1y = dx - bx, dy - by
    p2x, p2y = bx, by
    f0 = p0x * p0x + p0y * p0y
    f1 = 2.0 * (p0x * p1x + p0y * p1y)
    f2 = p1x * p1x + p1y * p1y + 2.0 * (p0x * p2x + p0y * p2y)
    f3 = 2.0 * (p1x * p2x + p1y * p2y)
    f4 = p2x * p2x + p2y * p2y
    q0, q1, q2 = required, alpha + beta, -beta
    return quartic_nonnegative(f0 - q0 * q0, f1 - 2.0 * q0 * q1,
                               f2 - (q1 * q1 + 2.0 * q0 * q2), f3 - 2.0 * q1 * q2,
                               f4 - q2 * q2)


@_jit
def pairs_keep_ramp_distance(pairs: np.ndarray, now: np.ndarray, nxt: np.ndarray,
                             ramp: np.ndarray, required: np.ndarray, alpha: np.ndarray,
                             beta: np.ndarray) -> bool:
    """Whether every pair keeps ``required`` over the sample (module notes).

    ``now, nxt (m, 2)``: the segments; ``ramp (m, 2)``: each robot's :math:`B`;
    ``alpha, beta (m,)``: the full deviation bounds of
    :func:`~sqpmpc.problem.plant.acceleration_path_deviation` (ramp included). A pair the
    disc bound (:func:`~sqpmpc.kernels.acceleration.bulging_segment_distance`) already clears
    passes at once; the others get the exact relative ramp.
    """
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        r0x, r0y = now[a, 0] - now[b, 0], now[a, 1] - now[b, 1]
        dx = (nxt[a, 0] - nxt[b, 0]) - r0x
        dy = (nxt[a, 1] - nxt[b, 1]) - r0y
        al, be = alpha[a] + alpha[b], beta[a] + beta[b]
        if bulging_segment_distance(r0x, r0y, dx, dy, al, be) >= required[p]:
            continue
        ramp_a = math.hypot(ramp[a, 0], ramp[a, 1])
        ramp_b = math.hypot(ramp[b, 0], ramp[b, 1])
        if not _ramp_path_keeps(r0x, r0y, dx, dy, ramp[a, 0] - ramp[b, 0],
                                ramp[a, 1] - ramp[b, 1], al, be - ramp_a - ramp_b,
                                required[p]):
            return False
    return True


def ramp_vectors(headings: np.ndarray, accelerations: np.ndarray,
                 sample_time: float) -> np.ndarray:
    """Each robot's :math:`B = a T_s^2/2\\,(\\cos\\psi_0, \\sin\\psi_0)`, ``(m, 2)``."""
    k = 0.5 * sample_time * sample_time * np.asarray(accelerations, dtype=float)
    psi = np.asarray(headings, dtype=float)
    return np.ascontiguousarray(np.stack([k * np.cos(psi), k * np.sin(psi)], axis=-1))



def warm_up_pair_paths() -> None:
    """Compile or load every kernel of this module."""
    now = np.array([[0.0, 0.0], [1.0, 0.0]])
    ramp = np.zeros((2, 2))
    pairs_keep_ramp_distance(np.array([[0, 1]], dtype=np.int64), now, now, ramp,
                             np.array([2.0]), np.zeros(2), np.zeros(2))

r"""Compiled kernels of the unicycle with velocity states and acceleration inputs (Euler step).

The model is :class:`sqpmpc.models.acceleration.AccelerationUnicycle`: states
``(x, y, psi, v, omega)``, inputs ``(a, alpha)``, a robot's QP block laid out
``(chi_0, u_0, chi_1, ..., u_{N-1}, chi_N)`` with 7 variables per stage. The
Euler step (the model's notes) with :math:`\bar v = v + T_s a/2`:

.. math::

    x^+ = x + T_s\bar v\cos\psi,\; y^+ = y + T_s\bar v\sin\psi,\;
    \psi^+ = \psi + T_s\omega + \tfrac{T_s^2}{2}\alpha,\; v^+ = v + T_s a,\;
    \omega^+ = \omega + T_s\alpha.

The kernels have the signatures of :class:`sqpmpc.models.base.ModelKernels`
and the arithmetic of the model's NumPy functions (tested against them).

The checks at the end take a robot's deviation from its predicted segment as the bound
:math:`\alpha s + \beta s(1-s)` itself (:func:`sqpmpc.problem.plant.acceleration_path_deviation`:
a robot ramping its speed lags or leads on its segment by :math:`|a|T_s^2 s(1-s)/2`),
not its linear majorant :math:`(\alpha + \beta) s`, which is four times the largest
bulge.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sqpmpc.kernels.collision import growing_segment_distance

__all__ = [
    "bulging_segment_distance",
    "moving_points_keep_bulging_distance",
    "pairs_keep_bulging_distance",
    "acceleration_defect_l1",
    "acceleration_linearize",
    "acceleration_rollout",
    "acceleration_shift_iterate",
    "warm_up_acceleration",
]

_jit = numba.njit(cache=True, nogil=True)
_S = 7  # variables per stage


@_jit
def _step(x: float, y: float, psi: float, v: float, w: float, a: float, al: float,
          h: float) -> tuple[float, float, float, float, float]:
    hv = h * (v + 0.5 * h * a)
    return (x + hv * math.cos(psi), y + hv * math.sin(psi), psi + h * w + 0.5 * h * h * al,
            v + h * a, w + h * al)


@_jit
def acceleration_rollout(initial: np.ndarray, inputs: np.ndarray, h: float,
                         out: np.ndarray) -> None:
    """States ``out (m, N+1, 5)`` of ``inputs (m, N, 2)`` from ``initial (m, 5)``."""
    m, N = inputs.shape[0], inputs.shape[1]
    for r in range(m):
        s = (initial[r, 0], initial[r, 1], initial[r, 2], initial[r, 3], initial[r, 4])
        for k in range(5):
            out[r, 0, k] = s[k]
        for i in range(N):
            s = _step(s[0], s[1], s[2], s[3], s[4], inputs[r, i, 0], inputs[r, i, 1], h)
            for k in range(5):
                out[r, i + 1, k] = s[k]


@_jit
def acceleration_linearize(z: np.ndarray, m: int, N: int, block: int, h: float,
                           dyn_A: np.ndarray, dyn_B: np.ndarray, dyn_lower: np.ndarray,
                           dyn_upper: np.ndarray) -> None:
    r"""The Euler linearization at ``z`` into the QP's dynamics values: ``-A`` at the model's
    12 pattern entries, ``-B`` at its 7, and
    :math:`c = (T_s\bar v\psi\sin\psi, -T_s\bar v\psi\cos\psi, 0, 0, 0)`."""
    hh = 0.5 * h * h
    for r in range(m):
        for i in range(N):
            b = r * block + i * _S
            psi = z[b + 2]
            hv = h * (z[b + 3] + 0.5 * h * z[b + 5])
            c = math.cos(psi)
            s = math.sin(psi)
            k = (r * N + i) * 12
            for d in range(5):
                dyn_A[k + d] = -1.0
            dyn_A[k + 5] = hv * s          # -(d x+/d psi)
            dyn_A[k + 6] = -(h * c)        # d x+/d v
            dyn_A[k + 7] = -0.0            # d x+/d omega (RK4 and exact only)
            dyn_A[k + 8] = -(hv * c)
            dyn_A[k + 9] = -(h * s)
            dyn_A[k + 10] = -0.0
            dyn_A[k + 11] = -h
            k = (r * N + i) * 7
            dyn_B[k] = -(hh * c)
            dyn_B[k + 1] = -0.0
            dyn_B[k + 2] = -(hh * s)
            dyn_B[k + 3] = -0.0
            dyn_B[k + 4] = -hh
            dyn_B[k + 5] = -h
            dyn_B[k + 6] = -h
            j = (r * N + i) * 5
            hvpsi = hv * psi
            dyn_lower[j] = dyn_upper[j] = hvpsi * s
            dyn_lower[j + 1] = dyn_upper[j + 1] = (-hvpsi) * c
            for d in range(2, 5):
                dyn_lower[j + d] = dyn_upper[j + d] = 0.0


@_jit
def acceleration_shift_iterate(z: np.ndarray, y: np.ndarray, z_order: np.ndarray,
                               y_order: np.ndarray, m: int, N: int, block: int, h: float,
                               z_out: np.ndarray, y_out: np.ndarray) -> None:
    """Iterate and multipliers shifted by one stage; the new last state is the step of the
    old last state under the held last input."""
    for i in range(z_order.shape[0]):
        z_out[i] = z[z_order[i]]
    for i in range(y_order.shape[0]):
        y_out[i] = y[y_order[i]]
    for r in range(m):
        last = r * block + _S * N
        s = _step(z[last], z[last + 1], z[last + 2], z[last + 3], z[last + 4], z[last - 2],
                  z[last - 1], h)
        for k in range(5):
            z_out[last + k] = s[k]


@_jit
def acceleration_defect_l1(z: np.ndarray, initial: np.ndarray, m: int, N: int, block: int,
                           h: float) -> float:
    """L1 norm of the dynamics defects and of the initial-state defect at ``z``."""
    total = 0.0
    for r in range(m):
        base = r * block
        for k in range(5):
            total += abs(z[base + k] - initial[r, k])
        for i in range(N):
            b = base + _S * i
            s = _step(z[b], z[b + 1], z[b + 2], z[b + 3], z[b + 4], z[b + 5], z[b + 6], h)
            for k in range(5):
                total += abs(z[b + _S + k] - s[k])
    return total


_GOLDEN = 0.6180339887498949


@_jit
def _bulge(r0x: float, r0y: float, dx: float, dy: float, alpha: float, beta: float,
           s: float) -> float:
    return math.hypot(r0x + s * dx, r0y + s * dy) - alpha * s - beta * s * (1.0 - s)


@_jit
def bulging_segment_distance(r0x: float, r0y: float, dx: float, dy: float, alpha: float,
                             beta: float) -> float:
    r"""Smallest :math:`\lVert r_0 + s\Delta\rVert - \alpha s - \beta s(1-s)` over
    :math:`s \in [0, 1]`: the smallest distance of a relative segment whose true path may
    stray :math:`\alpha s + \beta s(1-s)` from it.

    For :math:`\beta > 0` the function is convex (a norm, a linear term and
    :math:`\beta(s^2 - s)`): golden-section search, 60 steps (the bracket shrinks to
    :math:`3 \cdot 10^{-13}`), and the end points. For :math:`\beta \le 0` the bound is
    at most :math:`\alpha s`: the linear case, exactly as
    :func:`sqpmpc.kernels.collision.growing_segment_distance`.
    """
    if beta <= 0.0:
        return growing_segment_distance(r0x, r0y, dx, dy, alpha)
    lo, hi = 0.0, 1.0
    c = hi - _GOLDEN * (hi - lo)
    d = lo + _GOLDEN * (hi - lo)
    fc = _bulge(r0x, r0y, dx, dy, alpha, beta, c)
    fd = _bulge(r0x, r0y, dx, dy, alpha, beta, d)
    for _ in range(60):
        if fc < fd:
            hi, d, fd = d, c, fc
            c = hi - _GOLDEN * (hi - lo)
            fc = _bulge(r0x, r0y, dx, dy, alpha, beta, c)
        else:
            lo, c, fc = c, d, fd
            d = lo + _GOLDEN * (hi - lo)
            fd = _bulge(r0x, r0y, dx, dy, alpha, beta, d)
    return min(fc, fd, _bulge(r0x, r0y, dx, dy, alpha, beta, 0.0),
               _bulge(r0x, r0y, dx, dy, alpha, beta, 1.0))


@_jit
def pairs_keep_bulging_distance(pairs: np.ndarray, now: np.ndarray, nxt: np.ndarray,
                                required: np.ndarray, alpha: np.ndarray,
                                beta: np.ndarray) -> bool:
    """Whether every pair keeps ``required`` along the segments ``now -> nxt`` when robot
    ``j`` may stray ``alpha[j] s + beta[j] s (1 - s)`` from its segment (the pair: the
    sums)."""
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        r0x, r0y = now[a, 0] - now[b, 0], now[a, 1] - now[b, 1]
        dx = (nxt[a, 0] - nxt[b, 0]) - r0x
        dy = (nxt[a, 1] - nxt[b, 1]) - r0y
        if bulging_segment_distance(r0x, r0y, dx, dy, alpha[a] + alpha[b],
                                    beta[a] + beta[b]) < required[p]:
            return False
    return True


@_jit
def moving_points_keep_bulging_distance(x0: float, y0: float, x1: float, y1: float,
                                        start: np.ndarray, end: np.ndarray, keep: np.ndarray,
                                        alpha: float, beta: float) -> bool:
    """Whether the path near ``p0 -> p1`` keeps ``keep[o]`` from points moving straight from
    ``start[o]`` to ``end[o]`` over the same sample (obstacles), the path within
    ``alpha s + beta s (1 - s)`` of its segment."""
    for o in range(start.shape[0]):
        rx, ry = x0 - start[o, 0], y0 - start[o, 1]
        dx = (x1 - end[o, 0]) - rx
        dy = (y1 - end[o, 1]) - ry
        if bulging_segment_distance(rx, ry, dx, dy, alpha, beta) < keep[o]:
            return False
    return True


def warm_up_acceleration() -> None:
    """Compile or load every kernel of this module."""
    x = np.zeros((2, 5))
    u = np.zeros((2, 2, 2))
    acceleration_rollout(x, u, 0.1, np.empty((2, 3, 5)))
    z = np.zeros(2 * 19)
    acceleration_linearize(z, 2, 2, 19, 0.1, np.empty(48), np.empty(28), np.empty(20),
                           np.empty(20))
    order = np.arange(38)
    acceleration_shift_iterate(z, z, order, order, 2, 2, 19, 0.1, np.empty(38), np.empty(38))
    acceleration_defect_l1(z, x, 2, 2, 19, 0.1)
    pairs = np.array([[0, 1]], dtype=np.int64)
    pairs_keep_bulging_distance(pairs, x[:, :2].copy(), x[:, :2].copy(), np.ones(1),
                                np.zeros(2), np.ones(2))
    moving_points_keep_bulging_distance(0.0, 0.0, 1.0, 0.0, np.ones((1, 2)), np.ones((1, 2)),
                                        np.ones(1), 0.0, 0.1)

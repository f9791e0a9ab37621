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
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
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

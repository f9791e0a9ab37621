r"""Unicycle kinematics (paper eq. 1) and its discretizations (eq. 3, RK4, exact).

The continuous model is

.. math::

    \dot x = v \cos\psi, \qquad \dot y = v \sin\psi, \qquad \dot\psi = \omega,

with state :math:`\chi = (x, y, \psi)` and input :math:`u = (v, \omega)`. Three
discretizations with sample time :math:`T_s` are provided:

- ``"euler"`` (the paper's eq. 3, the default):
  :math:`\chi_{k+1} = \chi_k + T_s f(\chi_k, u_k)`;
- ``"rk4"``: the classical fourth-order Runge-Kutta step with the input held;
- ``"exact"``: the unicycle integrated exactly under a zero-order-hold input,
  a circular arc (a straight segment when :math:`\omega = 0`). With
  :math:`a = \omega T_s / 2` and :math:`\operatorname{sinc} a = \sin a / a`,

  .. math::

      p_{k+1} = p_k + T_s v \operatorname{sinc}(a)
      \begin{bmatrix}\cos(\psi_k + a) \\ \sin(\psi_k + a)\end{bmatrix},
      \qquad \psi_{k+1} = \psi_k + T_s \omega,

  the chord of the arc: it turns by half the heading change and is shortened
  by :math:`\operatorname{sinc} a`. :math:`\operatorname{sinc}` and its
  derivative are evaluated by their Taylor series for :math:`|a| < 10^{-3}`, so
  the step and its Jacobians are smooth through :math:`\omega = 0`.

Every function is vectorized: states have shape ``(..., 3)`` and inputs
``(..., 2)`` with any common leading shape (robots, stages, both), and
Jacobians come back as ``(..., 3, 3)`` and ``(..., 3, 2)`` arrays, computed
analytically (chain rule through the RK4 stages).
"""

from __future__ import annotations

from typing import Literal

import numpy as np

from sqpmpc.errors import ProblemError

__all__ = [
    "DISCRETIZATIONS",
    "Discretization",
    "continuous_dynamics",
    "discrete_dynamics",
    "discrete_jacobians",
    "weighted_dynamics_hessian",
    "estimate_input",
    "rollout",
    "sinc_and_derivative",
    "NX",
    "NU",
]

NX = 3
NU = 2
Discretization = Literal["euler", "rk4", "exact"]
DISCRETIZATIONS: tuple[str, ...] = ("euler", "rk4", "exact")
_SERIES = 1e-3  # |a| below which sinc and its derivative use their Taylor series


def _check_method(method: str) -> None:
    if method not in DISCRETIZATIONS:
        raise ProblemError(
            f"discretization must be one of {DISCRETIZATIONS}, got {method!r}"
        )


def sinc_and_derivative(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    r""":math:`\operatorname{sinc} a = \sin a / a` and its derivative, smooth at 0.

    For :math:`|a| < 10^{-3}` the series :math:`1 - a^2/6 + a^4/120` and
    :math:`-a/3 + a^3/30` are used (their truncation error is below
    :math:`10^{-18}` there).
    """
    a = np.asarray(a, dtype=float)
    small = np.abs(a) < _SERIES
    safe = np.where(small, 1.0, a)
    sin, cos = np.sin(safe), np.cos(safe)
    a2 = a * a
    sinc = np.where(small, 1.0 - a2 / 6.0 + a2 * a2 / 120.0, sin / safe)
    dsinc = np.where(small, -a / 3.0 + a * a2 / 30.0, (safe * cos - sin) / (safe * safe))
    return sinc, dsinc


def _exact_step(states: np.ndarray, inputs: np.ndarray, h: float, jacobians: bool
                ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """The exact zero-order-hold step (and its Jacobians), see the module notes."""
    psi = states[..., 2]
    v, w = inputs[..., 0], inputs[..., 1]
    a = 0.5 * h * w
    s, ds = sinc_and_derivative(a)
    mid = psi + a
    c, sn = np.cos(mid), np.sin(mid)
    length = h * v * s
    shape = np.broadcast_shapes(states.shape[:-1], inputs.shape[:-1])
    nxt = np.empty(shape + (3,))
    nxt[..., 0] = states[..., 0] + length * c
    nxt[..., 1] = states[..., 1] + length * sn
    nxt[..., 2] = psi + h * w
    if not jacobians:
        return nxt, None, None
    A = np.broadcast_to(np.eye(3), shape + (3, 3)).copy()
    A[..., 0, 2] = -length * sn
    A[..., 1, 2] = length * c
    B = np.zeros(shape + (3, 2))
    B[..., 0, 0] = h * s * c
    B[..., 1, 0] = h * s * sn
    # d/d omega: a = h w / 2 moves both the length (through sinc) and the direction
    dlen = h * v * ds * (0.5 * h)
    B[..., 0, 1] = dlen * c - length * sn * (0.5 * h)
    B[..., 1, 1] = dlen * sn + length * c * (0.5 * h)
    B[..., 2, 1] = h
    return nxt, A, B


def continuous_dynamics(states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    r"""Right-hand side :math:`f(\chi, u) = (v\cos\psi, v\sin\psi, \omega)`.

    Parameters
    ----------
    states
        Array ``(..., 3)`` of :math:`(x, y, \psi)`.
    inputs
        Array ``(..., 2)`` of :math:`(v, \omega)`.

    Returns
    -------
    np.ndarray
        Array ``(..., 3)``.
    """
    psi = states[..., 2]
    v = inputs[..., 0]
    out = np.empty(np.broadcast_shapes(states.shape, inputs.shape[:-1] + (3,)))
    np.multiply(v, np.cos(psi), out=out[..., 0])
    np.multiply(v, np.sin(psi), out=out[..., 1])
    out[..., 2] = inputs[..., 1]
    return out


def _continuous_jacobians(
    states: np.ndarray, inputs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Jacobians of :func:`continuous_dynamics`, shapes ``(..., 3, 3)`` and ``(..., 3, 2)``."""
    psi = states[..., 2]
    v = inputs[..., 0]
    c, s = np.cos(psi), np.sin(psi)
    shape = np.broadcast_shapes(psi.shape, v.shape)
    J_x = np.zeros(shape + (3, 3))
    J_x[..., 0, 2] = -v * s
    J_x[..., 1, 2] = v * c
    J_u = np.zeros(shape + (3, 2))
    J_u[..., 0, 0] = c
    J_u[..., 1, 0] = s
    J_u[..., 2, 1] = 1.0
    return J_x, J_u


def discrete_dynamics(
    states: np.ndarray,
    inputs: np.ndarray,
    sample_time: float,
    method: str = "euler",
) -> np.ndarray:
    r"""One step :math:`\chi^+ = f_d(\chi, u)` of the chosen discretization.

    Parameters
    ----------
    states
        Array ``(..., 3)``.
    inputs
        Array ``(..., 2)``, held constant over the step.
    sample_time
        :math:`T_s` in seconds.
    method
        ``"euler"`` (paper eq. 3), ``"rk4"`` or ``"exact"``.

    Returns
    -------
    np.ndarray
        Next states, ``(..., 3)``.
    """
    _check_method(method)
    states = np.asarray(states, dtype=float)
    inputs = np.asarray(inputs, dtype=float)
    h = float(sample_time)
    if method == "exact":
        return _exact_step(states, inputs, h, False)[0]
    if method == "euler":
        if states.shape[:-1] == inputs.shape[:-1]:  # hot path: no broadcasting needed
            psi = states[..., 2]
            hv = h * inputs[..., 0]
            out = np.empty(states.shape)
            np.add(states[..., 0], hv * np.cos(psi), out=out[..., 0])
            np.add(states[..., 1], hv * np.sin(psi), out=out[..., 1])
            np.add(psi, h * inputs[..., 1], out=out[..., 2])
            return out
        return states + h * continuous_dynamics(states, inputs)
    k1 = continuous_dynamics(states, inputs)
    k2 = continuous_dynamics(states + 0.5 * h * k1, inputs)
    k3 = continuous_dynamics(states + 0.5 * h * k2, inputs)
    k4 = continuous_dynamics(states + h * k3, inputs)
    return states + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def discrete_jacobians(
    states: np.ndarray,
    inputs: np.ndarray,
    sample_time: float,
    method: str = "euler",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""Next state and Jacobians :math:`A = \partial f_d/\partial\chi`,
    :math:`B = \partial f_d/\partial u`.

    For Euler,

    .. math::

        A = I + T_s \begin{bmatrix} 0 & 0 & -v\sin\psi \\ 0 & 0 & v\cos\psi \\ 0&0&0
        \end{bmatrix}, \qquad
        B = T_s \begin{bmatrix} \cos\psi & 0 \\ \sin\psi & 0 \\ 0 & 1 \end{bmatrix}.

    For RK4 the chain rule is applied through the four stages
    :math:`\xi_1 = \chi`, :math:`\xi_{i+1} = \chi + c_i T_s k_i`,
    :math:`k_i = f(\xi_i, u)`, with
    :math:`\mathrm{d}k_i = J_\chi(\xi_i)\,\mathrm{d}\xi_i + J_u(\xi_i)\,\mathrm{d}u`.
    For the exact step, with :math:`\ell = T_s v \operatorname{sinc} a` and
    :math:`\phi = \psi + a`,

    .. math::

        \frac{\partial p^+}{\partial \psi} = \ell \begin{bmatrix}-\sin\phi \\
        \cos\phi\end{bmatrix}, \quad
        \frac{\partial p^+}{\partial v} = T_s \operatorname{sinc}(a)
        \begin{bmatrix}\cos\phi \\ \sin\phi\end{bmatrix}, \quad
        \frac{\partial p^+}{\partial \omega} = \frac{T_s}{2}\Big(T_s v
        \operatorname{sinc}'(a) \begin{bmatrix}\cos\phi \\ \sin\phi\end{bmatrix}
        + \ell \begin{bmatrix}-\sin\phi \\ \cos\phi\end{bmatrix}\Big).

    Returns
    -------
    tuple of np.ndarray
        ``(next_states (..., 3), A (..., 3, 3), B (..., 3, 2))``.
    """
    _check_method(method)
    states = np.asarray(states, dtype=float)
    inputs = np.asarray(inputs, dtype=float)
    h = float(sample_time)
    if method == "exact":
        return _exact_step(states, inputs, h, True)  # type: ignore[return-value]
    shape = np.broadcast_shapes(states.shape[:-1], inputs.shape[:-1])
    eye = np.broadcast_to(np.eye(3), shape + (3, 3))
    if method == "euler":
        J_x, J_u = _continuous_jacobians(states, inputs)
        nxt = states + h * continuous_dynamics(states, inputs)
        return nxt, eye + h * J_x, h * J_u
    # RK4: d(xi)/d(chi, u) tracked as a pair (D_x (...,3,3), D_u (...,3,2)).
    xi = states
    D_x = eye.copy()
    D_u = np.zeros(shape + (3, 2))
    acc = np.zeros(shape + (3,))
    acc_x = np.zeros(shape + (3, 3))
    acc_u = np.zeros(shape + (3, 2))
    coeffs = (0.5, 0.5, 1.0, None)
    weights = (1.0, 2.0, 2.0, 1.0)
    for c_i, w_i in zip(coeffs, weights, strict=True):
        k = continuous_dynamics(xi, inputs)
        J_x, J_u = _continuous_jacobians(xi, inputs)
        dk_x = J_x @ D_x
        dk_u = J_x @ D_u + J_u
        acc = acc + w_i * k
        acc_x = acc_x + w_i * dk_x
        acc_u = acc_u + w_i * dk_u
        if c_i is not None:
            xi = states + c_i * h * k
            D_x = eye + c_i * h * dk_x
            D_u = c_i * h * dk_u
    nxt = states + (h / 6.0) * acc
    return nxt, eye + (h / 6.0) * acc_x, (h / 6.0) * acc_u


def weighted_dynamics_hessian(
    states: np.ndarray,
    inputs: np.ndarray,
    weights: np.ndarray,
    sample_time: float,
    method: str = "euler",
) -> np.ndarray:
    r"""Hessian of :math:`\lambda^\top f_d(\chi, u)` in :math:`(\psi, v, \omega)`.

    Only :math:`\psi`, :math:`v` and :math:`\omega` enter the unicycle's
    nonlinearity, so the full ``5 x 5`` Hessian in :math:`(x, y, \psi, v, \omega)`
    is zero outside this ``3 x 3`` block. For Euler,

    .. math::

        \nabla^2 = T_s \begin{bmatrix}
        -v(\lambda_x\cos\psi + \lambda_y\sin\psi) & -\lambda_x\sin\psi + \lambda_y\cos\psi & 0\\
        -\lambda_x\sin\psi + \lambda_y\cos\psi & 0 & 0 \\ 0 & 0 & 0\end{bmatrix}.

    For RK4 and the exact step the block is obtained by central differences of
    the analytic Jacobians (step 1e-6), which is accurate to about 1e-9 here.

    Parameters
    ----------
    states, inputs
        Linearization points ``(..., 3)`` and ``(..., 2)``.
    weights
        Multipliers :math:`\lambda`, ``(..., 3)``.

    Returns
    -------
    np.ndarray
        ``(..., 3, 3)`` symmetric blocks ordered :math:`(\psi, v, \omega)`.
    """
    _check_method(method)
    states = np.asarray(states, dtype=float)
    inputs = np.asarray(inputs, dtype=float)
    lam = np.asarray(weights, dtype=float)
    h = float(sample_time)
    shape = np.broadcast_shapes(states.shape[:-1], inputs.shape[:-1], lam.shape[:-1])
    H = np.zeros(shape + (3, 3))
    if method == "euler":
        psi = states[..., 2]
        v = inputs[..., 0]
        c, s = np.cos(psi), np.sin(psi)
        H[..., 0, 0] = -h * v * (lam[..., 0] * c + lam[..., 1] * s)
        off = h * (-lam[..., 0] * s + lam[..., 1] * c)
        H[..., 0, 1] = off
        H[..., 1, 0] = off
        return H
    eps = 1e-6
    for col in range(3):
        dx = np.zeros(3)
        du = np.zeros(2)
        if col == 0:
            dx[2] = eps
        else:
            du[col - 1] = eps
        _, A_p, B_p = discrete_jacobians(states + dx, inputs + du, h, method)
        _, A_m, B_m = discrete_jacobians(states - dx, inputs - du, h, method)
        g_p = np.concatenate(
            (np.einsum("...i,...i->...", lam, A_p[..., :, 2])[..., None],
             np.einsum("...i,...ij->...j", lam, B_p)), axis=-1)
        g_m = np.concatenate(
            (np.einsum("...i,...i->...", lam, A_m[..., :, 2])[..., None],
             np.einsum("...i,...ij->...j", lam, B_m)), axis=-1)
        H[..., :, col] = (g_p - g_m) / (2.0 * eps)
    return 0.5 * (H + np.swapaxes(H, -1, -2))


def rollout(
    initial_state: np.ndarray,
    inputs: np.ndarray,
    sample_time: float,
    method: str = "euler",
) -> np.ndarray:
    """Simulate a sequence of inputs.

    Parameters
    ----------
    initial_state
        ``(..., 3)``.
    inputs
        ``(N, ..., 2)``: the input sequence, stage first.

    Returns
    -------
    np.ndarray
        ``(N + 1, ..., 3)`` states, the initial one first.
    """
    inputs = np.asarray(inputs, dtype=float)
    x0 = np.asarray(initial_state, dtype=float)
    if method == "euler":  # closed form: headings by cumulative sums, then positions
        h = float(sample_time)
        # add.accumulate is cumsum without its Python wrapper (the same sums)
        turn = np.empty((inputs.shape[0] + 1,) + inputs.shape[1:-1])
        turn[0] = 0.0
        np.multiply(h, np.add.accumulate(inputs[..., 1], axis=0), out=turn[1:])
        psi = x0[..., 2] + turn
        hv = h * inputs[..., 0]
        step = np.empty(inputs.shape[:-1] + (2,))
        np.multiply(hv, np.cos(psi[:-1]), out=step[..., 0])
        np.multiply(hv, np.sin(psi[:-1]), out=step[..., 1])
        out = np.empty(psi.shape + (3,))
        out[0] = x0
        np.add(x0[..., :2], np.add.accumulate(step, axis=0), out=out[1:, ..., :2])
        out[..., 2] = psi
        return out
    out = [x0]
    for u in inputs:
        out.append(discrete_dynamics(out[-1], u, sample_time, method))
    return np.stack(out)


def estimate_input(
    previous_state: np.ndarray, current_state: np.ndarray, sample_time: float
) -> np.ndarray:
    r"""Estimate the input applied between two states (paper section 3.2 fallback).

    Inverts the Euler step: :math:`v = (p_k - p_{k-1})^\top
    (\cos\psi_{k-1}, \sin\psi_{k-1}) / T_s` and
    :math:`\omega = \mathrm{wrap}(\psi_k - \psi_{k-1}) / T_s`.

    Parameters
    ----------
    previous_state, current_state
        ``(..., 3)``.

    Returns
    -------
    np.ndarray
        ``(..., 2)`` estimated :math:`(v, \omega)`.
    """
    prev = np.asarray(previous_state, dtype=float)
    cur = np.asarray(current_state, dtype=float)
    heading = np.stack((np.cos(prev[..., 2]), np.sin(prev[..., 2])), axis=-1)
    v = np.einsum("...i,...i->...", cur[..., :2] - prev[..., :2], heading) / sample_time
    dpsi = np.angle(np.exp(1j * (cur[..., 2] - prev[..., 2])))
    return np.stack((v, dpsi / sample_time), axis=-1)

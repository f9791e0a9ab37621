r"""The unicycle with velocity states and acceleration inputs (CONTRACT 1c, the second model).

States :math:`\chi = (x, y, \psi, v, \omega)`, inputs :math:`u = (a, \alpha)`,
the accelerations, held constant over a sample:

.. math::

    \dot x = v\cos\psi,\quad \dot y = v\sin\psi,\quad \dot\psi = \omega,\quad
    \dot v = a,\quad \dot\omega = \alpha.

The velocities then change linearly over a sample, from :math:`(v_k, \omega_k)`
to :math:`(v_{k+1}, \omega_{k+1}) = (v_k + T_s a_k, \omega_k + T_s\alpha_k)`,
which a robot with the declared acceleration limits can follow. Discretizations:

- ``"euler"`` (default): the velocities and the heading integrated exactly
  (they are polynomials), the position by one Euler step along the heading
  :math:`\psi_k` with the sample's mean speed :math:`\bar v = v_k + T_s a_k/2`:

  .. math::

      p_{k+1} = p_k + T_s \bar v (\cos\psi_k, \sin\psi_k), \quad
      \psi_{k+1} = \psi_k + T_s\bar\omega, \quad \bar\omega = \omega_k + T_s\alpha_k/2.

  This is the paper's Euler step (eq. 3) under the input :math:`(\bar v, \bar\omega)`:
  a plan of this model *is* a paper-unicycle plan with inputs :math:`(\bar v_i,
  \bar\omega_i)` (:meth:`AccelerationUnicycle.velocity_plan`), which is what the
  neighbours, the recordings and the wire receive;
- ``"rk4"``: the classical Runge-Kutta step of the five equations;
- ``"exact"``: the exact solution: heading and velocities in closed form, the
  position :math:`\int_0^{T_s} (v_k + a t) e^{i\psi(t)}\,dt` by 16-point
  Gauss-Legendre quadrature (the integrand is analytic and turns by less than a
  radian per sample for any sensible bounds: the quadrature error is at
  rounding level), Jacobians by differentiating under the integral.

The velocity commands sent to the robots are the velocities of stage 1,
:math:`(v_1, \omega_1)` (:meth:`AccelerationUnicycle.commands`): what the
robot is to reach at the end of the sample.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.kernels.acceleration import (
    acceleration_defect_l1,
    acceleration_linearize,
    acceleration_rollout,
    acceleration_shift_iterate,
)
from sqpmpc.models.base import ModelKernels, RobotModel, check_box

__all__ = ["ACCELERATION_DISCRETIZATIONS", "AccelerationUnicycle", "acceleration_dynamics"]

ACCELERATION_DISCRETIZATIONS: tuple[str, ...] = ("euler", "rk4", "exact")
_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(16)
_GL_T = 0.5 * (_GL_NODES + 1.0)   # nodes on [0, 1]
_GL_W = 0.5 * _GL_WEIGHTS


def _check(method: str) -> None:
    if method not in ACCELERATION_DISCRETIZATIONS:
        raise ProblemError(f"discretization must be one of {ACCELERATION_DISCRETIZATIONS}, got "
                           f"{method!r}")


def _f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    out = np.empty(np.broadcast_shapes(x.shape, u.shape[:-1] + (5,)))
    out[..., 0] = x[..., 3] * np.cos(x[..., 2])
    out[..., 1] = x[..., 3] * np.sin(x[..., 2])
    out[..., 2] = x[..., 4]
    out[..., 3] = u[..., 0]
    out[..., 4] = u[..., 1]
    return out


def _f_jacobians(x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
    c, s = np.cos(x[..., 2]), np.sin(x[..., 2])
    J_x = np.zeros(shape + (5, 5))
    J_x[..., 0, 2] = -x[..., 3] * s
    J_x[..., 0, 3] = c
    J_x[..., 1, 2] = x[..., 3] * c
    J_x[..., 1, 3] = s
    J_x[..., 2, 4] = 1.0
    J_u = np.zeros(shape + (5, 2))
    J_u[..., 3, 0] = 1.0
    J_u[..., 4, 1] = 1.0
    return J_x, J_u


def _step(x: np.ndarray, u: np.ndarray, h: float, method: str, jac: bool
          ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """One step and, with ``jac``, its Jacobians ``A (..., 5, 5)``, ``B (..., 5, 2)``."""
    shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
    psi, v, w = x[..., 2], x[..., 3], x[..., 4]
    a, al = u[..., 0], u[..., 1]
    nxt = np.empty(shape + (5,))
    eye = np.broadcast_to(np.eye(5), shape + (5, 5))
    if method == "rk4":
        k1 = _f(x, u)
        k2 = _f(x + 0.5 * h * k1, u)
        k3 = _f(x + 0.5 * h * k2, u)
        k4 = _f(x + h * k3, u)
        nxt[...] = x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        if not jac:
            return nxt, None, None
        xi, D_x, D_u = x, eye.copy(), np.zeros(shape + (5, 2))
        acc_x, acc_u = np.zeros(shape + (5, 5)), np.zeros(shape + (5, 2))
        for c_i, w_i in zip((0.5, 0.5, 1.0, None), (1.0, 2.0, 2.0, 1.0), strict=True):
            k = _f(xi, u)
            J_x, J_u = _f_jacobians(xi, u)
            dk_x, dk_u = J_x @ D_x, J_x @ D_u + J_u
            acc_x, acc_u = acc_x + w_i * dk_x, acc_u + w_i * dk_u
            if c_i is not None:
                xi, D_x, D_u = x + c_i * h * k, eye + c_i * h * dk_x, c_i * h * dk_u
        return nxt, eye + (h / 6.0) * acc_x, (h / 6.0) * acc_u
    nxt[..., 2] = psi + h * w + 0.5 * h * h * al
    nxt[..., 3] = v + h * a
    nxt[..., 4] = w + h * al
    A = B = None
    if jac:
        A = eye.copy()
        B = np.zeros(shape + (5, 2))
        A[..., 2, 4] = h
        A[..., 3, 3] = 1.0
        B[..., 2, 1] = 0.5 * h * h
        B[..., 3, 0] = h
        B[..., 4, 1] = h
    if method == "euler":
        vbar = v + 0.5 * h * a
        c, s = np.cos(psi), np.sin(psi)
        nxt[..., 0] = x[..., 0] + h * vbar * c
        nxt[..., 1] = x[..., 1] + h * vbar * s
        if jac:
            A[..., 0, 2] = -h * vbar * s
            A[..., 1, 2] = h * vbar * c
            A[..., 0, 3] = h * c
            A[..., 1, 3] = h * s
            B[..., 0, 0] = 0.5 * h * h * c
            B[..., 1, 0] = 0.5 * h * h * s
        return nxt, A, B
    # exact: p+ = p + h * sum_q W_q (v + a h t_q) e^{i psi(h t_q)}
    t = h * _GL_T                                         # (16,)
    ph = psi[..., None] + w[..., None] * t + 0.5 * al[..., None] * t * t
    speed = v[..., None] + a[..., None] * t
    c, s = np.cos(ph), np.sin(ph)
    wq = h * _GL_W
    nxt[..., 0] = x[..., 0] + (wq * speed * c).sum(-1)
    nxt[..., 1] = x[..., 1] + (wq * speed * s).sum(-1)
    if jac:
        sc, ss = wq * speed * c, wq * speed * s           # d/dpsi of (cos, sin) terms
        A[..., 0, 2] = -ss.sum(-1)
        A[..., 1, 2] = sc.sum(-1)
        A[..., 0, 3] = (wq * c).sum(-1)
        A[..., 1, 3] = (wq * s).sum(-1)
        A[..., 0, 4] = -(ss * t).sum(-1)
        A[..., 1, 4] = (sc * t).sum(-1)
        B[..., 0, 0] = (wq * t * c).sum(-1)
        B[..., 1, 0] = (wq * t * s).sum(-1)
        B[..., 0, 1] = -(ss * 0.5 * t * t).sum(-1)
        B[..., 1, 1] = (sc * 0.5 * t * t).sum(-1)
    return nxt, A, B


def acceleration_dynamics(states: np.ndarray, inputs: np.ndarray, sample_time: float,
                          method: str = "euler") -> np.ndarray:
    """One step of ``states (..., 5)`` under accelerations ``(..., 2)`` (module notes); the
    bounds play no part (what a plant integrates)."""
    _check(method)
    return _step(np.asarray(states, float), np.asarray(inputs, float), float(sample_time),
                 method, False)[0]


_EULER_KERNELS = ModelKernels(linearize=acceleration_linearize, rollout=acceleration_rollout,
                              shift=acceleration_shift_iterate,
                              defect_l1=acceleration_defect_l1, clip_and_roll_out=None)


@dataclass(frozen=True, eq=False)
class AccelerationUnicycle(RobotModel):
    r"""The unicycle with velocity states and acceleration inputs (module notes).

    Parameters
    ----------
    velocity_lower, velocity_upper
        ``(2,)`` bounds of :math:`(v, \omega)`, state bounds on stages 1..N (the
        scenario's ``[bounds] v, omega``).
    acceleration_lower, acceleration_upper
        ``(2,)`` bounds of :math:`(a, \alpha)`, input bounds (the scenario's
        ``[bounds] acceleration, angular_acceleration``); each must contain 0
        (a robot must be able to hold its velocity and to brake).
    """

    velocity_lower: np.ndarray
    velocity_upper: np.ndarray
    acceleration_lower: np.ndarray
    acceleration_upper: np.ndarray

    name: ClassVar[str] = "acceleration unicycle"
    nx: ClassVar[int] = 5
    nu: ClassVar[int] = 2
    state_names: ClassVar[tuple[str, ...]] = ("x", "y", "psi", "v", "omega")
    input_names: ClassVar[tuple[str, ...]] = ("a", "alpha")
    speed_offset: ClassVar[int] = 3
    command_speed_offset: ClassVar[int] = 7 + 3   # v of stage 1
    velocity_states: ClassVar[tuple[int, ...]] = (3, 4)
    discretizations: ClassVar[tuple[str, ...]] = ACCELERATION_DISCRETIZATIONS
    # union over the discretizations (Euler leaves (0, 4), (1, 4) and B's (0, 1), (1, 1) at 0)
    a_pattern: ClassVar[tuple[np.ndarray, np.ndarray]] = (
        np.array([0, 1, 2, 3, 4, 0, 0, 0, 1, 1, 1, 2]),
        np.array([0, 1, 2, 3, 4, 2, 3, 4, 2, 3, 4, 4]))
    b_pattern: ClassVar[tuple[np.ndarray, np.ndarray]] = (
        np.array([0, 0, 1, 1, 2, 3, 4]), np.array([0, 1, 0, 1, 1, 0, 1]))
    curvature_offsets: ClassVar[tuple[int, ...]] = (2, 3, 4, 5, 6)  # psi, v, omega, a, alpha

    def __post_init__(self) -> None:
        vlo, vhi = check_box(self.velocity_lower, self.velocity_upper, 2, "velocity bounds")
        alo, ahi = check_box(self.acceleration_lower, self.acceleration_upper, 2,
                             "acceleration bounds")
        if (alo > 0.0).any() or (ahi < 0.0).any() or not np.isfinite(
                np.concatenate((alo, ahi, vlo, vhi))).all():
            raise ProblemError("acceleration bounds: expected finite bounds with lower <= 0 <= "
                               f"upper, got {alo} and {ahi}")
        for name, value in (("velocity_lower", vlo), ("velocity_upper", vhi),
                            ("acceleration_lower", alo), ("acceleration_upper", ahi),
                            ("input_lower", alo), ("input_upper", ahi),
                            ("state_lower", vlo), ("state_upper", vhi)):
            object.__setattr__(self, name, value)

    # ------------------------------------------------------------ dynamics
    def discrete_dynamics(self, states: np.ndarray, inputs: np.ndarray, sample_time: float,
                          method: str = "euler") -> np.ndarray:
        """One step of ``states (..., 5)`` under ``inputs (..., 2)`` (module notes)."""
        return acceleration_dynamics(states, inputs, sample_time, method)

    def discrete_jacobians(self, states: np.ndarray, inputs: np.ndarray, sample_time: float,
                           method: str = "euler") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r"""``(next, A, B)``. Euler: :math:`\partial p^+/\partial\psi = T_s\bar v(-\sin\psi,
        \cos\psi)`, :math:`\partial p^+/\partial v = T_s(\cos\psi, \sin\psi)`,
        :math:`\partial p^+/\partial a = \tfrac{T_s^2}{2}(\cos\psi, \sin\psi)`,
        :math:`\partial\psi^+/\partial(\omega, \alpha) = (T_s, T_s^2/2)`."""
        _check(method)
        return _step(np.asarray(states, float), np.asarray(inputs, float), float(sample_time),
                     method, True)  # type: ignore[return-value]

    def weighted_dynamics_hessian(self, states: np.ndarray, inputs: np.ndarray,
                                  weights: np.ndarray, sample_time: float,
                                  method: str = "euler") -> np.ndarray:
        r"""Hessian of :math:`\lambda^\top f_d` on :math:`(\psi, v, \omega, a, \alpha)`, by
        central differences (step 1e-6) of the analytic Jacobians, symmetrized."""
        x = np.asarray(states, float)
        u = np.asarray(inputs, float)
        lam = np.asarray(weights, float)
        shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1], lam.shape[:-1])
        H = np.zeros(shape + (5, 5))
        eps = 1e-6

        def grad(xx: np.ndarray, uu: np.ndarray) -> np.ndarray:
            _, A, B = self.discrete_jacobians(xx, uu, sample_time, method)
            return np.concatenate((np.einsum("...i,...ij->...j", lam, A[..., :, 2:]),
                                   np.einsum("...i,...ij->...j", lam, B)), axis=-1)

        for col in range(5):
            dx, du = np.zeros(5), np.zeros(2)
            if col < 3:
                dx[2 + col] = eps
            else:
                du[col - 3] = eps
            H[..., :, col] = (grad(x + dx, u + du) - grad(x - dx, u - du)) / (2.0 * eps)
        return 0.5 * (H + np.swapaxes(H, -1, -2))

    def kernels(self, method: str) -> ModelKernels | None:
        """The compiled Euler kernels of :mod:`sqpmpc.kernels.acceleration` (``None`` for rk4
        and exact: the NumPy functions run, vectorized over robots and stages)."""
        return _EULER_KERNELS if method == "euler" else None

    def rollout(self, initial: np.ndarray, inputs: np.ndarray, sample_time: float,
                method: str = "euler") -> np.ndarray:
        """States ``(m, N+1, 5)`` of ``inputs (m, N, 2)``: the Euler kernel, else step by step."""
        if method != "euler" or np.ndim(inputs) != 3:
            return super().rollout(initial, inputs, sample_time, method)
        out = np.empty((inputs.shape[0], inputs.shape[1] + 1, 5))
        acceleration_rollout(np.ascontiguousarray(initial, dtype=float),
                             np.ascontiguousarray(inputs, dtype=float), float(sample_time), out)
        return out

    # ------------------------------------------------------------ what others see
    def velocity_plan(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        r"""The mean velocities :math:`(\bar v_i, \bar\omega_i) = ((v_i + v_{i+1})/2, \dots)`:
        their paper-Euler rollout is the plan's poses under ``"euler"``."""
        return 0.5 * (states[..., :-1, 3:5] + states[..., 1:, 3:5])

    def motion_states(self, poses: np.ndarray, velocities: np.ndarray, sample_time: float
                      ) -> tuple[np.ndarray, np.ndarray]:
        r"""Poses and velocities as the states; the accelerations
        :math:`(v_{i+1} - v_i) / T_s` as the inputs."""
        v = np.asarray(velocities, dtype=float)
        return (np.concatenate((np.asarray(poses, dtype=float), v), axis=-1),
                np.diff(v, axis=-2) / float(sample_time))

    def commands(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        r"""The velocities of stage 1, :math:`(v_1, \omega_1)`, ``(m, 2)``."""
        return np.array(states[:, 1, 3:5], dtype=float)

    def measured_states(self, states: np.ndarray, last_commands: np.ndarray) -> np.ndarray:
        """``(m, 5)``: the measured velocities, else the last commands (CONTRACT 1c)."""
        if states.shape[1] == 5:
            return np.array(states, dtype=float)
        return np.concatenate((states[:, :3], last_commands), axis=1)

    def braking_inputs(self, initial: np.ndarray, horizon: int, sample_time: float
                       ) -> np.ndarray:
        r"""Every stage's acceleration toward the velocity closest to zero within the bounds,
        as hard as the bounds allow: :math:`a_i = \mathrm{clip}((\bar 0 - v_i)/T_s,
        a_{\min}, a_{\max})`; the robot stops in :math:`\lceil |v_0| / (a T_s)\rceil` samples."""
        target = np.clip(0.0, self.velocity_lower, self.velocity_upper)
        vel = np.array(initial[:, 3:5], dtype=float)
        out = np.empty((initial.shape[0], horizon, 2))
        for i in range(horizon):
            out[:, i] = np.clip((target - vel) / sample_time, self.acceleration_lower,
                                self.acceleration_upper)
            vel = vel + sample_time * out[:, i]
        return out

    def clip_first_input(self, states: np.ndarray, inputs: np.ndarray,
                         sample_time: float) -> None:
        """The first accelerations clipped to their bounds and so that the commanded
        velocities (stage 1) stay within their bounds of :meth:`velocity_bounds` (the QP's
        tolerance removed)."""
        lower, upper = self.velocity_bounds(states, 1, sample_time)
        v0 = states[:, 3:5]
        a = np.clip(inputs[:, 0], (lower[:, 0] - v0) / sample_time,
                    (upper[:, 0] - v0) / sample_time)
        np.clip(a, self.acceleration_lower, self.acceleration_upper, out=inputs[:, 0])

    def velocity_bounds(self, initial: np.ndarray, horizon: int, sample_time: float
                        ) -> tuple[np.ndarray, np.ndarray]:
        """The velocity bounds on stages 1..N, widened where a measured velocity outside them
        cannot be brought inside at once: stage ``i`` allows what braking as hard as the bounds
        allow reaches (the QP stays feasible after a push or a noisy measurement)."""
        v0 = initial[:, None, 3:5]
        steps = sample_time * np.arange(1, horizon + 1)[None, :, None]
        upper = np.maximum(self.velocity_upper, v0 + steps * self.acceleration_lower)
        lower = np.minimum(self.velocity_lower, v0 + steps * self.acceleration_upper)
        return lower, upper

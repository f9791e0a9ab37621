r"""The paper's unicycle as a :class:`~sqpmpc.models.base.RobotModel` (the first model).

States :math:`\chi = (x, y, \psi)`, inputs :math:`u = (v, \omega)`: the
velocities change at once (the paper's robot). The arithmetic is that of
:mod:`sqpmpc.models.unicycle` (NumPy) and, for the Euler step, of the compiled
kernels of :mod:`sqpmpc.kernels.ocp` (``euler_*``, ``shift_iterate``,
``clip_and_roll_out``), which are this model's kernels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from sqpmpc.kernels.ocp import (
    clip_and_roll_out,
    euler_defect_l1,
    euler_linearize,
    euler_rollout,
    shift_iterate,
)
from sqpmpc.models import unicycle
from sqpmpc.models.base import ModelKernels, RobotModel, check_box

__all__ = ["UNICYCLE_A_PATTERN", "UNICYCLE_B_PATTERN", "UnicycleModel"]

# Structural entries of A_k (rows, cols) and B_k for the unicycle under every
# discretization: x and y depend on psi, v and omega; psi on psi and omega.
UNICYCLE_A_PATTERN = (np.array([0, 1, 2, 0, 1]), np.array([0, 1, 2, 2, 2]))
UNICYCLE_B_PATTERN = (np.array([0, 0, 1, 1, 2]), np.array([0, 1, 0, 1, 1]))

_EULER_KERNELS = ModelKernels(linearize=euler_linearize, rollout=euler_rollout,
                              shift=shift_iterate, defect_l1=euler_defect_l1,
                              clip_and_roll_out=clip_and_roll_out)


@dataclass(frozen=True, eq=False)
class UnicycleModel(RobotModel):
    """The paper's unicycle (eq. 1), input bounds on :math:`(v, \\omega)`.

    Parameters
    ----------
    input_lower, input_upper
        ``(2,)`` bounds of :math:`(v, \\omega)` (the scenario's ``[bounds] v, omega``).
    """

    input_lower: np.ndarray
    input_upper: np.ndarray

    name: ClassVar[str] = "unicycle"
    nx: ClassVar[int] = 3
    nu: ClassVar[int] = 2
    state_names: ClassVar[tuple[str, ...]] = ("x", "y", "psi")
    input_names: ClassVar[tuple[str, ...]] = ("v", "omega")
    speed_offset: ClassVar[int] = 3
    command_speed_offset: ClassVar[int] = 3
    discretizations: ClassVar[tuple[str, ...]] = unicycle.DISCRETIZATIONS
    a_pattern: ClassVar[tuple[np.ndarray, np.ndarray]] = UNICYCLE_A_PATTERN
    b_pattern: ClassVar[tuple[np.ndarray, np.ndarray]] = UNICYCLE_B_PATTERN
    curvature_offsets: ClassVar[tuple[int, ...]] = (2, 3, 4)  # psi, v, omega

    def __post_init__(self) -> None:
        lo, hi = check_box(self.input_lower, self.input_upper, 2, "unicycle input bounds")
        object.__setattr__(self, "input_lower", lo)
        object.__setattr__(self, "input_upper", hi)
        object.__setattr__(self, "state_lower", np.zeros(0))
        object.__setattr__(self, "state_upper", np.zeros(0))

    def discrete_dynamics(self, states: np.ndarray, inputs: np.ndarray, sample_time: float,
                          method: str = "euler") -> np.ndarray:
        """:func:`sqpmpc.models.unicycle.discrete_dynamics`."""
        return unicycle.discrete_dynamics(states, inputs, sample_time, method)

    def discrete_jacobians(self, states: np.ndarray, inputs: np.ndarray, sample_time: float,
                           method: str = "euler") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`sqpmpc.models.unicycle.discrete_jacobians`."""
        return unicycle.discrete_jacobians(states, inputs, sample_time, method)

    def weighted_dynamics_hessian(self, states: np.ndarray, inputs: np.ndarray,
                                  weights: np.ndarray, sample_time: float,
                                  method: str = "euler") -> np.ndarray:
        """:func:`sqpmpc.models.unicycle.weighted_dynamics_hessian` on ``(psi, v, omega)``."""
        return unicycle.weighted_dynamics_hessian(states, inputs, weights, sample_time, method)

    def rollout(self, initial: np.ndarray, inputs: np.ndarray, sample_time: float,
                method: str = "euler") -> np.ndarray:
        """States ``(m, N+1, 3)``: the Euler kernel, else :func:`sqpmpc.models.unicycle.rollout`."""
        if method == "euler":
            out = np.empty((inputs.shape[0], inputs.shape[1] + 1, 3))
            euler_rollout(np.asarray(initial, float), np.ascontiguousarray(inputs, dtype=float),
                          float(sample_time), out)
            return out
        return np.swapaxes(unicycle.rollout(initial, np.swapaxes(inputs, 0, 1), sample_time,
                                            method), 0, 1)

    def kernels(self, method: str) -> ModelKernels | None:
        """The compiled Euler kernels of :mod:`sqpmpc.kernels.ocp` (``None`` for rk4/exact)."""
        return _EULER_KERNELS if method == "euler" else None

    def velocity_plan(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """The inputs themselves."""
        return inputs

    def motion_states(self, poses: np.ndarray, velocities: np.ndarray, sample_time: float
                      ) -> tuple[np.ndarray, np.ndarray]:
        """The poses, and the mean velocities of each sample as its inputs."""
        return (np.array(poses, dtype=float),
                0.5 * (velocities[..., :-1, :] + velocities[..., 1:, :]))

    def commands(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """The first inputs ``(m, 2)`` (a copy)."""
        return inputs[:, 0].copy()

    def measured_states(self, states: np.ndarray, last_commands: np.ndarray) -> np.ndarray:
        """The poses (measured velocities are not states of this model)."""
        return states[:, :3]

    def braking_inputs(self, initial: np.ndarray, horizon: int, sample_time: float
                       ) -> np.ndarray:
        """The input closest to zero within the bounds on every stage (the robot stops at once)."""
        return np.broadcast_to(np.clip(0.0, self.input_lower, self.input_upper),
                               (initial.shape[0], horizon, 2)).copy()

r"""The robot-model seam: what the OCP, the QP layout, the kernels and the rows need of a robot.

A :class:`RobotModel` is a frozen, validated description of one kind of robot:

- its dimensions and names: ``nx`` states, ``nu`` inputs;
- which entries are what: the position is always the first two states
  ``(x, y)`` (the collision and obstacle rows, the references and the cost
  read them there), the heading is :attr:`RobotModel.heading`, the forward
  speed is at :attr:`RobotModel.speed_offset` of a stage block
  ``(chi_i, u_i)``; :attr:`RobotModel.velocity_states` are the states that
  are velocities (empty for the paper's unicycle, whose velocities are inputs);
- the discrete dynamics :math:`\chi^+ = f_d(\chi, u)` under each
  discretization it supports (:attr:`RobotModel.discretizations`), their
  Jacobians and the weighted Hessian of :math:`\lambda^\top f_d` on the
  variables that enter nonlinearly (:attr:`RobotModel.curvature_offsets`);
- the structural non-zeros of the Jacobians (:attr:`RobotModel.a_pattern`,
  :attr:`RobotModel.b_pattern`), from which the QP layout fixes its sparsity once;
- the bounds: box bounds of the inputs and of the states (``±inf`` where a
  state is free), and the footprint: a disc of the robot's diameter;
- optional compiled kernels for its hot path (:attr:`RobotModel.kernels`);
  without them the OCP uses the vectorized NumPy functions;
- how a plan maps to what the rest of the project exchanges: poses
  ``(x, y, psi)`` and the paper unicycle's velocity inputs ``(v, omega)``
  (:meth:`RobotModel.poses`, :meth:`RobotModel.velocity_plan`,
  :meth:`RobotModel.commands`), so plans, recordings and the wire schema stay
  those of the paper's unicycle whatever the model.

The paper's unicycle is :class:`sqpmpc.models.unicycle.UnicycleModel`; the
unicycle with velocity states and acceleration inputs is
:class:`sqpmpc.models.acceleration.AccelerationUnicycle`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.kernels.ocp import headings_jump

__all__ = ["ModelKernels", "RobotModel", "check_box", "continuous_headings"]


@dataclass(frozen=True)
class ModelKernels:
    """The compiled hot path of a model under one discretization (numba functions).

    Attributes
    ----------
    linearize
        ``(z, m, N, block, h, dyn_A, dyn_B, dyn_lower, dyn_upper)``: the
        dynamics rows of the iterate ``z`` into the QP's value views.
    rollout
        ``(initial (m, nx), inputs (m, N, nu), h, out (m, N+1, nx))``.
    shift
        ``(z, y, z_order, y_order, m, N, block, h, z_out, y_out)``: the iterate
        shifted by one stage, the last state stepped under the held last input.
    defect_l1
        ``(z, initial (m, nx), m, N, block, h) -> float``: L1 norm of the
        dynamics and initial-state defects.
    clip_and_roll_out
        ``(initial, inputs, lower, upper, h, out) -> bool``: the first input
        clipped to its bounds in place, then rolled out (``False``: not finite);
        ``None``: :meth:`RobotModel.clip_first_input` and the rollout run instead.
    """

    linearize: object
    rollout: object
    shift: object
    defect_l1: object
    clip_and_roll_out: object | None


def check_box(lower: object, upper: object, size: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Validated ``(size,)`` lower/upper arrays (no NaN, lower <= upper); ``what`` names them."""
    lo = np.asarray(lower, dtype=float)
    hi = np.asarray(upper, dtype=float)
    if lo.shape != (size,) or hi.shape != (size,):
        raise ProblemError(f"{what}: expected lower and upper of shape ({size},), got "
                           f"{lo.shape} and {hi.shape}")
    if np.isnan(lo).any() or np.isnan(hi).any() or (lo > hi).any():
        raise ProblemError(f"{what}: expected lower <= upper without NaN, got {lo} and {hi}")
    lo.setflags(write=False)
    hi.setflags(write=False)
    return lo, hi


class RobotModel(ABC):
    """A robot model (see the module notes). Subclasses are frozen dataclasses.

    Class attributes every model sets: :attr:`name`, :attr:`nx`, :attr:`nu`,
    :attr:`state_names`, :attr:`input_names`, :attr:`heading`,
    :attr:`speed_offset`, :attr:`velocity_states`, :attr:`discretizations`,
    :attr:`a_pattern`, :attr:`b_pattern`, :attr:`curvature_offsets`.
    """

    name: ClassVar[str]
    nx: ClassVar[int]
    nu: ClassVar[int]
    state_names: ClassVar[tuple[str, ...]]
    input_names: ClassVar[tuple[str, ...]]
    #: the footprint: a disc of each robot's diameter (the scenario's ``robots[].diameter``);
    #: two robots keep ``(d_a + d_b) / 2`` between their positions, a robot and an obstacle
    #: ``(d + d_o) / 2``
    footprint: ClassVar[str] = "disc"
    #: index of the heading psi in the state (the position is always states 0, 1)
    heading: ClassVar[int] = 2
    #: offset of the forward speed in a stage block ``(chi_i, u_i)`` (states first)
    speed_offset: ClassVar[int]
    #: offset in a robot's QP block of the speed commanded at a sample (the unicycle's
    #: first input; a velocity model's speed of stage 1)
    command_speed_offset: ClassVar[int]
    #: states that are velocities (bounded on stages 1..N by the state bounds)
    velocity_states: ClassVar[tuple[int, ...]] = ()
    discretizations: ClassVar[tuple[str, ...]]
    #: structural non-zeros ``(rows, cols)`` of A = df/dchi and B = df/du (all discretizations)
    a_pattern: ClassVar[tuple[np.ndarray, np.ndarray]]
    b_pattern: ClassVar[tuple[np.ndarray, np.ndarray]]
    #: stage-block offsets of the variables entering the dynamics nonlinearly (Hessian block)
    curvature_offsets: ClassVar[tuple[int, ...]]

    #: instance fields of every model: the box bounds ``(nu,)`` of the inputs and
    #: ``(len(velocity_states),)`` of the velocity states (read-only arrays)
    input_lower: np.ndarray
    input_upper: np.ndarray
    state_lower: np.ndarray
    state_upper: np.ndarray

    def check_discretization(self, method: str) -> None:
        """Refuse a discretization the model does not have (one :class:`ProblemError`)."""
        if method not in self.discretizations:
            raise ProblemError(f"discretization: the {self.name} model supports "
                               f"{', '.join(map(repr, self.discretizations))}, got {method!r}")

    # ------------------------------------------------------------ dynamics
    @abstractmethod
    def discrete_dynamics(self, states: np.ndarray, inputs: np.ndarray, sample_time: float,
                          method: str = "euler") -> np.ndarray:
        """Next states ``(..., nx)`` of ``states (..., nx)`` under ``inputs (..., nu)``."""

    @abstractmethod
    def discrete_jacobians(self, states: np.ndarray, inputs: np.ndarray, sample_time: float,
                           method: str = "euler") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(next (..., nx), A (..., nx, nx), B (..., nx, nu))``."""

    @abstractmethod
    def weighted_dynamics_hessian(self, states: np.ndarray, inputs: np.ndarray,
                                  weights: np.ndarray, sample_time: float,
                                  method: str = "euler") -> np.ndarray:
        r"""Hessian of :math:`\lambda^\top f_d` on the :attr:`curvature_offsets` variables,
        ``(..., c, c)``."""

    def rollout(self, initial: np.ndarray, inputs: np.ndarray, sample_time: float,
                method: str = "euler") -> np.ndarray:
        """States ``(m, N+1, nx)`` of ``inputs (m, N, nu)`` from ``initial (m, nx)``."""
        x = np.asarray(initial, dtype=float)
        inputs = np.asarray(inputs, dtype=float)
        out = np.empty(inputs.shape[:-2] + (inputs.shape[-2] + 1, self.nx))
        out[..., 0, :] = x
        for i in range(inputs.shape[-2]):
            out[..., i + 1, :] = self.discrete_dynamics(out[..., i, :], inputs[..., i, :],
                                                        sample_time, method)
        return out

    def kernels(self, method: str) -> ModelKernels | None:
        """Compiled kernels for ``method``, or ``None`` (the NumPy path)."""
        return None

    # ------------------------------------------------------------ what others see
    def poses(self, states: np.ndarray) -> np.ndarray:
        """Poses ``(..., 3)`` ``(x, y, psi)`` of states ``(..., nx)`` (a copy)."""
        return np.array(states[..., :3], dtype=float)

    @abstractmethod
    def velocity_plan(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """The paper unicycle's inputs ``(..., N, 2)`` whose Euler rollout gives the plan's poses
        (what the neighbours receive)."""

    @abstractmethod
    def motion_states(self, poses: np.ndarray, velocities: np.ndarray, sample_time: float
                      ) -> tuple[np.ndarray, np.ndarray]:
        """The model's states ``(..., N+1, nx)`` and inputs ``(..., N, nu)`` of a motion given by
        its poses ``(..., N+1, 3)`` and velocities ``(v, omega)`` ``(..., N+1, 2)`` at the stages
        (the references of a tracked motion: :mod:`sqpmpc.coordination.motion`)."""

    @abstractmethod
    def commands(self, states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """The velocity commands ``(m, 2)`` ``(v, omega)`` sent to the robots for a plan
        ``states (m, N+1, nx)``, ``inputs (m, N, nu)``."""

    @abstractmethod
    def measured_states(self, states: np.ndarray, last_commands: np.ndarray) -> np.ndarray:
        """Model states ``(m, nx)`` from measurements ``(m, 3)`` poses or ``(m, 5)`` poses and
        measured ``(v, omega)``; ``last_commands (m, 2)`` stand in for missing velocities."""

    @abstractmethod
    def braking_inputs(self, initial: np.ndarray, horizon: int, sample_time: float
                       ) -> np.ndarray:
        """Inputs ``(m, N, nu)`` that stop the robots from ``initial (m, nx)`` as fast as the
        bounds allow and then hold them."""

    def velocity_bounds(self, initial: np.ndarray, horizon: int, sample_time: float
                        ) -> tuple[np.ndarray, np.ndarray]:
        """Bounds ``(m, N, nv)`` of the velocity states on stages 1..N from ``initial (m, nx)``
        (models with velocity states override it)."""
        shape = (initial.shape[0], horizon, 0)
        return np.zeros(shape), np.zeros(shape)

    def clip_first_input(self, states: np.ndarray, inputs: np.ndarray,
                         sample_time: float) -> None:
        """Clip the first inputs ``inputs[:, 0]`` of a plan from ``states (m, nx)`` to what
        the bounds allow (in place)."""
        np.clip(inputs[:, 0], self.input_lower, self.input_upper, out=inputs[:, 0])


def continuous_headings(headings: np.ndarray, last: np.ndarray | None) -> np.ndarray:
    r"""Measured ``headings (m,)`` on the branch of the ``last`` sample's (``None``: as is).

    A robot's odometry reports its yaw wrapped (to :math:`(-\pi, \pi]`, MuJoCo's and
    ROS's convention) while plans and warm starts are continuous in it: a robot driving
    along :math:`\pm\pi` would be asked to turn a full circle. A heading more than
    :math:`\pi` from the last one is moved by whole turns to within :math:`\pi` of it (no
    robot turns half a circle in a sample); the others are returned unchanged, bit for bit.
    """
    psi = np.array(headings, dtype=float)
    if last is not None and headings_jump(psi, np.asarray(last, dtype=float)):
        jump = np.abs(psi - last) > np.pi
        psi[jump] = last[jump] + (np.remainder(psi[jump] - last[jump] + np.pi,
                                               2.0 * np.pi) - np.pi)
    return psi

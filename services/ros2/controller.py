"""The controller of a ROS 2 robot: the decentralized one, its first-input check the robot's.

In lockstep the decentralized controller verifies the first input of each
plan itself and, when it fails, falls back to the shifted previous plan or
brakes; the liveness rules (:mod:`sqpmpc.rules.liveness`: ``detour``,
``stall-repair``, ...) then see the input the robot really applied, and the
next sample starts from the plan it really follows. A ROS 2 robot has no
common clock: its check is :meth:`services.ros2.neighbours.Neighbours.path_is_safe`
(every neighbour's exact arcs, or the disc it may reach, along the exact arc of
the whole sample). :class:`Ros2Controller` makes that check part of the
controller's own (:meth:`Ros2Controller.first_input_safe`), so the same
fallbacks and the same rules run as in lockstep: a robot held by a neighbour
counts as standing still for ``detour`` (it would not otherwise: the controller
would take the refused input as applied), and a refused input may still give
way to the shifted plan of the previous sample when that one passes the check.
"""

from __future__ import annotations

import logging

import numpy as np

from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.problem.scenario import Scenario

from .neighbours import Neighbours

__all__ = ["Ros2Controller"]


class _NoPaperWarning(logging.Filter):
    """The controller's warning about its obstacle mode, which alone has no guarantee: here
    :meth:`services.ros2.neighbours.Neighbours.path_is_safe` verifies every input."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "decentralized mode 'paper'" not in record.getMessage()


class Ros2Controller(DecentralizedController):
    """:class:`~sqpmpc.control.decentralized.DecentralizedController` (every neighbour a
    moving obstacle) whose first-input check also asks :attr:`neighbours`.

    Parameters
    ----------
    scenario, robot_id, settings
        As the decentralized controller's.

    Attributes
    ----------
    neighbours
        What the robot knows of its neighbours; set before the first :meth:`step`.
    check_time
        Wall time (Unix s) at which the sample's input is applied; set before each
        :meth:`step`.
    """

    def __init__(self, scenario: Scenario, robot_id: int, settings: SolverSettings) -> None:
        # every neighbour is a moving obstacle (its committed arcs); the robot's own check
        # (Neighbours.path_is_safe, in first_input_safe) is what keeps the distance
        logging.getLogger(DecentralizedController.__module__).addFilter(_NoPaperWarning())
        super().__init__(scenario, robot_id, settings, "paper")
        self.neighbours: Neighbours | None = None
        self.check_time = 0.0

    def command_of(self, next_states: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        """The velocity command ``(v, omega)`` of a first input: the input itself, or, for a
        model with velocity states (acceleration limits), the velocities of stage 1."""
        velocities = list(self.model.velocity_states)
        if velocities:
            return np.asarray(next_states[0, velocities], dtype=float)
        return np.asarray(inputs[0], dtype=float)

    def first_input_safe(self, states: np.ndarray, next_states: np.ndarray,
                         inputs: np.ndarray) -> bool:
        """The decentralized controller's check, then the robot's: the command on its exact
        arc from :attr:`check_time` for one sample keeps every neighbour's distance
        (:meth:`services.ros2.neighbours.Neighbours.path_is_safe`)."""
        if not super().first_input_safe(states, next_states, inputs):
            return False
        if self.neighbours is None:
            return True
        return self.neighbours.path_is_safe(np.asarray(states[0, :3], dtype=float),
                                            self.command_of(next_states, inputs),
                                            self.check_time)

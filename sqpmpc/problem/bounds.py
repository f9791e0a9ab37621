"""The scenario's ``[bounds]``: velocities, positions and the robots' dynamic limits.

With ``acceleration`` and ``angular_acceleration`` (CONTRACT 1c) the robots are the
unicycle with velocity states and acceleration inputs
(:class:`~sqpmpc.models.acceleration.AccelerationUnicycle`), else the paper's
(:class:`~sqpmpc.models.paper.UnicycleModel`); :meth:`Bounds.robot_model` says which.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from sqpmpc.models.acceleration import AccelerationUnicycle
from sqpmpc.models.base import RobotModel
from sqpmpc.models.paper import UnicycleModel
from sqpmpc.problem.references import _FieldError, _real_vector

__all__ = ["Bounds"]

_PAIR = "an array of 2 finite numbers [lower, upper] with lower <= upper"


def _pair(value: Any, key: str, unit: str) -> tuple[float, float]:
    lower, upper = _real_vector(value, 2, key, f"{_PAIR} ({unit})")
    if lower > upper:
        raise _FieldError(key, f"expected lower <= upper, found lower {lower!r} above upper "
                          f"{upper!r}")
    return lower, upper


@dataclass(frozen=True)
class Bounds:
    """Inclusive box bounds on velocities, (optionally) positions and accelerations.

    Parameters
    ----------
    v, omega
        ``(lower, upper)`` of the speed (m/s) and turn rate (rad/s).
    x, y
        Optional ``(lower, upper)`` of the position coordinates, m; ``None``
        means unbounded.
    acceleration, angular_acceleration
        Optional ``(lower, upper)`` of how fast the robot can change ``v``
        (m/s^2) and ``omega`` (rad/s^2), CONTRACT 1c; both or neither, each
        with ``lower <= 0 <= upper`` and ``lower < upper``. With them the robots are
        the unicycle with velocity states and acceleration inputs
        (:class:`~sqpmpc.models.acceleration.AccelerationUnicycle`); without them
        the paper's, whose velocities change at once.
    """

    v: tuple[float, float]
    omega: tuple[float, float]
    x: tuple[float, float] | None = None
    y: tuple[float, float] | None = None
    acceleration: tuple[float, float] | None = None
    angular_acceleration: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "v", _pair(self.v, "v", "m/s"))
        object.__setattr__(self, "omega", _pair(self.omega, "omega", "rad/s"))
        for name in ("x", "y"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _pair(value, name, "m"))
        limits = {"acceleration": "m/s^2", "angular_acceleration": "rad/s^2"}
        given = [name for name in limits if getattr(self, name) is not None]
        if len(given) == 1:
            other = next(name for name in limits if name not in given)
            raise _FieldError(other, f"expected {other} with {given[0]} (a robot's dynamic "
                              "limits are declared together), found none")
        for name in given:
            lo, hi = _pair(getattr(self, name), name, limits[name])
            if not lo <= 0.0 <= hi or lo == hi:
                raise _FieldError(name, f"expected lower <= 0 <= upper with lower < upper (a "
                                  f"robot must be able to speed up and to brake), found "
                                  f"[{lo!r}, {hi!r}]")
            object.__setattr__(self, name, (lo, hi))

    @property
    def dynamic_limits(self) -> bool:
        """Whether acceleration bounds are declared (the velocities are then states)."""
        return self.acceleration is not None

    def acceleration_lower(self) -> np.ndarray:
        """Lower bounds of ``(a, alpha)``, shape ``(2,)`` (only with :attr:`dynamic_limits`)."""
        return np.array([self.acceleration[0], self.angular_acceleration[0]])

    def acceleration_upper(self) -> np.ndarray:
        """Upper bounds of ``(a, alpha)``, shape ``(2,)`` (only with :attr:`dynamic_limits`)."""
        return np.array([self.acceleration[1], self.angular_acceleration[1]])

    def robot_model(self) -> RobotModel:
        """The robots' model: the paper's unicycle, or with :attr:`dynamic_limits` the
        unicycle with velocity states and acceleration inputs."""
        if not self.dynamic_limits:
            return UnicycleModel(self.input_lower(), self.input_upper())
        return AccelerationUnicycle(self.input_lower(), self.input_upper(),
                                    self.acceleration_lower(), self.acceleration_upper())

    def input_lower(self) -> np.ndarray:
        """:math:`u_{\\min} = (v_{\\min}, \\omega_{\\min})`, shape ``(2,)``."""
        return np.array([self.v[0], self.omega[0]])

    def input_upper(self) -> np.ndarray:
        """:math:`u_{\\max} = (v_{\\max}, \\omega_{\\max})`, shape ``(2,)``."""
        return np.array([self.v[1], self.omega[1]])

    def position_lower(self) -> np.ndarray:
        """Lower position bound ``(x, y)``, ``-inf`` where absent, shape ``(2,)``."""
        return np.array([b[0] if b is not None else -np.inf for b in (self.x, self.y)])

    def position_upper(self) -> np.ndarray:
        """Upper position bound ``(x, y)``, ``+inf`` where absent, shape ``(2,)``."""
        return np.array([b[1] if b is not None else np.inf for b in (self.x, self.y)])

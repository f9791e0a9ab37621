"""A ROS 2 robot's command stream: cmd_vel held steady between samples.

A base's velocity controller stops the robot when no command came for its
timeout (``cmd_vel_timeout`` of ROS 2 Jazzy's diff_drive_controller: 0.5 s by
default), which is exactly one sample at ``Ts`` = 0.5 s: a command sent once
per sample times out whenever it is a little late. :class:`CommandStream`
publishes each command at once and then again every ``period`` until the next
one, so the base always has a fresh command in force: the sample's input, or
zero when the controller stopped the robot (stale odometry, lost plan
exchange, shutdown). It also keeps the commands given (not the repeats) for
the robot's own state (:func:`services.ros2.timing.own_motion`).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable

from . import msgs
from .graph import Ros2Publisher

__all__ = ["CommandStream"]

KEPT_COMMANDS = 16
"""Commands kept at least (older ones than the newest odometry are dropped beyond)."""


class CommandStream:
    """cmd_vel of one robot.

    Parameters
    ----------
    publisher
        The ``cmd_vel`` publisher (:meth:`services.ros2.graph.Ros2Node.publisher`).
    stamped
        ``TwistStamped`` (with ``frame()`` as its frame id) instead of ``Twist``.
    period
        Seconds between two publications of the command in force (``None``: only when
        a command is given).
    frame
        The frame id of a ``TwistStamped`` (the odometry's child frame).

    Attributes
    ----------
    lock
        Held while a command is given (the sample loop, the stop timer, the watchdog).
    sent
        ``(time, v, omega)`` of the commands given (time order).
    republished, zero_commands
        Repeats published; zero commands given.
    """

    def __init__(self, publisher: Ros2Publisher, stamped: bool, period: float | None,
                 frame: Callable[[], str]) -> None:
        self.publisher, self.stamped, self.period, self.frame = publisher, stamped, period, frame
        self.lock = threading.RLock()
        self.sent: list[tuple[float, float, float]] = []
        self.held = (0.0, 0.0)
        self.held_at = -math.inf
        self.done = False
        self.republished = self.zero_commands = 0

    def _publish(self, v: float, omega: float, at: float) -> None:
        twist = msgs.Twist(msgs.Vector3(float(v)), msgs.Vector3(0.0, 0.0, float(omega)))
        if self.stamped:
            self.publisher.publish(msgs.TwistStamped(
                msgs.Header(msgs.Time.from_seconds(at), self.frame()), twist))
        else:
            self.publisher.publish(twist)
        self.held_at = at

    def command(self, v: float, omega: float, at: float, since: float) -> None:
        """Publish ``(v, omega)`` now and hold it (republished until the next command).

        Parameters
        ----------
        v, omega
            Linear (m/s) and angular (rad/s) velocity.
        at
            Wall time of the command (Unix s; a ``TwistStamped``'s stamp).
        since
            The newest odometry's time: the commands before it are dropped, all but the
            last :data:`KEPT_COMMANDS`.
        """
        with self.lock:
            self._publish(v, omega, at)
            self.held = (float(v), float(omega))
            self.sent.append((at, float(v), float(omega)))
            if len(self.sent) > KEPT_COMMANDS and self.sent[0][0] < since:
                self.sent = [c for c in self.sent if c[0] >= since] or self.sent[-1:]
            if v == 0.0 and omega == 0.0:
                self.zero_commands += 1

    def republish(self, now: float) -> bool:
        """Publish the command in force again if it was last published ``period`` ago.

        Parameters
        ----------
        now
            Wall time, Unix s.

        Returns
        -------
        bool
            Whether it was published (never without a period nor after :meth:`finish`).
        """
        if self.period is None:
            return False
        with self.lock:
            if self.done or now - self.held_at < self.period:
                return False
            self._publish(*self.held, now)
            self.republished += 1
            return True

    def finish(self, at: float) -> None:
        """Publish zero, and no repeat after it (the controller ends).

        Parameters
        ----------
        at
            Wall time, Unix s.
        """
        with self.lock:
            self.done = True
            self.command(0.0, 0.0, at, -math.inf)

"""Acceleration limits (CONTRACT 1c) in the ROS 2 mode: the simulated robots ramp their
velocities within the limits, the controller's own state carries the measured velocities."""

from __future__ import annotations

import numpy as np
import pytest

from services.ros2.check import poses_at
from services.ros2.simfleet import SimRobot
from services.ros2.timing import arc, own_motion, ramp

LIMITS = (np.array([-0.5, -1.0]), np.array([0.5, 1.0]))
TS = 0.2
TICK = 0.005


def _run(robot: SimRobot, commands: list[tuple[float, float, float]], times: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray]:
    """States and velocities at ``times``, the ``(t, v, omega)`` commands given in time
    order in between (as a live robot sees them)."""
    states, vel, todo = [], [], sorted(commands)
    for t in times:
        while todo and todo[0][0] <= t:
            robot.command(todo[0][1], todo[0][2], todo[0][0])
            todo.pop(0)
        s, v = robot.at(t)
        states.append(s)
        vel.append(v)
    return np.array(states), np.array(vel)


def test_simulated_robot_ramps_within_the_limits_and_reaches_the_command():
    start = 1000.0
    commands = [(start + 0.0012, 0.6, 0.0),  # 1.2 s at the limit of 0.5 m/s^2
                (start + 1.5, 0.6, -0.05),  # a small turn: reached within one sample
                (start + 2.0, 0.0, 0.0)]
    robot = SimRobot(1, 0.3, np.array([0.0, 0.0, 0.0]), start, LIMITS, TS, TICK)
    times = start + np.arange(0.0, 4.0, 0.001)
    states, vel = _run(robot, commands, times)
    assert vel[0].tolist() == [0.0, 0.0]
    steps = np.abs(np.diff(vel, axis=0))
    assert (steps <= LIMITS[1] * TICK + 1e-12).all()  # never faster than the limits
    assert vel[np.searchsorted(times, start + 1.3), 0] == pytest.approx(0.6)
    assert vel[np.searchsorted(times, start + 1.2), 0] < 0.6  # not before its limit allows
    assert vel[np.searchsorted(times, start + 1.5 + TS + TICK), 1] == pytest.approx(-0.05)
    assert vel[-1].tolist() == [0.0, 0.0]  # stopped (0.6 m/s at 0.5 m/s^2: 1.2 s)
    # the log is the motion: poses from the segments equal the robot's own
    assert np.allclose(poses_at(np.asarray(robot.segments), times), states, atol=1e-9)


def test_without_limits_the_command_holds_at_once():
    robot = SimRobot(2, 0.3, np.array([1.0, 2.0, 0.5]), 10.0)
    robot.command(0.4, 0.2, 10.5)
    state, vel = robot.at(11.5)
    assert vel == (0.4, 0.2)
    assert np.allclose(state, arc(np.array([1.0, 2.0, 0.5]), 0.4, 0.2, 1.0))


def test_ramp_is_linear_until_the_target_and_its_mean_is_exact():
    end, mean = ramp(np.array([0.0, 0.0]), np.array([0.05, -2.0]), 0.2, TS, LIMITS)
    assert end.tolist() == pytest.approx([0.05, -0.2])  # v reached, omega at its limit
    # v reaches 0.05 after 0.2 s (rate 0.25): mean 0.025; omega at -1 rad/s^2: mean -0.1
    assert mean.tolist() == pytest.approx([0.025, -0.1])


def test_own_motion_carries_the_measured_velocities_and_the_commands_sent():
    pose = np.array([0.0, 0.0, 0.0])
    odom = (100.0, pose, 0.3, 0.0)
    # no limits: measured velocities until the command, then the command at once
    p, v = own_motion(odom, [(100.05, 0.5, 0.1)], 100.15, TS)
    assert v.tolist() == [0.5, 0.1]
    assert np.allclose(p, arc(arc(pose, 0.3, 0.0, 0.05), 0.5, 0.1, 0.1))
    # limits: the velocity ramps toward the command as the simulated robot does
    robot = SimRobot(1, 0.3, pose, 99.0, LIMITS, TS, TICK)
    sent = [(99.0, 0.3, 0.0), (100.05, 0.5, 0.4)]
    robot.command(0.3, 0.0, 99.0)
    state, measured = robot.at(100.0)
    odom = (100.0, state, *measured)
    times = np.array([100.1, 100.2, 100.3, 100.6])
    states, vel = _run(robot, sent[1:], times)
    for t, true_state, true_vel in zip(times, states, vel, strict=True):
        p, v = own_motion(odom, sent, t, TS, LIMITS)
        assert np.allclose(v, true_vel, atol=LIMITS[1].max() * TICK + 1e-9)
        assert np.allclose(p, true_state, atol=1e-3)
    assert v.tolist() == pytest.approx([0.5, 0.4])

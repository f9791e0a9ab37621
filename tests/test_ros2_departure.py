"""A ROS 2 robot's controller leaves for good: the others plan around it (issue 35).

Real processes on loopback, as in ``tests/test_ros2_fleet.py``: the simulated ROS 2
robots (:mod:`services.ros2.simfleet`), two Zenoh routers and one ``sqpmpc robot --ros2``
per robot. The scenario declares a 0.9 m grid, so the ``coordination`` rule alone is on;
robot 3 waits at its start vertex for robot 1 to cross its way down, and robot 2 waits
for robot 3 to leave the vertex on its own way down. Robot 3's controller is killed
(``kill -9``) while it waits: each other controller, after ``--rejoin-timeout`` s without
its liveliness token, tells its controller robot 3 left for good and re-plans (robot 2
around it). Invariants only: each other controller counts one departure, no collision of
the true poses, robots 1 and 2 arrive.
"""

from __future__ import annotations

import json
import logging
import os
import signal
import time
from types import SimpleNamespace

import pytest

from services.ros2.check import check_fleet
from services.ros2.options import add_ros2_arguments
from services.ros2.record import counts_in_log
from services.testing import free_ports, start_service, stop_processes
from sqpmpc.cli.options import Parser
from sqpmpc.problem.scenario_file import load_scenario
from tests import HANG

SCENARIO = """
name = "ros2-departure"
t_end = 20.0
sample_time = 0.5
horizon = 8

[weights]
Q = [1.0, 1.0]
R = [0.5, 0.5]

[bounds]
v = [-0.6, 0.6]
omega = [-0.7853981633974483, 0.7853981633974483]
x = [-0.45, 3.15]
y = [-1.35, 2.25]

[roadmap]
cell = 0.9
origin = [0.0, 0.0]

[[robots]]
id = 1
initial_state = [0.0, 0.0, 0.0]
diameter = 0.3
reference = { type = "point", position = [2.7, 0.0] }

[[robots]]
id = 2
initial_state = [1.8, 1.8, -1.5707963267948966]
diameter = 0.3
reference = { type = "point", position = [1.8, 0.0] }

[[robots]]
id = 3
initial_state = [1.8, 0.9, -1.5707963267948966]
diameter = 0.3
reference = { type = "point", position = [1.8, -0.9] }
"""
KILL_AT = 1.5  # s after the epoch: robot 3 still waits for robot 1 (it crosses at ~3 s)
REJOIN = 2.0  # --rejoin-timeout of every controller, s (the controllers end within it)


def test_a_ros2_controller_gone_for_good_is_planned_around(tmp_path):
    pytest.importorskip("zenoh_ros2_sdk")  # the simulated robots
    scenario_file = tmp_path / "departure.toml"
    scenario_file.write_text(SCENARIO)
    scenario = load_scenario(str(scenario_file))
    assert scenario.roadmap is not None  # coordination alone, by default
    ros_port, sq_port = free_ports(2)
    ros_ep, sq_ep = f"tcp/127.0.0.1:{ros_port}", f"tcp/127.0.0.1:{sq_port}"
    epoch_file = tmp_path / "epoch"
    logs = tmp_path / "logs"
    procs = [start_service("router", ["--listen", ros_ep], logs, "ros2-router"),
             start_service("router", ["--listen", sq_ep], logs, "router")]
    sim = start_service("ros2.simfleet", [
        "--scenario", str(scenario_file), "--router", f"127.0.0.1:{ros_port}",
        "--out", str(tmp_path), "--epoch-file", str(epoch_file)], logs, "simfleet")
    procs.append(sim)
    robots = {i: start_service("robot", [
        "--id", str(i), "--scenario", str(scenario_file), "--ros2", "--ros2-connect", ros_ep,
        "--zenoh-mode", "client", "--connect", sq_ep, "--run", "ros2departure",
        "--epoch-file", str(epoch_file), "--rejoin-timeout", repr(REJOIN), "--insecure"],
        logs, f"robot-{i}") for i in (1, 2, 3)}
    procs += robots.values()
    try:
        # every controller up (its odometry wait logged) before the clock starts
        deadline = time.monotonic() + HANG
        while not all("waiting for odometry" in r.output() for r in robots.values()):
            assert time.monotonic() < deadline, [r.output()[-500:] for r in robots.values()]
            assert all(r.proc.poll() is None for r in robots.values()), \
                [r.output()[-2000:] for r in robots.values()]
            time.sleep(0.1)
        epoch = time.time() + 2.0
        epoch_file.write_text(repr(epoch))
        while time.time() < epoch + KILL_AT:
            time.sleep(0.02)
        os.kill(robots[3].proc.pid, signal.SIGKILL)  # for good: never started again
        robots[3].proc.wait(HANG)
        for i in (1, 2):
            assert robots[i].wait(HANG) == 0, robots[i].output()[-3000:]
    finally:
        if sim.proc.poll() is None:
            sim.proc.send_signal(signal.SIGINT)
            sim.wait(HANG)
        stop_processes(procs)
    for i in (1, 2):
        text = robots[i].output()
        counts = counts_in_log(text)
        assert counts["coordination_departures"] == 1, text[-3000:]
        assert text.count("robot 3's controller has been gone") == 1, text[-3000:]
    data = json.loads((tmp_path / "poses.json").read_text())
    result = check_fleet(data, scenario, tolerance=0.05)
    assert result.collisions == 0 and result.certified_clearance > 0.0
    assert result.final_errors["1"] <= 0.05 and result.final_errors["2"] <= 0.05, \
        result.final_errors


def _parse(*argv: str):
    parser = Parser(prog="sqpmpc robot")
    add_ros2_arguments(parser)
    return parser.parse_args(list(argv))


def test_rejoin_timeout_option_defaults_to_the_plants_and_refuses_non_positive(capsys):
    from services.plant import REJOIN_TIMEOUT, build_parser

    assert _parse().rejoin_timeout == REJOIN_TIMEOUT
    assert build_parser().parse_args(["--scenario", "x"]).rejoin_timeout == REJOIN_TIMEOUT
    assert _parse("--rejoin-timeout", "0.5").rejoin_timeout == 0.5
    for bad in ("0", "-1", "nan", "inf", "soon"):
        with pytest.raises(SystemExit) as exc:
            _parse("--rejoin-timeout", bad)
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert f"--rejoin-timeout: expected a number > 0, got {bad}" in err, err
        assert err.count("error:") == 1


def test_a_neighbour_gone_for_the_rejoin_timeout_is_told_departed_and_back_again(caplog):
    from services.ros2.robot import Ros2Robot

    told: list[list[int]] = []
    left: list[int] = []
    robot = SimpleNamespace(
        name="robot/1", robot_id=1, ids=[1, 2, 3, 4], rejoin_timeout=5.0,
        departed=frozenset(), gone_since={},
        controller=SimpleNamespace(update_departed=lambda ids: told.append(list(ids))),
        neighbours=SimpleNamespace(left=lambda rid, now: left.append(rid)))
    for name in ("central", "robot/x", "robot/1", "robot/9", "plant"):  # not a neighbour
        Ros2Robot.on_liveliness(robot, name, False)
    assert robot.gone_since == {} and left == []
    Ros2Robot.on_liveliness(robot, "robot/3", False)
    Ros2Robot.on_liveliness(robot, "robot/4", False)
    assert left == [3, 4]
    gone = robot.gone_since[3]
    robot.gone_since[4] = gone + 2.0
    with caplog.at_level(logging.INFO, logger="services.ros2.robot"):
        Ros2Robot.update_departed(robot, gone + 4.9)  # not yet
        Ros2Robot.update_departed(robot, gone + 5.0)
        Ros2Robot.update_departed(robot, gone + 6.0)  # unchanged: not told again
        Ros2Robot.update_departed(robot, gone + 7.0)
        Ros2Robot.on_liveliness(robot, "robot/3", True)  # back: taking part again
        Ros2Robot.update_departed(robot, gone + 8.0)
    assert told == [[3], [3, 4], [4]]
    assert robot.departed == frozenset({4})
    messages = [r.getMessage() for r in caplog.records]
    assert sum("robot 3's controller has been gone for 5 s" in m for m in messages) == 1
    assert sum("robot 4's controller has been gone" in m for m in messages) == 1
    assert sum("robot 3's controller is back" in m for m in messages) == 1

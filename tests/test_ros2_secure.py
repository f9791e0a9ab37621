"""The ROS 2 side secured as rmw_zenoh's: a router in TLS mode with access control
(:mod:`services.ros2.secure`), sessions opened from ``--ros2-zenoh-config`` files: each robot's
controller and base reach each other, another participant's injected cmd_vel and spoofed
odometry do not, and a process without a certificate gets no link at all."""

from __future__ import annotations

import argparse
import queue
import time
from pathlib import Path

import zenoh

from services.ros2 import msgs
from services.ros2.graph import Ros2Node
from services.ros2.options import ros2_config
from services.ros2.secure import write_ros2_configs
from services.testing import free_ports, start_service, stop_processes
from services.transport import make_config
from tests import HANG

TWIST, ODOM = "geometry_msgs/msg/Twist", "nav_msgs/msg/Odometry"
PATIENCE = HANG
"""Longest wait for a message that must come (a cap on a failure, not a measured time)."""


def _session(keys: Path, name: str) -> zenoh.Session:
    """A client session from participant ``name``'s file, as ``--ros2-zenoh-config`` opens it."""
    args = argparse.Namespace(ros2_zenoh_config=keys / f"{name}.json5", ros2_connect=None,
                              ros2_zenoh_mode="client")
    return zenoh.open(ros2_config(args))


def _odometry(x: float) -> msgs.Odometry:
    return msgs.Odometry(pose=msgs.PoseWithCovariance(msgs.Pose(msgs.Point(x))))


def _until(got: queue.SimpleQueue, send, good: float) -> list[float]:
    """Call ``send()`` every 0.1 s until ``good`` came; everything received on the way."""
    seen: list[float] = []
    deadline = time.monotonic() + PATIENCE
    while good not in seen:
        assert time.monotonic() < deadline, f"{good} never came (saw {seen})"
        send()
        try:
            seen.append(got.get(timeout=0.1))
        except queue.Empty:
            pass
        while not got.empty():
            seen.append(got.get())
    return seen


def test_a_secured_ros2_router_lets_through_each_robots_own_participants_only(tmp_path):
    port = free_ports(1)[0]
    keys = tmp_path / "keys"
    write_ros2_configs(keys, [1, 2], 0, f"tls/127.0.0.1:{port}")
    router = start_service("router", ["--zenoh-config", str(keys / "ros2-router.json5"),
                                      "--log-level", "WARNING"], tmp_path / "logs")
    sessions: list[zenoh.Session] = []
    try:
        sessions += [_session(keys, n) for n in ("base-1", "controller-1", "controller-2")]
        base, ctl, intruder = (Ros2Node(s, n, "/robot1") for s, n in zip(
            sessions, ("sim_robot1", "sqpmpc_robot1", "intruder"), strict=True))
        commands: queue.SimpleQueue[float] = queue.SimpleQueue()
        odometry: queue.SimpleQueue[float] = queue.SimpleQueue()
        base.subscribe("cmd_vel", TWIST, lambda rec: commands.put(rec.msg.linear.x))
        ctl.subscribe("odom", ODOM, lambda rec: odometry.put(rec.msg.pose.pose.position.x))
        cmd_pub, odom_pub = ctl.publisher("cmd_vel", TWIST), base.publisher("odom", ODOM)
        fake_cmd, fake_odom = intruder.publisher("cmd_vel", TWIST), intruder.publisher("odom", ODOM)
        # an outsider without a certificate: plain TCP to the TLS port, no link
        outsider = zenoh.open(make_config((), [f"tcp/127.0.0.1:{port}"], "peer"))
        sessions.append(outsider)
        stray = Ros2Node(outsider, "outsider", "/robot1")
        stray_cmd, stray_odom = stray.publisher("cmd_vel", TWIST), stray.publisher("odom", ODOM)

        def attack() -> None:
            for pub in (fake_cmd, stray_cmd):
                pub.publish(msgs.Twist(msgs.Vector3(9.0)))
            for pub in (fake_odom, stray_odom):
                pub.publish(_odometry(9.0))

        seen_cmd, seen_odom = [], []
        for good in (0.25, 0.5):  # attacks before, in between and after the good messages
            attack()
            seen_cmd += _until(commands, lambda g=good: (attack(), cmd_pub.publish(
                msgs.Twist(msgs.Vector3(g)))), good)
            seen_odom += _until(odometry, lambda g=good: (attack(), odom_pub.publish(
                _odometry(g))), good)
        assert set(seen_cmd) == {0.25, 0.5} and set(seen_odom) == {0.25, 0.5}
        assert not list(outsider.info.routers_zid()) and not list(outsider.info.peers_zid())
        assert list(sessions[1].info.routers_zid())  # the controller's link is the router
    finally:
        for s in sessions:
            s.close()
        stop_processes([router])

"""Simulated ROS 2 robots, written with an independent rmw_zenoh implementation.

``python -m services.ros2.simfleet --scenario S --router HOST:PORT --out DIR
[--ids 1,2] [--rate 50] [--domain D] [--twist-stamped] [--odom-stop ID:T]
[--duration S] [--epoch UNIX_S | --epoch-file FILE] [--seed K] [--control-rate HZ]
[--cmd-timeout S]``

Each robot of the scenario (or of ``--ids``) is a unicycle that starts at the
scenario's initial state, obeys ``/robot<ID>/cmd_vel`` (``Twist`` or
``TwistStamped``) from the moment a command arrives, moves on the exact arc
between commands, and publishes ``nav_msgs/Odometry`` on ``/robot<ID>/odom``
at ``--rate`` Hz with a phase of its own (not aligned with any controller's
sample), pose and twist in the scenario's frame. Its ROS 2 side is
zenoh-ros2-sdk (keys, CDR, attachments and graph tokens of that package, CDR
by rosbags), not the project's encoder: a controller that drives these robots
speaks the format as another implementation reads it.

With the scenario's acceleration limits (CONTRACT 1c) each robot's velocities
ramp toward a command no faster than the limits, updated at ``--control-rate``
Hz (:class:`SimRobot`), and its odometry reports the velocities it has.

Each robot stops by itself when no command came for ``--cmd-timeout`` s (default
0.5, the ``cmd_vel_timeout`` of ROS 2 Jazzy's diff_drive_controller; checked at
every odometry instant and when the next command comes: a gap longer than the
timeout stopped the robot at its end; not judged within ``STALL`` s after the
simulator itself did not run for ``STALL`` s, when commands may still be queued:
a real base does not stall with its controller), as such a base does, and
counts it (a *command timeout*, counted when the command it held was not zero)
and how long it stood on it, until the next command. A timeout judged while the
controller kept sending is the simulator's own lag, not the controller's: each
command's source timestamp (its rmw_zenoh attachment) is compared with the one
before it, and a timeout that a command sent within ``--cmd-timeout`` of the
previous one reveals as such is taken back (counted as ``lagged_timeouts``). A
command equal to the one in force changes nothing (under acceleration limits its ramp
goes on).

``--odom-stop ID:T`` stops robot ``ID``'s odometry at ``t = T`` (s after the
epoch) while it keeps obeying its commands (a failed sensor). On SIGINT,
SIGTERM or after ``--duration`` the fleet writes ``DIR/poses.json``: per
robot its diameter and every command segment ``[t, x, y, psi, v, omega]``
(wall time, state at that time, the input from then on), which
:mod:`services.ros2.check` reads to measure collisions at and between samples.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import random
import struct
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from sqpmpc.cli.options import Parser, nonnegative_float, positive_float
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.io.atomic import atomic_path
from sqpmpc.problem.plant import ramp_accelerations
from sqpmpc.problem.scenario_file import load_scenario

from ..node import install_signal_handlers, setup_logging
from .sdk import use_local_definitions
from .timing import arc

__all__ = ["STALL", "SimRobot", "build_parser", "main"]

log = logging.getLogger("services.ros2.simfleet")
PROG = "services.ros2.simfleet"
STALL = 0.1
"""A simulator loop that did not run for this long stalled (the machine's load): command
timeouts are not judged for as long after it (its queued commands come first)."""


class SimRobot:
    """One simulated robot: exact unicycle arcs between velocity changes, its log of segments.

    Without acceleration limits a command's velocities hold from its arrival.
    With ``limits`` (CONTRACT 1c: the scenario's ``[bounds]`` ``acceleration``
    and ``angular_acceleration``) the robot's velocity controller runs every
    ``tick`` s (on the grid ``j tick`` of wall time, as a drive controller's
    update loop) and moves each velocity toward the command by ``rate tick``,
    ``rate = clip((command - v) / sample_time, lower, upper)`` fixed when the
    command arrives (as the plant's robots: the command reached within one
    sample when the limits allow), never past the command; the velocities
    hold between ticks. So no velocity changes by more than ``|limit| tick``
    in a tick, and the log's segments are exactly the motion.

    Parameters
    ----------
    robot_id, diameter
        The scenario's robot.
    state
        Initial ``(x, y, psi)``.
    start
        Wall time the state holds at.
    limits
        ``(lower, upper)`` accelerations of ``(v, omega)``, or ``None``.
    sample_time
        The scenario's ``Ts`` (with ``limits``).
    tick
        Period of the velocity controller, s (with ``limits``).
    timeout
        Command timeout, s (0: none): :meth:`expire`.

    Attributes
    ----------
    timeouts
        Command timeouts that stopped the robot (the command in force was not zero) and
        that the controller caused: no command was sent for ``timeout`` s.
    timed_out
        Seconds the robot stood on its command timeout (until the next command).
    lagged
        Timeouts judged on the simulator's lag and taken back: the next command had been
        sent within ``timeout`` of the one before (its source timestamp).
    """

    def __init__(self, robot_id: int, diameter: float, state: np.ndarray, start: float,
                 limits: tuple[np.ndarray, np.ndarray] | None = None,
                 sample_time: float = 0.1, tick: float = 0.005, timeout: float = 0.0) -> None:
        self.robot_id = robot_id
        self.diameter = diameter
        self.limits = None if limits is None else (np.asarray(limits[0], dtype=float),
                                                   np.asarray(limits[1], dtype=float))
        self.sample_time = float(sample_time)
        self.tick = float(tick)
        self._lock = threading.Lock()
        self._t = start
        self._state = np.asarray(state, dtype=float).copy()
        self._vel = np.zeros(2)
        self._cmd = np.zeros(2)
        self._rate = np.zeros(2)
        self._tick = math.floor(start / self.tick)  # the last tick applied
        self.segments: list[list[float]] = [[start, *self._state.tolist(), 0.0, 0.0]]
        self.commands = 0
        self.timeout = float(timeout)
        self.timeouts = 0
        self.timed_out = 0.0
        self.lagged = 0
        self.judge_from = -math.inf  # no timeout is judged before (a stalled simulator)
        self._last_command: float | None = None  # when the last command came
        self._last_sent: float | None = None  # its source timestamp, if known
        self._counted = False  # the expiry in force was counted as a timeout
        self._expired_at: float | None = None  # when the timeout stopped it (until a command)

    def _advance(self, t: float) -> None:
        """Move the state to wall time ``t`` (the velocity controller's ticks on the way)."""
        if t <= self._t:
            return
        while self.limits is not None and not np.array_equal(self._vel, self._cmd):
            when = (self._tick + 1) * self.tick
            if when > t:
                break
            self._state = arc(self._state, *self._vel, max(0.0, when - self._t))
            self._t, self._tick = max(when, self._t), self._tick + 1
            step = self._vel + self._rate * self.tick
            past = (step - self._cmd) * np.sign(self._rate) >= 0.0
            self._vel = np.where(past | (self._rate == 0.0), self._cmd, step)
            self.segments.append([self._t, *self._state.tolist(), *self._vel.tolist()])
        self._state = arc(self._state, *self._vel, t - self._t)
        self._t = t

    def at(self, t: float) -> tuple[np.ndarray, tuple[float, float]]:
        """State at wall time ``t`` (not before the last command) and the velocities then."""
        with self._lock:
            self._advance(t)
            return self._state.copy(), (float(self._vel[0]), float(self._vel[1]))

    def command(self, v: float, omega: float, t: float, sent: float | None = None) -> None:
        """The command ``(v, omega)`` from wall time ``t`` on (one equal to the command in
        force changes nothing but the time of the last command).

        Parameters
        ----------
        v, omega
            The commanded velocities.
        t
            Wall time it is applied from (its arrival), Unix s.
        sent
            Its source timestamp (the publisher's clock, Unix s), if known: sent within
            ``timeout`` of the previous command's, a timeout since is this simulator's lag
            (the command was on its way), not the controller's, and is not counted.
        """
        with self._lock:
            lag = (sent is not None and self._last_sent is not None
                   and sent - self._last_sent <= self.timeout)
            if not lag:
                self._expire(t)  # it may have timed out since the last (checked at odometry)
            self._advance(t)
            self._last_command = t
            if sent is not None:
                self._last_sent = max(sent, self._last_sent or -math.inf)
            if self._expired_at is not None:
                if lag and self._counted:  # the controller kept sending: taken back
                    self.timeouts -= 1
                    self.lagged += 1
                elif not lag:
                    self.timed_out += max(0.0, t - self._expired_at)
                self._expired_at = None
            self.commands += 1
            cmd = np.array([float(v), float(omega)])
            if np.array_equal(cmd, self._cmd):
                return
            self._set(cmd)

    def expire(self, t: float) -> bool:
        """At wall time ``t``: stop the robot (a zero command from its timeout's end on, or
        from its last move of the state if later) when no command came for ``timeout`` s,
        as a base's command timeout; ``True`` if it did now."""
        with self._lock:
            return self._expire(t)

    def _expire(self, t: float) -> bool:
        """:meth:`expire` (the caller holds the lock)."""
        if t < self.judge_from:  # the simulator itself stood: commands may be queued
            return False
        if (self.timeout <= 0.0 or self._last_command is None
                or self._expired_at is not None or t - self._last_command <= self.timeout):
            return False
        when = max(self._last_command + self.timeout, self._t)
        self._advance(when)
        self._expired_at = when
        self._counted = bool(self._cmd.any())
        if not self._counted:
            return False
        self.timeouts += 1
        self._set(np.zeros(2))
        return True

    def _set(self, cmd: np.ndarray) -> None:
        """The command in force from ``self._t`` on (the caller holds the lock)."""
        self._cmd = cmd
        if self.limits is None:
            self._vel = self._cmd.copy()
            self.segments.append([self._t, *self._state.tolist(), *self._vel.tolist()])
            return
        self._tick = math.floor(self._t / self.tick)
        self._rate = ramp_accelerations(self._cmd, self._vel, self.sample_time, *self.limits)


def _odom_message(pub, classes: dict, robot: SimRobot, t: float) -> None:
    """Publish robot's odometry at ``t`` with the SDK's publisher ``pub``."""
    state, (v, w) = robot.at(t)
    c = classes
    sec, nsec = divmod(int(round(t * 1e9)), 1_000_000_000)
    half = 0.5 * float(state[2])
    pose = c["Pose"](position=c["Point"](x=float(state[0]), y=float(state[1]), z=0.0),
                     orientation=c["Quaternion"](x=0.0, y=0.0, z=float(np.sin(half)),
                                                 w=float(np.cos(half))))
    twist = c["Twist"](linear=c["Vector3"](x=v, y=0.0, z=0.0),
                       angular=c["Vector3"](x=0.0, y=0.0, z=w))
    pub.publish(header=c["Header"](stamp=c["Time"](sec=sec, nanosec=nsec), frame_id="odom"),
                child_frame_id=f"robot{robot.robot_id}/base_link",
                pose=c["PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                twist=c["TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))


def _read_epoch(path: Path) -> float | None:
    """The epoch in ``path`` once it exists (``None`` before)."""
    try:
        return float(path.read_text())
    except (OSError, ValueError):
        return None


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.ros2.simfleet``."""
    p = Parser(prog=prog, description=__doc__.splitlines()[0])
    p.add_argument("--scenario", required=True, help="TOML file or built-in name")
    p.add_argument("--router", default="127.0.0.1:7447", metavar="HOST:PORT",
                   help="the ROS 2 side's Zenoh router (default 127.0.0.1:7447)")
    p.add_argument("--out", type=Path, required=True, help="folder for poses.json")
    p.add_argument("--ids", default=None, help="comma-separated robot ids (default: all)")
    p.add_argument("--rate", type=positive_float, default=50.0, help="odometry rate, Hz")
    p.add_argument("--control-rate", type=positive_float, default=200.0, metavar="HZ",
                   help="update rate of the robots' velocity controllers under the "
                        "scenario's acceleration limits, Hz (default 200)")
    p.add_argument("--domain", type=int, default=0, help="ROS domain id")
    p.add_argument("--cmd-timeout", type=nonnegative_float, default=0.5, metavar="S",
                   help="a robot stops when no command came for S s, as diff_drive_controller's "
                        "cmd_vel_timeout (default 0.5; 0: never)")
    p.add_argument("--twist-stamped", action="store_true",
                   help="cmd_vel carries TwistStamped")
    p.add_argument("--odom-stop", action="append", default=[], metavar="ID:T",
                   help="robot ID's odometry stops at t = T s after the epoch (repeatable)")
    p.add_argument("--duration", type=positive_float, default=None, metavar="S",
                   help="stop after S s (default: on SIGINT/SIGTERM)")
    p.add_argument("--epoch", type=float, default=None, help="wall time of t = 0 (Unix s)")
    p.add_argument("--epoch-file", type=Path, default=None, metavar="FILE",
                   help="the epoch is in FILE once it exists (as for the controllers)")
    p.add_argument("--seed", type=int, default=0, help="seed of the odometry phases")
    p.add_argument("--log-level", default="INFO")
    return p


def _stops(items: list[str], ids: list[int]) -> dict[int, float]:
    out = {}
    for item in items:
        rid, sep, t = item.partition(":")
        try:
            out[int(rid)] = float(t)
        except ValueError:
            raise ProblemError(f"--odom-stop: expected ID:T, got {item!r}") from None
        if not sep or int(rid) not in ids:
            raise ProblemError(f"--odom-stop {item}: robot {rid} is not simulated here")
    return out


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit status."""
    args = build_parser(prog).parse_args(argv)
    setup_logging(args.log_level, "simfleet")
    try:
        scenario = load_scenario(args.scenario)
        ids = ([int(i) for i in args.ids.split(",")] if args.ids
               else [int(i) for i in scenario.ids])
        for rid in ids:
            scenario.index_of(rid)
        stops = _stops(args.odom_stop, ids)
        host, _, port = args.router.rpartition(":")
        router = (host or "127.0.0.1", int(port))
    except (ScenarioError, ProblemError, ValueError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    use_local_definitions(Path(tempfile.mkdtemp(prefix="sqpmpc-msgs-")))
    import zenoh_ros2_sdk as sdk
    from zenoh_ros2_sdk.attachment import Attachment

    # the SDK keeps one session per process, opened by whichever call comes first
    sdk.ZenohSession.get_instance(*router)
    classes = {name: sdk.get_message_class(f"{pkg}/msg/{name}") for pkg, name in (
        ("std_msgs", "Header"), ("builtin_interfaces", "Time"), ("geometry_msgs", "Pose"),
        ("geometry_msgs", "Point"), ("geometry_msgs", "Quaternion"),
        ("geometry_msgs", "Twist"), ("geometry_msgs", "Vector3"),
        ("geometry_msgs", "PoseWithCovariance"), ("geometry_msgs", "TwistWithCovariance"))}
    stop = threading.Event()
    install_signal_handlers(stop)
    start = time.time()
    epoch = args.epoch if args.epoch is not None or args.epoch_file else start
    looked = 0.0
    bounds = scenario.bounds
    limits = (bounds.acceleration_lower(), bounds.acceleration_upper()) \
        if bounds.dynamic_limits else None
    robots = {rid: SimRobot(rid, float(scenario.robots[scenario.index_of(rid)].diameter),
                            scenario.initial_states()[scenario.index_of(rid)], start, limits,
                            scenario.sample_time, 1.0 / args.control_rate, args.cmd_timeout)
              for rid in ids}
    cmd_type = "geometry_msgs/msg/TwistStamped" if args.twist_stamped else \
        "geometry_msgs/msg/Twist"
    endpoints = []

    source = threading.local()  # the source timestamp of the sample being handled

    class StampedSubscriber(sdk.ROS2Subscriber):
        """The SDK's subscriber; its callback also learns the sample's source timestamp
        (the rmw_zenoh attachment, read by the SDK's own :class:`Attachment`)."""

        def _process_sample(self, sample: object) -> None:
            source.stamp = None
            raw = getattr(sample, "attachment", None)
            if raw is not None:
                try:
                    source.stamp = Attachment.from_bytes(raw.to_bytes()).timestamp_ns * 1e-9
                except (TypeError, ValueError, struct.error):
                    pass
            super()._process_sample(sample)

    def on_cmd(robot: SimRobot):
        def callback(msg: object) -> None:
            t = time.time()
            twist = msg.twist if args.twist_stamped else msg
            robot.command(float(twist.linear.x), float(twist.angular.z), t,
                          getattr(source, "stamp", None))
        return callback

    pubs = {}
    for rid, robot in robots.items():
        ns = f"/robot{rid}"
        endpoints.append(StampedSubscriber(f"{ns}/cmd_vel", cmd_type, callback=on_cmd(robot),
                                            node_name=f"sim_robot{rid}", namespace=ns,
                                            domain_id=args.domain, router_ip=router[0],
                                            router_port=router[1]))
        pubs[rid] = sdk.ROS2Publisher(f"{ns}/odom", "nav_msgs/msg/Odometry",
                                      node_name=f"sim_robot{rid}", namespace=ns,
                                      domain_id=args.domain, router_ip=router[0],
                                      router_port=router[1])
    endpoints.extend(pubs.values())
    rng = random.Random(args.seed)
    period = 1.0 / args.rate
    due = {rid: start + rng.random() * period for rid in robots}
    sent = dict.fromkeys(robots, 0)
    ticked, stalls = time.time(), 0
    log.info("%d robots, odometry at %g Hz", len(robots), args.rate)
    end = None if args.duration is None else start + args.duration
    try:
        while not stop.is_set() and (end is None or time.time() < end):
            rid = min(due, key=due.get)
            wait = due[rid] - time.time()
            if wait > 0.0 and stop.wait(wait):
                break
            t = time.time()
            if t - ticked > STALL:  # this process stood: let queued commands in first
                stalls += 1
                for robot in robots.values():
                    robot.judge_from = t + STALL
            ticked = t
            due[rid] += period * max(1, int((t - due[rid]) // period) + 1)
            if epoch is None and t - looked > 0.1:
                looked = t
                epoch = _read_epoch(args.epoch_file)
            if robots[rid].expire(t):
                log.warning("robot %d: no command for %g s: stopped (command timeout)", rid,
                            args.cmd_timeout)
            if rid in stops and epoch is not None and t - epoch >= stops[rid]:
                continue  # the sensor failed
            _odom_message(pubs[rid], classes, robots[rid], t)
            sent[rid] += 1
    finally:
        now = time.time()
        out = {"epoch": start if epoch is None else epoch, "start": start, "end": now,
               "rate": args.rate, "cmd_timeout": args.cmd_timeout, "stalls": stalls,
               "odom_stop": {str(k): v for k, v in stops.items()},
               "robots": {str(rid): {"diameter": r.diameter, "segments": r.segments,
                                     "odometry_sent": sent[rid],
                                     "command_timeouts": r.timeouts,
                                     "lagged_timeouts": r.lagged,
                                     "timed_out": r.timed_out}
                          for rid, r in robots.items()}}
        args.out.mkdir(parents=True, exist_ok=True)
        with atomic_path(args.out / "poses.json") as tmp:
            tmp.write_text(json.dumps(out))
        for ep in endpoints:
            ep.close()
        log.info("wrote %s (%d commands)", args.out / "poses.json",
                 sum(r.commands for r in robots.values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())

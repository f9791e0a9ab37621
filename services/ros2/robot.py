"""``sqpmpc robot --id ID --scenario S --ros2``: one robot's controller driving a ROS 2 robot.

No plant process: the robot runs on its own clock (wall time, the
scenario's ``Ts``), takes its own state from the robot's ``nav_msgs/Odometry``
on ``NS/odom`` and sends ``geometry_msgs/Twist`` (``--twist-stamped``:
``TwistStamped``) on ``NS/cmd_vel`` and its plan as ``nav_msgs/Path`` on
``NS/plan``, in rmw_zenoh's format (:mod:`services.ros2.graph`) on a Zenoh
session of its own (``--ros2-connect``, default the ROS 2 router
``tcp/127.0.0.1:7447``). Its plans also go to its neighbours over the
sqpmpc keys (``robot/<id>/plan``, secured by ``--credentials`` as in every
run), with the wall time of their stage 0 in ``stamp``.

One sample ``k`` (instant ``T_k = T_0 + k Ts``, ``t_k = T_k - epoch`` for the
references):

1. at ``T_k - lead``: the own state at ``T_k`` from the newest odometry (pose
   and ``v``, ``omega``), carried forward on the exact unicycle arc with the
   measured twist and then the commands sent since; each neighbour's motion
   from its plans (:func:`services.ros2.timing.committed`): a robot applies a
   plan's first input from the plan's stamp for one sample, so that arc is
   exact, and after it the neighbour either decides again knowing this
   robot's new plan or is bounded by its reach;
2. the controller's step with every neighbour a moving obstacle (its exact
   arcs, then standing where they end, at the own stage times);
3. the check of the first input (:meth:`Ros2Robot.path_is_safe`): along the
   exact arc of the whole sample, every neighbour's distance plus
   ``--ros2-margin`` from where it is (arcs, then standing still for a
   neighbour that will see this plan before it decides, or the disc it may
   reach otherwise); if not, the robot stands still, which is always safe:
   every neighbour deciding later keeps out of where this robot stops (it
   checks the same way), and one deciding at about the same time had to keep
   out of it already (it took this robot's previous arc, then standing still);
4. the plan is sent at once, the command at ``T_k``.

Every robot of a fleet uses the same ``--lead`` (it tells when a neighbour
decides). The safety argument is per pair: at every instant the robot that
decided last knew the other's motion up to then and kept the distance from it.

The command is zero when the odometry is older than ``--odom-timeout``
(checked continuously, so within one sample of its loss), at the end
(``t_end``), and on SIGINT/SIGTERM; while the odometry is stale the robot
publishes a plan that stands still where the odometry and the commands sent
put it. A neighbour that has not sent a plan yet is unknown (it is not
running); one whose token disappears (it stopped, commanding zero) is held
where its last plan put it, standing still. Before moving, the robot waits up
to ``--timeout`` for a plan of every neighbour whose token it sees.
"""

from __future__ import annotations

import argparse
import logging
import math
import random
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import zenoh

from sqpmpc.cli.options import nonnegative_float, positive_float
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.plans import PlanMessage
from sqpmpc.problem.scenario import Scenario

from ..control import controller_settings
from ..messages import Message, PlanMsg, encode
from ..node import POLL, Node, options_of
from ..transport import make_config
from . import msgs
from .graph import Received, Ros2Node, check_name
from .timing import Estimate, TimedPlan, arc, arcs, committed, neighbour_estimate

__all__ = ["FAR", "Ros2Robot", "add_ros2_arguments", "main_ros2", "ros2_problem"]

log = logging.getLogger(__name__)

FAR = 1.0e4
"""Where a neighbour never heard from is put (m): beyond every interaction radius."""
KEPT_PLANS = 4
"""Plans kept per neighbour (the newest few: one stamped before each of the own instants)."""
ROW_MARGIN_FACTOR = 3.0
"""The QP's collision margin is at least this many times ``--ros2-margin``."""
STOP_GRACE = 0.01
"""Seconds after a sample's instant without its command before the robot is stopped."""
PUBLISH_SLACK = 0.005
"""A plan not ready this long before its instant is dropped: the robot stands still."""
CHECK_STEPS = 100
"""Points per sample at which :meth:`Ros2Robot.path_is_safe` measures the distances."""


class _NoPaperWarning(logging.Filter):
    """The controller's warning about its obstacle mode, which alone has no guarantee: here
    :meth:`Ros2Robot.path_is_safe` verifies every input."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "decentralized mode 'paper'" not in record.getMessage()



def add_ros2_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``--ros2`` options of ``sqpmpc robot``."""
    g = parser.add_argument_group("ROS 2 robot (CONTRACT 4)")
    g.add_argument("--ros2", action="store_true",
                   help="drive a ROS 2 robot (odom, cmd_vel, plan topics over rmw_zenoh) on "
                        "this robot's own clock, without a plant process")
    g.add_argument("--ros2-namespace", default=None, metavar="NS",
                   help="the robot's ROS 2 namespace (default /robot<ID>)")
    g.add_argument("--ros2-domain", type=int, default=0, metavar="D",
                   help="ROS domain id, 0..232 (default 0)")
    g.add_argument("--twist-stamped", action="store_true",
                   help="send geometry_msgs/TwistStamped on cmd_vel (Jazzy's "
                        "diff_drive_controller) instead of Twist")
    g.add_argument("--ros2-connect", action="append", default=None, metavar="EP",
                   help="Zenoh endpoint of the ROS 2 side, e.g. the rmw_zenoh router "
                        "(repeatable; default tcp/127.0.0.1:7447)")
    g.add_argument("--ros2-zenoh-mode", choices=("client", "peer"), default="client",
                   help="the ROS 2 session's mode (default client of the router)")
    g.add_argument("--epoch", type=float, default=None, metavar="UNIX_S",
                   help="wall time (Unix s) of the scenario's t = 0, shared by the fleet "
                        "(default: this robot's start)")
    g.add_argument("--epoch-file", type=Path, default=None, metavar="FILE",
                   help="wait (publishing standing plans) until FILE exists and holds the "
                        "epoch in Unix s: a launcher starts the fleet's clock once every "
                        "controller is up")
    g.add_argument("--odom-timeout", type=positive_float, default=0.3, metavar="S",
                   help="odometry older than this is stale: command zero at once (default "
                        "0.3 s; keep it below Ts: zero within one sample)")
    g.add_argument("--lead", type=positive_float, default=None, metavar="S",
                   help="start each sample's computation this long before its instant "
                        "(default 0.3 Ts)")
    g.add_argument("--ros2-margin", type=nonnegative_float, default=0.02, metavar="M",
                   help="added to every required distance in the check of each input: "
                        "odometry and timing errors, m (default 0.02)")
    g.add_argument("--ros2-guard", type=nonnegative_float, default=0.02, metavar="S",
                   help="bound on the clock offset between robots, s (default 0.02): a "
                        "neighbour deciding less than this after this robot's check is held "
                        "by its reach (every robot of a fleet uses the same --lead)")


def ros2_problem(args: argparse.Namespace, scenario: Scenario) -> str | None:
    """Why the ``--ros2`` options cannot run, if so (one message naming the flag)."""
    if len(args.id) != 1:
        return "--ros2 drives one robot: give one --id"
    if not 0 <= args.ros2_domain <= 232:
        return f"--ros2-domain: expected 0..232, got {args.ros2_domain}"
    ns = args.ros2_namespace or f"/robot{args.id[0]}"
    try:
        check_name(ns, "--ros2-namespace")
    except ValueError as exc:
        return str(exc)
    lead = args.lead if args.lead is not None else 0.3 * scenario.sample_time
    if lead >= scenario.sample_time:
        return f"--lead: must be less than Ts = {scenario.sample_time:g} s, got {lead:g}"
    if args.epoch is not None and args.epoch_file is not None:
        return "give --epoch or --epoch-file, not both"
    if options_of(args).decentralized_mode != "shared":
        return "--decentralized-mode: --ros2 holds every neighbour by its own check"
    return None


class Ros2Robot(Node):
    """The controller of one ROS 2 robot (see the module notes).

    Parameters
    ----------
    scenario
        The problem (its plant model is taken as ``exact``: a real robot moves on arcs).
    args
        Parsed ``sqpmpc robot`` arguments with ``--ros2``.
    """

    def __init__(self, scenario: Scenario, args: argparse.Namespace) -> None:
        scenario = replace(scenario, plant=replace(scenario.plant, model="exact"))
        self.robot_id = int(args.id[0])
        # every neighbour is a moving obstacle (its committed arcs); the robot's own
        # check (path_is_safe) is what keeps the distance
        logging.getLogger("sqpmpc.controllers").addFilter(_NoPaperWarning())
        settings = controller_settings(args)
        # the QP keeps more room than the check asks for (the check is continuous, the
        # QP's rows are at the stage instants)
        settings = replace(settings, collision_margin=max(
            settings.collision_margin, ROW_MARGIN_FACTOR * float(args.ros2_margin)))
        self.controller = DecentralizedController(scenario, self.robot_id, settings, "paper")
        super().__init__(scenario, args, f"robot/{self.robot_id}", "decentralized")
        self.index = scenario.index_of(self.robot_id)
        self.neighbours = [i for i in self.ids if i != self.robot_id]
        self.Ts = scenario.sample_time
        self.v_max = float(self.controller.context.max_speed)
        self.margin = float(args.ros2_margin)
        self.guard = float(args.ros2_guard)
        self.required = scenario.required_distances()[self.index]
        self.lead = args.lead if args.lead is not None else 0.3 * self.Ts
        self.odom_timeout = float(args.odom_timeout)
        self.timeout = float(args.timeout)
        self.startup_timeout = args.startup_timeout
        self.epoch = args.epoch
        self.epoch_file: Path | None = args.epoch_file
        self.plans: dict[int, list[TimedPlan]] = {i: [] for i in self.neighbours}
        self.departed: dict[int, Estimate] = {}
        self.blocked_by_concurrent = False
        self._cmd_lock = threading.RLock()
        self.counts = {"samples": 0, "brakes": 0, "phase_shifts": 0, "late_samples": 0,
                       "stopped_late": 0,
                       "stale_odometry": 0,
                       "zero_commands": 0, "plans_received": 0, "plans_refused": 0}
        self._lock = threading.Lock()
        self._odom: tuple[float, np.ndarray, float, float] | None = None  # t, pose, v, w
        self._frame = ("odom", "base_link")
        self._sent: list[tuple[float, float, float]] = []  # (time, v, omega) commands sent
        self._braked = False
        ns = args.ros2_namespace or f"/robot{self.robot_id}"
        self.twist_stamped = bool(args.twist_stamped)
        connect = args.ros2_connect if args.ros2_connect is not None else [
            "tcp/127.0.0.1:7447"]
        self.ros_session = zenoh.open(make_config((), connect, args.ros2_zenoh_mode))
        try:
            self.ros = Ros2Node(self.ros_session, f"sqpmpc_robot{self.robot_id}", ns,
                                args.ros2_domain)
            self.ros.subscribe("odom", "nav_msgs/msg/Odometry", self._on_odom)
            self.cmd_pub = self.ros.publisher(
                "cmd_vel", "geometry_msgs/msg/TwistStamped" if self.twist_stamped
                else "geometry_msgs/msg/Twist")
            self.path_pub = self.ros.publisher("plan", "nav_msgs/msg/Path")
        except Exception:
            self.ros_session.close()
            raise

    # ------------------------------------------------------------------ inputs
    def _on_odom(self, rec: Received) -> None:
        """Keep the newest odometry (runs on a Zenoh thread)."""
        o: msgs.Odometry = rec.msg
        p = o.pose.pose
        pose = np.array([p.position.x, p.position.y, msgs.quaternion_yaw(p.orientation)])
        v, w = float(o.twist.twist.linear.x), float(o.twist.twist.angular.z)
        if not (np.isfinite(pose).all() and math.isfinite(v) and math.isfinite(w)):
            return
        stamp = o.header.stamp.seconds()
        # the stamp if it is plausible (same clock), else the arrival
        t = stamp if abs(stamp - rec.arrival) < 1.0 else rec.arrival
        with self._lock:
            if self._odom is None or t > self._odom[0]:
                self._odom = (t, pose, v, w)
                self._frame = (o.header.frame_id or "odom", o.child_frame_id or "base_link")

    def on_message(self, kind: str, msg: Message) -> None:
        if not isinstance(msg, PlanMsg) or msg.id not in self.plans:
            return
        now = time.time()
        if msg.stamp > now + self.Ts or msg.stamp < now - self.scenario.horizon * self.Ts:
            self.counts["plans_refused"] += 1  # from the future, or too old to matter
            return
        kept = self.plans[msg.id]
        if any(p.stamp == msg.stamp for p in kept):
            return
        kept.append(TimedPlan(msg.stamp, msg.states, msg.inputs))
        kept.sort(key=lambda p: p.stamp)
        del kept[:-KEPT_PLANS]
        self.departed.pop(msg.id, None)  # back
        self.counts["plans_received"] += 1

    def on_liveliness(self, name: str, alive: bool) -> None:
        if alive or not name.startswith("robot/"):
            return
        try:
            rid = int(name.split("/", 1)[1])
        except ValueError:
            return
        if rid in self.plans and self.plans[rid]:
            # it stopped (zero on shutdown): standing where its plan had it now
            est = neighbour_estimate(self.plans[rid], time.time(), self.Ts, self.v_max)
            if est is not None:
                self.departed[rid] = Estimate(est.state, est.uncertainty + self.v_max * self.Ts)
            self.plans[rid].clear()

    # ------------------------------------------------------------------ states
    def own_state(self, t: float) -> np.ndarray | None:
        """The own state at wall time ``t`` from the newest odometry and the commands sent
        since (``None``: no odometry yet)."""
        with self._lock:
            if self._odom is None:
                return None
            t0, state, v, w = self._odom
        for ts, cv, cw in self._sent:
            if ts <= t0:
                continue
            if ts >= t:
                break
            state = arc(state, v, w, ts - t0)
            t0, v, w = ts, cv, cw
        return arc(state, v, w, max(0.0, t - t0))

    def odometry_age(self, now: float) -> float:
        """Seconds since the newest odometry (infinite: none yet)."""
        with self._lock:
            return math.inf if self._odom is None else now - self._odom[0]

    def neighbour_plans(self, t: float, sample: int
                        ) -> tuple[np.ndarray, dict[int, PlanMessage]]:
        """Every robot's state at wall time ``t`` (own row left zero; unknown robots far
        away) and, per neighbour heard from, its committed motion sampled at the own
        stage times ``t + i Ts`` as a plan of the previous sample (what the controller
        shifts to stages 1..N): exact arcs, then standing where the last one ends."""
        N = self.scenario.horizon
        states = np.zeros((len(self.ids), 3))
        plans: dict[int, PlanMessage] = {}
        times = t + self.Ts * np.arange(-1, N)
        for j, rid in enumerate(self.ids):
            if rid == self.robot_id:
                continue
            left = self.departed.get(rid)
            if left is not None:
                states[j] = left.state
                pos = np.repeat(left.state[None, :2], N + 1, axis=0)
            elif self.plans[rid]:
                pos, _ = committed(self.plans[rid], times, self.Ts, self.v_max, True)
                now = committed(self.plans[rid], np.array([t]), self.Ts, self.v_max, True)[0]
                states[j, :2] = now[0]
            else:
                states[j] = (FAR + 10.0 * j, FAR, 0.0)
                continue
            stage = np.zeros((N + 1, 3))
            stage[:, :2] = pos
            plans[rid] = PlanMessage(rid, sample - 1, stage, np.zeros((N, 2)))
        return states, plans

    def path_is_safe(self, own: np.ndarray, u: np.ndarray, Tk: float) -> bool:
        """Whether applying ``u`` from ``own`` at ``Tk`` for one sample keeps every
        neighbour's distance (plus ``--ros2-margin``) at every instant.

        A neighbour that decides its next input after this check (its next stamp
        minus the lead is after now plus ``--ros2-guard``, the bound on the clock
        offset) is checked against its exact arcs and then standing still: when
        it decides, it either has this robot's new plan and avoids it, or it has
        an older one and keeps out of everywhere this robot may be. Any other
        neighbour (it decided before this check, its plan not here yet) is
        checked against its exact arcs and then the disc it may reach.
        Neighbours that left: their resting place plus a sample's reach.
        """
        dt = self.Ts / CHECK_STEPS
        times = Tk + dt * np.arange(CHECK_STEPS + 1)
        path = arcs(own, float(u[0]), float(u[1]), times - Tk)
        now = time.time()
        slack = self.margin + self.v_max * dt  # between check points both move v_max dt/2
        for j, rid in enumerate(self.ids):
            if rid == self.robot_id:
                continue
            left = self.departed.get(rid)
            concurrent = False
            if left is not None:
                pos, rad = left.state[None, :2], np.full(1, left.uncertainty)
            elif self.plans[rid]:
                kept = self.plans[rid]
                later = kept[-1].stamp + self.Ts - self.lead > now + self.guard
                pos, rad = committed(kept, times, self.Ts, self.v_max, later)
                concurrent = not later
            else:
                continue
            gap = np.hypot(path[:, 0] - pos[:, 0], path[:, 1] - pos[:, 1]) - rad
            if float(gap.min()) < self.required[j] + slack:
                self.blocked_by_concurrent = concurrent
                return False
        return True

    # ------------------------------------------------------------------ outputs
    def command(self, v: float, omega: float, at: float) -> None:
        """Send ``(v, omega)`` on cmd_vel now and remember it (for the own state)."""
        twist = msgs.Twist(msgs.Vector3(float(v)), msgs.Vector3(0.0, 0.0, float(omega)))
        with self._cmd_lock:  # the main thread and the stop timer
            if self.twist_stamped:
                self.cmd_pub.publish(msgs.TwistStamped(
                    msgs.Header(msgs.Time.from_seconds(at), self._frame[1]), twist))
            else:
                self.cmd_pub.publish(twist)
            self._sent.append((at, float(v), float(omega)))
            del self._sent[:-16]
            if v == 0.0 and omega == 0.0:
                self.counts["zero_commands"] += 1

    def publish_plan(self, sample: int, stamp: float, states: np.ndarray,
                     inputs: np.ndarray) -> None:
        """The plan to the neighbours (sqpmpc keys) and as a Path on ``NS/plan``."""
        t = stamp - (self.epoch or 0.0)
        self.bus.put(encode(PlanMsg(self.robot_id, sample, t, stamp, states, inputs)),
                     "robot", self.robot_id, "plan")
        frame = self._frame[0]
        poses = tuple(msgs.PoseStamped(
            msgs.Header(msgs.Time.from_seconds(stamp + i * self.Ts), frame),
            msgs.Pose(msgs.Point(float(s[0]), float(s[1])), msgs.yaw_quaternion(float(s[2]))))
            for i, s in enumerate(states))
        self.path_pub.publish(msgs.Path(msgs.Header(msgs.Time.from_seconds(stamp), frame),
                                        poses))

    def brake(self, now: float, sample: int) -> None:
        """Zero on cmd_vel; a plan standing where the robot is."""
        self.command(0.0, 0.0, now)
        state = self.own_state(now)
        if state is not None:
            N = self.scenario.horizon
            self.publish_plan(sample, now, np.repeat(state[None], N + 1, axis=0),
                              np.zeros((N, 2)))

    def _watch(self, until: float, sample: int) -> None:
        """Handle events until wall time ``until``; brake at once if the odometry goes
        stale."""
        while not self.stop.is_set():
            now = time.time()
            if not self._braked and self.odometry_age(now) > self.odom_timeout:
                self._braked = True
                self.counts["stale_odometry"] += 1
                log.warning("%s: odometry %.3f s old: commanding zero", self.name,
                            self.odometry_age(now))
                self.brake(now, sample)
            if now >= until:
                return
            self.pump(min(POLL, max(until - now, 0.0), 0.01))

    # ------------------------------------------------------------------ loop
    def run(self) -> int:
        """Serve until ``t_end``, SIGINT or SIGTERM; returns the exit status."""
        self.start([("robot", i, "plan") for i in self.neighbours])
        log.info("%s waiting for odometry on %s", self.name, self.ros.resolve("odom"))
        if not self.wait_until(lambda: self.odometry_age(time.time()) < self.odom_timeout,
                               self.startup_timeout):
            if not self.stop.is_set():
                log.error("%s: no odometry within %s s", self.name, self.startup_timeout)
            return 0 if self.stop.is_set() else 1
        if self.epoch_file is not None:
            self.epoch = self._wait_for_epoch()
            if self.epoch is None:
                return 0 if self.stop.is_set() else 1
        start = time.time()
        epoch = self.epoch if self.epoch is not None else start
        self.epoch = epoch
        self._announce(start)
        # its own phase: no two robots' instants line up
        T0 = max(time.time() + self.lead, epoch) + random.random() * self.Ts
        k, end = 0, epoch + self.scenario.t_end
        try:
            while not self.stop.is_set():
                Tk = T0 + k * self.Ts
                if Tk > end:
                    break
                self._watch(Tk - self.lead, k)
                if self.stop.is_set():
                    break
                self._step(k, Tk)
                k += 1
                if self.blocked_by_concurrent:
                    # blocked by a neighbour that decides at about the same instants: it
                    # would stay so every sample; move this robot's instants away from it
                    self.blocked_by_concurrent = False
                    self.counts["phase_shifts"] += 1
                    T0 += random.uniform(0.2, 0.4) * self.Ts
                behind = time.time() + self.lead - (T0 + k * self.Ts)
                if behind > 0.0:  # overran: skip to the next instant still ahead
                    k += math.ceil(behind / self.Ts)
        finally:
            self.command(0.0, 0.0, time.time())
        log.info("%s: %s, %d invalid messages dropped", self.name,
                 ", ".join(f"{v} {k}" for k, v in self.counts.items()), self.validator.invalid)
        return 0

    def _wait_for_epoch(self) -> float | None:
        """Publish standing plans until ``--epoch-file`` holds a number (``None``: stopped,
        or a file that is not a number)."""
        while not self.stop.is_set():
            if self.epoch_file.exists():
                text = self.epoch_file.read_text().strip()
                try:
                    return float(text)
                except ValueError:
                    log.error("%s: --epoch-file %s holds %r, not a time in Unix s",
                              self.name, self.epoch_file, text[:40])
                    return None
            self.brake(time.time(), 0)
            self.wait_until(lambda: False, min(self.Ts, 0.2))
        return None

    def _announce(self, start: float) -> None:
        """Publish standing plans until the epoch and until a plan of every neighbour seen
        alive has come (at most ``--timeout``): a robot that moves knows where every
        running neighbour is."""
        deadline = start + self.timeout
        while not self.stop.is_set():
            now = time.time()
            self.brake(now, 0)
            alive = [i for i in self.neighbours if f"robot/{i}" in self.alive]
            if now >= self.epoch - self.Ts and (all(self.plans[i] for i in alive)
                                                or now >= deadline):
                break
            self.wait_until(lambda: False, min(self.Ts, 0.2))
        missing = [i for i in self.neighbours if not self.plans[i]]
        if missing:
            log.warning("%s starts without plans from %s", self.name, missing)

    def _step(self, k: int, Tk: float) -> None:
        """Compute sample ``k`` (instant ``Tk``), send the plan, the command at ``Tk``."""
        now = time.time()
        if self.odometry_age(now) > self.odom_timeout:
            self.brake(now, k)  # stays braked while the odometry is stale
            return
        self._braked = False
        # the previous plan commits its input until Tk only: if this sample's command is
        # not out by then (a stalled process), stop the robot there
        sent = threading.Event()

        def stop_if_late() -> None:
            with self._cmd_lock:
                if not sent.is_set():
                    self.counts["stopped_late"] += 1
                    self.command(0.0, 0.0, time.time())

        timer = threading.Timer(max(0.0, Tk + STOP_GRACE - time.time()), stop_if_late)
        timer.daemon = True
        timer.start()
        try:
            own = self.own_state(Tk)
            states, plans = self.neighbour_plans(Tk, k)
            states[self.index] = own
            out = self.controller.step(k, Tk - self.epoch, states, plans, None)
            u = out.inputs[0]
            late = time.time() > Tk - PUBLISH_SLACK
            if not late and self.path_is_safe(own, u, Tk):
                plan = self.controller.published
                self.publish_plan(k, Tk, plan.states, plan.inputs)
            else:  # standing still is safe: every neighbour keeps out of where it stops
                u = np.zeros(2)
                self.counts["late_samples" if late else "brakes"] += 1
                N = self.scenario.horizon
                self.publish_plan(k, Tk, np.repeat(own[None], N + 1, axis=0),
                                  np.zeros((N, 2)))
            self._watch(Tk, k)
            if self._braked:  # the odometry went stale meanwhile: the zero stands
                return
            with self._cmd_lock:
                sent.set()
            self.command(float(u[0]), float(u[1]), time.time())
            self.counts["samples"] += 1
        finally:
            timer.cancel()

    def close(self) -> None:
        """Undeclare the ROS 2 node, close both sessions."""
        try:
            self.ros.close()
        finally:
            self.ros_session.close()
            super().close()


def main_ros2(args: argparse.Namespace, scenario: Scenario, prog: str) -> int:
    """Run ``sqpmpc robot --ros2`` (called by :func:`services.robot.main`)."""
    from ..node import fail, open_node, session_lost

    problem = ros2_problem(args, scenario)
    if problem:
        fail(prog, problem)
    node = open_node(prog, lambda: Ros2Robot(scenario, args))
    try:
        return node.run()
    except zenoh.ZError as exc:
        return session_lost(prog, exc)
    finally:
        node.close()

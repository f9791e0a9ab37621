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

1. at ``T_k - lead``, after waiting for a plan in flight of a neighbour that
   decides before this robot (:meth:`services.ros2.neighbours.Neighbours.awaited`):
   the own state at ``T_k`` from the newest odometry, carried forward on exact
   arcs with the measured twist and the commands sent since; each neighbour's
   motion from its plans (:func:`services.ros2.timing.committed`): a robot
   applies a plan's first input from its stamp for one sample, exactly, and
   then decides again knowing this robot's new plan or is bounded by its reach;
2. the step of :class:`services.ros2.controller.Ros2Controller`, every
   neighbour a moving obstacle (its exact arcs, then standing where they end);
3. inside it, the check of the first input
   (:meth:`services.ros2.neighbours.Neighbours.path_is_safe`) along the exact
   arc of the whole sample; if it fails, the shifted plan if that passes, else
   the robot stands still, which is always safe: a neighbour deciding later
   keeps out of where it stops, one deciding at about the same time kept out of
   it already (this robot's previous arc, then standing); the rules see what
   the robot applied, as in lockstep. A robot held by a neighbour deciding at
   about its instants shifts its own and announces it (a standing plan
   stamped a sample before its new instant);
4. the plan is sent at once, the command at ``T_k``.

Every robot of a fleet uses the same ``--lead`` (it tells when a neighbour
decides). The safety argument is per pair: at every instant the robot that
decided last knew the other's motion up to then and kept the distance from it.

The command is republished at ``--cmd-rate`` Hz (default 20: well inside the
0.5 s ``cmd_vel_timeout`` of ROS 2 Jazzy's diff_drive_controller) holding the
sample's input, so a base's command timeout never fires in a normal run. It is
zero when the odometry is older than ``--odom-timeout`` (checked continuously),
when the plan exchange is lost (the sqpmpc session has no link left after it had
one: neighbours can no longer see this robot's plans), at the end and on
SIGINT/SIGTERM; an odometry stamped more than ``--odom-future`` s after its
arrival is refused and counted (``odometry_future``): one such message would
otherwise be taken as the newest until its stamp; while the odometry is
stale it publishes at each instant a plan standing where odometry and commands put
it, stamped at that instant. A neighbour without a plan yet is unknown (not running);
one whose token disappears (it stopped, commanding zero) is held where its last plan
put it, standing still.
Before moving, the robot waits up to ``--timeout`` for every alive neighbour's plan.

**A neighbour leaves for good.** There is no plant to say who left: each controller
judges from the liveliness it sees. A neighbour whose controller's token has been away for
``--rejoin-timeout`` s (default 30, as the plant's) is told to the controller as departed
(:meth:`~sqpmpc.control.pipeline.ControllerPipeline.update_departed`, with every such
neighbour), at a sample boundary of this robot's own loop (the liveliness event is handled
on the main thread, between samples, as every event); the coordination rule
(:mod:`sqpmpc.rules.coordination`) then plans again with it standing where it is
(``coordination_departures`` in the final counts). A neighbour whose token comes back is
taking part again from the next sample: told so, it is planned to its goal again. Each
change is logged once. The controllers of a fleet decide this at slightly different
instants (each its own phase, each when its own session saw the token go) and from
slightly different estimates (each robot's own odometry, the neighbours' plans): for a
while one may execute the new plan and another the old one. Safety does not depend on
it: the collision rows and the check of every input keep each pair apart whatever plan
each one executes, and the departed robot is held where its last plan put it, standing,
as every neighbour that left. The new plan is a function of the vertices nearest to the
robots (:func:`sqpmpc.coordination.fleet.replan_from_positions`), so controllers that see
the same vertex configuration make the same plan; ones that see a robot nearer another
vertex may plan differently, and then each executes its own plan, as after a re-plan when
progress stops.
"""

from __future__ import annotations

import argparse
import logging
import math
import random
import threading
import time
from collections import deque
from dataclasses import replace
from pathlib import Path

import numpy as np
import zenoh

from sqpmpc.problem.scenario import Scenario

from ..control import controller_settings
from ..messages import Message, PlanMsg, encode
from ..node import POLL, Node
from ..priority import Priority
from . import msgs
from .controller import Ros2Controller
from .graph import Received, Ros2Node
from .neighbours import MIN_SPACING, Neighbours
from .options import MAX_CMD_RATE, check_margin, odom_timeout, ros2_config, ros2_problem
from .startup import PUBLISH_SLACK, StartUp
from .stream import CommandStream
from .timing import own_motion

__all__ = ["Ros2Robot", "main_ros2"]

log = logging.getLogger(__name__)

ROW_MARGIN_FACTOR = 3.0
"""The QP's collision margin is at least this many times ``--ros2-margin`` (plus, under
acceleration limits, what :func:`services.ros2.options.check_margin` adds)."""
WATCH_PERIOD = 1.0 / MAX_CMD_RATE
"""How often the watchdog thread looks at the odometry's age (and republishes), s."""
STOP_GRACE = 0.01
"""Seconds after a sample's instant without its command before the robot is stopped."""
CLOSE_GRACE = 0.05
"""Seconds between the last zero on cmd_vel and the ROS 2 session's close."""
LINK_PERIOD = 0.1
"""How often the watchdog thread looks whether the plan exchange still has a link, s."""


class Ros2Robot(StartUp, Node):
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
        ros_config = ros2_config(args)  # a bad file: one error before any session opens
        self.robot_id = int(args.id[0])
        settings = controller_settings(args, scenario)
        # the QP keeps more room than the check asks for (the check is continuous, the
        # QP's rows are at the stage instants)
        self.check_margin = check_margin(args.ros2_margin, scenario)
        settings = replace(settings, collision_margin=max(
            settings.collision_margin, self.check_margin
            + (ROW_MARGIN_FACTOR - 1.0) * float(args.ros2_margin)))
        self.controller = Ros2Controller(scenario, self.robot_id, settings)
        # stage-one-override on the obstacle rows too: a stage-1 row the current positions
        # violate is capped at the current gap, so standing still stays feasible
        self.controller.collisions.stage_one_rule_for_obstacles = True
        # --priority auto by default, as every service (services.priority). No rate limit
        # by default: through a router, a per-key limit drops a robot's own plans with a
        # flood on its key (one link carries both): neighbours lost sight of the robot and
        # collided with it (docs/ros2.md, Protections); --max-rate opts in
        if getattr(args, "priority", None) is None:
            args.priority = Priority("auto")
        super().__init__(scenario, args, f"robot/{self.robot_id}", "decentralized")
        self.index = scenario.index_of(self.robot_id)
        self.Ts = scenario.sample_time
        self.lead = args.lead if args.lead is not None else 0.3 * self.Ts
        self.neighbours = Neighbours(self.ids, self.robot_id,
                                     scenario.required_distances()[self.index], self.Ts,
                                     scenario.horizon, float(self.controller.context.max_speed),
                                     self.lead, args.ros2_guard, self.check_margin,
                                     keep_current=scenario.bounds.dynamic_limits,
                                     input_bounds=(scenario.bounds.input_lower(),
                                                   scenario.bounds.input_upper()),
                                     tolerance=args.plan_tolerance)
        self.controller.neighbours = self.neighbours  # its first-input check is the robot's
        self.limits = (scenario.bounds.acceleration_lower(),
                       scenario.bounds.acceleration_upper()) \
            if scenario.bounds.dynamic_limits else None
        """Acceleration limits ``(lower, upper)`` of ``(v, omega)`` (CONTRACT 1c), or ``None``."""
        self.odom_timeout = odom_timeout(args, scenario)
        self.timeout = float(args.timeout)
        self.startup_timeout = args.startup_timeout
        self.epoch = args.epoch
        self.epoch_file: Path | None = args.epoch_file
        self.counts = {"samples": 0, "brakes": 0, "shifted_plans": 0, "phase_shifts": 0,
                       "late_samples": 0, "plan_waits": 0, "stopped_late": 0,
                       "stale_odometry": 0, "odometry_future": 0,
                       "plan_network_lost": 0, "republished": 0, "skipped_samples": 0}
        self.cmd_period = 1.0 / args.cmd_rate if args.cmd_rate > 0.0 else None
        """Period of the command stream (``--cmd-rate``), s; ``None``: once per sample."""
        self.odom_future = float(args.odom_future)
        self.rejoin_timeout = float(args.rejoin_timeout)
        """A neighbour's controller gone this long has left for good (``--rejoin-timeout``),
        s."""
        self.departed: frozenset[int] = frozenset()
        """The neighbours the controller was told left for good (:meth:`update_departed`)."""
        self.gone_since: dict[int, float] = {}
        """Wall time at which each neighbour's controller token went away (not back since), s."""
        self._last_stamp = -math.inf  # of the last plan sent
        self._linked = False  # the plan exchange had a link
        self._lost = False  # ... and has none now
        self._lock = threading.Lock()
        self._odom: tuple[float, np.ndarray, float, float] | None = None  # t, pose, v, w
        self._frame = ("odom", "base_link")
        self._step_seconds: deque[float] = deque(maxlen=10)  # the recent steps' durations
        self._braked = False
        self._standing: np.ndarray | None = None
        self._done = False
        ns = args.ros2_namespace or f"/robot{self.robot_id}"
        self.twist_stamped = bool(args.twist_stamped)
        self.ros_session = zenoh.open(ros_config)
        try:
            self.ros = Ros2Node(self.ros_session, f"sqpmpc_robot{self.robot_id}", ns,
                                args.ros2_domain)
            self.ros.subscribe("odom", "nav_msgs/msg/Odometry", self._on_odom)
            self.stream = CommandStream(self.ros.publisher(
                "cmd_vel", "geometry_msgs/msg/TwistStamped" if self.twist_stamped
                else "geometry_msgs/msg/Twist"), self.twist_stamped, self.cmd_period,
                lambda: self._frame[1])
            self._cmd_lock = self.stream.lock  # the main thread, stop timer and watchdog
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
        if stamp > rec.arrival + self.odom_future:  # it would be the newest until then
            with self._lock:
                self.counts["odometry_future"] += 1
                first = self.counts["odometry_future"] == 1
            if first:
                log.warning("%s: refused an odometry stamped %.3f s in the future (more than "
                            "--odom-future %g s; counted as odometry_future)", self.name,
                            stamp - rec.arrival, self.odom_future)
            return
        # the stamp if it is plausible (same clock), else the arrival
        t = stamp if stamp > rec.arrival - 1.0 else rec.arrival
        with self._lock:
            if self._odom is None or t > self._odom[0]:
                self._odom = (t, pose, v, w)
                self._frame = (o.header.frame_id or "odom", o.child_frame_id or "base_link")

    def on_message(self, kind: str, msg: Message) -> None:
        if isinstance(msg, PlanMsg):
            first = msg.id not in self.neighbours.untrusted
            why = self.neighbours.add(msg, time.time())
            if why is not None and first:
                log.warning("%s: robot %d is untrusted from now on: its plan is %s (its "
                            "refused plans never kept, a second claim kept out of too)",
                            self.name, msg.id, why)

    def on_liveliness(self, name: str, alive: bool) -> None:
        """A neighbour's controller came or went (the main thread, between samples): one
        that went is held where its last plan put it and, gone ``--rejoin-timeout`` s,
        told departed at a sample boundary (:meth:`update_departed`); one that came is
        taking part again."""
        if not name.startswith("robot/"):
            return
        try:
            rid = int(name.split("/", 1)[1])
        except ValueError:
            return
        if rid == self.robot_id or rid not in self.ids:
            return
        now = time.time()
        if alive:
            self.gone_since.pop(rid, None)
            return
        self.gone_since.setdefault(rid, now)
        self.neighbours.left(rid, now)

    def update_departed(self, at: float) -> None:
        """Tell the controller, at a sample boundary, which neighbours left for good: those
        whose controller's token has been away for ``--rejoin-timeout`` s at wall time
        ``at`` (one back is taking part again); each change is logged once."""
        departed = frozenset(rid for rid, since in self.gone_since.items()
                             if at - since >= self.rejoin_timeout)
        if departed == self.departed:
            return
        left, back = sorted(departed - self.departed), sorted(self.departed - departed)
        self.controller.update_departed(sorted(departed))
        self.departed = departed
        for rid in left:
            log.warning("%s: robot %d's controller has been gone for %g s (--rejoin-timeout):"
                        " it left for good, planned standing where it is", self.name, rid,
                        self.rejoin_timeout)
        for rid in back:
            log.info("%s: robot %d's controller is back: taking part again", self.name, rid)

    def own_state(self, t: float) -> np.ndarray | None:
        """The own pose at wall time ``t`` from the newest odometry and the commands sent
        since (``None``: no odometry yet)."""
        motion = self.own_motion(t)
        return None if motion is None else motion[0]

    def own_motion(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The own pose and velocities ``(v, omega)`` at wall time ``t``
        (:func:`services.ros2.timing.own_motion`: the newest odometry carried forward with
        the commands sent since, ramping under the scenario's acceleration limits);
        ``None``: no odometry yet."""
        with self._lock:
            if self._odom is None:
                return None
            odom = self._odom
        return own_motion(odom, list(self.stream.sent), t, self.Ts, self.limits)

    def controller_states(self, others: np.ndarray, t: float) -> np.ndarray:
        """The controller's measured states at wall time ``t``: the neighbours' poses
        ``others`` ``(n, 3)`` with the own row replaced by the own pose, and, when the
        robots have velocity states (acceleration limits, CONTRACT 1c), ``(n, 5)`` with
        the own velocities appended (the neighbours' velocity columns are zero: the
        controller takes a neighbour's motion from its plan)."""
        pose, vel = self.own_motion(t)
        if self.limits is None:
            out = np.array(others, dtype=float)
            out[self.index] = pose
            return out
        out = np.zeros((others.shape[0], 5))
        out[:, :3] = others
        out[self.index] = (*pose, *vel)
        return out

    def odometry_age(self, now: float) -> float:
        """Seconds since the newest odometry (infinite: none yet)."""
        with self._lock:
            return math.inf if self._odom is None else now - self._odom[0]

    # ------------------------------------------------------------------ outputs
    def command(self, v: float, omega: float, at: float) -> None:
        """Send ``(v, omega)`` on cmd_vel now and hold it (:mod:`services.ros2.stream`)."""
        with self._lock:  # the commands since the newest odometry (own_state needs all)
            since = -math.inf if self._odom is None else self._odom[0]
        self.stream.command(v, omega, at, since)

    def publish_plan(self, sample: int, stamp: float, states: np.ndarray,
                     inputs: np.ndarray) -> None:
        """The plan to the neighbours (sqpmpc keys) and as a Path on ``NS/plan``; a plan
        stamped before the last one sent (a stop announced inside a sample already
        planned) is stamped with the last one's instead, a standing one at least
        :data:`~services.ros2.neighbours.MIN_SPACING` samples after it: the stamps never go
        back nor crowd (:meth:`services.ros2.neighbours.Neighbours.add`)."""
        standing = not np.asarray(inputs)[0].any()
        # a standing plan at most every MIN_SPACING Ts (true: it stands from then on too)
        stamp = max(stamp, self._last_stamp + (MIN_SPACING * self.Ts if standing else 0.0))
        self._last_stamp = stamp
        self.neighbours.sent(stamp, states, inputs)  # where it is: no neighbour stands there
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

    def brake(self, now: float, sample: int, stamp: float | None = None) -> None:
        """Zero on cmd_vel now; a plan standing where it is, stamped ``stamp`` (or now)."""
        self.command(0.0, 0.0, now)
        state = self.own_state(now)
        if state is not None:
            N = self.scenario.horizon
            self.publish_plan(sample, now if stamp is None else max(stamp, now),
                              np.repeat(state[None], N + 1, axis=0), np.zeros((N, 2)))

    def _stop_if_stale(self) -> bool:
        """Command zero at once if the odometry is stale and the robot is not braked yet
        (the watchdog thread and the main loop); ``True`` if it did."""
        with self._cmd_lock:
            now = time.time()
            if self._braked or self.odometry_age(now) <= self.odom_timeout:
                return False
            self._braked = True
            self.counts["stale_odometry"] += 1
            self.command(0.0, 0.0, now)
        log.warning("%s: odometry %.3f s old: commanding zero", self.name,
                    self.odometry_age(now))
        return True

    def _watchdog(self) -> None:
        """A thread: stop the robot within ``WATCH_PERIOD`` of its odometry going stale
        and within :data:`LINK_PERIOD` of its plan exchange losing its last link, whatever
        the main loop is doing (a long step, a stalled process); republish the command in
        force every ``--cmd-rate`` period."""
        looked = 0.0
        while not self.stop.wait(WATCH_PERIOD) and not self._done:
            now = time.time()
            self._stop_if_stale()
            if now - looked >= LINK_PERIOD:
                looked = now
                self._stop_if_lost()
            if self.stream.republish(time.time()):
                self.counts["republished"] += 1

    def _watch(self, until: float, sample: int) -> None:
        """Handle events until wall time ``until``; when the odometry has gone stale,
        publish a plan standing where the robot stopped."""
        while not self.stop.is_set():
            now = time.time()
            if self._stop_if_stale():
                self.brake(now, sample)
            if now >= until:
                return
            self.pump(min(POLL, max(until - now, 0.0), 0.01))

    # ------------------------------------------------------------------ loop
    def run(self) -> int:
        """Serve until ``t_end``, SIGINT or SIGTERM; returns the exit status."""
        self.start([("robot", i, "plan") for i in self.neighbours.plans])
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
        watchdog = threading.Thread(target=self._watchdog, name="odometry-watchdog",
                                    daemon=True)
        watchdog.start()
        self.raise_priority()  # every thread, the watchdog's too (services.priority)
        try:
            while not self.stop.is_set():
                Tk = T0 + k * self.Ts
                if Tk > end:
                    break
                self._watch(Tk - self.lead, k)
                if self.stop.is_set():
                    break
                self._await_plans(Tk)
                self.update_departed(Tk)
                self._step(k, Tk)
                k += 1
                if self.neighbours.blocked_by_concurrent:  # by a neighbour deciding at
                    # about the same instants, as every sample: move away from them
                    self.neighbours.blocked_by_concurrent = False
                    self.counts["phase_shifts"] += 1
                    shift = random.uniform(0.2, 0.4) * self.Ts
                    T0 += shift
                    if self._standing is not None:  # it stands until its new instant
                        self._announce_shift(k - 1, T0 + (k - 1) * self.Ts)
                behind = time.time() + self.lead - (T0 + k * self.Ts)
                if behind > 0.0:  # overran: skip to the next instant still ahead
                    skipped = math.ceil(behind / self.Ts)
                    self.counts["skipped_samples"] += skipped
                    k += skipped
        finally:
            self._done = True
            self.stream.finish(time.time())  # zero, no repeat after it
        counts = {**self.counts, "zero_commands": self.stream.zero_commands,
                  "plans_received": self.neighbours.received,
                  "plans_refused": self.neighbours.refused,
                  "false_plans": sum(self.neighbours.untrusted.values())}
        # the controller's own (fallbacks, the rules': coordination_departures, ...); a name
        # the robot counts too ("samples": the controller's steps) keeps the robot's
        counts.update((key, value) for key, value in self.controller.counters().items()
                      if key not in counts)
        for rid, n in sorted(self.neighbours.untrusted.items()):
            log.warning("%s: untrusted robot %d: %d false plans refused (first: %s)",
                        self.name, rid, n, self.neighbours.reasons[rid])
        log.info("%s: %s, %d invalid messages dropped", self.name,
                 ", ".join(f"{v} {k}" for k, v in counts.items()), self.validator.invalid)
        return 0

    def _step(self, k: int, Tk: float) -> None:
        """Compute sample ``k`` (instant ``Tk``), send the plan, the command at ``Tk``."""
        now = time.time()
        if self.odometry_age(now) > self.odom_timeout or self._lost:
            # braked while stale or cut off; its plan stamped at Tk as every plan, not a
            # lead early
            self.brake(now, k, Tk)
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
            others, plans = self.neighbours.for_controller(Tk, k)
            states = self.controller_states(others, Tk)
            own = states[self.index, :3]
            self.neighbours.blocked_by_concurrent = False
            self._standing = None  # where it stands this sample, if so
            self.controller.check_time = Tk
            started = time.perf_counter()
            out = self.controller.step(k, Tk - self.epoch, states, plans, None)
            self._step_seconds.append(time.perf_counter() - started)
            late = time.time() > Tk - PUBLISH_SLACK
            if not late and out.fallback != "brake":  # the input (or the shifted plan's)
                u = out.inputs[0]  # passed the check (Ros2Controller.first_input_safe)
                plan = self.controller.published
                self.publish_plan(k, Tk, plan.states, plan.inputs)
                self.neighbours.blocked_by_concurrent = False  # it moves: no phase shift
                if out.fallback is not None:
                    self.counts["shifted_plans"] += 1
            else:  # standing still is safe: every neighbour keeps out of where it stops
                u = np.zeros(2)
                self._standing = own.copy()
                self.counts["late_samples" if late else "brakes"] += 1
                N = self.scenario.horizon
                self.publish_plan(k, Tk, np.repeat(own[None], N + 1, axis=0),
                                  np.zeros((N, 2)))
            self._watch(Tk, k)
            with self._cmd_lock:  # the watchdog cannot stop it in between
                if self._braked or self._lost:  # the odometry went stale or the plan
                    return  # exchange was lost meanwhile: the zero stands
                sent.set()
                self.command(float(u[0]), float(u[1]), time.time())
            self.counts["samples"] += 1
        finally:
            timer.cancel()

    def close(self) -> None:
        """Zero on cmd_vel once more (given time to leave: a put just before the session
        closes can be lost), undeclare the ROS 2 node, close both sessions."""
        try:
            self.stream.finish(time.time())
            time.sleep(CLOSE_GRACE)
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

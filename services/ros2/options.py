"""The ``--ros2`` options of ``sqpmpc robot`` (CONTRACT 4) and their checks."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import zenoh

from sqpmpc.cli.options import nonnegative_float, positive_float
from sqpmpc.errors import ProblemError
from sqpmpc.problem.plant import model_margin
from sqpmpc.problem.scenario import Scenario

from ..node import options_of
from ..presence import REJOIN_TIMEOUT
from .graph import check_name

__all__ = ["MAX_CMD_RATE", "add_ros2_arguments", "check_margin", "odom_timeout", "ros2_config",
           "ros2_problem"]

MAX_CMD_RATE = 100.0
"""Highest ``--cmd-rate``, Hz: the watchdog thread that republishes looks this often."""



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
    g.add_argument("--ros2-zenoh-config", type=Path, default=None, metavar="FILE",
                   help="a Zenoh config file for the ROS 2 session, e.g. one made for an "
                        "rmw_zenoh network secured with TLS and access control (docs/ros2.md; "
                        "its connect endpoints unless --ros2-connect is given)")
    g.add_argument("--cmd-rate", type=nonnegative_float, default=20.0, metavar="HZ",
                   help="republish the command in force on cmd_vel at this rate (default 20: "
                        "well inside a base's 0.5 s command timeout; above 1/Ts, at most 100; 0: "
                        "once per sample)")
    g.add_argument("--odom-future", type=nonnegative_float, default=0.05, metavar="S",
                   help="refuse (and count) an odometry stamped more than this after its "
                        "arrival, s (default 0.05; clocks must agree within it)")
    g.add_argument("--epoch", type=float, default=None, metavar="UNIX_S",
                   help="wall time (Unix s) of the scenario's t = 0, shared by the fleet "
                        "(default: this robot's start)")
    g.add_argument("--epoch-file", type=Path, default=None, metavar="FILE",
                   help="wait (publishing standing plans) until FILE exists and holds the "
                        "epoch in Unix s: a launcher starts the fleet's clock once every "
                        "controller is up")
    g.add_argument("--odom-timeout", type=positive_float, default=None, metavar="S",
                   help="odometry older than this is stale: command zero at once (default "
                        "0.6 Ts; below Ts: zero within one sample)")
    g.add_argument("--lead", type=positive_float, default=None, metavar="S",
                   help="start each sample's computation this long before its instant "
                        "(default 0.3 Ts)")
    g.add_argument("--ros2-margin", type=nonnegative_float, default=0.02, metavar="M",
                   help="added to every required distance in the check of each input: "
                        "odometry and timing errors, m (default 0.02)")
    g.add_argument("--plan-tolerance", type=nonnegative_float, default=0.05, metavar="M",
                   help="a neighbour's plan must start within this (plus the check's margin) "
                        "of where its past plans put it, else it is refused and the "
                        "neighbour untrusted, m (default 0.05)")
    g.add_argument("--rejoin-timeout", type=positive_float, default=REJOIN_TIMEOUT,
                   metavar="S",
                   help="a neighbour's controller gone (its liveliness token away) this long "
                        "has left for good: this controller plans without it (it stands "
                        "where it is, the coordination rule plans around it) until it is "
                        f"back, s (default {REJOIN_TIMEOUT:g}, as the plant's)")
    g.add_argument("--ros2-guard", type=nonnegative_float, default=0.02, metavar="S",
                   help="bound on the clock offset between robots, s (default 0.02): a "
                        "neighbour deciding less than this after this robot's check is held "
                        "by its reach (every robot of a fleet uses the same --lead)")


def odom_timeout(args: argparse.Namespace, scenario: Scenario) -> float:
    """``--odom-timeout``, s: given, else 0.6 Ts (0.3 s at the paper's Ts = 0.5 s)."""
    return float(args.odom_timeout) if args.odom_timeout is not None else \
        0.6 * scenario.sample_time


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
    if odom_timeout(args, scenario) >= scenario.sample_time:
        return (f"--odom-timeout: must be less than Ts = {scenario.sample_time:g} s (zero "
                f"within one sample of the odometry's loss), got {odom_timeout(args, scenario):g}")
    if lead >= scenario.sample_time:
        return f"--lead: must be less than Ts = {scenario.sample_time:g} s, got {lead:g}"
    if args.epoch is not None and args.epoch_file is not None:
        return "give --epoch or --epoch-file, not both"
    if args.ros2_zenoh_config is not None and not args.ros2_zenoh_config.is_file():
        return f"--ros2-zenoh-config {args.ros2_zenoh_config}: no such file"
    if args.cmd_rate > MAX_CMD_RATE:
        return (f"--cmd-rate: at most {MAX_CMD_RATE:g} Hz (the controller's watchdog, which "
                f"republishes, looks every {1.0 / MAX_CMD_RATE:g} s), got {args.cmd_rate:g}")
    if args.cmd_rate > 0.0 and 1.0 / args.cmd_rate >= scenario.sample_time:
        return (f"--cmd-rate: must be above 1/Ts = {1.0 / scenario.sample_time:g} Hz (or 0: "
                f"once per sample), got {args.cmd_rate:g}")
    if options_of(args).decentralized_mode != "shared":
        return "--decentralized-mode: --ros2 holds every neighbour by its own check"
    return None


def ros2_config(args: argparse.Namespace) -> zenoh.Config:
    """The ROS 2 session's Zenoh config: ``--ros2-zenoh-config`` (or an empty one), its
    connect endpoints replaced by ``--ros2-connect`` when given (default, without either,
    the router ``tcp/127.0.0.1:7447``), mode ``--ros2-zenoh-mode``, multicast scouting off.

    Raises
    ------
    ProblemError
        A config file Zenoh cannot read (one message naming the flag).
    """
    path = args.ros2_zenoh_config
    try:
        conf = zenoh.Config() if path is None else zenoh.Config.from_file(str(path))
    except (zenoh.ZError, ValueError, OSError) as exc:
        raise ProblemError(f"--ros2-zenoh-config {path}: {str(exc).split(' at /')[0]}") \
            from None
    connect = args.ros2_connect
    if connect is None:
        own = json.loads(conf.get_json("connect/endpoints"))
        has_own = path is not None and isinstance(own, list) and bool(own)
        connect = own if has_own else ["tcp/127.0.0.1:7447"]
    conf.insert_json5("mode", json.dumps(args.ros2_zenoh_mode))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    if args.ros2_zenoh_mode == "client":
        conf.insert_json5("connect/timeout_ms", "-1")  # wait for the router
    elif path is None:
        conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
    return conf


def check_margin(margin: float, scenario: Scenario) -> float:
    """The margin of the check of each input (:mod:`services.ros2.neighbours`), m:
    ``--ros2-margin`` and, under acceleration limits (CONTRACT 1c), what the check's arcs
    do not hold: the check takes a command as followed at once on its arc, the robot ramps
    to it (up to :func:`sqpmpc.problem.plant.model_margin` off the arc, for the pair), and
    a robot told to stop stands where it was only after its braking distance
    ``v^2 / (2 |a|)`` at the fastest speed."""
    bounds = scenario.bounds
    if not bounds.dynamic_limits:
        return float(margin)
    lo, hi = bounds.input_lower(), bounds.input_upper()
    alo, ahi = bounds.acceleration_lower(), bounds.acceleration_upper()
    ramp = model_margin(lo, hi, scenario.sample_time, "exact", scenario.plant, (alo, ahi))
    braking = max(hi[0] ** 2 / (2.0 * abs(alo[0])), lo[0] ** 2 / (2.0 * abs(ahi[0])))
    return float(margin) + ramp + braking

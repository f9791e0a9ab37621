"""A ROS 2 fleet as on real robots: each robot a host of its own, routers between them.

``python -m services.ros2.hosts --scenario S [--loss P] [--delay S] [--out DIR]
[--rate HZ] [--insecure] [--startup S] [--tolerance M] [--log-level L]
[controller options...]`` (root only: it makes network namespaces)

Makes a :class:`services.netns.HostLab` with one host per robot and a hub,
``--loss`` (default 0.05) of the packets dropped in each direction of every
host's link and ``--delay`` (default 0.02 s) added each way by a relay
(:mod:`services.relay`) in the hub, then runs:

- in the hub: the sqpmpc router (mutual TLS with the run's credentials,
  access control; ``--insecure``: plain TCP), a ROS 2 router (the fleet's
  graph) and the relay, which takes every host's links to both routers;
- in each robot's host: its own ROS 2 router (as ``rmw_zenohd`` on a robot;
  it joins the hub's through the relay), its simulated ROS 2 robot
  (:mod:`services.ros2.simfleet` with ``--ids``, odometry at ``--rate``) and
  its controller ``sqpmpc robot --id I --ros2``, client of the host's ROS 2
  router and, through the lossy, delayed link, of the hub's sqpmpc router.

So a plan from one robot to another crosses two links (its host's, the
other's): two relays' delays and two links' loss. The epoch (t = 0, shared as
in :mod:`services.ros2.demo`) is set once every controller's ROS 2 node is in
the hub's graph. When every controller has reached ``t_end`` the robots'
true poses are merged (``DIR/poses.json``) and checked
(:mod:`services.ros2.check`, ``DIR/check.json``; with ``--t-end`` past the
scenario's, also up to the scenario's ``t_end``: ``DIR/check-scenario-t_end.json``);
``DIR/lab.json`` holds the
lab's set-up and the packets the loss rules dropped. The namespaces are
removed at the end, also after an error, SIGINT or SIGTERM. Exit status 0
when no robot collided and every one arrived, 1 otherwise, 2 for bad input
or a machine that cannot make namespaces.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import secrets
import signal
import subprocess
import sys
import threading
import time
from dataclasses import asdict
from pathlib import Path

from sqpmpc.cli.options import Parser, nonnegative_float
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.io.recorder import prepare_output
from sqpmpc.problem.scenario_file import load_scenario

from ..children import Child, stop_children
from ..netns import HostLab, lab_problem
from ..node import install_signal_handlers
from .check import check_fleet
from .demo import Credentials, LoggedChild, add_fleet_arguments, start_clock

__all__ = ["PORTS", "build_parser", "main", "merge_poses", "probe_links"]

log = logging.getLogger("services.ros2.hosts")
PROG = "services.ros2.hosts"
PORTS = {"sqpmpc": 7447, "ros2": 7448, "echo": 7449, "relay_sqpmpc": 8447,
         "relay_ros2": 8448, "relay_echo": 8449}
"""TCP ports: the hub's routers (on its loopback), the relay's for each host's link."""


def merge_poses(parts: list[dict]) -> dict:
    """One fleet log from the hosts' ``poses.json`` (the time all of them cover)."""
    if not parts:
        raise ProblemError("no host wrote poses.json")
    epochs = {round(float(p["epoch"]), 6) for p in parts}
    if len(epochs) != 1:
        raise ProblemError(f"the hosts' fleets have different epochs: {sorted(epochs)}")
    out = {"epoch": parts[0]["epoch"], "start": max(float(p["start"]) for p in parts),
           "end": min(float(p["end"]) for p in parts), "rate": parts[0]["rate"],
           "odom_stop": {}, "robots": {}}
    for p in parts:
        out["odom_stop"].update(p.get("odom_stop", {}))
        out["robots"].update(p["robots"])
    return out


def probe_links(lab: HostLab, delay: float, count: int, env: dict[str, str],
                logs: Path) -> dict[str, dict]:
    """Measure the first and last host's links as the fleet will use them: UDP datagrams
    echoed by the hub over the link (the share lost on the round trip) and small TCP
    messages echoed through the relay (round-trip times, s). Host name -> measures."""
    py = [sys.executable, "-m", "services.relay"]
    hosts = {lab.hosts[0].index: lab.hosts[0], lab.hosts[-1].index: lab.hosts[-1]}
    children = []
    out: dict[str, dict] = {}
    try:
        for h in hosts.values():
            children.append(LoggedChild(f"hub/echo{h.index}", lab.hub_argv(
                *py, "echo", "--tcp", f"127.0.0.1:{PORTS['echo'] + h.index}", "--udp",
                f"{h.hub_address}:{PORTS['echo']}"), logs / f"hub-echo{h.index}.log", env))
        children.append(LoggedChild("hub/probe-relay", lab.hub_argv(
            *py, "relay", "--delay", repr(delay), *(a for h in hosts.values() for a in (
                "--route", f"{h.hub_address}:{PORTS['relay_echo']}=127.0.0.1:"
                           f"{PORTS['echo'] + h.index}"))), logs / "hub-probe-relay.log", env))
        time.sleep(2.0)
        for h in hosts.values():
            proc = subprocess.run(h.argv(*py, "probe", "--tcp",
                                         f"{h.hub_address}:{PORTS['relay_echo']}", "--udp",
                                         f"{h.hub_address}:{PORTS['echo']}", "--count",
                                         str(count)), capture_output=True, text=True,
                                  env=env, check=False, timeout=600)
            if proc.returncode != 0:
                raise ProblemError(f"the probe of host {h.index} failed: {proc.stderr.strip()}")
            out[f"host{h.index}"] = json.loads(proc.stdout)
    finally:
        stop_children(children, {}, 10.0)
    return out


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.ros2.hosts``."""
    p = Parser(prog=prog, description=__doc__.splitlines()[0])
    p.add_argument("--scenario", required=True, help="TOML file or built-in name")
    p.add_argument("--loss", type=nonnegative_float, default=0.05,
                   help="share of packets dropped in each direction of a host's link")
    p.add_argument("--delay", type=nonnegative_float, default=0.02,
                   help="one-way delay of a host's link, s (the hub's relay)")
    add_fleet_arguments(p, "ros2-hosts")
    p.add_argument("--probe", type=int, default=200, metavar="K",
                   help="round trips measured on the first and last host's links before the "
                        "run (0: none; default 200)")
    p.add_argument("--log-level", default="INFO", help="log level of the processes")
    return p


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit status."""
    args, extra = build_parser(prog).parse_known_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s ros2-hosts %(message)s",
                        stream=sys.stderr)
    try:
        scenario = load_scenario(args.scenario)
        if not args.loss < 1.0:
            raise ProblemError(f"--loss: expected a share below 1, got {args.loss}")
    except (ScenarioError, ProblemError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    problem = lab_problem()
    if problem:
        print(f"{prog}: error: {problem}", file=sys.stderr)
        return 2
    t_end = args.t_end or scenario.t_end
    ids = [int(i) for i in scenario.ids]
    out = args.out or Path("runs") / f"ros2-hosts-{scenario.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    try:  # the output contract of every runner: a non-empty --out only with --overwrite
        prepare_output(out, args.overwrite)
    except ProblemError as exc:
        print(f"{prog}: error: --out: {exc}", file=sys.stderr)
        return 2
    logs = out / "logs"
    run = f"ros2h-{os.getpid()}-{secrets.token_hex(3)}"
    py = [sys.executable, "-m"]
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    stop = threading.Event()
    received = install_signal_handlers(stop)
    lab = HostLab(len(ids), args.loss)
    credentials = None if args.insecure else Credentials(
        scenario, run, [h.hub_address for h in lab.hosts])
    proto = "tcp" if args.insecure else "tls"
    children: list[Child] = []
    status = 1
    links: dict[str, dict] = {}
    epoch_file = out / "epoch"
    epoch_file.unlink(missing_ok=True)
    try:
        lab.create()
        links = probe_links(lab, args.delay, args.probe, env, logs) if args.probe > 0 else {}

        def start(name: str, argv: list[str], logfile: Path, identity: str) -> LoggedChild:
            if credentials is None:
                return LoggedChild(name, argv, logfile, env)
            return credentials.start(name, argv, logfile, identity, env)

        quiet = ["--log-level", "WARNING"]
        children.append(start("hub/router", lab.hub_argv(
            *py, "services.router", "--listen", f"{proto}/127.0.0.1:{PORTS['sqpmpc']}",
            *quiet), logs / "hub-router.log", "router"))
        children.append(LoggedChild("hub/ros2-router", lab.hub_argv(
            *py, "services.router", "--listen", f"tcp/127.0.0.1:{PORTS['ros2']}", "--listen",
            f"tcp/{lab.hub_address}:{PORTS['ros2']}", *quiet), logs / "hub-ros2-router.log",
            env))
        routes = []
        for h in lab.hosts:
            routes += ["--route", f"{h.hub_address}:{PORTS['relay_sqpmpc']}=127.0.0.1:"
                                  f"{PORTS['sqpmpc']}",
                       "--route", f"{h.hub_address}:{PORTS['relay_ros2']}=127.0.0.1:"
                                  f"{PORTS['ros2']}"]
        children.append(LoggedChild("hub/relay", lab.hub_argv(
            *py, "services.relay", "relay", "--delay", repr(args.delay), *routes),
            logs / "hub-relay.log", env))
        robots = []
        for rid, h in zip(ids, lab.hosts, strict=True):
            local = f"tcp/127.0.0.1:{PORTS['ros2']}"
            children.append(LoggedChild(f"host{rid}/ros2-router", h.argv(
                *py, "services.router", "--listen", local, "--connect",
                f"tcp/{h.hub_address}:{PORTS['relay_ros2']}", *quiet),
                logs / f"host{rid}-ros2-router.log", env))
            children.append(LoggedChild(f"host{rid}/simfleet", h.argv(
                *py, "services.ros2.simfleet", "--scenario", args.scenario, "--ids", str(rid),
                "--router", f"127.0.0.1:{PORTS['ros2']}", "--out", str(out / f"host{rid}"),
                "--rate", repr(args.rate), "--seed", str(rid), "--epoch-file",
                str(epoch_file), "--log-level", args.log_level),
                logs / f"host{rid}-simfleet.log", env))
            robots.append(start(f"robot/{rid}", h.argv(
                *py, "services.robot", "--id", str(rid), "--scenario", args.scenario,
                "--t-end", repr(t_end), "--run", run, "--ros2", "--ros2-connect", local,
                "--zenoh-mode", "client", "--connect",
                f"{proto}/{h.hub_address}:{PORTS['relay_sqpmpc']}", "--epoch-file",
                str(epoch_file), "--log-level", args.log_level, *extra,
                *(["--insecure"] if credentials is None else [])),
                logs / f"robot-{rid}.log", f"robot-{rid}"))
        children.extend(robots)
        log.info("%d hosts, loss %g each way per link, delay %g s each way; logs in %s",
                 len(ids), args.loss, args.delay, logs)
        if not start_clock(f"tcp/{lab.hub_address}:{PORTS['ros2']}", ids, epoch_file,
                           args.startup, stop):
            log.error("the controllers were not all up within %g s (see %s)", args.startup,
                      logs)
        while not stop.is_set() and any(r.poll() is None for r in robots):
            time.sleep(0.2)
        failed = [r.name for r in robots if r.poll() not in (None, 0)]
        if failed:
            log.warning("controllers that failed: %s (see %s)", failed, logs)
        status = 128 + received["signal"] if stop.is_set() else (1 if failed else 0)
    except ProblemError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        status = 2
    finally:
        stop_children([c for c in children if c.name.startswith("robot/")], {}, 10.0)
        stop_children([c for c in children if c.name.endswith("simfleet")],
                      {c.name: signal.SIGINT for c in children}, 30.0)
        stop_children([c for c in children if c.name.startswith(("hub/", "host"))], {}, 10.0)
        try:
            packets = lab.packets() if status != 2 else {}
        except ProblemError:
            packets = {}
        lab.close()
        (out / "lab.json").write_text(json.dumps(
            {"hosts": len(ids), "loss": args.loss, "delay": args.delay, "t_end": t_end,
             "scenario_t_end": scenario.t_end,
             "packets": {str(k): {"total": t, "dropped": d} for k, (t, d) in packets.items()},
             "probes": links}, indent=1))
    if status == 2:
        return 2
    files = [out / f"host{rid}" / "poses.json" for rid in ids]
    missing = [str(f) for f in files if not f.exists()]
    if missing:
        log.error("hosts wrote no poses: %s (see %s)", missing, logs)
        return status or 1
    data = merge_poses([json.loads(f.read_text()) for f in files])
    (out / "poses.json").write_text(json.dumps(data))
    result = check_fleet(data, scenario, args.tolerance)
    (out / "check.json").write_text(json.dumps(asdict(result), indent=1))
    if t_end > scenario.t_end and data["epoch"] + scenario.t_end < data["end"]:
        # the same run cut at the scenario's own t_end: who had arrived by then
        cut = check_fleet({**data, "end": data["epoch"] + scenario.t_end}, scenario,
                          args.tolerance)
        (out / "check-scenario-t_end.json").write_text(json.dumps(asdict(cut), indent=1))
        print(f"by the scenario's t_end {scenario.t_end:g} s: {cut.arrived}/{cut.robots} "
              f"within {cut.tolerance:g} m")
    print(f"{result.robots} robots on {len(ids)} hosts: {result.collisions} collisions "
          f"(certified clearance {result.certified_clearance:.4f} m), "
          f"{result.arrived}/{result.robots} within {result.tolerance:g} m (largest "
          f"{max(result.final_errors.values()):.3f} m)")
    print(f"wrote {out}")
    return status if status else (0 if result.ok else 1)


if __name__ == "__main__":
    sys.exit(main())

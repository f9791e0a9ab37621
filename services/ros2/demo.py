"""A ROS 2 fleet on this machine: simulated ROS 2 robots, one ``sqpmpc robot --ros2`` each.

``python -m services.ros2.demo --scenario S [--out DIR] [--t-end T] [--rate HZ]
[--odom-stop ID:T] [--twist-stamped] [--insecure] [--cmd-timeout S]
[--attack KIND:ID] [--kill ID:T[:R]] [--log-level L] [controller options...]``
(also ``sqpmpc launch --ros2-demo ...``)

Starts, as processes on loopback (multicast scouting off):

- the ROS 2 side's Zenoh router (plain TCP, as ``rmw_zenohd``);
- the simulated robots (:mod:`services.ros2.simfleet`, written with
  zenoh-ros2-sdk), odometry at ``--rate`` Hz (default 50) with phases of
  their own;
- the sqpmpc side's router with the run's credentials (mutual TLS, access
  control; ``--insecure``: plain TCP), for the plans. As :mod:`services.launch`,
  the demo issues them in its memory, only the identities used (``router``,
  ``robot-<id>``), and hands each child only its own over an inherited socket
  (:mod:`services.handover`): no key is written to disk;
- one controller process per robot, ``sqpmpc robot --id I --ros2`` (client of
  both routers; its sample loop at ``--priority auto``, the simulated robots and the
  routers put at the same priority once the fleet is up: they stand in for the
  robots' own real-time drive controllers), all with the same epoch (t = 0 of the
  references, a few seconds after the start: every controller is up by then) and each
  with a random phase of its sample instants.

Options it does not know are given to every controller (e.g.
``--collision-margin 0.02``). When every controller has reached ``t_end`` the
fleet writes the true poses and :mod:`services.ros2.check` measures them
(``DIR/poses.json``, ``DIR/check.json``, the processes' logs in ``DIR/logs``); the folder
also holds what every runner writes (``metrics.json``, ``trajectory.npz``,
``record.msgpack``, ``recording.mcap``, the plots after the summary:
:mod:`services.ros2.record`); its ``metrics.json`` also holds ``insecure`` (true with
``--insecure``) and ``controller_counts`` (every controller's final counts added up, e.g.
``odometry_future``, ``stale_odometry``, ``plan_network_lost``). A non-empty ``--out`` is
refused unless ``--overwrite``.
Exit status 0 when no robot collided and every one arrived, 1 otherwise, 2 for
bad input.
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
from collections.abc import Callable, Sequence
from dataclasses import asdict
from pathlib import Path

from sqpmpc.cli.options import Parser, nonnegative_float, positive_float
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.io.files import write_plots, write_run
from sqpmpc.io.recorder import owner_hint, prepare_output
from sqpmpc.io.reporting import summarize
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import load_scenario

from ..children import Child, free_ports, stop_children
from ..credentials import issue
from ..handover import Handover, make_private
from ..node import install_signal_handlers
from ..priority import NICE, RT_PRIORITY
from .check import check_fleet
from .record import controller_counts, fleet_record

__all__ = ["Credentials", "LoggedChild", "add_fleet_arguments", "build_parser", "main",
           "robot_side_priority", "start_clock"]

log = logging.getLogger("services.ros2.demo")
PROG = "services.ros2.demo"
PROGRESS_EVERY = 5.0
"""Seconds between two progress lines while the controllers start and the fleet runs."""


class LoggedChild(Child):
    """A :class:`services.children.Child` whose stderr goes to a file."""

    def __init__(self, name: str, argv: list[str], logfile: Path,
                 env: dict[str, str] | None = None, pass_fds: tuple[int, ...] = ()) -> None:
        self.name = name
        self.argv = argv
        self.reported = False
        logfile.parent.mkdir(parents=True, exist_ok=True)
        with open(logfile, "wb") as err:
            self.proc = subprocess.Popen(argv, process_group=0, env=env, stderr=err,
                                         stdout=err, pass_fds=pass_fds)


class Credentials:
    """The demo's credentials, in its memory only (as :mod:`services.launch`): the sqpmpc
    side's ``router`` and one ``robot-<id>`` per controller (no ``plant``: there is none),
    each child handed only its own over an inherited socket (:mod:`services.handover`)."""

    def __init__(self, scenario: Scenario, run: str, hosts: Sequence[str] = ()) -> None:
        make_private()  # it holds every identity's key for a moment
        names = ["router", *(f"robot-{int(i)}" for i in scenario.ids)]
        # hosts: addresses the certificates are also valid for (the router's, as dialled)
        self.issued = issue(scenario, run, names, hosts)
        self.handover = Handover(self.issued.meta)

    def start(self, name: str, argv: list[str], logfile: Path, identity: str,
              env: dict[str, str]) -> LoggedChild:
        """Start a child that receives ``identity``'s credentials (``--credentials-fd``)."""
        fd = self.handover.child_end({identity: self.issued.config(identity)})
        try:
            return LoggedChild(name, [*argv, "--credentials-fd", str(fd)], logfile, env, (fd,))
        finally:
            self.handover.started()


def robot_side_priority(children: Sequence[Child]) -> str:
    """Put every thread of ``children`` (the simulated robots and the routers: what stands
    in for the robots' own real-time drive controllers and their middleware) at the
    controllers' ``--priority auto`` (:mod:`services.priority`), once the fleet is up;
    returns what was done."""
    done = "normal priority (neither SCHED_RR nor a negative nice is permitted)"
    for child in children:
        try:
            tids = [int(t) for t in os.listdir(f"/proc/{child.proc.pid}/task")]
        except OSError:
            continue
        for tid in tids:
            try:
                os.sched_setscheduler(tid, os.SCHED_RR, os.sched_param(RT_PRIORITY))
                done = f"SCHED_RR priority {RT_PRIORITY}"
            except PermissionError:
                try:
                    os.setpriority(os.PRIO_PROCESS, tid, NICE)
                    done = f"nice {NICE}"
                except PermissionError:
                    pass
            except ProcessLookupError:
                pass
    return done


def start_clock(endpoint: str, ids: list[int], epoch_file: Path, timeout: float,
                stop: threading.Event, gone: Callable[[], list[str]] = list) -> bool:
    """Once every controller's ROS 2 node is in the graph (seen on the ROS 2 router at
    ``endpoint``), write the epoch (2 s from then) into ``epoch_file``; ``False`` if not all
    came in time or a controller ended before (``gone``: the names of the controllers that
    ended; the epoch is written all the same)."""
    import zenoh

    from ..transport import make_config

    wanted = {f"sqpmpc_robot{i}" for i in ids}
    seen: set[str] = set()
    lock = threading.Lock()

    def on_token(sample: zenoh.Sample) -> None:
        parts = str(sample.key_expr).split("/")
        if len(parts) == 9 and parts[5] == "NN":
            with lock:
                seen.add(parts[8])

    deadline = time.time() + timeout
    done = threading.Event()

    def lines() -> None:  # a line every few seconds, also while the session connects
        t0 = time.monotonic()
        while not done.wait(PROGRESS_EVERY):
            with lock:
                up = len(wanted & seen)
            log.info("waiting for the controllers' ROS 2 nodes: %d/%d up after %.0f s", up,
                     len(wanted), time.monotonic() - t0)

    heartbeat = threading.Thread(target=lines, daemon=True)
    heartbeat.start()
    try:
        with zenoh.open(make_config((), [endpoint], "client")) as session:
            sub = session.liveliness().declare_subscriber("@ros2_lv/**", on_token,
                                                          history=True)
            while not stop.is_set() and time.time() < deadline and not gone():
                with lock:
                    if wanted <= seen:
                        break
                time.sleep(0.2)
            sub.undeclare()
    finally:
        done.set()
        heartbeat.join()
    ok = wanted <= seen
    tmp = epoch_file.with_suffix(".tmp")
    tmp.write_text(repr(time.time() + 2.0))
    tmp.replace(epoch_file)
    return ok


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.ros2.demo``."""
    p = Parser(prog=prog, description=__doc__.splitlines()[0])
    p.add_argument("--scenario", required=True, help="TOML file or built-in name")
    add_fleet_arguments(p, "ros2")
    p.add_argument("--odom-stop", action="append", default=[], metavar="ID:T",
                   help="robot ID's odometry stops at t = T s (repeatable)")
    p.add_argument("--twist-stamped", action="store_true", help="cmd_vel as TwistStamped")
    p.add_argument("--cmd-timeout", type=nonnegative_float, default=0.5, metavar="S",
                   help="the simulated robots stop when no command came for S s (default "
                        "0.5, diff_drive_controller's; 0: never)")
    p.add_argument("--attack", default=None, metavar="KIND:ID",
                   help="benchmarks: once the clock starts, a services.forger with robot ID's "
                        "own credentials sends KIND (freeze, herd or flood) until the end")
    p.add_argument("--kill", action="append", default=[], metavar="ID:T[:R]",
                   help="kill -9 robot ID's controller at t = T s and start it again R s "
                        "later (default 3; it rejoins with credentials handed over anew)")
    p.add_argument("--log-level", default="INFO", help="log level of the processes")
    return p


def _faults(args: argparse.Namespace, ids: list[int]) -> tuple[tuple[str, int] | None,
                                                                 list[tuple[int, float, float]]]:
    """``--attack`` as ``(kind, id)`` and ``--kill`` as ``(id, t, restart after)``; raises
    :class:`ProblemError` naming the flag."""
    attack = None
    if args.attack is not None:
        kind, _, rid = args.attack.partition(":")
        if kind not in ("freeze", "herd", "flood") or not rid.isdigit() or int(rid) not in ids:
            raise ProblemError(f"--attack: expected freeze|herd|flood:ID with ID a robot of the "
                               f"scenario, got {args.attack!r}")
        attack = (kind, int(rid))
    kills = []
    for item in args.kill:
        parts = item.split(":")
        try:
            rid, t, after = int(parts[0]), float(parts[1]), float(parts[2]) if len(parts) > 2 \
                else 3.0
        except (ValueError, IndexError):
            raise ProblemError(f"--kill: expected ID:T[:R], got {item!r}") from None
        if rid not in ids or len(parts) > 3 or t < 0.0 or after < 0.0:
            raise ProblemError(f"--kill {item}: expected a robot of the scenario, T, R >= 0")
        kills.append((rid, t, after))
    return attack, kills


def add_fleet_arguments(p: argparse.ArgumentParser, kind: str) -> None:
    """The options every simulated ROS 2 fleet run takes (this demo and
    :mod:`services.ros2.hosts`): output folder ``runs/<kind>-<scenario>-<time>``, t_end,
    odometry rate, security, start-up wait and arrival tolerance."""
    p.add_argument("--out", type=Path, default=None,
                   help=f"output folder (default runs/{kind}-<scenario>-<time>)")
    p.add_argument("--overwrite", action="store_true",
                   help="use an --out folder that holds a previous run (its files are "
                        "replaced); without it a non-empty --out is refused")
    p.add_argument("--t-end", type=positive_float, default=None, help="override t_end, s")
    p.add_argument("--rate", type=positive_float, default=50.0, help="odometry rate, Hz")
    p.add_argument("--insecure", action="store_true",
                   help="plans over plain TCP without credentials (debugging only)")
    p.add_argument("--startup", type=positive_float, default=600.0, metavar="S",
                   help="longest wait for every controller to be up, s (default 600)")
    p.add_argument("--tolerance", type=positive_float, default=0.05,
                   help="arrival: final distance to the reference, m")


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit status."""
    args, extra = build_parser(prog).parse_known_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s ros2-demo %(message)s",
                        stream=sys.stderr)
    try:
        scenario = load_scenario(args.scenario)
    except (ScenarioError, ProblemError) as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    t_end = args.t_end or scenario.t_end
    ids = [int(i) for i in scenario.ids]
    try:
        attack, kills = _faults(args, ids)
    except ProblemError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    out = args.out or Path("runs") / f"ros2-{scenario.name}-{time.strftime('%Y%m%d-%H%M%S')}"
    try:  # the output contract of every runner: a non-empty --out only with --overwrite
        prepare_output(out, args.overwrite)
    except ProblemError as exc:
        print(f"{prog}: error: --out: {exc}{owner_hint(out)}", file=sys.stderr)
        return 2
    for old in ("poses.json", "check.json", "epoch"):  # --overwrite: this run's only
        (out / old).unlink(missing_ok=True)
    logs = out / "logs"
    run = f"ros2-{os.getpid()}-{secrets.token_hex(3)}"
    py = [sys.executable, "-m"]
    sq_port, ros_port = free_ports(2)
    proto = "tcp" if args.insecure else "tls"
    sq_ep, ros_ep = f"{proto}/127.0.0.1:{sq_port}", f"tcp/127.0.0.1:{ros_port}"
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")
    stop = threading.Event()
    received = install_signal_handlers(stop)
    children: list[Child] = []
    status = 1
    try:
        credentials = None if args.insecure else Credentials(scenario, run)

        def start(name: str, argv: list[str], logfile: Path, identity: str) -> LoggedChild:
            if credentials is None:
                return LoggedChild(name, argv, logfile, env)
            return credentials.start(name, argv, logfile, identity, env)

        children.append(LoggedChild("ros2-router", [*py, "services.router", "--listen", ros_ep,
                                                    "--log-level", "WARNING"],
                                    logs / "ros2-router.log", env))
        children.append(start("router", [*py, "services.router", "--listen", sq_ep,
                                         "--log-level", "WARNING"], logs / "router.log",
                              "router"))
        epoch_file = out / "epoch"
        epoch_file.unlink(missing_ok=True)
        sim = [*py, "services.ros2.simfleet", "--scenario", args.scenario, "--router",
               f"127.0.0.1:{ros_port}", "--out", str(out), "--rate", repr(args.rate),
               "--epoch-file", str(epoch_file), "--log-level", args.log_level,
               "--cmd-timeout", repr(args.cmd_timeout)]
        sim += [a for s in args.odom_stop for a in ("--odom-stop", s)]
        if args.twist_stamped:
            sim.append("--twist-stamped")
        children.append(LoggedChild("simfleet", sim, logs / "simfleet.log", env))
        robots = []
        commands: dict[int, list[str]] = {}
        for rid in ids:
            cmd = [*py, "services.robot", "--id", str(rid), "--scenario", args.scenario,
                   "--t-end", repr(t_end), "--run", run, "--ros2", "--ros2-connect", ros_ep,
                   "--zenoh-mode", "client", "--connect", sq_ep, "--epoch-file",
                   str(epoch_file), "--log-level", args.log_level, *extra]
            if args.twist_stamped:
                cmd.append("--twist-stamped")
            if credentials is None:
                cmd.append("--insecure")
            commands[rid] = cmd
            robots.append(start(f"robot/{rid}", cmd, logs / f"robot-{rid}.log",
                                f"robot-{rid}"))
        children.extend(robots)
        log.info("%d robots, t_end %g s; logs in %s", len(ids), t_end, logs)
        def ended() -> list[str]:
            return [r.name for r in robots if r.poll() is not None]

        if not start_clock(ros_ep, ids, epoch_file, args.startup, stop, ended):
            if ended():  # a controller refused to run: its log says why
                log.error("controllers ended before the fleet was up: %s (see %s)",
                          ", ".join(ended()), logs)
                return 1
            log.error("the controllers were not all up within %g s (see %s)", args.startup,
                      logs)
        epoch = float(epoch_file.read_text())
        log.info("simulated robots and routers at %s", robot_side_priority(
            [c for c in children if c.name in ("ros2-router", "router", "simfleet")]))
        if attack is not None:
            kind, rid = attack
            children.append(start("forger", [
                *py, "services.forger", "--scenario", args.scenario, "--run", run,
                "--zenoh-mode", "client", "--connect", sq_ep, "--identity", f"robot-{rid}",
                "--attack", kind, "--target", str(rid), "--duration",
                repr(epoch + t_end - time.time() + 5.0), "--log-level", "WARNING"],
                logs / "forger.log", f"robot-{rid}"))
        pending = sorted(kills, key=lambda k: k[1])
        shown = time.monotonic()
        while not stop.is_set() and (any(r.poll() is None for r in robots) or pending):
            now = time.time() - epoch
            if time.monotonic() - shown >= PROGRESS_EVERY:  # a line while the fleet runs
                shown = time.monotonic()
                log.info("running: t = %.0f s of %g s, %d/%d controllers on", now, t_end,
                         sum(r.poll() is None for r in robots), len(robots))
            for rid, t, after in [k for k in pending if now >= k[1] + (k[2] if any(
                    r.name == f"robot/{k[0]}" and r.poll() is not None for r in robots)
                    else 0.0)]:
                old = next(r for r in robots if r.name == f"robot/{rid}")
                if old.poll() is None:  # kill -9 now, start again `after` s later
                    os.kill(old.proc.pid, signal.SIGKILL)
                    old.proc.wait()
                    log.info("killed robot %d's controller at t = %.2f s", rid, now)
                    continue
                pending.remove((rid, t, after))
                robots.remove(old)
                robots.append(start(f"robot/{rid}", commands[rid],
                                    logs / f"robot-{rid}-restarted.log", f"robot-{rid}"))
                children.append(robots[-1])
                log.info("started robot %d's controller again at t = %.2f s", rid, now)
            time.sleep(0.05)
        failed = [r.name for r in robots if r.poll() not in (None, 0)]
        if failed:
            log.warning("controllers that failed: %s (see %s)", failed, logs)
        status = 128 + received["signal"] if stop.is_set() else (1 if failed else 0)
    finally:
        stop_children([c for c in children if c.name.startswith("robot/")
                       or c.name == "forger"], {}, 10.0)
        stop_children([c for c in children if c.name == "simfleet"],
                      {"simfleet": signal.SIGINT}, 30.0)
        stop_children([c for c in children if "router" in c.name], {}, 10.0)
    poses = out / "poses.json"
    if not poses.exists():
        log.error("the fleet wrote no poses (see %s)", logs)
        return status or 1
    data = json.loads(poses.read_text())
    result = check_fleet(data, scenario, args.tolerance)
    (out / "check.json").write_text(json.dumps(asdict(result), indent=1))
    record = fleet_record(data, scenario, t_end)  # the run folder of every runner
    # extra keys (CONTRACT's keys unchanged): the plans without credentials, if so, and the
    # controllers' counts (odometry_future: future-stamped odometry refused, ...)
    record.extra["insecure"] = bool(args.insecure)
    record.extra["controller_counts"] = controller_counts(logs)
    print(summarize(write_run(out, record, plots=False)), flush=True)
    write_plots(out, record)
    print(f"{result.robots} robots: {result.collisions} collisions (certified clearance "
          f"{result.certified_clearance:.4f} m), {result.arrived}/{result.robots} within "
          f"{result.tolerance:g} m (largest {max(result.final_errors.values()):.3f} m), "
          f"{sum(result.command_timeouts.values())} command timeouts"
          f" ({sum(result.lagged_timeouts.values())} more judged on the simulator's lag "
          "and taken back)"
          + "".join(f"; robot {r}: zero {d:.3f} s after its odometry stopped"
                    if d is not None else f"; robot {r}: no zero after its odometry stopped"
                    for r, d in result.stop_to_zero.items()))
    print(f"wrote {out}")
    return status if status else (0 if result.ok else 1)


if __name__ == "__main__":
    sys.exit(main())

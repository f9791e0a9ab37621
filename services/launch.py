# ruff: noqa: E402
"""Run a distributed closed loop on this machine: the plant and the controllers as processes.

``python -m services.launch --scenario S --scheme centralized|decentralized [--out DIR]
[--mode lockstep|realtime] [--settings FILE.toml] [controller options as sqpmpc run:
--decentralized-mode, --collision-margin, --discretization, ... --t-end T,
--sample-time TS, --horizon N] [--no-plots] [--pin-cpus] [--robots-per-process K]
[--all-plans] [--insecure]`` (also ``sqpmpc launch ...``)

Every process gets the same controller options (the flags given here and the
``--settings`` file): a distributed lockstep run gives the trajectory of
``sqpmpc run`` with the same flags. The plant's status lines (every 10 s) and
warnings reach the launcher's stderr.

The launcher first issues the run's credentials in its memory
(:func:`services.credentials.issue`: a CA, one certificate per process of this
run only -- no ``central`` in a decentralized run, no ``router`` peer to peer)
and hands each child only its own identity over an inherited socket
(``--credentials-fd``, :mod:`services.handover`; the launcher and the children
are non-dumpable): no key is written to disk, so a launch leaves nothing of
its credentials behind whatever its end (SIGKILL included), and a process
holding robot 2's key cannot read another's. Every link is mutual TLS and a
process may publish only its own keys, so a local process that was not
given them cannot move a robot (``docs/security.md``). ``--credentials DIR``
uses a folder made by ``sqpmpc credentials`` instead; ``--insecure``
(debugging only) runs on plain TCP without credentials.

Every process is a Zenoh peer on loopback only (multicast scouting off): the
plant listens on a free port chosen at start, each controller listens on its
own and connects to the plant (peers find each other through it). With
``--robots-per-process K`` one process hosts K robots' controllers, each with
its own thread and its own Zenoh session on a free loopback port
(:func:`services.robot.host`); the default is one process per robot. The
launcher opens no Zenoh session itself. Each child runs in its own process
group (in the launcher's session: a terminal's Ctrl-C reaches the launcher
only, and the children share one scheduling autogroup, which matters on few
cores) and, on Linux, receives SIGTERM if the launcher dies. When the launcher
exits (normally, on an error, SIGINT or SIGTERM) it stops and reaps every
child: SIGINT to the plant (which then writes what it has) and SIGTERM to the
controllers, SIGKILL after a grace period. A stop at any moment, start-up
included, ends every process without a traceback (a signal that comes while
a service still imports its modules is honoured once it can be,
:mod:`services.early`) and leaves a run folder readable by ``sqpmpc metrics``:
stopped before the plant started, the launcher still starts it, and a run
stopped before its first sample says so (``steps 0``, ``interrupted``). A
controller killed while the run goes on (a crash, ``kill -9``) is
started again at once, with its credentials handed over anew (at most
:data:`MAX_RESTARTS` times); it rejoins as a late robot does.

Exit status: the plant's (0 when the run completed), 2 for bad input.
"""

from __future__ import annotations

if __name__ == "__main__":  # before the slow imports: a stop during them is honoured
    from services.early import catch_signals

    catch_signals()

import argparse
import json
import logging
import os
import secrets
import signal
import sys
import threading
import time
from pathlib import Path

from sqpmpc import __version__
from sqpmpc.cli.options import (
    Parser,
    add_controller_options,
    combination_problem,
    nonnegative_float,
    option_words,
    positive_float,
    positive_int,
)
from sqpmpc.errors import ProblemError
from sqpmpc.io.files import write_plots
from sqpmpc.io.recorder import owner_hint, prepare_output
from sqpmpc.io.reporting import STATUS_PERIOD
from sqpmpc.io.runlog import RECORD_FILE, RecordError, read_record
from sqpmpc.problem.goals import unreachable_goals

from .children import Child, free_ports, stop_children, wait_all
from .credentials import config_for, identities, issue, read_meta
from .handover import Handover, make_private
from .node import install_signal_handlers, options_of, scenario_from_args
from .plant import summarize
from .priority import parse_priority

__all__ = ["Child", "build_parser", "free_ports", "main", "stop_children"]

log = logging.getLogger("services.launch")
PROG = "services.launch"
PLANT_GRACE = 30.0
"""Seconds the plant may take to write its outputs after being interrupted."""
MAX_RATE_PER_SAMPLE = 20.0
"""Real time: messages per sample period a robot may publish on one of its keys."""
"""Longest wait for a child to handle signals before one is sent to it anyway, s."""
START_EVERY = 5.0
"""Seconds between two lines while the run's processes start."""
MAX_RESTARTS = 3
"""Times the launcher starts a controller killed by a signal again (not one that exited)."""
RESTART_SIGNALS = frozenset({signal.SIGKILL, signal.SIGSEGV, signal.SIGABRT, signal.SIGBUS,
                             signal.SIGILL, signal.SIGFPE})
"""A controller ended by one of these (a crash, ``kill -9``) is started again; one stopped
by SIGTERM or SIGINT is not."""
CONTROLLER_GRACE = 5.0
"""Seconds the controllers may take to exit after the plant finished."""


def build_parser(prog: str = PROG) -> argparse.ArgumentParser:
    """The argument parser of ``python -m services.launch`` (``sqpmpc launch``)."""
    parser = Parser(prog=prog, description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("--scenario", required=True, help="TOML file or built-in name")
    parser.add_argument("--scheme", required=True, choices=("centralized", "decentralized"))
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default runs/<scenario>-<scheme>-<mode>-<time>)")
    parser.add_argument("--overwrite", action="store_true",
                        help="use an --out folder that holds a previous run (its files are "
                             "replaced); without it a non-empty --out is refused before the "
                             "run, as by sqpmpc run")
    parser.add_argument("--mode", choices=("lockstep", "realtime"), default="lockstep")
    parser.add_argument("--run", default=None, help="run namespace (default: a fresh name)")
    parser.add_argument("--timeout", type=positive_float, default=None,
                        help="lockstep: the plant's wait for a sample's inputs, s")
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    parser.add_argument("--status-every", type=nonnegative_float, default=None, metavar="S",
                        help="the plant's status lines on stderr every S seconds (default "
                             f"{START_EVERY:g} here, {STATUS_PERIOD:g} for the plant alone; "
                             "0: none)")
    parser.add_argument("--pin-cpus", action="store_true",
                        help="pin each controller to one CPU (round robin)")
    parser.add_argument("--log-level", default="WARNING", help="log level of the services")
    parser.add_argument("--router", action="store_true",
                        help="start a Zenoh router (services.router) and run every process as "
                             "its client instead of peer to peer (one link per session, "
                             "batched)")
    parser.add_argument("--robots-per-process", type=positive_int, default=None, metavar="K",
                        help="decentralized: host K robots' controllers in each process (one "
                             "thread and one Zenoh session each; default 1: one process per "
                             "robot)")
    parser.add_argument("--insecure", action="store_true",
                        help="debugging only: plain TCP without credentials (any local "
                             "process can then publish on the run's keys)")
    parser.add_argument("--no-flood-limits", action="store_true",
                        help="benchmarks only: no per-publisher rate or size limit "
                             "(services.limits) in the run's processes")
    parser.add_argument("--priority", default="auto", metavar="off|auto|N",
                        type=lambda text: parse_priority(text) and text,
                        help="real time: the scheduling priority of every process's sample "
                             "loop (services.priority; default auto: SCHED_RR where "
                             "permitted, else a negative nice, else unchanged)")
    parser.add_argument("--credentials", type=Path, default=None, metavar="DIR",
                        help="the run's credentials made by 'sqpmpc credentials' (same "
                             "--run) instead of fresh ones, e.g. to let a services.viewer "
                             "started with the same folder join the run")
    parser.add_argument("--connect", dest="also_connect", action="append", default=[],
                        metavar="EP", help="also connect every process of the run to this "
                                           "Zenoh endpoint (the router with --router), e.g. "
                                           "a services.viewer's --listen (repeatable; tls/ "
                                           "unless --insecure)")
    parser.add_argument("--ros2-demo", action="store_true",
                        help="run simulated ROS 2 robots, one 'sqpmpc robot --ros2' each, "
                             "instead (services.ros2.demo: its own options)")
    add_controller_options(parser, all_plans=True)
    return parser


def _commands(args: argparse.Namespace, ids: list[int], run: str, out: Path,
              sample_time: float, credentials: Path | None = None,
              secured: bool = False) -> list[tuple[str, list[str]]]:
    """``(name, argv)`` of every child; ``secured`` without a ``credentials`` folder: the
    caller adds ``--credentials-fd`` (:mod:`services.handover`)."""
    py = [sys.executable, "-m"]
    common = ["--scenario", args.scenario, "--run", run, "--log-level", args.log_level]
    if args.no_flood_limits:
        common.append("--no-flood-limits")
    elif args.mode == "realtime":  # per-publisher rate limit (services.limits)
        common += ["--max-rate", repr(MAX_RATE_PER_SAMPLE / sample_time)]
    if args.mode == "realtime":  # the sample loops at real-time priority where permitted
        common += ["--priority", args.priority]
    secure = [] if credentials is None else ["--credentials", str(credentials)]
    common += secure
    proto = "tcp" if credentials is None and not secured else "tls"
    k = args.robots_per_process or 1
    groups = [ids[j:j + k] for j in range(0, len(ids), k)]
    names = ["central"] if args.scheme == "centralized" else [
        "robot/" + ",".join(str(i) for i in g) for g in groups]
    ports = free_ports(1 + len(names))
    plant_ep = f"{proto}/127.0.0.1:{ports[0]}"
    decentralized = args.scheme == "decentralized"
    run_options = option_words(args, decentralized)  # every process: the same settings
    plant = [*py, "services.plant", *common, "--listen", plant_ep, "--scheme", args.scheme,
             "--mode", args.mode, "--out", str(out), "--quiet", *run_options]
    if args.router:  # the router listens on the plant's port, every process is its client
        plant = [*py, "services.plant", *common, "--zenoh-mode", "client", "--connect",
                 plant_ep, "--scheme", args.scheme, "--mode", args.mode, "--out", str(out),
                 "--quiet", *run_options]
    if args.timeout is not None:
        plant += ["--timeout", repr(args.timeout)]
    plant.append("--no-plots")  # the launcher draws them after printing the summary
    status_every = START_EVERY if args.status_every is None else args.status_every
    plant += ["--status-every", repr(status_every)]
    cmds = [("plant", plant)]
    controller_extra: list[str] = list(run_options)
    if args.mode == "realtime":  # a QP that cannot finish in time becomes a counted fallback
        controller_extra += ["--qp-time-limit", repr(0.4 * sample_time)]
    for name, port in zip(names, ports[1:], strict=True):
        rids = name.split("/")[1].split(",") if "/" in name else []
        # several sessions in one process: each listens on a free loopback port of its own
        listen = ["--listen", f"{proto}/127.0.0.1:{port}"] if len(rids) <= 1 else []
        if args.router:
            listen = ["--zenoh-mode", "client"]
        net = [*listen, "--connect", plant_ep, *controller_extra]
        if name == "central":
            cmds.append((name, [*py, "services.central", *common, *net]))
        else:
            id_args = [a for rid in rids for a in ("--id", rid)]
            insecure = ["--insecure"] if proto == "tcp" else []  # named, as it must be
            cmds.append((name, [*py, "services.robot", *id_args, *common, *net, *insecure]))
    extra = [a for ep in args.also_connect for a in ("--connect", ep)]
    if args.router:
        cmds.insert(0, ("router", [*py, "services.router", "--listen", plant_ep,
                                   "--log-level", args.log_level, *secure, *extra]))
    else:  # every peer links to it from the start (e.g. a viewer gets every plan)
        for _, cmd in cmds:
            cmd += extra
    return cmds


def _identities_of(name: str) -> list[str]:
    """The identities a child serves: ``"robot/1,2"`` -> ``["robot-1", "robot-2"]``."""
    if name.startswith("robot/"):
        return [f"robot-{i}" for i in name.split("/", 1)[1].split(",")]
    return [name]


def _run_of(credentials: Path | None) -> str | None:
    """The run a credentials folder was made for (``None``: no folder or unreadable)."""
    if credentials is None:
        return None
    try:
        run = read_meta(credentials).get("run")
    except ProblemError:
        return None  # config_for names the problem
    return run if isinstance(run, str) else None


def _credential_problem(args: argparse.Namespace) -> str | None:
    """Why ``--credentials``, ``--insecure`` and ``--connect`` cannot go together, if so."""
    if args.insecure and args.credentials is not None:
        return "give --credentials DIR or --insecure, not both"
    if args.credentials is not None:
        names = ["plant", "central" if args.scheme == "centralized" else "robot/1"]
        for name in names + (["router"] if args.router else []):
            try:
                config_for(argparse.Namespace(credentials=args.credentials, run=args.run),
                           name)
            except ProblemError as exc:
                return str(exc)
    for ep in args.also_connect:
        if not args.insecure and not ep.startswith("tls/"):
            return (f"--connect {ep}: the run's links are mutual TLS; give a tls/ endpoint "
                    "(and the same --credentials to both sides) or --insecure")
    return None


class StartProgress:
    """Lines on stderr while the run starts: the processes compile nothing, but importing,
    loading the kernels and joining take seconds on a busy machine. Every
    :data:`START_EVERY` seconds until the plant records its first sample, one line with
    the elapsed time; then the plant's own status lines take over."""

    def __init__(self, record: Path, processes: int) -> None:
        self.record = record
        self.processes = processes
        self.t0 = self.shown = time.monotonic()
        self.started = False
        log.info("started %d processes; waiting for them to join (a line every %.0f s)",
                 processes, START_EVERY)

    def tick(self) -> None:
        """Call often: prints a line when one is due, until the first sample."""
        if self.started:
            return
        if self.record.exists() and self.record.stat().st_size > 0:
            self.started = True
            log.info("the run started after %.1f s", time.monotonic() - self.t0)
            return
        now = time.monotonic()
        if now - self.shown >= START_EVERY:
            self.shown = now
            log.info("still starting: %.0f s (the processes import, load the kernels and "
                     "join)", now - self.t0)


def _plots(out: Path) -> None:
    """The run's plots from its record, after the summary (a failure says so, once)."""
    try:
        record = read_record(out)
    except RecordError as exc:
        log.warning("no plots: %s", exc)
        return
    write_plots(out, record)


def main(argv: list[str] | None = None, prog: str = PROG) -> int:
    """Entry point; returns the exit status."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if "--ros2-demo" in argv:  # simulated ROS 2 robots, one --ros2 controller each
        from .ros2.demo import main as ros2_demo

        return ros2_demo([a for a in argv if a != "--ros2-demo"], prog)
    args = build_parser(prog).parse_args(argv)
    make_private()  # it holds every identity's key for a moment
    logging.basicConfig(level=logging.INFO, format="%(asctime)s launch %(message)s",
                        stream=sys.stderr)
    args.connect, args.listen = [], []
    run = args.run or _run_of(args.credentials) or f"run-{os.getpid()}-{secrets.token_hex(3)}"
    args.run = run
    # bad input (scenario, options, rules) is refused here once, not by every child
    scenario = scenario_from_args(prog, args)  # exits 2 with one message on bad input
    problem = combination_problem(options_of(args), args.scheme, scenario.n_robots)
    if args.scheme == "centralized" and args.robots_per_process is not None:
        problem = "--robots-per-process does nothing with --scheme centralized"
    problem = problem or _credential_problem(args)
    unreachable = unreachable_goals(scenario)
    if unreachable and not problem:
        problem = f"{scenario.source}: {unreachable[0]}" + (
            f" (and {len(unreachable) - 1} more robot(s))" if len(unreachable) > 1 else "")
    if problem:
        print(f"{prog}: error: {problem}", file=sys.stderr)
        return 2
    out = args.out or Path("runs") / (f"{scenario.name}-{args.scheme}-{args.mode}-"
                                      f"{time.strftime('%Y%m%d-%H%M%S')}")
    try:  # the output contract of every runner: a non-empty --out only with --overwrite
        prepare_output(out, args.overwrite)
    except ProblemError as exc:
        print(f"{prog}: error: --out: {exc}{owner_hint(out)}", file=sys.stderr)
        return 2
    stop = threading.Event()
    received = install_signal_handlers(stop)
    env = dict(os.environ)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")  # small matrices: threads only compete with the other processes
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    metrics_file = out / "metrics.json"
    before = metrics_file.stat().st_mtime_ns if metrics_file.exists() else None
    children: list[Child] = []
    status = 1
    issued = None
    try:
        if args.credentials is None and not args.insecure:
            # in this process's memory only; each child receives its own over a socket
            issued = issue(scenario, run, identities(scenario, args.scheme, args.router),
                           scheme=args.scheme)
        commands = _commands(args, [int(i) for i in scenario.ids], run, out,
                             scenario.sample_time, args.credentials, issued is not None)
        handover = Handover(issued.meta) if issued is not None else None

        def spawn(name: str, cmd: list[str], cpu: int | None) -> Child:
            """Start a child; with issued credentials, its own handed over anew."""
            if handover is None or issued is None:
                return Child(name, cmd, cpu, env)
            fd = handover.child_end({i: issued.config(i) for i in _identities_of(name)})
            try:
                return Child(name, [*cmd, "--credentials-fd", str(fd)], cpu, env, (fd,))
            finally:
                handover.started()

        how: dict[str, tuple[list[str], int | None]] = {}
        restarts: dict[str, int] = {}
        for j, (name, cmd) in enumerate(commands):
            if stop.is_set() and name != "plant":
                continue  # stopped already: only the plant, which writes the (empty) run
            cpu = cpus[(j - 1) % len(cpus)] if args.pin_cpus and cpus and j > 0 else None
            how[name] = (cmd, cpu)
            children.append(spawn(name, cmd, cpu))
        plant = next((c for c in children if c.name == "plant"), None)
        progress = StartProgress(out / RECORD_FILE, len(children))
        while plant is not None and not stop.is_set():
            progress.tick()
            code = plant.poll()
            if code is not None:
                status = code
                break
            for j, c in enumerate(children):
                if c is plant:
                    continue
                code = c.poll()
                if (code is not None and -code in RESTART_SIGNALS and c.name != "router"
                        and restarts.get(c.name, 0) < MAX_RESTARTS):
                    # killed (a crash, kill -9): start it again, its credentials anew
                    restarts[c.name] = restarts.get(c.name, 0) + 1
                    log.warning("%s was killed by %s: starting it again (%d of at most %d)",
                                c.name, signal.Signals(-code).name, restarts[c.name],
                                MAX_RESTARTS)
                    children[j] = spawn(c.name, *how[c.name])
                elif code not in (None, 0) and not c.reported:
                    c.reported = True
                    log.warning("%s exited with status %s", c.name, code)
            time.sleep(0.05)
        services = [c for c in children if c.name != "router"]
        if stop.is_set():
            sig = received.get("signal", signal.SIGTERM)
            log.info("stopping on %s", signal.Signals(sig).name)
            status = 128 + sig
        else:
            # the plant is done: the controllers leave on its 'done' message
            if not wait_all(services, CONTROLLER_GRACE):
                log.warning("controllers still running %.0f s after the plant: stopping them",
                            CONTROLLER_GRACE)
    finally:
        # the router last: the plant's 'done' and the controllers' exits go through it
        stop_children([c for c in children if c.name != "router"], {"plant": signal.SIGINT},
                      PLANT_GRACE)
        stop_children([c for c in children if c.name == "router"], {}, PLANT_GRACE)
    if metrics_file.exists() and metrics_file.stat().st_mtime_ns != before:
        print(summarize(json.loads(metrics_file.read_text())), flush=True)
        if not args.no_plots:
            _plots(out)
        print(f"wrote {out}")
    else:
        log.error("no metrics were written (plant status %s)", status)
    return status


if __name__ == "__main__":
    sys.exit(main())

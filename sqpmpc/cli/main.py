"""Command line: ``sqpmpc run SCENARIO --scheme centralized|decentralized [--out DIR]``.

One ``sqpmpc`` command: ``run`` (a closed loop in this process), ``list``,
``generate``, ``rules``, ``metrics``, ``credentials``, ``animate``, and the
distributed services ``launch``, ``plant``, ``robot``, ``central``, ``router``,
``viewer`` (the same parsers as ``python -m services.<name>``). The controller
options are the same everywhere (:mod:`sqpmpc.cli.options`), also from
``--settings FILE.toml``.

Exit status of ``sqpmpc run``: 0 when the run completed (with
``--fail-on-miss``: and every robot arrived, without any collision), 1 when the
run stopped midway (what it had is written), 2 for bad input (scenario file,
options, an ``--out`` that is a file or a non-empty folder without
``--overwrite``: refused before the run), 4 with ``--fail-on-miss`` when the
run completed but a robot did not arrive (final error above 0.05 m) or a
collision happened, 130 on Ctrl-C (what was simulated is written).
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import sys
import time
from pathlib import Path

from sqpmpc.cli import animate, runlog
from sqpmpc.cli.options import (
    Parser,
    add_controller_options,
    combination_problem,
    nonnegative_float,
    positive_float,
    positive_int,
    probability,
    resolve_options,
    with_overrides,
)
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.io.files import write_plots, write_run
from sqpmpc.io.recorder import prepare_output
from sqpmpc.io.reporting import STATUS_PERIOD, StatusLines, missed_goal, summarize
from sqpmpc.problem.fleets import FLEET_KINDS, antipodal_swap, grid_to_grid, random_crossings
from sqpmpc.problem.goals import unreachable_goals
from sqpmpc.problem.movingai import mapf_scenario
from sqpmpc.problem.scenario_file import builtin_scenario_names, load_scenario
from sqpmpc.rules.registry import describe_rules
from sqpmpc.sim.simulation import ClosedLoopSimulation, SimulationOptions
from sqpmpc.version import __version__

__all__ = ["build_parser", "main"]

log = logging.getLogger("sqpmpc")

#: ``sqpmpc NAME ...`` runs ``python -m services.NAME ...`` in this process.
SERVICES = {
    "launch": "a distributed run on this machine: the plant and the controllers as processes",
    "plant": "the plant service of a distributed run",
    "robot": "one robot's decentralized controller service (or several: --id repeated)",
    "central": "the centralized controller service",
    "router": "a Zenoh router for the services",
    "viewer": "live view of a distributed run for Foxglove",
    "docker": "write a Docker Compose file for a distributed run of any scenario",
}


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``sqpmpc`` command."""
    parser = Parser(prog="sqpmpc", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"sqpmpc {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a closed loop in one process")
    names = ", ".join(builtin_scenario_names())
    run.add_argument("scenario", help=f"TOML file or built-in name ({names})")
    run.add_argument("--scheme", required=True, choices=("centralized", "decentralized"))
    run.add_argument("--out", type=Path, default=None,
                     help="output folder (default: runs/<new>); a file or a non-empty folder "
                          "is refused before the run unless --overwrite")
    run.add_argument("--overwrite", action="store_true",
                     help="use an --out folder that holds a previous run: its files are "
                          "replaced (other files are left alone)")
    run.add_argument("--fail-on-miss", action="store_true",
                     help="exit with status 4 when a robot did not arrive (final error above "
                          "0.05 m) or a collision happened (for scripts)")
    add_controller_options(run)
    run.add_argument("--message-drop", type=probability, default=None, metavar="P",
                     help="decentralized: probability that a plan message is lost "
                          "(default 0)")
    run.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    run.add_argument("--quiet", action="store_true",
                     help="no progress or summary (default: a progress bar on a terminal, "
                          "else status lines on stderr)")
    run.add_argument("--status-every", type=nonnegative_float, default=STATUS_PERIOD,
                     metavar="S", help="not on a terminal: a status line on stderr every S "
                                       f"seconds (default {STATUS_PERIOD:g}; 0: none)")
    sub.add_parser("list", help="list the built-in scenarios")
    gen = sub.add_parser("generate", help="write a fleet scenario file (swap, random "
                                          "crossings, grid-to-grid)")
    gen.add_argument("kind", choices=(*FLEET_KINDS, "mapf"),
                     help="swap: antipodal swap on a circle; crossings: random starts and "
                          "goals (seeded); grid: a grid sent to the mirrored grid; mapf: a "
                          "MovingAI .map (with its .scen agents or random cells)")
    gen.add_argument("--map", type=Path, help="mapf: the MovingAI .map file")
    gen.add_argument("--scen", type=Path,
                     help="mapf: a MovingAI .scen file (its first --robots agents; default: "
                          "random free cells, --seed)")
    gen.add_argument("--cell", type=positive_float, help="mapf: cell size, m (default 1)")
    gen.add_argument("--v-max", type=positive_float, help="mapf: bound of |v|, m/s (default 1)")
    gen.add_argument("--acceleration", type=positive_float, nargs=2,
                     metavar=("A", "ALPHA"),
                     help="mapf: bounds of |a| (m/s^2) and |alpha| (rad/s^2); default none")
    gen.add_argument("--robots", type=positive_int, help="swap, crossings: number of robots")
    gen.add_argument("--seed", type=int, help="crossings: random seed")
    gen.add_argument("--rows", type=positive_int, help="grid: rows")
    gen.add_argument("--cols", type=positive_int, help="grid: columns")
    gen.add_argument("--spacing", type=positive_float,
                     help="crossings, grid: smallest distance between robots, m")
    gen.add_argument("--gap", type=nonnegative_float,
                     help="grid: distance between the two grids, m")
    gen.add_argument("--sample-time", type=positive_float, default=None,
                     help="Ts, s (default 0.5; mapf 0.2)")
    gen.add_argument("--horizon", type=positive_int, default=None,
                     help="N (default 8; mapf 10)")
    gen.add_argument("--diameter", type=positive_float, default=0.3, help="robot diameter, m")
    gen.add_argument("--out", type=Path, default=None, help="file to write (default: stdout)")
    sub.add_parser("rules", help="list the liveness rules and the always-on safety rows")
    runlog.add_parser(sub)  # sqpmpc metrics RUN_DIR
    sub.add_parser("credentials", add_help=False,
                   help="issue a run's certificates and access control (python -m "
                        "services.credentials; 'sqpmpc credentials --help')")
    animate.add_parser(sub)
    for name, text in SERVICES.items():
        sub.add_parser(name, add_help=False,
                       help=f"{text} (python -m services.{name}; 'sqpmpc {name} --help')")
    return parser


_GENERATE_OPTIONS = {"swap": ("robots",), "crossings": ("robots", "seed", "spacing"),
                     "grid": ("rows", "cols", "spacing", "gap"),
                     "mapf": ("robots", "seed", "map", "scen", "cell", "v_max", "acceleration")}
_REQUIRED = {"swap": ("robots",), "crossings": ("robots", "seed"), "grid": ("rows", "cols"),
             "mapf": ("map", "robots")}


def _generate(args: argparse.Namespace) -> int:
    """``sqpmpc generate``: write the scenario file, or refuse with one message (status 2)."""
    kind = args.kind
    given = [k for k in ("robots", "seed", "rows", "cols", "spacing", "gap", "map", "scen",
                         "cell", "v_max", "acceleration") if getattr(args, k) is not None]
    wrong = [k for k in given if k not in _GENERATE_OPTIONS[kind]]
    missing = [k for k in _REQUIRED[kind] if getattr(args, k) is None]
    try:
        if wrong:
            takes = ", ".join("--" + k.replace("_", "-") for k in _GENERATE_OPTIONS[kind])
            raise ProblemError(f"--{wrong[0].replace('_', '-')} does not apply to '{kind}' "
                               f"(it takes {takes})")
        if missing:
            raise ProblemError(f"'{kind}' needs --{missing[0]}")
        mapf = kind == "mapf"
        common = {"sample_time": args.sample_time or (0.2 if mapf else 0.5),
                  "horizon": args.horizon or (10 if mapf else 8),
                  "diameter": args.diameter}
        extra = {k: getattr(args, k) for k in ("spacing", "gap") if getattr(args, k) is not None}
        if kind == "mapf":
            accel = args.acceleration or (None, None)
            scenario = mapf_scenario(
                args.map, args.robots, scen_path=args.scen, cell=args.cell or 1.0,
                v_max=args.v_max or 1.0, acceleration=accel[0],
                angular_acceleration=accel[1], seed=args.seed or 0, **common)
        elif kind == "swap":
            scenario = antipodal_swap(args.robots, **common)
        elif kind == "crossings":
            scenario = random_crossings(args.robots, args.seed, **common, **extra)
        else:
            scenario = grid_to_grid(args.rows, args.cols, **extra, **common)
    except (ProblemError, ScenarioError) as exc:
        print(f"sqpmpc generate: error: {exc}", file=sys.stderr)
        return 2
    text = scenario.to_toml()
    if args.out is None:
        sys.stdout.write(text)
        return 0
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    except OSError as exc:
        print(f"sqpmpc generate: error: cannot write {args.out}: {exc.strerror or exc}",
              file=sys.stderr)
        return 2
    print(f"wrote {args.out} ({scenario.name}: {scenario.n_robots} robots, "
          f"t_end {scenario.t_end:g} s)")
    return 0


def _credentials(argv: list[str]) -> int:
    """``sqpmpc credentials ...``, a command of the services (looked up by name: the services
    sit above this layer)."""
    credentials = importlib.import_module("services.credentials")
    parser = Parser(prog="sqpmpc")
    credentials.add_parser(parser.add_subparsers(dest="command"))
    try:
        args = parser.parse_args(["credentials", *argv])
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else 2
    return int(credentials.main(args))


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] and argv[0] in SERVICES:  # the service's own parser and options
        service = importlib.import_module(f"services.{argv[0]}")
        return int(service.main(argv[1:], prog=f"sqpmpc {argv[0]}"))
    if argv[:1] == ["credentials"]:  # the services' mTLS and access control
        return _credentials(argv[1:])
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a bad option (one line on stderr)
        return exc.code if isinstance(exc.code, int) else 2
    if args.command == "list":
        print("\n".join(builtin_scenario_names()))
        return 0
    if args.command == "rules":
        print(describe_rules())
        return 0
    if args.command == "generate":
        return _generate(args)
    if getattr(args, "handler", None) is not None:
        return int(args.handler(args))
    terminal = sys.stderr.isatty()
    try:
        options = resolve_options(args)
        scenario = with_overrides(load_scenario(args.scenario), options)
        problem = combination_problem(options, args.scheme, scenario.n_robots)
        if args.scheme == "centralized" and args.message_drop is not None:
            problem = "--message-drop does nothing with --scheme centralized"
        unreachable = unreachable_goals(scenario)
        if unreachable and not problem:
            problem = f"{scenario.source}: {unreachable[0]}" + (
                f" (and {len(unreachable) - 1} more robot(s))" if len(unreachable) > 1 else "")
        if problem:
            raise ProblemError(problem)
        sim_options = SimulationOptions(decentralized_mode=options.decentralized_mode,
                                        message_drop_probability=args.message_drop or 0.0,
                                        progress=terminal and not args.quiet)
        sim = ClosedLoopSimulation(scenario, args.scheme,
                                   options.solver_settings(scenario=scenario), sim_options)
        stamp = time.strftime("%Y%m%d-%H%M%S")
        out = args.out or Path("runs") / f"{scenario.name}-{args.scheme}-{stamp}"
        try:
            prepare_output(out, args.overwrite)
        except ProblemError as exc:
            raise ProblemError(f"--out: {exc}") from None
    except (ScenarioError, ProblemError) as exc:
        print(f"sqpmpc run: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # before the run started: nothing to write
        print("sqpmpc: interrupted before the run started", file=sys.stderr)
        return 130
    status = 0
    status_lines = None if terminal or args.quiet else StatusLines(
        scenario, f"{scenario.name} {args.scheme}", args.status_every)
    try:
        if status_lines is None:
            sim.run()
        else:  # not a terminal (a log file, a pipe): plain lines, no carriage return
            while sim.k < scenario.steps:
                sim.step()
                status_lines.update(sim.k, sim.states[sim.k])
    except KeyboardInterrupt:
        print("sqpmpc: interrupted; writing what was simulated", file=sys.stderr)
        status = 130
    except Exception as exc:  # the run stopped midway: keep what it had, then report
        print(f"sqpmpc: the run stopped at sample {sim.k}: {exc!r}; writing what was simulated",
              file=sys.stderr)
        status = 1
    record = sim.record()
    metrics = write_run(out, record, plots=False)  # the plots after the summary
    if not args.quiet:
        print(summarize(metrics))
        if metrics.get("no_route"):
            print("no route through the map for robot(s) "
                  f"{', '.join(map(str, metrics['no_route']))}: their goals are walled off "
                  "or nearer an obstacle than their radius")
    if not args.no_plots:
        write_plots(out, record, quiet=args.quiet)
    if not args.quiet:
        print(f"wrote {out}")
    else:
        print(json.dumps({"out": str(out)}))
    miss = missed_goal(metrics)
    if status == 0 and args.fail_on_miss and miss:
        print(f"sqpmpc run: goal missed (--fail-on-miss): {miss}", file=sys.stderr)
        return 4
    return status


if __name__ == "__main__":
    sys.exit(main())

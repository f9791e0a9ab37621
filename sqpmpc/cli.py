"""Command line: ``sqpmpc run SCENARIO --scheme centralized|decentralized [--out DIR]``.

Exit status: 0 when the run completed (whatever the metrics say), 2 for bad
input (scenario file, options), 1 when the run stopped midway (what it had is
written), 130 on Ctrl-C (likewise).
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
import time
from pathlib import Path

from . import __version__, animate, runlog
from .errors import ProblemError, ScenarioError
from .fleets import FLEET_KINDS, antipodal_swap, grid_to_grid, random_crossings
from .metrics import write_run
from .model import DISCRETIZATIONS
from .registry import add_rule_arguments, describe_rules, rules_from_arguments
from .scenario import builtin_scenario_names, load_scenario
from .settings import (
    FLEET_NEIGHBOUR_SLOTS,
    FLEET_QP_SOLVER,
    FLEET_ROBOTS,
    QP_SOLVER_CHOICES,
    SolverSettings,
    neighbour_slots_argument,
)
from .simulation import ClosedLoopSimulation, SimulationOptions

__all__ = ["build_parser", "main"]

log = logging.getLogger("sqpmpc")


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``sqpmpc`` command."""
    parser = argparse.ArgumentParser(prog="sqpmpc", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"sqpmpc {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a closed loop in one process")
    names = ", ".join(builtin_scenario_names())
    run.add_argument("scenario", help=f"TOML file or built-in name ({names})")
    run.add_argument("--scheme", required=True, choices=("centralized", "decentralized"))
    run.add_argument("--out", type=Path, default=None, help="output folder (default: runs/<new>)")
    run.add_argument("--decentralized-mode", choices=("shared", "paper"), default="shared",
                     help="shared-responsibility hyperplanes (default) or the paper's "
                          "literal scheme")
    run.add_argument("--iteration", choices=("rti", "sqp"), default="rti",
                     help="one QP per sample (rti, default) or SQP to convergence")
    run.add_argument("--hessian", choices=("gauss-newton", "exact"), default="gauss-newton")
    run.add_argument("--discretization", choices=DISCRETIZATIONS, default="euler")
    run.add_argument("--neighbour-slots", type=neighbour_slots_argument, default="auto",
                     metavar="N|all|auto",
                     help="collision slots per robot, filled with the nearest neighbours "
                          f"within reach; 'all': one per other robot; 'auto' (default): "
                          f"{FLEET_NEIGHBOUR_SLOTS} on fleets of more than {FLEET_ROBOTS} "
                          f"robots, else all")
    run.add_argument("--qp-solver", choices=QP_SOLVER_CHOICES, default="auto",
                     help=f"QP backend; 'auto' (default): {FLEET_QP_SOLVER} for the "
                          f"decentralized robots of fleets of more than {FLEET_ROBOTS}, else "
                          f"osqp (docs/qp-backends.md, docs/fleet.md)")
    run.add_argument("--collision-margin", type=float, default=None,
                     help="added to every required distance in the QP, m (default 0.001); "
                          "raise it to cover a plant that differs from the prediction model")
    run.add_argument("--slack-penalty", type=float, default=None,
                     help="L1 price of collision slacks on stages 2..N")
    add_rule_arguments(run)
    run.add_argument("--message-drop", type=float, default=0.0,
                     help="decentralized: probability that a plan message is lost")
    run.add_argument("--no-plots", action="store_true", help="skip the PNG plots")
    run.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    sub.add_parser("list", help="list the built-in scenarios")
    gen = sub.add_parser("generate", help="write a fleet scenario file (swap, random "
                                          "crossings, grid-to-grid)")
    gen.add_argument("kind", choices=FLEET_KINDS,
                     help="swap: antipodal swap on a circle; crossings: random starts and "
                          "goals (seeded); grid: a grid sent to the mirrored grid")
    gen.add_argument("--robots", type=int, help="swap, crossings: number of robots")
    gen.add_argument("--seed", type=int, help="crossings: random seed")
    gen.add_argument("--rows", type=int, help="grid: rows")
    gen.add_argument("--cols", type=int, help="grid: columns")
    gen.add_argument("--spacing", type=float,
                     help="crossings, grid: smallest distance between robots, m")
    gen.add_argument("--gap", type=float, help="grid: distance between the two grids, m")
    gen.add_argument("--sample-time", type=float, default=0.5, help="Ts, s (default 0.5)")
    gen.add_argument("--horizon", type=int, default=8, help="N (default 8)")
    gen.add_argument("--diameter", type=float, default=0.3, help="robot diameter, m")
    gen.add_argument("--out", type=Path, default=None, help="file to write (default: stdout)")
    sub.add_parser("rules", help="list the liveness rules and the always-on safety rows")
    runlog.add_parser(sub)  # sqpmpc metrics RUN_DIR
    from services import credentials  # sqpmpc credentials (the services' mTLS + ACL)

    credentials.add_parser(sub)
    animate.add_parser(sub)
    sub.add_parser("viewer", add_help=False,
                   help="live view of a distributed run for Foxglove (python -m "
                        "services.viewer; 'sqpmpc viewer --help')")
    return parser


def _summary(metrics: dict) -> str:
    st = metrics["solve_time"]
    rms = metrics["rms_tracking_error"]
    return (
        f"{metrics['scenario']} / {metrics['scheme']}: steps {metrics['steps']}, "
        f"min clearance {metrics['min_clearance']}, collisions {metrics['collisions']}, "
        f"input bound violations {metrics['input_bound_violations']}, "
        f"solver failures {metrics['solver_failures']}, closed-loop cost "
        f"{metrics['closed_loop_cost']:.4g}, RMS error "
        f"{', '.join(f'{k}: {v:.3f}' for k, v in rms.items())} m, "
        f"controller time median {st['median_ms']:.3f} ms, total {st['total_s']:.3f} s"
    )


_GENERATE_OPTIONS = {"swap": ("robots",), "crossings": ("robots", "seed", "spacing"),
                     "grid": ("rows", "cols", "spacing", "gap")}
_REQUIRED = {"swap": ("robots",), "crossings": ("robots", "seed"), "grid": ("rows", "cols")}


def _generate(args: argparse.Namespace) -> int:
    """``sqpmpc generate``: write the scenario file, or refuse with one message (status 2)."""
    kind = args.kind
    given = [k for k in ("robots", "seed", "rows", "cols", "spacing", "gap")
             if getattr(args, k) is not None]
    wrong = [k for k in given if k not in _GENERATE_OPTIONS[kind]]
    missing = [k for k in _REQUIRED[kind] if getattr(args, k) is None]
    try:
        if wrong:
            raise ProblemError(f"--{wrong[0]} does not apply to '{kind}' (it takes "
                               f"{', '.join('--' + k for k in _GENERATE_OPTIONS[kind])})")
        if missing:
            raise ProblemError(f"'{kind}' needs --{missing[0]}")
        common = {"sample_time": args.sample_time, "horizon": args.horizon,
                  "diameter": args.diameter}
        extra = {k: getattr(args, k) for k in ("spacing", "gap") if getattr(args, k) is not None}
        if kind == "swap":
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


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["viewer"]:  # the service's own parser and options
        from services.viewer import main as viewer_main

        return viewer_main(argv[1:])
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    args = build_parser().parse_args(argv)
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
    try:
        scenario = load_scenario(args.scenario)
        base = SolverSettings()
        settings = SolverSettings(
            iteration_scheme=args.iteration,
            hessian=args.hessian,
            discretization=args.discretization,
            collision_margin=base.collision_margin if args.collision_margin is None
            else args.collision_margin,
            slack_penalty=base.slack_penalty if args.slack_penalty is None
            else args.slack_penalty,
            rules=rules_from_arguments(args),
            qp_solver=args.qp_solver,
            neighbour_slots=args.neighbour_slots,
        )
        options = SimulationOptions(decentralized_mode=args.decentralized_mode,
                                    message_drop_probability=args.message_drop,
                                    progress=not args.quiet)
        sim = ClosedLoopSimulation(scenario, args.scheme, settings, options)
    except (ScenarioError, ProblemError) as exc:
        print(f"sqpmpc: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # before the run started: nothing to write
        print("sqpmpc: interrupted before the run started", file=sys.stderr)
        return 130
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out = args.out or Path("runs") / f"{scenario.name}-{args.scheme}-{stamp}"
    status = 0
    try:
        sim.run()
    except KeyboardInterrupt:
        print("sqpmpc: interrupted; writing what was simulated", file=sys.stderr)
        status = 130
    except Exception as exc:  # the run stopped midway: keep what it had, then report
        print(f"sqpmpc: the run stopped at sample {sim.k}: {exc!r}; writing what was simulated",
              file=sys.stderr)
        status = 1
    metrics = write_run(out, sim.record(), plots=not args.no_plots)
    if not args.quiet:
        print(_summary(metrics))
        print(f"wrote {out}")
    else:
        print(json.dumps({"out": str(out)}))
    return status


if __name__ == "__main__":
    sys.exit(main())

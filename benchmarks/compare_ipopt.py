r"""sqpmpc against a converged CasADi + IPOPT reference, side by side in one run.

Usage (from the repository root, with the ``bench`` extra installed)::

    python -m benchmarks.compare_ipopt                  # full comparison, writes docs/benchmarks.md
    python -m benchmarks.compare_ipopt --quick          # short smoke run, prints only
    python -m benchmarks.compare_ipopt --scenarios head-on swap-6 --output /tmp/b.md
    python -m benchmarks.compare_ipopt --baseline ../before   # per-sample time before/after

For every scenario it runs the closed loop with

- the reference (:mod:`benchmarks.ipopt_reference`): the centralized OCP with
  the nonlinear distance constraints solved to convergence by IPOPT (exact
  Hessian) at every sample, multipliers warm-started; a second IPOPT row with a
  primal-only warm start shows how much the closed loop of this non-convex
  problem depends on which local optimum IPOPT lands in;
- sqpmpc RTI centralized / decentralized, SQP centralized / decentralized
  (``iteration_scheme="sqp"``), RTI centralized with ``hessian="exact"``, RTI
  with the PIQP backend (``qp_solver="piqp"``) and RTI decentralized with DAQP,
  all with the library's default settings,

and prints two tables (quality and time, where the time goes) and the targets
met or missed. Everything is measured in the run; nothing is hard-coded.

Before and after: ``--baseline PATH`` names another checkout (for example a ``git
worktree`` of the commit before a change); then, instead of the comparison with IPOPT,
the per-sample controller time of this checkout and of ``PATH`` is measured side by
side in alternating rounds, each in a subprocess with its own ``PYTHONPATH``, with the
same measure (:mod:`benchmarks.baseline`; scenarios default to paper-s2, RTI, both
schemes), and written to ``docs/before-after.md``.

Timing: every closed loop is deterministic, so RTI and IPOPT runs are repeated
``--repeats`` times and the repetition with the smallest total controller
time is kept (like ``timeit``; this filters out interference from other
processes); SQP runs, 30-100 x slower, run once.
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import platform
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from sqpmpc.control.settings import SolverSettings
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.record import RunRecord
from sqpmpc.sim.simulation import ClosedLoopSimulation, SimulationOptions

from .baseline import BaselineError, compare_baseline, render_baseline, resolve_checkout
from .report import publish, render_report
from .rows import (
    COMMAND,
    DEFAULT_SCENARIOS,
    DOC_PATH,
    QUICK_T_END,
    ROWS,
    RowResult,
    RowSpec,
    ScenarioResult,
)

#: Where ``--baseline`` writes its report.
BASELINE_DOC_PATH = Path(__file__).resolve().parents[1] / "docs" / "before-after.md"

__all__ = ["BASELINE_DOC_PATH", "build_parser", "compare", "machine_info", "machine_line", "main",
           "run_row"]


# ------------------------------------------------------------------------------ running


def _best_of(repeats: int, run: Callable[[], tuple[RunRecord, dict[str, float] | None]],
             ) -> tuple[RunRecord, dict[str, float] | None, int, float, bool]:
    """Run ``repeats`` times; keep the run with the smallest total controller time."""
    best: tuple[RunRecord, dict[str, float] | None] | None = None
    same = True
    t0 = time.perf_counter()
    for _ in range(max(repeats, 1)):
        record, timing = run()
        if best is None:
            best = (record, timing)
            continue
        same &= bool(np.array_equal(record.states, best[0].states))
        if record.solve_times.sum() < best[0].solve_times.sum():
            best = (record, timing)
    assert best is not None
    return best[0], best[1], max(repeats, 1), time.perf_counter() - t0, same


def run_row(scenario: Scenario, spec: RowSpec, repeats: int) -> RowResult:
    """Run one configuration on one scenario (best of ``repeats`` by controller time).

    Parameters
    ----------
    scenario
        The problem.
    spec
        The configuration.
    repeats
        Repetitions of the deterministic closed loop.

    Returns
    -------
    RowResult
        Metrics and timing of the kept repetition.
    """
    if spec.is_ipopt:
        from .ipopt_reference import simulate_ipopt

        def run() -> tuple[RunRecord, dict[str, float] | None]:
            record, _ = simulate_ipopt(scenario, **spec.settings)
            return record, None
    else:
        settings = SolverSettings(**spec.settings)

        def run() -> tuple[RunRecord, dict[str, float] | None]:
            sim = ClosedLoopSimulation(scenario, spec.scheme, settings, SimulationOptions())
            record = sim.run()
            return record, dict(sim.timing)

    record, timing, runs, wall, same = _best_of(repeats, run)
    return RowResult(spec, compute_metrics(record), timing,
                     int(record.solve_times.shape[0] * record.solve_times.shape[1]),
                     wall, runs, same)


def _quick(scenario: Scenario) -> Scenario:
    """The scenario cut to at most :data:`QUICK_T_END` seconds (whole samples)."""
    steps = min(scenario.steps, max(1, round(QUICK_T_END / scenario.sample_time)))
    return scenario.with_changes(t_end=steps * scenario.sample_time)


def compare(scenarios: Sequence[str], sqp_scenarios: Sequence[str] | None = None,
            repeats: int = 3, quick: bool = False,
            log: Callable[[str], None] | None = None) -> list[ScenarioResult]:
    """Run every row on every scenario.

    Parameters
    ----------
    scenarios
        Built-in names or TOML paths.
    sqp_scenarios
        Scenarios (as given in ``scenarios``) on which the SQP rows run;
        ``None`` means all.
    repeats
        Repetitions of RTI and IPOPT runs (SQP runs once).
    quick
        Cut every scenario to :data:`QUICK_T_END` seconds.
    log
        Progress callback (one line per run).

    Returns
    -------
    list[ScenarioResult]
        One entry per scenario, rows in :data:`ROWS` order (SQP rows omitted
        where not run).
    """
    out: list[ScenarioResult] = []
    for name in scenarios:
        scenario = load_scenario(name)
        if quick:
            scenario = _quick(scenario)
        rows = []
        for spec in ROWS:
            if spec.kind == "sqp" and sqp_scenarios is not None and name not in sqp_scenarios:
                continue
            reps = 1 if spec.kind == "sqp" else repeats
            row = run_row(scenario, spec, reps)
            rows.append(row)
            if log is not None:
                log(f"{scenario.name:>11} | {spec.label:<42} | cost {row.cost:10.3f} | "
                    f"median {row.median_sample_ms:8.3f} ms | {row.wall_s:6.1f} s "
                    f"({row.runs} run{'s' if row.runs > 1 else ''})")
        out.append(ScenarioResult(scenario, rows))
    return out


# ------------------------------------------------------------------------------ machine


def machine_line(started: float) -> str:
    """The reports' machine line: CPU, cores, versions, date and wall time since ``started``."""
    info = machine_info()
    return (f"Machine: {info['CPU']}, {info['cores']}, Python {info['Python']}, "
            f"OSQP {info['OSQP']};\n{info['date']}; wall time "
            f"{time.perf_counter() - started:.0f} s.")


def machine_info() -> dict[str, str]:
    """CPU model, core count, versions, date and load, as strings."""
    import osqp

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        import casadi

        casadi_version = casadi.__version__
    except ImportError:
        casadi_version = "not installed"
    try:
        usable = len(os.sched_getaffinity(0))
    except AttributeError:
        usable = os.cpu_count() or 0
    return {
        "CPU": cpu,
        "cores": f"{os.cpu_count()} logical ({usable} usable by this process)",
        "OS": f"{platform.system()} {platform.release()}",
        "Python": platform.python_version(),
        "NumPy": np.__version__,
        "OSQP": getattr(osqp, "__version__", "unknown"),
        "CasADi": casadi_version,
        "date": dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC"),
    }


def _load() -> str:
    try:
        return " / ".join(f"{v:.2f}" for v in os.getloadavg())
    except OSError:
        return "n/a"


# ------------------------------------------------------------------------------ CLI


def build_parser() -> argparse.ArgumentParser:
    """The command-line parser."""
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.compare_ipopt",
        description="sqpmpc against a converged CasADi + IPOPT reference, side by side.")
    parser.add_argument("--scenarios", nargs="+", default=list(DEFAULT_SCENARIOS),
                        metavar="NAME", help="built-in names or TOML files "
                        f"(default: {' '.join(DEFAULT_SCENARIOS)})")
    parser.add_argument("--sqp-scenarios", nargs="*", default=None, metavar="NAME",
                        help="scenarios with SQP rows (default: all; --quick: head-on; "
                        "give no name for none)")
    parser.add_argument("--quick", action="store_true",
                        help=f"cut runs to {QUICK_T_END:g} s, one repetition, SQP on head-on "
                        "only, print without writing the docs")
    parser.add_argument("--repeats", type=int, default=None,
                        help="repetitions of RTI and IPOPT runs (default 3, --quick 1)")
    parser.add_argument("--output", type=Path, default=None,
                        help="markdown file to write (default: docs/benchmarks.md for a full "
                        "run, none with --quick)")
    parser.add_argument("--no-write", action="store_true", help="print only")
    parser.add_argument("--baseline", metavar="PATH", default=None,
                        help="instead: per-sample time of this checkout and the checkout at "
                        "PATH side by side (default scenario paper-s2, RTI, both schemes; "
                        "writes docs/before-after.md)")
    parser.add_argument("--rounds", type=int, default=3,
                        help="--baseline: alternating rounds (default 3)")
    parser.add_argument("--iteration-scheme", choices=("rti", "sqp"), default="rti",
                        help="--baseline: iteration scheme (default rti)")
    return parser


def _main_baseline(args: argparse.Namespace, argv: Sequence[str] | None) -> int:
    """``--baseline``: the before/after timing table (:mod:`benchmarks.baseline`)."""
    try:
        root = resolve_checkout(args.baseline)
    except BaselineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    scenarios = args.scenarios if args.scenarios != list(DEFAULT_SCENARIOS) else ["paper-s2"]
    repeats = args.repeats if args.repeats is not None else 5
    output = args.output if args.output is not None else BASELINE_DOC_PATH
    if args.no_write:
        output = None
    started = time.perf_counter()
    try:
        result = compare_baseline(root, scenarios, ("centralized", "decentralized"),
                                  args.iteration_scheme, args.rounds, repeats,
                                  lambda line: print(line, file=sys.stderr, flush=True))
    except BaselineError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    argv_text = " ".join(sys.argv[1:] if argv is None else argv)
    report = render_baseline(result, f"{COMMAND} {argv_text}".strip(),
                             machine_line(started), args.iteration_scheme, repeats)
    publish(report, output)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    args = build_parser().parse_args(argv)
    if args.baseline is not None:
        return _main_baseline(args, argv)
    try:
        import casadi  # noqa: F401
    except ImportError:
        print("CasADi is missing: install the benchmark extra, pip install '.[bench]'",
              file=sys.stderr)
        return 2
    repeats = args.repeats if args.repeats is not None else (1 if args.quick else 3)
    sqp = args.sqp_scenarios
    if sqp is None and args.quick:
        sqp = [s for s in args.scenarios if s == "head-on"]
    output = args.output
    if output is None and not args.quick:
        output = DOC_PATH
    if args.no_write:
        output = None

    def log(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    info = machine_info()
    load_before = _load()
    t0 = time.perf_counter()
    results = compare(args.scenarios, sqp, repeats, args.quick, log)
    wall = time.perf_counter() - t0
    defaults = SolverSettings()
    notes = {
        "sqpmpc defaults": (
            f"kkt_tolerance {defaults.kkt_tolerance:g}, max_sqp_iterations "
            f"{defaults.max_sqp_iterations}, OSQP eps_abs/eps_rel {defaults.osqp.eps_abs:g}/"
            f"{defaults.osqp.eps_rel:g}, collision_margin {defaults.collision_margin:g} m, "
            f"rules {', '.join(r.name for r in defaults.rules)}, slack_penalty "
            f"{defaults.slack_penalty:g}"),
        "repetitions (RTI, IPOPT)": f"{repeats}, best kept",
        "SQP rows on": "all scenarios" if sqp is None else (", ".join(sqp) or "none"),
        "quick": f"yes, runs cut to {QUICK_T_END:g} s" if args.quick else "no (full runs)",
        "load average (1/5/15 min) before / after": f"{load_before}; {_load()}",
        "wall time of the whole comparison": f"{wall:.0f} s",
    }
    argv_text = " ".join(sys.argv[1:] if argv is None else argv)
    command = f"{COMMAND} {argv_text}".strip()
    report = render_report(results, info, command, notes)
    publish(report, output)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

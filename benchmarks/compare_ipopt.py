r"""sqpmpc against a converged CasADi + IPOPT reference, side by side in one run.

Usage (from the repository root, with the ``bench`` extra installed)::

    python -m benchmarks.compare_ipopt                  # full comparison, writes docs/benchmarks.md
    python -m benchmarks.compare_ipopt --quick          # short smoke run, prints only
    python -m benchmarks.compare_ipopt --scenarios head-on swap-6 --output /tmp/b.md

For every scenario it runs the closed loop with

- the reference (:mod:`benchmarks.ipopt_reference`): the centralized OCP with
  the nonlinear distance constraints solved to convergence by IPOPT (exact
  Hessian) at every sample, multipliers warm-started; a second IPOPT row with a
  primal-only warm start shows how much the closed loop of this non-convex
  problem depends on which local optimum IPOPT lands in;
- sqpmpc RTI centralized / decentralized, SQP centralized / decentralized
  (``iteration_scheme="sqp"``) and RTI centralized with ``hessian="exact"``,
  all with the library's default settings,

and prints two tables (quality and time, where the time goes) and the targets
met or missed. Everything is measured in the run; nothing is hard-coded.

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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sqpmpc.metrics import RunRecord, compute_metrics
from sqpmpc.rti import SolverSettings
from sqpmpc.scenario import Scenario, load_scenario
from sqpmpc.simulation import ClosedLoopSimulation, SimulationOptions

__all__ = [
    "DEFAULT_SCENARIOS",
    "TARGETS",
    "RowResult",
    "RowSpec",
    "ScenarioResult",
    "build_parser",
    "compare",
    "machine_info",
    "main",
    "render_report",
]

DEFAULT_SCENARIOS = ("paper-s1", "paper-s2", "swap-6", "head-on", "crossing-4")
COMMAND = "python -m benchmarks.compare_ipopt"
DOC_PATH = Path(__file__).resolve().parent.parent / "docs" / "benchmarks.md"
QUICK_T_END = 30.0
GOAL_TOLERANCE = 0.05

TARGETS: dict[str, float] = {
    "rti_cost_ratio": 1.05,  # RTI closed-loop cost <= 1.05 x IPOPT centralized
    "sqp_cost_ratio": 1.01,  # SQP <= 1.01 x
    "rti_time_ratio": 30.0,  # IPOPT controller time / RTI controller time >= 30
    "central_median_ms": 0.2,  # paper-s2 centralized RTI median sample
    "decentral_median_ms": 0.1,  # decentralized median per-robot sample
    "osqp_overhead": 1.5,  # whole controller time / OSQP's own solve time
    "goal_m": GOAL_TOLERANCE,  # every robot ends within this of its goal
}
TIMING_SCENARIO = "paper-s2"


@dataclass(frozen=True)
class RowSpec:
    """One controller configuration of the comparison.

    Attributes
    ----------
    label
        Row name in the tables.
    kind
        ``"ipopt"`` (reference), ``"ipopt-segment"`` (the reference with the
        distance also required between samples), ``"ipopt-variant"``,
        ``"rti"`` or ``"sqp"`` (which cost target applies).
    scheme
        ``"centralized"`` or ``"decentralized"``.
    settings
        Keyword arguments of :class:`sqpmpc.rti.SolverSettings` (sqpmpc rows)
        or of :func:`benchmarks.ipopt_reference.simulate_ipopt` (IPOPT rows).
    """

    label: str
    kind: str
    scheme: str
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def is_ipopt(self) -> bool:
        """Whether the row is an IPOPT run."""
        return self.kind.startswith("ipopt")


REFERENCE = RowSpec("IPOPT centralized (reference)", "ipopt", "centralized")
SEGMENT_REFERENCE = RowSpec("IPOPT centralized, inter-sample safe", "ipopt-segment",
                            "centralized", {"intersample_points": 3})
ROWS: tuple[RowSpec, ...] = (
    REFERENCE,
    SEGMENT_REFERENCE,
    RowSpec("IPOPT centralized, primal-only warm start", "ipopt-variant", "centralized",
            {"warm_start_duals": False}),
    RowSpec("sqpmpc RTI centralized", "rti", "centralized"),
    RowSpec("sqpmpc RTI decentralized", "rti", "decentralized"),
    RowSpec("sqpmpc SQP centralized", "sqp", "centralized", {"iteration_scheme": "sqp"}),
    RowSpec("sqpmpc SQP decentralized", "sqp", "decentralized", {"iteration_scheme": "sqp"}),
    RowSpec("sqpmpc RTI centralized, exact Hessian", "rti", "centralized",
            {"hessian": "exact"}),
)


@dataclass
class RowResult:
    """Measured outcome of one row on one scenario.

    Attributes
    ----------
    spec
        The configuration.
    metrics
        :func:`sqpmpc.metrics.compute_metrics` of the kept run.
    timing
        sqpmpc only: summed ``assembly_s``, ``qp_s``, ``osqp_solve_s`` and
        ``total_s`` of the kept run (``None`` for IPOPT).
    controller_steps
        Controller calls: samples times controllers.
    wall_s
        Wall time of all repetitions, s.
    runs
        Repetitions made.
    deterministic
        Whether every repetition produced the same closed-loop trajectory.
    """

    spec: RowSpec
    metrics: dict[str, Any]
    timing: dict[str, float] | None
    controller_steps: int
    wall_s: float
    runs: int
    deterministic: bool = True

    @property
    def cost(self) -> float:
        """Closed-loop cost of the executed trajectory."""
        return float(self.metrics["closed_loop_cost"])

    @property
    def total_time_s(self) -> float:
        """Controller time summed over samples and controllers, s."""
        return float(self.metrics["solve_time"]["total_s"])

    @property
    def median_sample_ms(self) -> float:
        """Median over samples of the controller time summed over controllers, ms."""
        return float(self.metrics["solve_time"]["median_ms"])

    @property
    def median_per_robot_ms(self) -> float:
        """Largest per-robot median controller time, ms (decentralized: one QP per robot)."""
        return float(max(self.metrics["solve_time"]["per_robot_median_ms"].values()))

    @property
    def final_error(self) -> float:
        """Largest final distance of a robot to its reference, m."""
        return float(self.metrics["max_final_position_error"])

    @property
    def at_goal(self) -> bool:
        """Every robot ended within :data:`GOAL_TOLERANCE` of its goal."""
        return self.final_error <= GOAL_TOLERANCE


@dataclass
class ScenarioResult:
    """All rows of one scenario; ``rows[0]`` is the IPOPT reference."""

    scenario: Scenario
    rows: list[RowResult]

    @property
    def reference(self) -> RowResult:
        """The IPOPT reference row."""
        return self.rows[0]

    @property
    def segment_reference(self) -> RowResult | None:
        """The inter-sample-safe IPOPT row, if it ran."""
        return next((r for r in self.rows if r.spec.kind == "ipopt-segment"), None)


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


# ------------------------------------------------------------------------------ report


def _f(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None or not np.isfinite(value) else f"{value:.{digits}f}"


def _mark(ok: bool) -> str:
    return "yes" if ok else "NO"


def _cost_target(row: RowResult) -> float | None:
    return {"rti": TARGETS["rti_cost_ratio"], "sqp": TARGETS["sqp_cost_ratio"]}.get(
        row.spec.kind)


def _cost_cell(row: RowResult, ref: RowResult | None) -> str:
    if ref is None:
        return "n/a"
    ratio = row.cost / ref.cost
    target = _cost_target(row)
    if row.spec.kind == ref.spec.kind:
        return "1 (reference)"
    if target is None:
        return _f(ratio)
    return f"{ratio:.3f} (<= {target:g}: {_mark(ratio <= target)})"


def _time_cell(row: RowResult, ref: RowResult) -> str:
    if row.spec.kind == "ipopt":
        return "1 (reference)"
    ratio = ref.total_time_s / row.total_time_s
    if row.spec.kind == "rti":
        target = TARGETS["rti_time_ratio"]
        return f"{ratio:.1f} (>= {target:g}: {_mark(ratio >= target)})"
    return f"{ratio:.2f}"


def _median_cell(row: RowResult) -> str:
    if row.spec.scheme == "decentralized":
        return f"{row.median_sample_ms:.3f} (per robot {row.median_per_robot_ms:.3f})"
    return f"{row.median_sample_ms:.3f}"


def _goal_cell(row: RowResult) -> str:
    return f"{row.final_error:.3f} ({_mark(row.at_goal)})"


def quality_table(results: Sequence[ScenarioResult]) -> str:
    """Markdown table: cost, time ratios, clearance, failures and goals per row."""
    head = ("| scenario | controller | closed-loop cost | cost ratio vs IPOPT | "
            "cost ratio vs inter-sample-safe IPOPT | "
            "controller-time ratio IPOPT / row | median sample ms | min clearance m | "
            "collisions | inter-sample min clearance m (collisions) | solver failures | "
            "max final error m (<= 0.05) |")
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for res in results:
        ref = res.reference
        for row in res.rows:
            m = row.metrics
            lines.append(
                f"| {res.scenario.name} | {row.spec.label} | {row.cost:.3f} | "
                f"{_cost_cell(row, ref)} | {_cost_cell(row, res.segment_reference)} | "
                f"{_time_cell(row, ref)} | {_median_cell(row)} | "
                f"{_f(m['min_clearance'], 4)} | {m['collisions']} | "
                f"{_f(m['intersample_min_clearance'], 4)} ({m['intersample_collisions']}) | "
                f"{m['solver_failures']} | {_goal_cell(row)} |")
    return "\n".join(lines)


def timing_table(results: Sequence[ScenarioResult]) -> str:
    """Markdown table: where the sqpmpc controller time goes, mean per controller step."""
    head = ("| scenario | controller | controller steps | assembly ms | QP update + solve ms | "
            "of which OSQP solve ms | rest ms | whole controller ms | "
            "controller / OSQP solve (<= 1.5) |")
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for res in results:
        for row in res.rows:
            if row.timing is None:
                continue
            t, n = row.timing, row.controller_steps
            rest = t["total_s"] - t["assembly_s"] - t["qp_s"]
            ratio = t["total_s"] / t["osqp_solve_s"] if t["osqp_solve_s"] > 0 else float("inf")
            ms = 1e3 / n
            lines.append(
                f"| {res.scenario.name} | {row.spec.label} | {n} | "
                f"{t['assembly_s'] * ms:.4f} | {t['qp_s'] * ms:.4f} | "
                f"{t['osqp_solve_s'] * ms:.4f} | {rest * ms:.4f} | {t['total_s'] * ms:.4f} | "
                f"{ratio:.2f} ({_mark(ratio <= TARGETS['osqp_overhead'])}) |")
    return "\n".join(lines)


@dataclass(frozen=True)
class _Value:
    """One measured value checked against a target."""

    scenario: str
    row: str
    value: float
    ok: bool
    counted: bool = True


_SHORT = {
    REFERENCE.label: "IPOPT",
    SEGMENT_REFERENCE.label: "IPOPT-seg",
    "IPOPT centralized, primal-only warm start": "IPOPT-primal",
    "sqpmpc RTI centralized": "RTI-c",
    "sqpmpc RTI decentralized": "RTI-d",
    "sqpmpc SQP centralized": "SQP-c",
    "sqpmpc SQP decentralized": "SQP-d",
    "sqpmpc RTI centralized, exact Hessian": "RTI-c-exact",
}


def _verdict(title: str, values: list[_Value], digits: int = 3) -> list[str]:
    """A bullet ``title: verdict`` and one sub-bullet per scenario with the values."""
    counted = [v for v in values if v.counted]
    missed = sum(not v.ok for v in counted)
    if not counted:
        head = "not measured" if not values else "no comparable run"
    elif missed == 0:
        head = f"**MET** ({len(counted)} of {len(counted)})"
    else:
        head = f"**MISSED** in {missed} of {len(counted)}"
    skipped = len(values) - len(counted)
    if skipped:
        head += f"; {skipped} not counted (the IPOPT reference did not reach the goal)"
    lines = [f"- {title}: {head}"]
    scenarios: dict[str, list[_Value]] = {}
    for v in values:
        scenarios.setdefault(v.scenario, []).append(v)
    for name, vals in scenarios.items():
        tag = "" if all(v.counted for v in vals) else " (not counted)"
        cells = ", ".join(f"{v.row} {v.value:.{digits}f}{'' if v.ok else ' (missed)'}"
                          for v in vals)
        lines.append(f"  - {name}{tag}: {cells}")
    return lines


def targets_summary(results: Sequence[ScenarioResult]) -> list[str]:
    """Bullets: every target with its verdict and every measured value.

    Cost targets are not counted on scenarios where the IPOPT reference did
    not bring every robot to its goal (it is then not an optimum to compare
    with); the values are still listed.
    """
    cost: dict[str, list[_Value]] = {"rti": [], "sqp": []}
    cost_seg: dict[str, list[_Value]] = {"rti": [], "sqp": []}
    time_ratio: list[_Value] = []
    overhead: list[_Value] = []
    central: list[_Value] = []
    decentral: list[_Value] = []
    goals: list[_Value] = []
    ipopt_goals: list[_Value] = []
    deadlocked: list[tuple[str, float]] = []
    for res in results:
        ref, name = res.reference, res.scenario.name
        if not ref.at_goal:
            deadlocked.append((name, ref.final_error))
        for row in res.rows:
            short = _SHORT.get(row.spec.label, row.spec.label)
            goal = _Value(name, short, row.final_error, row.at_goal)
            if row.spec.is_ipopt:
                ipopt_goals.append(goal)
                continue
            goals.append(goal)
            target = _cost_target(row)
            if target is not None:
                ratio = row.cost / ref.cost
                cost[row.spec.kind].append(_Value(name, short, ratio, ratio <= target,
                                                  ref.at_goal))
                seg = res.segment_reference
                if seg is not None:
                    ratio = row.cost / seg.cost
                    cost_seg[row.spec.kind].append(
                        _Value(name, short, ratio, ratio <= target, seg.at_goal))
            if row.spec.kind == "rti":
                r = ref.total_time_s / row.total_time_s
                time_ratio.append(_Value(name, short, r, r >= TARGETS["rti_time_ratio"]))
            if row.timing is not None and row.timing["osqp_solve_s"] > 0:
                r = row.timing["total_s"] / row.timing["osqp_solve_s"]
                overhead.append(_Value(name, short, r, r <= TARGETS["osqp_overhead"]))
            if (row.spec.kind == "rti" and name == TIMING_SCENARIO and not row.spec.settings
                    and row.spec.scheme == "centralized"):
                v = row.median_sample_ms
                central.append(_Value(name, short, v, v <= TARGETS["central_median_ms"]))
            if row.spec.kind == "rti" and row.spec.scheme == "decentralized":
                v = row.median_per_robot_ms
                decentral.append(_Value(name, short, v, v <= TARGETS["decentral_median_ms"]))
    lines: list[str] = []
    lines += _verdict(f"RTI closed-loop cost <= {TARGETS['rti_cost_ratio']:g} x IPOPT "
                      "centralized (ratio)", cost["rti"])
    lines += _verdict(f"SQP closed-loop cost <= {TARGETS['sqp_cost_ratio']:g} x IPOPT "
                      "centralized (ratio)", cost["sqp"])
    lines += _verdict(f"RTI closed-loop cost <= {TARGETS['rti_cost_ratio']:g} x IPOPT "
                      "centralized, inter-sample safe (ratio)", cost_seg["rti"])
    lines += _verdict(f"SQP closed-loop cost <= {TARGETS['sqp_cost_ratio']:g} x IPOPT "
                      "centralized, inter-sample safe (ratio)", cost_seg["sqp"])
    lines += _verdict(f"RTI controller time >= {TARGETS['rti_time_ratio']:g} x less than "
                      "IPOPT's (IPOPT total / RTI total, all controllers)", time_ratio, 1)
    lines += _verdict(f"median centralized RTI sample on {TIMING_SCENARIO} <= "
                      f"{TARGETS['central_median_ms']:g} ms (ms)", central)
    lines += _verdict(f"median decentralized per-robot sample <= "
                      f"{TARGETS['decentral_median_ms']:g} ms (largest per-robot median, ms)",
                      decentral)
    lines += _verdict(f"whole controller time <= {TARGETS['osqp_overhead']:g} x OSQP's own "
                      "solve time (ratio)", overhead, 2)
    lines += _verdict(f"sqpmpc: every robot ends within {GOAL_TOLERANCE:g} m of its goal "
                      "(max final error, m)", goals)
    lines += _verdict(f"IPOPT: every robot ends within {GOAL_TOLERANCE:g} m of its goal "
                      "(max final error, m)", ipopt_goals)
    if deadlocked:
        lines.append(
            f"- the IPOPT reference did not bring every robot within {GOAL_TOLERANCE:g} m of "
            "its goal on " + ", ".join(f"{name} ({err:.3f} m)" for name, err in deadlocked)
            + ". In the symmetric encounters this is a standoff (deadlock) of the converged "
            "plain OCP: cost ratios there compare against a reference that never arrives, "
            "not against an optimum (a ratio below 1 means sqpmpc arrived).")
    nondet = [f"{r.scenario.name} {row.spec.label}" for r in results for row in r.rows
              if not row.deterministic]
    if nondet:
        lines.append("- repetitions differed (non-deterministic closed loop): "
                     + ", ".join(nondet))
    return lines


def render_report(results: Sequence[ScenarioResult], info: dict[str, str],
                  command: str, notes: dict[str, str]) -> str:
    """The whole ``docs/benchmarks.md`` text.

    Parameters
    ----------
    results
        Output of :func:`compare`.
    info
        Output of :func:`machine_info`.
    command
        The command line that produced the results.
    notes
        Run facts (``repeats``, ``sqp scenarios``, ``load``, ``wall time``, ...).
    """
    from .ipopt_reference import WARM_MU_INIT

    machine = "\n".join(f"- {k}: {v}" for k, v in {**info, **notes}.items())
    legend = "; ".join(f"{short} = {label}" for label, short in _SHORT.items())
    return f"""# Benchmarks: sqpmpc against a converged IPOPT reference

Reproduce (from the repository root, after `pip install .[bench]`; CasADi is
the `bench` extra):

```
{command}
```

Everything below is written by that command from one run, all controllers
measured side by side; nothing is hard-coded. `--quick` runs a short smoke
version that only prints.

## What is compared

- **IPOPT centralized (reference)** (`benchmarks/ipopt_reference.py`): the
  centralized OCP of the paper (eq. 7) with the same Euler dynamics, weights
  and input bounds and the *nonlinear* distance constraints of eq. 5
  (`|p_j - p_l|^2 >= d_jl^2` on stages 1..N, no slacks, no margin, no detour
  rule), solved to convergence by CasADi + IPOPT (exact Hessian, `tol = 1e-8`)
  at every sample, warm-started from the shifted previous solution and
  multipliers (`warm_start_init_point`, `mu_init = {WARM_MU_INIT:g}`).
  Eq. 5 constrains the distance at the samples only, and with the paper's
  sampling times the converged optimum uses it: robots pass *through* each
  other between samples (see the *inter-sample* column: the relative motion
  along the straight segments the Euler plant moves on, exact for it).
  **IPOPT centralized, inter-sample safe** is the same OCP with the distance
  also required at 3 evenly spaced points inside every interval (a sampled
  version of the continuous constraint, which leaves dips of a few mm between
  those points): the converged optimum of a problem that, like sqpmpc's,
  does not let robots tunnel. Cost ratios are printed against both.
  **IPOPT centralized, primal-only warm start** solves the same NLPs with
  IPOPT's default initialization: the problem is non-convex, so the two land
  in different local optima and their closed-loop costs differ; that spread is
  the resolution of the cost ratios.
- **sqpmpc** with its default settings: RTI (one OSQP QP per sample) and SQP
  (`iteration_scheme="sqp"`, iterated to the KKT tolerance), centralized and
  decentralized (shared-responsibility hyperplanes), and RTI centralized with
  `hessian="exact"`.

Columns: *closed-loop cost* is the cost of the executed trajectory
(`compute_metrics`); *cost ratio* = row / IPOPT reference (and row / the
inter-sample-safe IPOPT row); *inter-sample min clearance* is the smallest
clearance along the straight segments between samples, with the number of
(interval, pair) below -1e-6 m; *controller-time
ratio* = IPOPT's total controller time / the row's (all samples; for
decentralized rows the time of all robots is summed, as if one core ran them);
*median sample* is the median over samples of the controller time summed over
controllers (decentralized: also the largest per-robot median); *min clearance*
is the smallest centre distance minus the required distance over the run (IPOPT
has no margin, so its minimum is 0 to within its tolerance, printed `-0.0000`
when a few nm below; sqpmpc keeps `collision_margin`
= {SolverSettings().collision_margin:g} m); *solver failures* are samples where
sqpmpc applied a fallback input or IPOPT did not report success; *max final
error* is the largest distance of a robot to its reference at the end, with
whether every robot ended within {GOAL_TOLERANCE:g} m. IPOPT's controller time
is the wall time of its whole step (solver call included); sqpmpc's is the controller's
`compute_time` of every sample (everything the controller does). RTI and IPOPT
closed loops (deterministic) are repeated and the repetition with the smallest
total controller time is kept; SQP runs once. Target checks are printed next to
the measured values.

## Machine and run

{machine}

## Quality and time

{quality_table(results)}

## Where the time goes (sqpmpc, mean per controller step)

*assembly*: linearization and QP value writes; *QP update + solve*: wall
time of `OSQP.update` + warm start + `solve`; *of which OSQP solve*: OSQP's
own `solve_time` (the floor of this design); *rest*: everything else the
controller does (reference sampling, detour rule, shifting, verification of
the first input, plan rollout). The last column is the whole controller time
over OSQP's own solve time.

{timing_table(results)}

## Targets

Row names: {legend}.

{chr(10).join(targets_summary(results))}
"""


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
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    args = build_parser().parse_args(argv)
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
            f"keep_right_angle {defaults.keep_right_angle:g} rad, detour rule "
            f"{'on' if defaults.detour.enabled else 'off'}, slack_penalty "
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
    print(report)
    if output is not None:
        output.parent.mkdir(parents=True, exist_ok=True)
        output.write_text(report)
        log(f"written {output}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Markdown report of the IPOPT comparison: tables, target verdicts, ``docs/benchmarks.md``."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sqpmpc.control.settings import SolverSettings

from .rows import (
    GOAL_TOLERANCE,
    REFERENCE,
    SEGMENT_REFERENCE,
    TARGETS,
    TIMING_SCENARIO,
    RowResult,
    ScenarioResult,
)

__all__ = ["publish", "quality_table", "render_report", "targets_summary", "timing_table"]


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


def _time_target(row: RowResult) -> float:
    """IPOPT / RTI time ratio target: 10 on paper-s2 centralized, 5 elsewhere."""
    if row.spec.scheme == "centralized" and not row.spec.settings and (
            row.scenario_name == TIMING_SCENARIO):
        return TARGETS["rti_time_ratio_central"]
    return TARGETS["rti_time_ratio"]


def _time_cell(row: RowResult, ref: RowResult) -> str:
    if row.spec.kind == "ipopt":
        return "1 (reference)"
    ratio = ref.total_time_s / row.total_time_s
    if row.spec.kind == "rti":
        target = _time_target(row)
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
            "controller / OSQP solve | RTI: controller / (QP update + solve) (<= 1.3) |")
    lines = [head, "|" + "---|" * head.count(" | ") + "---|"]
    for res in results:
        for row in res.rows:
            if row.timing is None:
                continue
            t, n = row.timing, row.controller_steps
            rest = t["total_s"] - t["assembly_s"] - t["qp_s"]
            ratio = t["total_s"] / t["osqp_solve_s"] if t["osqp_solve_s"] > 0 else float("inf")
            qp_ratio = t["total_s"] / t["qp_s"] if t["qp_s"] > 0 else float("inf")
            qp_cell = (f"{qp_ratio:.2f} ({_mark(qp_ratio <= TARGETS['qp_overhead'])})"
                       if row.spec.kind == "rti" else f"{qp_ratio:.2f}")
            ms = 1e3 / n
            lines.append(
                f"| {res.scenario.name} | {row.spec.label} | {n} | "
                f"{t['assembly_s'] * ms:.4f} | {t['qp_s'] * ms:.4f} | "
                f"{t['osqp_solve_s'] * ms:.4f} | {rest * ms:.4f} | {t['total_s'] * ms:.4f} | "
                f"{ratio:.2f} | {qp_cell} |")
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
    "sqpmpc RTI centralized, PIQP": "RTI-c-piqp",
    "sqpmpc RTI decentralized, PIQP": "RTI-d-piqp",
    "sqpmpc RTI decentralized, DAQP": "RTI-d-daqp",
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
                time_ratio.append(_Value(name, short, r, r >= _time_target(row)))
            if row.spec.kind == "rti" and row.timing is not None and row.timing["qp_s"] > 0:
                r = row.timing["total_s"] / row.timing["qp_s"]
                overhead.append(_Value(name, short, r, r <= TARGETS["qp_overhead"]))
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
    lines += _verdict(f"RTI controller time >= {TARGETS['rti_time_ratio_central']:g} x less "
                      f"than IPOPT's on {TIMING_SCENARIO} centralized and >= "
                      f"{TARGETS['rti_time_ratio']:g} x elsewhere (IPOPT total / RTI total, "
                      "all controllers)", time_ratio, 1)
    lines += _verdict(f"median centralized RTI sample on {TIMING_SCENARIO} <= "
                      f"{TARGETS['central_median_ms']:g} ms (ms)", central)
    lines += _verdict(f"median decentralized per-robot sample <= "
                      f"{TARGETS['decentral_median_ms']:g} ms (largest per-robot median, ms)",
                      decentral)
    lines += _verdict(f"RTI: whole controller time <= {TARGETS['qp_overhead']:g} x the QP's "
                      "update + solve wall time (ratio)", overhead, 2)
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


def publish(report: str, path: Path | None) -> None:
    """Print a Markdown report and, unless ``path`` is ``None``, write it there."""
    print(report)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(report)
        print(f"written {path}", file=sys.stderr)

"""Leave-one-out ablation of the default liveness rules: which rules still pay?

Configurations (:func:`configurations`): ``all`` (the default rules,
:func:`sqpmpc.rules.registry.select_rules` with ``None``), ``-R`` (all minus
the default rule ``R``, and minus every rule that ``requires`` ``R``, named in
the report) for every default rule, and ``none``. Each configuration runs the
same workloads, every run a closed loop stopped once every robot has stayed
within 0.05 m of its goal for 10 s (:func:`benchmarks.maps.run_until_home`) and
classified by :func:`benchmarks.maps.classify` (success: every robot home;
else collision, stuck or timeout; makespan normalized by the shortest routes at
full speed):

- ``maps``: the seeded families of :mod:`benchmarks.maps`
  (:func:`benchmarks.maps.family_scenario`: swap, pillars, warehouse, grid), seeds
  ``0..runs-1`` per family at the family's sizes up to 32 robots in turn
  (``--large``: plus seed 0 at 64 robots per family), decentralized; and every
  built-in scenario, decentralized, and centralized up to 6 robots (as
  ``python -m benchmarks.maps --centralized-max 6``);
- ``liveness``: the encounters of :mod:`benchmarks.liveness` (swap-6, crossing-4,
  head-on), both schemes, from the nominal start and ``--liveness-seeds`` starts
  perturbed by :func:`benchmarks.liveness.perturbed` (10 mm / 10 mrad);
- ``physics``: the nominal MuJoCo robot of :mod:`benchmarks.physical` on swap-6,
  head-on and corridor (``--quick``: swap-6, head-on), both schemes, declaring
  the bounds measured from its step responses
  (:func:`benchmarks.physical.declared_bounds`, :func:`benchmarks.physical.with_bounds`);
  collisions there also count the physics steps at which footprints overlap
  by more than 1 mm;
- ``fleet``: the antipodal swaps of :mod:`benchmarks.fleet`
  (:func:`sqpmpc.problem.fleets.antipodal_swap`, unperturbed) of 4 to 32
  robots, decentralized.

A rule *pays* when removing it loses a success, adds a collision, or raises the
median normalized makespan of a family (a maps family or built-ins per scheme, a
liveness or physics scenario per scheme, the fleet swaps) by more than 5 %.

A scenario whose roadmap is exact (:func:`sqpmpc.rules.registry.roadmap_is_exact`:
grid formations, room-door, the MovingAI maps) runs the ``coordination`` rule alone by
default, not these rules: it is left out of every configuration (the report counts
them), so that a verdict is about the scenarios the rules serve.

Reproduce (writes ``docs/ablation.md``; 35 minutes of one core here, 12
configurations of 87 runs)::

    python -m benchmarks.ablation --large

``--quick`` runs a subset in under a minute per configuration (and writes nothing
unless ``--out`` is given); ``--runs K`` sets the seeds per maps family;
``--configs all,-route`` runs only those configurations; ``--json PATH`` also
keeps every run's outcome.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sqpmpc.control.settings import SolverSettings
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.fleets import antipodal_swap
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import builtin_scenario_names, load_scenario
from sqpmpc.rules.registry import RULES, default_names, roadmap_is_exact, select_rules
from sqpmpc.sim.physics import PhysicalRobot, PhysicalSimulation
from sqpmpc.sim.simulation import ClosedLoopSimulation

from . import fleet, liveness, maps, physical
from .compare_ipopt import machine_line

__all__ = ["Case", "configurations", "main", "run_case", "verdicts", "workloads"]

DOC_PATH = Path(__file__).resolve().parent.parent / "docs" / "ablation.md"
WORKLOADS = ("maps", "liveness", "physics", "fleet")
#: a family's median normalized makespan may grow this much before a rule pays for it
MAKESPAN_TOLERANCE = 0.05
OUTCOMES = ("success", "collision", "stuck", "timeout")


@dataclass(frozen=True)
class Case:
    """One closed loop of a workload: its family (the unit of the makespan verdict),
    its scenario (built lazily) and scheme; ``physics`` runs it on the MuJoCo robot."""

    workload: str
    family: str
    name: str
    scheme: str
    build: Callable[[], Scenario]
    physics: bool = False


def configurations(only: Sequence[str] | None = None) -> dict[str, tuple[tuple[str, ...], str]]:
    """Configuration label -> (rule names, note): ``all``, ``-R`` per default rule ``R``
    (minus the rules that require ``R``, transitively, said in the note), ``none``;
    ``only`` keeps those labels."""
    defaults = default_names()
    out: dict[str, tuple[tuple[str, ...], str]] = {"all": (tuple(defaults), "")}
    for rule in defaults:
        removed = {rule}
        grew = True
        while grew:
            extra = {n for n in defaults if n not in removed
                     and any(r in removed for r in RULES[n].requires)}
            removed |= extra
            grew = bool(extra)
        note = ("" if removed == {rule} else
                f"also without {', '.join(sorted(removed - {rule}))}, which require {rule}")
        out[f"-{rule}"] = (tuple(n for n in defaults if n not in removed), note)
    out["none"] = ((), "")
    if only is not None:
        unknown = [c for c in only if c not in out]
        if unknown:
            raise SystemExit(f"unknown configurations {unknown}; they are {', '.join(out)}")
        out = {c: out[c] for c in only}
    return out


def _all_workloads(runs: int, liveness_seeds: int, quick: bool, large: bool,
                   chosen: Sequence[str] = WORKLOADS) -> list[Case]:
    """Every case of the chosen workloads, in a fixed order."""
    cases: list[Case] = []
    if "maps" in chosen:
        for name in builtin_scenario_names():
            sc = load_scenario(name)
            if quick and sc.n_robots > 6:
                continue
            for scheme in ["decentralized"] + (["centralized"] if sc.n_robots <= 6 else []):
                cases.append(Case("maps", f"built-in {scheme}", name, scheme,
                                  lambda name=name: load_scenario(name)))
        for family in ("swap", "pillars", "warehouse", "grid"):
            sizes = [s for s in maps.SIZES[family] if s <= (16 if quick else 32)]
            for seed in range(runs):
                size = sizes[seed % len(sizes)]
                cases.append(Case("maps", family, f"{family}-{size} seed {seed}", "decentralized",
                                  lambda f=family, n=size, s=seed: maps.family_scenario(f, n, s)))
            if large:
                cases.append(Case("maps", family, f"{family}-64 seed 0", "decentralized",
                                  lambda f=family: maps.family_scenario(f, 64, 0)))
    if "liveness" in chosen:
        for name in liveness.SCENARIOS:
            for scheme in ("centralized", "decentralized"):
                for seed in range(liveness_seeds + 1):
                    cases.append(Case("liveness", f"{name} {scheme}", f"{name} seed {seed}",
                                      scheme, lambda name=name, seed=seed: liveness.perturbed(
                                          load_scenario(name), seed, 1e-2)))
    if "physics" in chosen:
        bounds = physical.declared_bounds(physical.step_response(PhysicalRobot()))
        for name in ("swap-6", "head-on") if quick else ("swap-6", "head-on", "corridor"):
            for scheme in physical.SCHEMES:
                cases.append(Case("physics", f"{name} {scheme}", name, scheme,
                                  lambda name=name: physical.with_bounds(load_scenario(name),
                                                                         bounds),
                                  physics=True))
    if "fleet" in chosen:
        for n in (s for s in fleet.SIZES if s <= (8 if quick else 32)):
            cases.append(Case("fleet", "swap decentralized", f"swap-{n}", "decentralized",
                              lambda n=n: antipodal_swap(n)))
    return cases


def workloads(runs: int, liveness_seeds: int, quick: bool, large: bool,
              chosen: Sequence[str] = WORKLOADS) -> tuple[list[Case], list[Case]]:
    """The cases of the chosen workloads that run the rules by default, in a fixed order
    (the same in every configuration), and the cases left out because their roadmap is
    exact (module docstring)."""
    cases = _all_workloads(runs, liveness_seeds, quick, large, chosen)
    exact = {id(case) for case in cases if roadmap_is_exact(case.build())}
    return ([c for c in cases if id(c) not in exact], [c for c in cases if id(c) in exact])


def run_case(case: Case, settings: SolverSettings) -> dict[str, Any]:
    """One closed loop of ``case`` under ``settings``: outcome, normalized makespan,
    collision counts (robots at and between samples, obstacles; on the physics plant
    also the physics steps of overlapping footprints) and wall time."""
    started = time.perf_counter()
    sc = case.build()
    sim: ClosedLoopSimulation = (PhysicalSimulation(sc, case.scheme, settings)
                                 if case.physics else
                                 ClosedLoopSimulation(sc, case.scheme, settings))
    maps.run_until_home(sim)
    record = sim.record()
    metrics = compute_metrics(record)
    out = maps.classify(record, metrics)
    robots = int(metrics["collisions"] + record.extra.get("overlap_steps", 0))
    obstacles = int(metrics["obstacle_collisions"] + record.extra.get("obstacle_overlap_steps", 0))
    between = int(metrics["intersample_collisions"])
    if robots + obstacles + between and out["outcome"] != "collision":
        out["outcome"] = "collision"
        out["makespan"] = math.nan
    return {"workload": case.workload, "family": case.family, "name": case.name,
            "scheme": case.scheme, "robots": sc.n_robots, "outcome": out["outcome"],
            "makespan": out["makespan"], "robot_collisions": robots,
            "between_collisions": between, "obstacle_collisions": obstacles,
            "wall_s": time.perf_counter() - started}


def _median(values: Sequence[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.median(finite)) if finite else math.nan


def _medians(rows: Sequence[dict[str, Any]]) -> dict[tuple[str, str], float]:
    """(workload, family) -> median normalized makespan of its successful runs."""
    groups: dict[tuple[str, str], list[float]] = {}
    for r in rows:
        groups.setdefault((r["workload"], r["family"]), []).append(r["makespan"])
    return {k: _median(v) for k, v in groups.items()}


def verdicts(rows: dict[str, list[dict[str, Any]]]) -> dict[str, tuple[bool, list[str]]]:
    """Configuration ``-R`` -> (whether ``R`` pays, the evidence) against ``all``: runs
    that succeed in ``all`` and not without it, runs that collide without it and not in
    ``all``, families whose median makespan grows more than :data:`MAKESPAN_TOLERANCE`;
    the evidence lists what improved too."""
    base = {(r["workload"], r["name"], r["scheme"]): r for r in rows["all"]}
    base_medians = _medians(rows["all"])
    out: dict[str, tuple[bool, list[str]]] = {}
    for label, runs in rows.items():
        if not label.startswith("-"):
            continue
        lost, gained, collided = [], [], []
        for r in runs:
            b = base.get((r["workload"], r["name"], r["scheme"]))
            if b is None:
                continue
            where = f"{r['workload']}: {r['name']} {r['scheme']}"
            if b["outcome"] == "success" and r["outcome"] != "success":
                lost.append(f"{where} ({r['outcome']})")
            elif b["outcome"] != "success" and r["outcome"] == "success":
                gained.append(where)
            if r["outcome"] == "collision" and b["outcome"] != "collision":
                collided.append(where)
        slower, faster = [], []
        for key, median in _medians(runs).items():
            ref = base_medians.get(key, math.nan)
            if not (math.isfinite(ref) and math.isfinite(median)):
                continue
            text = f"{key[0]} {key[1]} {ref:.2f} -> {median:.2f}"
            if median > (1.0 + MAKESPAN_TOLERANCE) * ref:
                slower.append(text)
            elif median < (1.0 - MAKESPAN_TOLERANCE) * ref:
                faster.append(text)
        evidence = []
        for title, items in (("loses", lost), ("collides", collided),
                             ("median makespan up > 5 %", slower), ("gains", gained),
                             ("median makespan down > 5 %", faster)):
            if items:
                evidence.append(f"{title}: {'; '.join(items)}")
        out[label] = (bool(lost or collided or slower), evidence)
    return out


def _cell_rows(runs: Sequence[dict[str, Any]]) -> Iterator[tuple[str, str]]:
    """(row label, cell) of one configuration's runs of one workload."""
    count = {o: sum(r["outcome"] == o for r in runs) for o in OUTCOMES}
    yield "success / runs", f"{count['success']}/{len(runs)}"
    yield ("collisions: robots / between samples / obstacles",
           f"{sum(r['robot_collisions'] for r in runs)} / "
           f"{sum(r['between_collisions'] for r in runs)} / "
           f"{sum(r['obstacle_collisions'] for r in runs)}")
    yield "collision runs", str(count["collision"])
    yield "stuck / timeout runs", f"{count['stuck']} / {count['timeout']}"
    yield "median makespan (successes)", f"{_median([r['makespan'] for r in runs]):.2f}"
    families: dict[str, list[dict[str, Any]]] = {}
    for r in runs:
        families.setdefault(r["family"], []).append(r)
    for family, rs in families.items():
        ok = sum(r["outcome"] == "success" for r in rs)
        yield (f"{family}: success, median makespan",
               f"{ok}/{len(rs)}, {_median([r['makespan'] for r in rs]):.2f}")
    yield "wall time s", f"{sum(r['wall_s'] for r in runs):.0f}"


def report(rows: dict[str, list[dict[str, Any]]], notes: dict[str, str], command: str,
           started: float, configs: dict[str, tuple[tuple[str, ...], str]],
           left_out: Sequence[str] = ()) -> str:
    """The Markdown report of the runs so far (``left_out``: the runs whose roadmap is
    exact, named)."""
    labels = list(rows)
    lines = ["# Ablation of the liveness rules", "",
             f"Generated by `{command}` (the module docstring of `benchmarks/ablation.py` "
             "says what runs). Every configuration runs the same closed loops: "
             "`all` is the default rules, `-R` the defaults without rule `R`, `none` no "
             "rule. A run succeeds when every robot is within 0.05 m of its goal; "
             "collisions count robots at samples, between samples and obstacles "
             "(`benchmarks.maps.classify`; on the MuJoCo plant also the physics steps at "
             "which footprints overlap); makespans are normalized by the shortest routes "
             "at full speed, medians over the successful runs.", "",
             machine_line(started), "", "## Configurations", ""]
    for label in labels:
        names = configs[label][0] if label in configs else ()
        note = notes.get(label, "")
        lines.append(f"- `{label}`: {', '.join(names) or 'no rule'}"
                     + (f" ({note})" if note else ""))
    if left_out:
        lines += ["", f"Left out of every configuration, because their roadmap is exact and "
                  f"they run the `coordination` rule alone by default ({len(left_out)}): "
                  + ", ".join(left_out) + "."]
    for workload in WORKLOADS:
        per = {label: [r for r in rows[label] if r["workload"] == workload] for label in labels}
        if not any(per.values()):
            continue
        cells = {label: dict(_cell_rows(runs)) for label, runs in per.items() if runs}
        keys = list(dict.fromkeys(k for c in cells.values() for k in c))
        lines += ["", f"## {workload}", "",
                  "| | " + " | ".join(f"`{c}`" for c in cells) + " |",
                  "|---" * (len(cells) + 1) + "|"]
        for key in keys:
            lines.append(f"| {key} | " + " | ".join(c.get(key, "-") for c in cells.values())
                         + " |")
    if "all" in rows:
        lines += ["", "## Verdicts", "",
                  "A rule *pays* when removing it loses a success, adds a collision or "
                  f"raises a family's median makespan by more than "
                  f"{100 * MAKESPAN_TOLERANCE:.0f} % (against `all`).", ""]
        for label, (pays, evidence) in verdicts(rows).items():
            lines.append(f"- `{label[1:]}`: **{'pays' if pays else 'does not pay'}**"
                         + (f". {' '.join(e + '.' for e in evidence)}" if evidence else
                            ": no run lost or gained, no family's median moved by 5 %."))
    lines += ["", "## Every run", "",
              "| configuration | workload | run | scheme | robots | outcome | makespan |",
              "|---|---|---|---|---|---|---|"]
    for label in labels:
        for r in rows[label]:
            lines.append(f"| `{label}` | {r['workload']} | {r['name']} | {r['scheme']} | "
                         f"{r['robots']} | {r['outcome']} | {r['makespan']:.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ablation and write the report; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.ablation",
                                     description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("--quick", action="store_true",
                        help="a subset: 2 seeds per maps family up to 16 robots, "
                             "built-ins up to 6 robots, 1 perturbed liveness start, swaps "
                             "of 4 and 8, physics on swap-6 and head-on; writes nothing "
                             "unless --out is given")
    parser.add_argument("--runs", type=int, default=None,
                        help="seeded runs per maps family (default 8, --quick 2)")
    parser.add_argument("--liveness-seeds", type=int, default=None,
                        help="perturbed starts per liveness encounter (default 3, --quick 1)")
    parser.add_argument("--large", action="store_true",
                        help="also one 64-robot run per maps family")
    parser.add_argument("--workloads", default=",".join(WORKLOADS))
    parser.add_argument("--configs", default=None,
                        help="comma-separated configuration labels (default: all of them)")
    parser.add_argument("--out", default=None, help="the report (default docs/ablation.md; "
                                                    "--quick: print only)")
    parser.add_argument("--json", default=None, help="also write the runs to this file")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    runs = args.runs if args.runs is not None else (2 if args.quick else 8)
    seeds = args.liveness_seeds if args.liveness_seeds is not None else (1 if args.quick else 3)
    configs = configurations(None if args.configs is None else args.configs.split(","))
    out = Path(args.out) if args.out else (None if args.quick else DOC_PATH)
    command = "python -m benchmarks.ablation " + " ".join(
        sys.argv[1:] if argv is None else argv)
    rows: dict[str, list[dict[str, Any]]] = {}
    notes = {label: note for label, (_, note) in configs.items() if note}
    cases, exact = workloads(runs, seeds, args.quick, args.large, args.workloads.split(","))
    left_out = [f"{case.name} {case.scheme}" for case in exact]
    print(f"{len(configs)} configurations x {len(cases)} runs ({len(left_out)} left out: "
          "coordination by default)", file=sys.stderr, flush=True)

    def write() -> None:
        text = report(rows, notes, command.strip(), started, configs, left_out)
        if out is not None:
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(text)
        if args.json:
            Path(args.json).write_text(json.dumps(
                {"rows": rows, "notes": notes,
                 "rules": {label: list(c[0]) for label, c in configs.items()}}))

    for label, (names, _) in configs.items():
        settings = SolverSettings(rules=select_rules(list(names)))
        rows[label] = []
        for case in cases:
            r = run_case(case, settings)
            rows[label].append(r)
            print(f"{label} {r['workload']} {r['name']} {r['scheme']}: {r['outcome']} "
                  f"{r['makespan']:.2f} ({r['wall_s']:.1f} s)", file=sys.stderr, flush=True)
        write()
    text = report(rows, notes, command.strip(), started, configs, left_out)
    if out is None:
        print(text)
    else:
        print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

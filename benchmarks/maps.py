"""Maps: do fleets arrive among pillars, shelves and each other, and how fast?

Seeded families, run decentralized (``--centralized-max M`` adds the
centralized scheme for runs of at most M robots):

- ``swap``: antipodal swaps (:func:`sqpmpc.problem.fleets.antipodal_swap`);
- ``pillars``: random crossings (:func:`sqpmpc.problem.fleets.random_crossings`)
  with pillars (circles of 0.4-0.8 m) dropped at random where they touch no
  start, goal or straight way's end;
- ``warehouse``: the built-in warehouse's shelves and walls, robots at random
  dock positions on both sides, goals at random in the aisles;
- ``grid``: grid-to-grid formations from 3x3 to 8x8;

plus every built-in scenario once. A run is a *success* when every robot is
within 0.05 m of its goal at ``t_end``; otherwise a *collision* (robots or
obstacles, at or between samples), *stuck* (an unarrived robot moved less than
0.1 m in the last 20 s) or *timeout*. Makespan and flowtime are normalized by
each robot's shortest route at full speed (:func:`sqpmpc.problem.routes.route_lengths`):
``max_j T_j / max_j (L_j / v_max)`` and ``sum_j T_j / sum_j (L_j / v_max)``, with
``T_j`` the time after which robot ``j`` stays within 0.05 m of its goal. A run
whose robots have all stayed within 0.05 m of their goals for 10 s is stopped
there (nothing moves any more).

Reproduce (writes ``docs/maps.md``)::

    python -m benchmarks.maps --runs 50
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from sqpmpc.control.settings import SolverSettings
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.fleets import antipodal_swap, grid_to_grid, random_crossings
from sqpmpc.problem.obstacles import Obstacle
from sqpmpc.problem.routes import route_lengths
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import builtin_scenario_names, load_scenario
from sqpmpc.rules.registry import select_rules
from sqpmpc.sim.record import RunRecord
from sqpmpc.sim.simulation import ClosedLoopSimulation

__all__ = ["classify", "family_scenario", "main", "run_until_home"]

V_MAX = 0.6
TOLERANCE = 0.05
SIZES = {"swap": (4, 6, 8, 16, 32, 64), "pillars": (4, 8, 16, 32, 64),
         "warehouse": (4, 8, 16, 32, 64), "grid": (9, 16, 25, 36, 49, 64)}


def _pillars(sc: Scenario, rng: np.random.Generator) -> Scenario:
    starts = sc.initial_states()[:, :2]
    goals = sc.reference_positions(0.0)
    side = float(np.abs(np.concatenate((starts, goals))).max())
    pillars: list[Obstacle] = []
    for _ in range(200):
        if len(pillars) >= max(2, sc.n_robots // 3):
            break
        d = float(rng.uniform(0.4, 0.8))
        c = rng.uniform(-side, side, size=2)
        ends = np.concatenate((starts, goals))
        if np.min(np.hypot(*(ends - c).T)) < 0.5 * d + 0.6:
            continue
        if any(np.hypot(*(c - np.asarray(o.position))) < 0.5 * (d + o.diameter) + 0.8
               for o in pillars):
            continue
        pillars.append(Obstacle(position=(float(c[0]), float(c[1])), diameter=d))
    return sc.with_changes(obstacles=tuple(pillars), name=f"pillars-{sc.n_robots}")


def _warehouse(n: int, rng: np.random.Generator) -> Scenario:
    base = load_scenario("warehouse")
    docks = [(x, y) for x in (-8.0, -7.3, -6.6, 6.6, 7.3, 8.0)
             for y in np.arange(-4.8, 4.81, 0.8)]
    aisles = [(x, y) for y in (-4.75, -2.4, 0.0, 2.4, 4.75)
              for x in (*np.arange(-3.6, 3.61, 0.8), -5.6, -4.8, 4.8, 5.6)]
    starts = [docks[i] for i in rng.choice(len(docks), n, replace=False)]
    goals = [aisles[i] for i in rng.choice(len(aisles), n, replace=False)]
    proto = base.robots[0]
    robots = tuple(type(proto)(id=i + 1, initial_state=(s[0], s[1], 0.0 if s[0] < 0 else math.pi),
                               diameter=proto.diameter,
                               reference=type(proto.reference)(position=g))
                   for i, (s, g) in enumerate(zip(starts, goals, strict=True)))
    return base.with_changes(robots=robots, name=f"warehouse-{n}",
                             t_end=float(max(120.0, 4.0 * n)))


def _perturbed(sc: Scenario, rng: np.random.Generator) -> Scenario:
    """Initial positions moved by up to 10 mm and headings turned by up to 10 mrad."""
    robots = tuple(type(r)(id=r.id, initial_state=(
        r.initial_state[0] + float(rng.uniform(-0.01, 0.01)),
        r.initial_state[1] + float(rng.uniform(-0.01, 0.01)),
        r.initial_state[2] + float(rng.uniform(-0.01, 0.01))), diameter=r.diameter,
        reference=r.reference) for r in sc.robots)
    return sc.with_changes(robots=robots, name=f"{sc.name}-s{int(rng.integers(1000))}")


def family_scenario(family: str, size: int, seed: int) -> Scenario:
    """The seeded scenario of a family with ``size`` robots (swaps and grids: their
    initial states perturbed by up to 10 mm and 10 mrad, seeded)."""
    rng = np.random.default_rng(seed)
    if family == "swap":
        return _perturbed(antipodal_swap(size), rng)
    if family == "pillars":
        return _pillars(random_crossings(size, seed), rng)
    if family == "warehouse":
        return _warehouse(size, rng)
    side = int(round(math.sqrt(size)))
    return _perturbed(grid_to_grid(side, side), rng)


def classify(record: RunRecord, metrics: dict) -> dict:
    """Outcome, normalized makespan and flowtime of one run."""
    sc = record.scenario
    t = record.t
    goals = sc.reference_positions(sc.t_end)
    err = np.hypot(*(record.states[:, :, :2] - goals[None]).transpose(2, 0, 1))
    inside = err <= TOLERANCE
    arrival = np.full(sc.n_robots, math.inf)
    for j in range(sc.n_robots):
        out = np.flatnonzero(~inside[:, j])
        if not out.size:
            arrival[j] = 0.0
        elif out[-1] < t.size - 1:
            arrival[j] = t[out[-1] + 1]
    lengths = route_lengths(sc, goals)
    ideal = np.array([math.nan if v is None else v / V_MAX for v in lengths])
    collided = (metrics["collisions"] + metrics["intersample_collisions"]
                + metrics["obstacle_collisions"]) > 0
    arrived = bool(np.isfinite(arrival).all() and err[-1].max() <= TOLERANCE)
    # makespan and flowtime only mean something for goals at rest
    goals_at_rest = all(type(r.reference).__name__ == "PointReference" for r in sc.robots)
    if collided:
        outcome = "collision"
    elif arrived:
        outcome = "success"
    else:
        window = max(1, int(round(20.0 / sc.sample_time)))
        moved = np.hypot(*(record.states[-1, :, :2]
                           - record.states[max(0, t.size - 1 - window), :, :2]).T)
        outcome = "stuck" if np.any((err[-1] > TOLERANCE) & (moved < 0.1)) else "timeout"
    return {"outcome": outcome,
            "makespan": float(arrival.max() / np.nanmax(ideal)) if arrived and goals_at_rest
            else math.nan,
            "flowtime": float(arrival.sum() / np.nansum(ideal)) if arrived and goals_at_rest
            else math.nan,
            "min_clearance": metrics["min_clearance"],
            "obstacle_clearance": metrics["min_obstacle_clearance"]}


def run_until_home(sim: ClosedLoopSimulation) -> None:
    """Step ``sim`` to its scenario's end, or until every robot, all with goals at rest, has
    stayed within :data:`TOLERANCE` of its goal for 10 s (nothing moves any more)."""
    sc = sim.scenario
    goals = sc.reference_positions(sc.t_end)
    at_rest = all(type(r.reference).__name__ == "PointReference" for r in sc.robots)
    settle = int(round(10.0 / sc.sample_time))
    inside_for = 0
    while sim.k < sc.steps:
        sim.step()
        if at_rest:
            err = np.hypot(*(sim.states[sim.k, :, :2] - goals).T).max()
            inside_for = inside_for + 1 if err <= TOLERANCE else 0
            if inside_for > settle:
                break


def _run(sc: Scenario, scheme: str, settings: SolverSettings | None = None) -> dict:
    """One closed loop, stopped early once every robot has stayed within the tolerance of
    its goal at rest for 10 s (nothing moves any more: every rule is quiet)."""
    t0 = time.perf_counter()
    sim = ClosedLoopSimulation(sc, scheme, settings)
    run_until_home(sim)
    record = sim.record()
    out = classify(record, compute_metrics(record))
    out.update(name=sc.name, robots=sc.n_robots, scheme=scheme,
               wall_s=time.perf_counter() - t0)
    return out


def _table(rows: list[dict], key: str) -> list[str]:
    lines = [f"| {key} | scheme | runs | robots | success | collision | stuck | timeout "
             "| median makespan | median flowtime |", "|---|---|---|---|---|---|---|---|---|---|"]
    groups: dict[tuple[str, str], list[dict]] = {}
    for r in rows:
        groups.setdefault((r[key], r["scheme"]), []).append(r)
    for (name, scheme), rs in groups.items():
        count = {o: sum(r["outcome"] == o for r in rs)
                 for o in ("success", "collision", "stuck", "timeout")}
        mk = [r["makespan"] for r in rs if math.isfinite(r["makespan"])]
        fl = [r["flowtime"] for r in rs if math.isfinite(r["flowtime"])]
        sizes = sorted({r["robots"] for r in rs})
        lines.append(f"| {name} | {scheme} | {len(rs)} | {sizes[0]}-{sizes[-1]} | "
                     f"{count['success']} | {count['collision']} | {count['stuck']} | "
                     f"{count['timeout']} | "
                     f"{np.median(mk) if mk else math.nan:.2f} | "
                     f"{np.median(fl) if fl else math.nan:.2f} |")
    return lines


def _summary(rows: list[dict]) -> list[str]:
    """The campaign in a few lines: safety, arrival, sizes, makespans."""
    runs = [r for r in rows if r["family"] != "built-in"]
    bad = [r for r in rows if r["outcome"] == "collision"]
    failed = [f"{r['name']} ({r['scheme']}, {r['outcome']})" for r in rows
              if r["outcome"] not in ("success", "collision")]
    lines = [f"- {len(rows)} runs ({len(rows) - len(runs)} of built-ins, {len(runs)} seeded), "
             f"{sum(r['scheme'] == 'centralized' for r in rows)} of them centralized; "
             f"wall time {sum(r['wall_s'] for r in rows) / 60:.0f} min.",
             f"- Collisions with robots or obstacles, at or between samples: {len(bad)} runs"
             + (f" ({', '.join(r['name'] for r in bad)})" if bad else "") + ".",
             f"- Every robot within {TOLERANCE} m of its goal by t_end: "
             f"{sum(r['outcome'] == 'success' for r in rows)} of {len(rows)} runs"
             + (f"; not: {', '.join(failed)}" if failed else "") + "."]
    for family in dict.fromkeys(r["family"] for r in runs):
        rs = [r for r in runs if r["family"] == family and r["scheme"] == "decentralized"]
        mk = [r["makespan"] for r in rs if math.isfinite(r["makespan"])]
        sizes = sorted({r["robots"] for r in rs})
        lines.append(f"- `{family}`, decentralized: {len(rs)} runs of {sizes[0]} to "
                     f"{sizes[-1]} robots ({sum(r['robots'] == sizes[-1] for r in rs)} at "
                     f"{sizes[-1]}); median normalized makespan "
                     f"{np.median(mk) if mk else math.nan:.2f}.")
    return lines


def _write(rows: list[dict], out: str, argv: Sequence[str]) -> None:
    """The report of the runs so far."""
    lines = ["# Maps: fleets among walls, shelves and pillars", "",
             "Generated by `python -m benchmarks.maps " + " ".join(argv) + "`. Families "
             "(seeded): `swap` antipodal swaps (initial states perturbed by up to 10 mm and "
             "10 mrad), `pillars` random crossings with random pillars, `warehouse` the "
             "built-in warehouse's shelves with random docks and goals in the aisles, `grid` "
             "grid-to-grid formations 3x3 to 8x8 (perturbed like the swaps); and every "
             "built-in. A run succeeds when every robot is within 0.05 m of its goal (or "
             "reference) at the end; otherwise it is a *collision* (robots or obstacles, at "
             "or between samples), *stuck* (an unarrived robot moved less than 0.1 m in the "
             "last 20 s) or a *timeout*. Makespan and flowtime are normalized by each robot's "
             "shortest route at full speed (0.6 m/s; the route through the static map, "
             "`sqpmpc.problem.routes`), for goals at rest only. A run whose robots all stayed "
             "within 0.05 m for 10 s is stopped there.", "", "## Summary", "",
             *_summary(rows), "",
             "## By family", "", *_table(rows, "family"), "",
             "## By family and size", "",
             *_table([r | {"size": f"{r['family']} {r['robots']}"} for r in rows], "size"),
             "", "## Every run", "",
             "| run | scheme | robots | outcome | makespan | flowtime | min clearance | "
             "min obstacle clearance |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        oc = r["obstacle_clearance"]
        lines.append(f"| {r['name']} | {r['scheme']} | {r['robots']} | {r['outcome']} | "
                     f"{r['makespan']:.2f} | {r['flowtime']:.2f} | "
                     f"{r['min_clearance']:.4f} | "
                     f"{'-' if oc is None else f'{oc:.4f}'} |")
    Path(out).write_text("\n".join(lines) + "\n")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the campaign and write the report."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.maps")
    parser.add_argument("--runs", type=int, default=50, help="seeded runs per family")
    parser.add_argument("--max-robots", type=int, default=64)
    parser.add_argument("--families", default="swap,pillars,warehouse,grid")
    parser.add_argument("--centralized-max", type=int, default=0,
                        help="also run the centralized scheme up to this many robots")
    parser.add_argument("--out", default="docs/maps.md")
    parser.add_argument("--budget", type=float, default=0.0,
                        help="stop starting rounds after this many seconds (0: no limit)")
    parser.add_argument("--rules", default=None,
                        help="comma-separated rules (default: the default rules; 'none': no rule)")
    args = parser.parse_args(argv)
    settings = None if args.rules is None else SolverSettings(rules=select_rules(
        [] if args.rules == "none" else args.rules.split(",")))

    def schemes(sc: Scenario) -> list[str]:
        return ["decentralized"] + (["centralized"] if sc.n_robots <= args.centralized_max
                                    else [])

    rows: list[dict] = []
    started = time.perf_counter()

    def report() -> None:
        _write(rows, args.out, argv if argv is not None else sys.argv[1:])

    for name in builtin_scenario_names():
        sc = load_scenario(name)
        if sc.n_robots > args.max_robots:
            continue
        for scheme in schemes(sc):
            rows.append(_run(sc, scheme, settings) | {"family": "built-in"})
            print(rows[-1], flush=True)
    report()
    families = args.families.split(",")
    for k in range(args.runs):  # round robin: a budget cut leaves every family alike
        if args.budget and time.perf_counter() - started > args.budget:
            break
        for family in families:
            sizes = [s for s in SIZES[family] if s <= args.max_robots]
            # every tenth run is the largest size, the others cycle through the rest
            size = sizes[-1] if k % 10 == 0 or len(sizes) == 1 else sizes[
                (k - k // 10) % (len(sizes) - 1)]
            sc = family_scenario(family, size, seed=k)
            for scheme in schemes(sc):
                rows.append(_run(sc, scheme, settings) | {"family": family})
                print(rows[-1], flush=True)
        report()
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

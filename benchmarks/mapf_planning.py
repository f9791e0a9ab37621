"""Planning CPU of the fleet's roadmap plans: antipodal swaps and the MovingAI maps.

For each instance the fleet plan (:func:`sqpmpc.coordination.fleet.fleet_plan`, as the
``coordination`` rule makes it: its margins, the turns' steps on) is computed once, kernels
compiled beforehand (:func:`sqpmpc.kernels.warmup.warm_up`), and every call it makes to
:func:`sqpmpc.coordination.mapf.plan_paths` is timed with ``time.process_time``: the
4-connected plan, then over the diagonals the pass that seeks only a plan of fewer steps
(open space only; MovingAI maps stay 4-connected). Reported per instance: the roadmap's
vertices, each pass's CPU and plan steps (``none``: no plan of fewer steps), the whole
fleet plan's CPU (roadmap, plans, schedule: :attr:`FleetPlan.seconds`), its makespan
steps and the turns of its paths (the changes of direction at vertices).

Instances: antipodal swaps of ``--swaps`` robots (``sqpmpc generate swap --robots N``);
``--random`` robots on a generated 64 x 64 map (``random-64-64-10-K``: a tenth of the
cells blocked at random, seed 0, the largest connected free region kept; starts and goals
at random free cells, seed 0; cell, robots and bounds as the MovingAI runs'); the
MovingAI maps warehouse-10-20-10-2-1, room-32-32-4, random-32-32-10 and maze-32-32-2
with the first ``--robots`` agents of ``-random-1.scen`` at a 0.5 m cell, robots of 0.3 m,
accelerations bounded by 2 m/s^2 and 10 rad/s^2 (``sqpmpc generate mapf --map F.map --scen
F-random-1.scen --robots K --cell 0.5 --diameter 0.3 --acceleration 2 10``), read from
``--maps-dir`` (skipped when the files are not there); scenario files given with
``--scenarios``.

``--lacam`` plans every instance's first 4-connected roadmap (the one the first pass
plans) with LaCAM alone too (:func:`~sqpmpc.coordination.mapf.plan_paths`, ``method=
"lacam"``, seed 0): the complete planner the fleet falls back on where prioritized
planning fails; its CPU and steps (``none``: no plan) in two more columns.

``--baseline PATH`` measures the checkout at ``PATH`` too (a directory holding an
``sqpmpc`` package, e.g. ``git archive <commit> sqpmpc | tar -x -C PATH``), in a
subprocess with its own ``PYTHONPATH``, and prints both side by side (old / new)::

    python -m benchmarks.mapf_planning
    python -m benchmarks.mapf_planning --swaps 256 --robots 64 --baseline /tmp/before
    python -m benchmarks.mapf_planning --swaps --robots --random 256 --lacam

``--repeats R`` plans every instance ``R`` times and keeps the least CPU of each.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sqpmpc.problem.scenario import Scenario

__all__ = ["MAPS", "instances", "main", "measure", "random_map", "render", "turns"]

#: The MovingAI maps (``<name>.map`` and ``<name>-random-1.scen`` in ``--maps-dir``).
MAPS = ("warehouse-10-20-10-2-1", "room-32-32-4", "random-32-32-10", "maze-32-32-2")
_HERE = Path(__file__).resolve()


def instances(swaps: list[int], robots: list[int], maps_dir: Path | None,
              scenarios: list[Path], random: list[int] | None = None
              ) -> list[tuple[str, object]]:
    """``(name, description)`` of every instance, descriptions JSON-able: ``["swap", n]``,
    ``["random", side, blocked share, k]``, ``["mapf", map, scen, k]`` or ``["file",
    path]``."""
    out: list[tuple[str, object]] = [(f"swap-{n}", ["swap", n]) for n in swaps]
    out += [(f"random-64-64-10-{k}", ["random", 64, 0.1, k]) for k in random or []]
    if maps_dir is not None:
        for name in MAPS:
            m, s = maps_dir / f"{name}.map", maps_dir / f"{name}-random-1.scen"
            if m.is_file() and s.is_file():
                out += [(f"{name}-{k}", ["mapf", str(m), str(s), k]) for k in robots]
    out += [(p.stem, ["file", str(p)]) for p in scenarios]
    return out


def random_map(side: int, blocked: float, seed: int = 0) -> np.ndarray:
    """A ``side x side`` map (``True``: blocked) with a share ``blocked`` of its cells
    blocked at random (seeded), then every free cell outside the largest 4-connected free
    region blocked too, so that every free cell reaches every other."""
    from scipy.ndimage import label

    rng = np.random.default_rng(seed)
    cells = rng.random((side, side)) < blocked
    regions, _ = label(~cells)
    sizes = np.bincount(regions.ravel())
    sizes[0] = 0  # the blocked cells
    return regions != int(np.argmax(sizes))


def _scenario(description: list) -> Scenario:
    from sqpmpc.problem.fleets import antipodal_swap
    from sqpmpc.problem.movingai import mapf_scenario
    from sqpmpc.problem.scenario_file import load_scenario

    kind = description[0]
    if kind == "swap":
        return antipodal_swap(int(description[1]))
    if kind == "random":
        side, share, k = int(description[1]), float(description[2]), int(description[3])
        rows = ["".join("@" if b else "." for b in row) for row in random_map(side, share)]
        with tempfile.TemporaryDirectory() as folder:
            path = Path(folder) / f"random-{side}-{side}.map"
            path.write_text(f"type octile\nheight {side}\nwidth {side}\nmap\n"
                            + "\n".join(rows) + "\n")
            return mapf_scenario(path, k, cell=0.5, diameter=0.3, acceleration=2.0,
                                 angular_acceleration=10.0, seed=0,
                                 name=f"random-{side}-{side}-{round(100 * share)}-{k}")
    if kind == "mapf":
        return mapf_scenario(description[1], int(description[3]), scen_path=description[2],
                             cell=0.5, diameter=0.3, acceleration=2.0,
                             angular_acceleration=10.0)
    return load_scenario(description[1])


def turns(configs: np.ndarray, positions: np.ndarray) -> int:
    """The changes of direction of every robot's path of the plan ``configs`` (``(T + 1,
    n)`` vertices), summed."""
    total = 0
    for path in configs.T:
        keep = np.concatenate(([True], path[1:] != path[:-1]))
        way = np.diff(positions[path[keep]], axis=0)
        if way.shape[0] < 2:
            continue
        angle = np.arctan2(way[:, 1], way[:, 0])
        bend = np.abs((np.diff(angle) + np.pi) % (2.0 * np.pi) - np.pi)
        total += int((bend > 1e-9).sum())
    return total


def measure(named: list[tuple[str, object]], repeats: int = 1, lacam: bool = False
            ) -> list[dict]:
    """Plan every instance in this process (the ``sqpmpc`` on ``sys.path``) ``repeats``
    times; one row each, its CPU times the least of the repeats (the machine's load adds,
    never removes); with ``lacam``, LaCAM alone on the first 4-connected roadmap too."""
    import sqpmpc.coordination.fleet as fleet
    from sqpmpc.control.settings import SolverSettings
    from sqpmpc.kernels.warmup import warm_up
    from sqpmpc.rules.registry import select_rules
    from sqpmpc.sim.simulation import ClosedLoopSimulation

    warm_up()
    calls: list[tuple[bool, float, int | None]] = []
    first: list[tuple[fleet.Roadmap, object, object]] = []  # the first 4-connected plan's
    plan_paths = fleet.plan_paths

    def timed(roadmap: fleet.Roadmap, *args: object, **kwargs: object) -> np.ndarray:
        if not first and roadmap.diagonals.size == 0:
            first.append((roadmap, args[0], args[1]))
        t0 = time.process_time()
        try:
            out = plan_paths(roadmap, *args, **kwargs)
        except fleet.PlanningError:
            calls.append((roadmap.diagonals.size > 0, time.process_time() - t0, None))
            raise
        calls.append((roadmap.diagonals.size > 0, time.process_time() - t0, out.shape[0] - 1))
        return out

    fleet.plan_paths = timed
    rows = []
    try:
        for name, description in named:
            scenario = _scenario(description)
            best: dict | None = None
            for _ in range(max(1, repeats)):
                fleet.clear_cache()  # planned afresh, not an equal scenario's plan
                calls.clear()
                first.clear()
                sim = ClosedLoopSimulation(scenario, "decentralized",
                                           SolverSettings(rules=select_rules(["coordination"])))
                plan = sim.controllers[0].rule("coordination").plan
                square = [c for c in calls if not c[0]]
                diagonal = [c for c in calls if c[0]]
                row = {
                    "instance": name, "robots": int(plan.robots.size),
                    "vertices": plan.roadmap.size,
                    "square_cpu": square[0][1], "square_steps": square[0][2],
                    "diagonal_cpu": diagonal[0][1] if diagonal else None,
                    "diagonal_steps": diagonal[0][2] if diagonal else None,
                    "diagonal_pass": bool(diagonal),
                    "fleet_cpu": plan.seconds, "makespan": plan.makespan_steps,
                    "turns": turns(plan.configs, plan.roadmap.positions)}
                if lacam:
                    roadmap, starts, goals = first[0]
                    t0 = time.process_time()
                    try:
                        out = plan_paths(roadmap, starts, goals, seed=0, method="lacam")
                        row["lacam_steps"] = out.shape[0] - 1
                    except fleet.PlanningError:
                        row["lacam_steps"] = None
                    row["lacam_cpu"] = time.process_time() - t0
                if best is not None:
                    for key in ("square_cpu", "diagonal_cpu", "fleet_cpu", "lacam_cpu"):
                        if key not in row:
                            continue
                        if row[key] is not None:
                            row[key] = min(row[key], best[key])
                best = row
            if best is None:  # no repeat (repeats < 1 counts as 1: never)
                continue
            rows.append(best)
            print(f"  {name}: fleet plan {best['fleet_cpu']:.3f} s, {best['makespan']} steps",
                  file=sys.stderr, flush=True)
    finally:
        fleet.plan_paths = plan_paths
    return rows


def _cell(row: dict | None, key: str) -> str:
    if row is None:
        return "-"
    value = row[key]
    if key == "diagonal_steps" and not row["diagonal_pass"]:
        return "n/a"
    if value is None:
        return "none" if key in ("diagonal_steps", "lacam_steps") else "n/a"
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def render(new: list[dict], old: list[dict] | None = None) -> str:
    """The table (markdown): one row per instance, ``old / new`` where both are measured."""
    keys = ("square_cpu", "square_steps", "diagonal_cpu", "diagonal_steps", "fleet_cpu",
            "makespan", "turns")
    heads = ("4-conn CPU s", "4-conn steps", "diagonal CPU s", "diagonal steps",
             "fleet plan CPU s", "makespan steps", "turns")
    if new and "lacam_cpu" in new[0]:
        keys += ("lacam_cpu", "lacam_steps")
        heads += ("LaCAM alone CPU s", "LaCAM steps")
    before = {r["instance"]: r for r in old or []}
    lines = ["| instance | robots | vertices | " + " | ".join(heads) + " |",
             "|---" * (3 + len(heads)) + "|"]
    for row in new:
        cells = [row["instance"], str(row["robots"]), str(row["vertices"])]
        for key in keys:
            cell = _cell(row, key)
            if old is not None:
                cell = f"{_cell(before.get(row['instance']), key)} / {cell}"
            cells.append(cell)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _baseline(root: Path, named: list[tuple[str, object]], repeats: int,
              lacam: bool = False) -> list[dict]:
    """:func:`measure` in a subprocess importing ``sqpmpc`` from ``root``."""
    env = dict(os.environ, PYTHONPATH=str(root))
    # run as a file, from the checkout (not from benchmarks/, whose modules would shadow)
    argv = ["mapf_planning", "--worker", json.dumps(named), "--repeats", str(repeats),
            *(["--lacam"] if lacam else [])]
    code = (f"import runpy, sys; sys.argv = {argv!r}; "
            f"runpy.run_path({str(_HERE)!r}, run_name='__main__')")
    done = subprocess.run([sys.executable, "-c", code], env=env, cwd=root,
                          capture_output=True, text=True, check=False)
    sys.stderr.write(done.stderr)
    if done.returncode != 0:
        raise RuntimeError(f"the baseline at {root} failed (status {done.returncode})")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.mapf_planning",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--swaps", type=int, nargs="*", default=[64, 128, 256],
                        help="antipodal swaps of these many robots (default 64 128 256)")
    parser.add_argument("--robots", type=int, nargs="*", default=[32, 64],
                        help="MovingAI agents (default 32 64)")
    parser.add_argument("--random", type=int, nargs="*", default=[256],
                        help="robots on a generated 64 x 64 map, a tenth of it blocked "
                        "(default 256)")
    parser.add_argument("--lacam", action="store_true",
                        help="plan every instance with LaCAM alone too (two more columns)")
    parser.add_argument("--maps-dir", type=Path, default=Path("/work/shared/mapf"),
                        help="the MovingAI .map and -random-1.scen files")
    parser.add_argument("--scenarios", type=Path, nargs="*", default=[],
                        help="scenario files to plan too")
    parser.add_argument("--baseline", metavar="PATH", default=None,
                        help="a checkout to measure too, side by side (old / new)")
    parser.add_argument("--repeats", type=int, default=1,
                        help="plans per instance, the least CPU kept (default 1)")
    parser.add_argument("--json", type=Path, default=None, help="write the rows there")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker is not None:  # the baseline's side: rows as JSON on the last line
        print(json.dumps(measure([tuple(x) for x in json.loads(args.worker)], args.repeats,
                                 args.lacam)))
        return 0
    named = instances(args.swaps, args.robots, args.maps_dir, args.scenarios, args.random)
    old = None
    if args.baseline is not None:
        from benchmarks.baseline import resolve_checkout

        print(f"baseline {args.baseline}:", file=sys.stderr)
        old = _baseline(resolve_checkout(args.baseline), named, args.repeats, args.lacam)
    print("this checkout:", file=sys.stderr)
    new = measure(named, args.repeats, args.lacam)
    print(render(new, old))
    if args.json is not None:
        args.json.write_text(json.dumps({"new": new, "old": old}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

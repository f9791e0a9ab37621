r"""Speed and scale (issue 34): CPU time per sample, side by side in one process.

Usage (from the repository root)::

    python -m benchmarks.speed                                 # writes docs/speed.md
    python -m benchmarks.speed --acados-path DIR               # with the acados peer
    python -m benchmarks.speed --quick --no-write

Parts, each measured in thread CPU time (``time.thread_time``), never wall time:

1. **QP tail** -- every QP of a paper-s2 centralized closed loop at N = 40 (OSQP,
   the library's settings), replayed by each backend as
   :class:`sqpmpc.qp.sparse.SparseQP` runs it (set up once, updated in place;
   OSQP and the active-set method warm-started): OSQP, OSQP capped at
   :data:`~sqpmpc.qp.backend.HANDOVER_ITERATIONS` iterations with PIQP for the
   rest (``"osqp+piqp"``), PIQP, PIQP's multistage KKT solver
   (``"piqp-multistage"``) and the active-set method (``"active-set"``, its
   iterations are KKT factorizations). The replays are interleaved QP by QP.
2. **Maze** -- 10 robots (decentralized) through 64 boxes of 0.5 m with 0.5 m
   corridors, and the same robots without the boxes, interleaved sample by sample:
   per-robot CPU per sample, arrivals, collisions with robots and with boxes (at
   and between samples), and the stages whose unshadowed pieces within reach
   outnumbered the slots (*overflows*: a row raised, no piece dropped).
3. **Fleets** -- antipodal swaps of 16, 64 and 256 robots (decentralized) in one
   process, **with the liveness rules off** (``--rules none``: the engine's own
   scaling): per-robot CPU per sample (median over the samples after the first),
   the first sample, and the process's peak RSS after each size; then the same
   swaps with each scenario's default rules (the ten rules; coordination for
   swap-256, whose crowd the roundabout has no room for).
4. **Profile** -- cProfile of a paper-s2 decentralized closed loop: where a
   sample's CPU goes (the QP solver against the Python pipeline).
   **Split** -- without a profiler: the controller step's CPU against its QP
   backend's (the backend's ``solve``: OSQP's update, warm start and solve),
   the rest being the Python pipeline and its kernels, per sample, for
   paper-s2 centralized at N = 8 and N = 40 and decentralized per robot; and
   OSQP's cost model on the centralized QPs (every QP replayed with 1 and 30
   iterations and no termination checks: the fixed cost of a QP and the cost
   of one iteration), from which the iterations that would fit in acados's C
   time are computed when acados runs too.
5. **Paper scenarios** -- paper-s1 and paper-s2, both schemes, with
   ``qp_solver="osqp"`` (the former default) and ``"auto"`` (centralized: the
   active-set method with PIQP behind it; decentralized: OSQP capped at the hand-over,
   PIQP for the rest): closed-loop cost, collisions, final errors.
6. **acados** (with ``--acados-path`` or an installed ``comma-deps-acados``):
   :mod:`benchmarks.acados_peer`'s table.

Nothing is hard-coded: every figure and verdict is computed from this run.
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import io
import os
import pstats
import resource
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from sqpmpc.control.settings import SolverSettings
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.fleets import antipodal_swap
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import load_scenario, parse_scenario
from sqpmpc.qp.backend import (
    ALL_CHANGED,
    HANDOVER_ITERATIONS,
    BackendSolution,
    OSQPSettings,
    make_backend,
)
from sqpmpc.qp.layout import QPLayout
from sqpmpc.qp.policies import HandOver
from sqpmpc.rules.registry import select_rules
from sqpmpc.sim.simulation import ClosedLoopSimulation

from .compare_ipopt import machine_info
from .report import publish

__all__ = ["fleets", "main", "maze", "maze_scenario", "paper", "profile", "qp_tail", "split"]

DOC_PATH = Path(__file__).resolve().parent.parent / "docs" / "speed.md"


def _ms(x: np.ndarray | float) -> float:
    return float(x) * 1e3


# ---------------------------------------------------------------------------- QP tail
def qp_tail(horizon: int = 40, t_end: float = 150.0) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """``(backend, CPU s per QP, iterations)`` of the replayed QPs (module docstring)."""
    sc = load_scenario("paper-s2").with_changes(horizon=horizon, t_end=t_end)
    sim = ClosedLoopSimulation(sc, "centralized", SolverSettings(qp_solver="osqp"))
    qp = sim.controllers[0].engine.qp
    captured = []
    solve = qp.solve

    def recording_solve(warm_x: np.ndarray | None = None,
                        warm_y: np.ndarray | None = None):  # noqa: ANN202 - QPResult
        captured.append((qp.P_values.copy(), qp.q.copy(), qp.A_values.copy(), qp.lower.copy(),
                         qp.upper.copy(), None if warm_x is None else warm_x.copy(),
                         None if warm_y is None else warm_y.copy()))
        return solve(warm_x, warm_y)

    qp.solve = recording_solve  # this benchmark's capture only
    sim.run()
    L, settings = qp.layout, qp.settings
    capped = make_backend("osqp", L, replace(settings, max_iter=HANDOVER_ITERATIONS))
    handover = HandOver(make_backend("piqp", L, settings))
    runs = {"osqp": make_backend("osqp", L, settings), "osqp+piqp": capped,
            "active-set": make_backend("active-set", L, capped.settings),
            "piqp": make_backend("piqp", L, settings),
            "piqp-multistage": make_backend("piqp-multistage", L, settings)}
    times: dict[str, list[float]] = {name: [] for name in runs}
    iters: dict[str, list[int]] = {name: [] for name in runs}
    for P, q, A, lo, up, wx, wy in captured:
        for name, backend in runs.items():
            warm = name.startswith("osqp") or name == "active-set"
            t0 = time.thread_time()
            sol = backend.solve(P, q, A, lo, up, ALL_CHANGED, wx if warm else None,
                                wy if warm else None)
            if name == "osqp+piqp" and not sol.solved and not sol.time_limit_reached:
                sol = handover.apply(sol, P, q, A, lo, up)
            times[name].append(time.thread_time() - t0)
            iters[name].append(sol.iterations)
    return [(name, np.array(times[name]), np.array(iters[name])) for name in runs]


# ---------------------------------------------------------------------------- maze
def maze_scenario(obstacles: bool = True, boxes: int = 8, pitch: float = 1.0,
                  side: float = 0.5, t_end: float = 80.0) -> Scenario:
    """10 robots through a ``boxes x boxes`` field of square boxes (side ``side``, centres
    ``pitch`` apart: corridors of ``pitch - side``): five cross it left to right, five
    bottom to top, in corridors 1, 2, 3, 5, 7; without the boxes when ``obstacles`` is
    false."""
    h = side / 2
    centres = [(pitch * (i + 0.5), pitch * (j + 0.5)) for i in range(boxes)
               for j in range(boxes)]
    walls = [{"points": [[x - h, y - h], [x + h, y - h], [x + h, y + h], [x - h, y + h]]}
             for x, y in centres] if obstacles else []
    end = pitch * boxes + 0.6
    robots = []
    for lane in (pitch * k for k in (1, 3, 5, 7, 2)):
        for start, goal in (([-0.6, lane, 0.0], [end, lane]),
                            ([lane, -0.6, np.pi / 2], [lane, end])):
            robots.append({"id": len(robots) + 1, "initial_state": start, "diameter": 0.3,
                           "reference": {"type": "point", "position": goal}})
    return parse_scenario({
        "name": "maze" if obstacles else "maze without boxes", "t_end": t_end,
        "sample_time": 0.5, "horizon": 8, "weights": {"Q": [1.0, 1.0], "R": [0.5, 0.5]},
        "bounds": {"v": [-0.6, 0.6], "omega": [-0.7853981633974483, 0.7853981633974483]},
        "robots": robots, "obstacles": walls}, source="<benchmarks.speed maze>")


def maze(t_end: float) -> dict[str, dict[str, float]]:
    """Per-robot CPU per sample with and without the boxes, interleaved (module docstring)."""
    sims = {name: ClosedLoopSimulation(maze_scenario(name == "boxes", t_end=t_end),
                                       "decentralized") for name in ("boxes", "no boxes")}
    while all(s.k < s.scenario.steps for s in sims.values()):
        for s in sims.values():
            s.step()
    out = {}
    for name, s in sims.items():
        m = compute_metrics(s.record())
        per_robot = s.cpu_times[1:s.k].mean(axis=1)
        out[name] = {"median": _ms(np.median(per_robot)), "p99": _ms(np.percentile(per_robot, 99)),
                     "first": _ms(s.cpu_times[0].mean()), "pieces": s.scenario.obstacle_slots,
                     "slots": s.controllers[0].engine.qp.layout.n_external - s.controllers[0].slots,
                     "collisions": m["collisions"],
                     "obstacle_collisions": m.get("obstacle_collisions"),
                     "final_error": m["max_final_position_error"], "fallbacks": s.fallbacks,
                     "overflows": sum(_polygon_rows(c).overflows for c in s.controllers
                                      if _polygon_rows(c) is not None)}
    return out


def _polygon_rows(controller: object) -> object | None:
    """A controller's polygon rows (:class:`sqpmpc.ocp.polygon_rows.PolygonRows`), if any."""
    rows = getattr(controller, "obstacle_rows", None)
    return getattr(rows, "polygons", None)


# ---------------------------------------------------------------------------- fleets
def fleets(sizes: tuple[int, ...], samples: int, default_rules: bool = False
           ) -> list[dict[str, float]]:
    """Swaps of ``sizes`` robots, rules off (or, ``default_rules``, the scenario's default
    rules, as ``sqpmpc run`` takes them), ``samples`` samples each, in this process."""
    settings = None if default_rules else SolverSettings(rules=select_rules(["none"]))
    rows = []
    for n in sizes:
        t0 = time.process_time()
        sim = ClosedLoopSimulation(antipodal_swap(n), "decentralized", settings)
        build = time.process_time() - t0
        for _ in range(samples):
            sim.step()
        per_robot = sim.cpu_times[:samples].mean(axis=1)
        rows.append({"robots": n, "build_s": build, "median": _ms(np.median(per_robot[1:])),
                     "p99": _ms(np.percentile(per_robot[1:], 99)), "first": _ms(per_robot[0]),
                     "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                     "rules": ("coordination" if [r.name for r in sim.settings.rules]
                               == ["coordination"] else "the ten rules")})
        del sim
        gc.collect()
    return rows


# ---------------------------------------------------------------------------- profile
def profile(t_end: float = 100.0) -> tuple[float, list[tuple[str, float]]]:
    """CPU per robot and sample (ms, profiler on) and the top functions' share of it."""
    sim = ClosedLoopSimulation(load_scenario("paper-s2").with_changes(t_end=t_end),
                               "decentralized")
    sim.step()
    prof = cProfile.Profile(time.thread_time)
    prof.enable()
    sim.run()
    prof.disable()
    stats = pstats.Stats(prof, stream=io.StringIO())
    total = sum(v[2] for v in stats.stats.values())  # tottime over every function
    calls = (sim.k - 1) * len(sim.controllers)
    top = sorted(((f"{Path(f).name}:{line} {fn}", v[2]) for (f, line, fn), v in
                  stats.stats.items()), key=lambda x: -x[1])[:12]
    return _ms(total / calls), [(name, t / total) for name, t in top]


# ---------------------------------------------------------------------------- split
#: ``(label, scheme, horizon)`` of the split (``None``: the scenario's own horizon).
SPLIT_CASES: tuple[tuple[str, str, int | None], ...] = (
    ("paper-s2 N 8", "centralized", None),
    ("paper-s2 N 40", "centralized", 40),
    ("paper-s2 decentralized, per robot", "decentralized", None),
)


def _osqp_cost_model(captured: list[tuple], backend_settings: OSQPSettings, layout: QPLayout
                     ) -> tuple[float, float]:
    """``(fixed, per iteration)`` CPU s of OSQP on the ``captured`` QPs: each replayed (set
    up once, updated in place, warm-started as recorded) with 1 and with 30 iterations and
    no termination checks, interleaved QP by QP; medians."""
    runs = {k: make_backend("osqp", layout, replace(backend_settings, max_iter=k,
                                                    check_termination=0)) for k in (1, 30)}
    times: dict[int, list[float]] = {k: [] for k in runs}
    for args in captured:
        for k, backend in runs.items():
            t0 = time.thread_time()
            backend.solve(*args[:5], ALL_CHANGED, *args[5:])
            times[k].append(time.thread_time() - t0)
    one, thirty = (float(np.median(times[k][1:])) for k in (1, 30))
    per = (thirty - one) / 29.0
    return one - per, per


def _split_case(label: str, scheme: str, horizon: int | None, t_end: float
                ) -> dict[str, float | str]:
    """One row of :func:`split`."""
    changes: dict[str, object] = {"t_end": t_end}
    if horizon is not None:
        changes["horizon"] = horizon
    sc = load_scenario("paper-s2").with_changes(**changes)
    sim = ClosedLoopSimulation(sc, scheme)
    qp_cpu = np.zeros((sc.steps + 1, len(sim.controllers)))
    iterations = np.zeros_like(qp_cpu)
    copying = np.zeros_like(qp_cpu)  # the capture's own CPU, taken off the step
    captured: list[tuple] = []
    keep = scheme == "centralized"  # the QPs as the backend gets them, for the replay

    def timing(solve: Callable[..., BackendSolution], j: int) -> Callable[..., BackendSolution]:
        def timed(*args: object) -> BackendSolution:
            if keep:
                t0 = time.thread_time()
                captured.append(tuple(None if a is None else np.array(a, copy=True)
                                      for i, a in enumerate(args) if i != 5))
                copying[sim.k, j] += time.thread_time() - t0
            t0 = time.thread_time()
            sol = solve(*args)
            qp_cpu[sim.k, j] += time.thread_time() - t0
            iterations[sim.k, j] += sol.iterations
            return sol
        return timed

    for j, ctrl in enumerate(sim.controllers):
        backend = ctrl.engine.qp.backend
        backend.solve = timing(backend.solve, j)  # this benchmark's timing only
    sim.run()
    step = sim.cpu_times[1:sim.k] - copying[1:sim.k]
    qp = qp_cpu[1:sim.k]
    row: dict[str, float | str] = {
        "label": label, "backend": sim.controllers[0].engine.qp.backend.name,
        "step": _ms(np.median(step.mean(axis=1))),
        "qp": _ms(np.median(qp.mean(axis=1))),
        "rest": _ms(np.median((step - qp).mean(axis=1))),
        "iterations": float(np.median(iterations[1:sim.k])),
        "fixed": float("nan"), "per_iteration": float("nan")}
    if captured:
        qp_obj = sim.controllers[0].engine.qp
        fixed, per = _osqp_cost_model(captured, qp_obj.backend.settings, qp_obj.layout)
        row["fixed"], row["per_iteration"] = _ms(fixed), _ms(per)
    return row


def split(t_end: float = 100.0) -> list[dict[str, float | str]]:
    """Per :data:`SPLIT_CASES`: medians over the samples after the first of the controller
    step's CPU, its QP backend's and the rest (ms per robot), OSQP's median iterations and,
    centralized, OSQP's fixed and per-iteration cost (module docstring)."""
    return [_split_case(label, scheme, horizon, t_end) for label, scheme, horizon in SPLIT_CASES]


# ---------------------------------------------------------------------------- paper
def paper() -> list[tuple[str, str, str, dict]]:
    """``(scenario, scheme, qp_solver, metrics)`` of the paper scenarios (module docstring)."""
    from sqpmpc.sim.simulation import simulate

    rows = []
    for name in ("paper-s1", "paper-s2"):
        for scheme in ("centralized", "decentralized"):
            for solver in ("osqp", "auto"):
                record = simulate(load_scenario(name), scheme, SolverSettings(qp_solver=solver))
                rows.append((name, scheme, solver, compute_metrics(record)))
    return rows


# ---------------------------------------------------------------------------- report
def _verdicts(acados: list, paper_rows: list | None, split_rows: list | None = None
              ) -> list[str]:
    """The issue's acados and per-robot targets (:func:`benchmarks.acados_peer.verdicts`,
    the per-robot median from the paper part's metrics), computed from the results; with
    the split, how many OSQP iterations would fit in acados's C time."""
    from .acados_peer import PER_ROBOT_TARGET_MS, verdicts

    out = verdicts(acados, None)
    by = {r.label: r for r in acados}
    for r in split_rows or []:
        if r["label"] in by and not np.isnan(r["fixed"]) and r["backend"] == "osqp":
            c = _ms(np.median(by[r["label"]].acados_c))
            fit = (c - r["rest"] - r["fixed"]) / r["per_iteration"]
            out.append(f"- {r['label']}: with this run's split, OSQP would have to stop within "
                       f"{fit:.0f} iterations at the median to fit in acados's C median "
                       f"(its median: {r['iterations']:.0f})")
    for name, scheme, solver, m in paper_rows or []:
        if (name, scheme, solver) == ("paper-s2", "decentralized", "auto"):
            per = float(np.median([v for v in m["solve_time"]["cpu"][
                "per_robot_median_ms"].values()]))
            ok = per <= PER_ROBOT_TARGET_MS
            out.append(f"- paper-s2 decentralized: per-robot CPU median {per:.3f} ms <= "
                       f"{PER_ROBOT_TARGET_MS} ms: {'met' if ok else 'NOT met'}")
    return out


def render(tail: list | None, maze_rows: dict | None, fleet_rows: list | None,
           prof: tuple | None, acados: str | None, command: str, wall: float,
           paper_rows: list | None = None, verdicts: list[str] | None = None,
           split_rows: list | None = None, default_fleet_rows: list | None = None) -> str:
    """The markdown page."""
    info = machine_info()
    lines = ["# Speed and scale", "", f"Reproduce: `{command}` (module docstring of "
             "`benchmarks/speed.py`: what is measured and how).", "",
             "Machine: " + ", ".join(f"{k} {v}" for k, v in info.items())
             + f"; run {wall:.0f} s; load average at the end {os.getloadavg()[0]:.2f}. "
             "All times are thread CPU time (a loaded machine still slows them: shared caches "
             "and cores).", "",
             "What the parts measure (issue 34): the QP backends' tail (`qp_solver=\"auto\"` "
             "is the active-set method, PIQP behind it, for the centralized QP of at most 8 "
             "paper unicycles, else OSQP capped at the hand-over with PIQP for the rest "
             "outside decentralized fleets; `piqp-multistage` is PIQP's multistage KKT "
             "solver on the QP in stage "
             "order), obstacle rows by reach (`sqpmpc.ocp.polygon_rows`: `OBSTACLE_SLOTS` rows "
             "per robot and stage for polygon pieces, filled from what the horizon can "
             "reach; a piece behind a chosen row is kept by it, more unshadowed pieces than "
             "slots raise a row: none is dropped; circles keep the nearest within reach), "
             "the per-robot cost of large "
             "fleets, where a sample's CPU goes, the paper scenarios under the new default "
             "and acados on the same OCPs.", ""]
    if tail:
        base = np.median(tail[0][1])
        lines += ["## QP tail: paper-s2 centralized, N = 40, every QP replayed", "",
                  f"{tail[0][1].size} QPs. *max / median*: the largest QP's CPU over the "
                  "backend's own median (the tail bound).", "",
                  "| backend | median us | p99 us | max us | max / median | median iterations "
                  "| max iterations | median / OSQP's |", "|---|---|---|---|---|---|---|---|"]
        for name, t, it in tail:
            lines.append(f"| {name} | {np.median(t) * 1e6:.1f} | {np.percentile(t, 99) * 1e6:.1f}"
                         f" | {t.max() * 1e6:.1f} | {t.max() / np.median(t):.1f} | "
                         f"{np.median(it):.0f} | {it.max()} | {np.median(t) / base:.2f} |")
        lines.append("")
    if maze_rows:
        b, f = maze_rows["boxes"], maze_rows["no boxes"]
        ratio = b["median"] / f["median"]
        lines += ["## Maze: 64 boxes, 0.5 m corridors, 10 robots (decentralized)", "",
                  "| map | pieces (rows per robot and stage) | per-robot CPU median / p99 ms | "
                  "first sample ms | collisions (robots / obstacles) | largest final error m "
                  "| fallbacks | overflows |",
                  "|---|---|---|---|---|---|---|---|"]
        for name, r in maze_rows.items():
            lines.append(f"| {name} | {r['pieces']} ({r['slots']}) | {r['median']:.3f} / "
                         f"{r['p99']:.3f} | {r['first']:.2f} | {r['collisions']} / "
                         f"{r['obstacle_collisions']} | {r['final_error']:.3f} | "
                         f"{r['fallbacks']} | {r['overflows']} |")
        lines += ["", f"Per-robot median with boxes / without: **{ratio:.2f}** (target <= 3: "
                  f"{'met' if ratio <= 3 else 'NOT met'}).", ""]
    if fleet_rows:
        lo, hi = fleet_rows[0], fleet_rows[-1]
        lines += ["## Fleets: antipodal swaps, decentralized, rules off (`--rules none`)", "",
                  "| robots | build s | per-robot CPU median / p99 ms | first sample ms per "
                  "robot | first / median | peak RSS MB (process, so far) |",
                  "|---|---|---|---|---|---|"]
        for r in fleet_rows:
            lines.append(f"| {r['robots']} | {r['build_s']:.2f} | {r['median']:.3f} / "
                         f"{r['p99']:.3f} | {r['first']:.3f} | {r['first'] / r['median']:.1f} "
                         f"| {r['rss_mb']:.0f} |")
        growth = hi["median"] / lo["median"]
        lines += ["", f"Per-robot median {hi['robots']} / {lo['robots']}: **{growth:.2f}** "
                  f"(target <= 1.3: {'met' if growth <= 1.3 else 'NOT met'}); peak RSS "
                  f"{hi['rss_mb']:.0f} MB (target <= 600: "
                  f"{'met' if hi['rss_mb'] <= 600 else 'NOT met'}); first sample "
                  f"{hi['first'] / hi['median']:.1f} x the median at {hi['robots']} (target "
                  f"<= 3: {'met' if hi['first'] <= 3 * hi['median'] else 'NOT met'}).", ""]
    if default_fleet_rows:
        lo, hi = default_fleet_rows[0], default_fleet_rows[-1]
        lines += ["## Fleets with the default rules (as `sqpmpc run` takes them)", "",
                  "The same swaps with each scenario's default rules: the ten liveness rules, "
                  "or the roadmap coordination alone where the roundabout has no room for "
                  "the crowd (`crowd_without_room`: swap-256). The coordination's execution "
                  "(its holds and waits, the motion along the plan) costs more per sample "
                  "than the rules; measured, not a target.", "",
                  "| robots | rules | build s | per-robot CPU median / p99 ms | first sample "
                  "ms per robot | first / median |", "|---|---|---|---|---|---|"]
        for r in default_fleet_rows:
            lines.append(f"| {r['robots']} | {r['rules']} | {r['build_s']:.2f} | "
                         f"{r['median']:.3f} / {r['p99']:.3f} | {r['first']:.3f} | "
                         f"{r['first'] / r['median']:.1f} |")
        lines += ["", f"Per-robot median {hi['robots']} / {lo['robots']}: "
                  f"{hi['median'] / lo['median']:.2f}; first sample "
                  f"{hi['first'] / hi['median']:.1f} x the median at {hi['robots']}.", ""]
    if prof:
        per, top = prof
        lines += ["## Profile: paper-s2 decentralized (cProfile on thread time)", "",
                  f"{per:.3f} ms per robot and sample with the profiler on. Share of the CPU:",
                  "", "| function | share |", "|---|---|"]
        lines += [f"| `{name}` | {share * 100:.1f} % |" for name, share in top]
        lines.append("")
    if split_rows:
        lines += ["## Split: where a sample's CPU goes (no profiler)", "",
                  "Medians over the samples after the first, ms per robot and sample: the "
                  "controller step, its QP backend's solve (update, warm start and solve, "
                  "with the backend's Python) and the rest (the Python pipeline and its "
                  "kernels). *Iterations*: the backend's (OSQP's ADMM iterations; the "
                  "active-set method's KKT factorizations). *OSQP fixed / per iteration*: "
                  "every centralized QP replayed by OSQP with 1 and 30 iterations and no "
                  "termination checks.", "",
                  "| case | backend | step | QP backend | rest | QP share | iterations | "
                  "OSQP fixed ms | OSQP per iteration ms |", "|" + "---|" * 9]
        for r in split_rows:
            fixed = "-" if np.isnan(r["fixed"]) else f"{r['fixed']:.4f}"
            per = "-" if np.isnan(r["per_iteration"]) else f"{r['per_iteration']:.4f}"
            lines.append(f"| {r['label']} | {r['backend']} | {r['step']:.4f} | {r['qp']:.4f} | "
                         f"{r['rest']:.4f} | {r['qp'] / r['step'] * 100:.0f} % | "
                         f"{r['iterations']:.0f} | {fixed} | {per} |")
        lines.append("")
    if paper_rows:
        lines += ["## Paper scenarios: the former default (OSQP) against auto", "",
                  "| scenario | scheme | qp_solver | closed-loop cost | cost / OSQP's | "
                  "collisions | largest final error m | CPU per sample median / p99 / max ms |",
                  "|---|---|---|---|---|---|---|---|"]
        base = 1.0
        for name, scheme, solver, m in paper_rows:
            cost = m["closed_loop_cost"]
            base = cost if solver == "osqp" else base
            cpu = m["solve_time"]["cpu"]
            lines.append(f"| {name} | {scheme} | {solver} | {cost:.4f} | {cost / base:.5f} | "
                         f"{m['collisions']} | {m['max_final_position_error']:.3f} | "
                         f"{cpu['median_ms']:.3f} / {cpu['p99_ms']:.3f} / {cpu['max_ms']:.3f} |")
        lines.append("")
    if acados:
        lines += ["## acados (SQP-RTI, HPIPM) on the same OCPs", "",
                  acados.replace("\n| case", "\n\n| case").replace("\nThe OCPs", "\n\nThe OCPs"),
                  ""]
    if verdicts:
        lines += ["## Targets of issue 34 against acados and per robot", "", *verdicts, ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the parts and write :data:`DOC_PATH`."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.speed", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="shorter runs")
    p.add_argument("--parts", default="tail,maze,fleets,profile,split,paper,acados")
    p.add_argument("--acados-path", default=os.environ.get("SQPMPC_ACADOS_PATH"))
    p.add_argument("--no-write", action="store_true")
    args = p.parse_args(argv)
    parts = set(args.parts.split(","))
    started = time.perf_counter()
    q = args.quick
    tail = qp_tail(40, 40.0 if q else 150.0) if "tail" in parts else None
    maze_rows = maze(40.0 if q else 80.0) if "maze" in parts else None
    fleet_rows = fleets((16, 64, 256), 8 if q else 20) if "fleets" in parts else None
    default_fleet_rows = (fleets((16, 64, 256), 8 if q else 20, default_rules=True)
                          if "fleets" in parts else None)
    prof = profile(30.0 if q else 100.0) if "profile" in parts else None
    split_rows = split(30.0 if q else 100.0) if "split" in parts else None
    paper_rows = paper() if "paper" in parts else None
    acados, verdicts = None, None
    if "acados" in parts:
        from . import acados_peer

        try:
            _, template = acados_peer.import_acados(args.acados_path)
        except ImportError as exc:
            print(f"acados not available ({exc}); its part is left out", file=sys.stderr)
        else:
            results = []
            for label, name, horizon, t_end in acados_peer.CASES:
                sc = acados_peer.load_case(name, horizon, 20.0 if q else t_end)
                results.append(acados_peer.run_case(label, sc, SolverSettings(), template))
            table = acados_peer.render(results, {}, "", 0.0).split("\n")
            acados = "\n".join(line for line in table if line.startswith("|") or (
                line.startswith("CPU") or line.startswith("The OCPs")))
            verdicts = _verdicts(results, paper_rows, split_rows)
    command = "python -m benchmarks.speed " + " ".join(argv if argv is not None
                                                        else sys.argv[1:])
    text = render(tail, maze_rows, fleet_rows, prof, acados, command.strip(),
                  time.perf_counter() - started, paper_rows, verdicts, split_rows,
                  default_fleet_rows)
    publish(text, None if args.no_write else DOC_PATH)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

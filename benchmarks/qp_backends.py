"""The QPs the controllers actually solve, replayed with OSQP settings and other solvers.

Usage (from the repository root, ``bench`` extra installed)::

    python -m benchmarks.qp_backends            # writes docs/qp-backends.md
    python -m benchmarks.qp_backends --quick    # shorter runs, prints only

Every QP of closed loops of ``paper-s2``, ``swap-6``, ``swap-16`` (both
schemes) and ``swap-64`` (decentralized; the first controller of a
decentralized run; each under the default settings, so the fleets' QPs have
8 neighbour slots) is captured as it is handed to
OSQP, with its warm start, then replayed the way :class:`sqpmpc.qp.sparse.SparseQP`
does it (set up once, values updated in place, warm-started) under:

- OSQP with the library's settings and one change at a time;
- PIQP (sparse interior point, ``SparseSolver.setup`` then ``update``);
- DAQP (dense dual active set: one ``daqp.Model``, updated with each QP's
  values and hot-started from the previous active set, as
  :mod:`sqpmpc.qp.daqp` runs it);
- OSQP stopped at an iteration cap with PIQP solving the QPs it left (the
  times added per QP): a bounded-effort combination.

Accuracy is measured against a high-accuracy Clarabel solution of each QP
(max |x - x_ref| and the largest constraint violation). Times are the wall
time of update + warm start + solve, best of ``--repeats`` replays (the
machine is shared). Nothing is hard-coded: the conclusions are computed from
the measured numbers.
"""

from __future__ import annotations

import argparse
import datetime as dt
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import osqp
import scipy.sparse as sp

from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.qp.backend import OSQPSettings, solve_interior_point
from sqpmpc.qp.sparse import SparseQP
from sqpmpc.sim.simulation import ClosedLoopSimulation

from .compare_ipopt import machine_info
from .report import publish

__all__ = ["CapturedQP", "capture", "main"]

DOC_PATH = Path(__file__).resolve().parent.parent / "docs" / "qp-backends.md"
HYBRID_CAPS = (100, 200)
CASES = (("paper-s2", "centralized"), ("paper-s2", "decentralized"),
         ("swap-6", "centralized"), ("swap-6", "decentralized"),
         ("swap-16", "centralized"), ("swap-16", "decentralized"),
         ("swap-64", "decentralized"))
_INF = 1e30
OSQP_VARIANTS: dict[str, dict[str, object]] = {
    "library settings": {},
    "rho 1": {"rho": 1.0},
    "rho 0.01": {"rho": 0.01},
    "adaptive_rho_tolerance 2": {"adaptive_rho_tolerance": 2.0},
    "adaptive_rho_interval 25": {"adaptive_rho_interval": 25},
    "adaptive_rho_interval automatic": {"adaptive_rho_interval": 0},
    "check_termination 25": {"check_termination": 25},
    "scaling 10": {"scaling": 10},
    "eps 1e-4": {"eps_abs": 1e-4, "eps_rel": 1e-4},
    "polishing": {"polishing": True},
}


@dataclass(frozen=True)
class CapturedQP:
    """One QP as SparseQP handed it to OSQP, with its warm start and a reference solution."""

    P: sp.csc_matrix
    q: np.ndarray
    A: sp.csc_matrix
    lower: np.ndarray
    upper: np.ndarray
    warm_x: np.ndarray | None
    warm_y: np.ndarray | None
    x_ref: np.ndarray | None = None


def capture(scenario: str, scheme: str, t_end: float | None) -> list[CapturedQP]:
    """Every QP of controller 0 in a closed loop, in order."""
    sc = load_scenario(scenario)
    if t_end is not None:
        sc = sc.with_changes(t_end=min(t_end, sc.t_end))
    sim = ClosedLoopSimulation(sc, scheme)
    qp: SparseQP = sim.controllers[0].engine.qp
    captured: list[CapturedQP] = []
    solve = qp.solve

    def recording_solve(warm_x: np.ndarray | None = None,
                        warm_y: np.ndarray | None = None):  # noqa: ANN202 - QPResult
        P, q, A, lo, up = qp.matrices()
        captured.append(CapturedQP(P, q, A, lo, up,
                                   None if warm_x is None else warm_x.copy(),
                                   None if warm_y is None else warm_y.copy()))
        return solve(warm_x, warm_y)

    qp.solve = recording_solve  # this benchmark's capture only
    sim.run()
    out = []
    for c in captured:
        ref = solve_interior_point(c.P, c.q, c.A, c.lower, c.upper)
        out.append(replace(c, x_ref=None if ref is None else ref[0]))
    return out


@dataclass
class Replay:
    """Per-QP times (s) and accuracy of one solver on one sequence."""

    times: np.ndarray
    iterations: np.ndarray
    error: float
    violation: float
    failures: int

    def row(self, label: str) -> str:
        t = self.times * 1e6
        return (f"| {label} | {np.median(t):.1f} | {t.mean():.1f} | {np.percentile(t, 99):.1f} | "
                f"{self.iterations.mean():.1f} | {self.error:.1e} | {self.violation:.1e} | "
                f"{self.failures} |")


def _accuracy(qps: list[CapturedQP], xs: list[np.ndarray | None]) -> tuple[float, float, int]:
    error = violation = 0.0
    failures = 0
    for c, x in zip(qps, xs, strict=True):
        if x is None or not np.all(np.isfinite(x)):
            failures += 1
            continue
        Az = c.A @ x
        violation = max(violation, float(np.max(c.lower - Az)), float(np.max(Az - c.upper)))
        if c.x_ref is not None:
            error = max(error, float(np.abs(x - c.x_ref).max()))
    return error, max(violation, 0.0), failures


def replay_osqp(qps: list[CapturedQP], changes: dict[str, object]) -> Replay:
    """OSQP set up once, updated in place and warm-started like SparseQP."""
    settings = {**OSQPSettings().to_osqp(), **changes}
    first = qps[0]
    solver = osqp.OSQP()
    solver.setup(first.P, first.q, first.A, np.maximum(first.lower, -_INF),
                 np.minimum(first.upper, _INF), **settings)
    times, iterations, xs = [], [], []
    solved = {osqp.SolverStatus.OSQP_SOLVED, osqp.SolverStatus.OSQP_SOLVED_INACCURATE}
    for i, c in enumerate(qps):
        t0 = time.perf_counter()
        if i:  # the first QP is the one set up, as in SparseQP
            solver.update(q=c.q, l=np.maximum(c.lower, -_INF), u=np.minimum(c.upper, _INF),
                          Px=c.P.data, Ax=c.A.data)
        if c.warm_x is not None:
            solver.warm_start(x=c.warm_x, y=c.warm_y)
        res = solver.solve(raise_error=False)
        times.append(time.perf_counter() - t0)
        iterations.append(res.info.iter)
        xs.append(res.x.copy() if res.info.status_val in solved else None)
    return Replay(np.array(times), np.array(iterations), *_accuracy(qps, xs))


def _split(c: CapturedQP) -> tuple[sp.csc_matrix, np.ndarray, sp.csc_matrix, np.ndarray,
                                   np.ndarray]:
    eq = c.lower == c.upper
    A = c.A.tocsr()
    lo, up = c.lower[~eq], c.upper[~eq]
    free = (lo <= -1e20) & (up >= 1e20)  # off rows, handed over as 0 in [-1, 1] (as the library)
    G = A[~eq].tocsr()
    G.data[free[np.repeat(np.arange(G.shape[0]), np.diff(G.indptr))]] = 0.0
    return (A[eq].tocsc(), c.upper[eq], G.tocsc(), np.where(free, -1.0, np.maximum(lo, -_INF)),
            np.where(free, 1.0, np.minimum(up, _INF)))


def replay_piqp(qps: list[CapturedQP]) -> Replay:
    """PIQP's sparse solver: set up once, then ``update`` with every QP's data."""
    import piqp

    def full(P: sp.csc_matrix) -> sp.csc_matrix:
        return (P + sp.triu(P, k=1).T).tocsc()

    solver = piqp.SparseSolver()
    solver.settings.eps_abs = solver.settings.eps_rel = 1e-6
    solver.settings.preconditioner_reuse_on_update = True  # as the library
    Ae, be, G, hl, hu = _split(qps[0])
    solver.setup(full(qps[0].P), qps[0].q, Ae, be, G, hl, hu)
    parts = [(full(c.P), _split(c)) for c in qps]  # conversions outside the timing
    times, iterations, xs = [], [], []
    for c, (P, (Ae, be, G, hl, hu)) in zip(qps, parts, strict=True):
        t0 = time.perf_counter()
        solver.update(P=P, c=c.q, A=Ae, b=be, G=G, h_l=hl, h_u=hu)
        status = solver.solve()
        times.append(time.perf_counter() - t0)
        iterations.append(solver.result.info.iter)
        xs.append(solver.result.x.copy() if status == piqp.PIQP_SOLVED else None)
    return Replay(np.array(times), np.array(iterations), *_accuracy(qps, xs))


def replay_daqp(qps: list[CapturedQP]) -> Replay:
    """DAQP as :mod:`sqpmpc.qp.daqp` runs it: one dense model, set up once, then
    updated with each QP's values and hot-started from the previous active set."""
    import daqp

    n, m = qps[0].P.shape[0], qps[0].A.shape[0]
    H, A = np.zeros((n, n)), np.zeros((m, n))
    model = None
    times, iterations, xs = [], [], []
    for c in qps:
        P, Ac = sp.coo_matrix(c.P), sp.coo_matrix(c.A)  # conversions outside the timing
        H[:] = 0.0
        H[P.row, P.col] = P.data
        H[P.col, P.row] = P.data
        A[:] = 0.0
        A[Ac.row, Ac.col] = Ac.data
        b_u, b_l = np.minimum(c.upper, _INF), np.maximum(c.lower, -_INF)
        t0 = time.perf_counter()
        if model is None:
            model = daqp.Model()
            model.setup(H, c.q, A, b_u, b_l, np.where(c.lower == c.upper, 5, 0).astype(np.int32))
        else:
            model.update(H=H, f=c.q, A=A, bupper=b_u, blower=b_l)
        x, _, flag, info = model.solve()
        times.append(time.perf_counter() - t0)
        iterations.append(info["iterations"])
        xs.append(np.asarray(x, dtype=float).copy() if flag == 1 else None)
    return Replay(np.array(times), np.array(iterations), *_accuracy(qps, xs))


def _best(repeats: int, run: Callable[[], Replay]) -> Replay:
    """The replay with the smallest total time (same QPs, same results each time)."""
    results = [run() for _ in range(max(repeats, 1))]
    return min(results, key=lambda r: float(r.times.sum()))


def _replays(qps: list[CapturedQP], repeats: int) -> dict[str, Replay]:
    """Every OSQP variant, PIQP and DAQP on one captured sequence.

    One untimed OSQP replay runs first and is discarded: the first replay in a
    process returned, on paper-s2, one QP with a 0.2 m violation under status
    *solved*, which no later replay and none of the library's own solves in
    the closed loops (largest violation 5e-5 m, checked) reproduced.
    """
    replay_osqp(qps, {})
    rows = {f"OSQP, {label}": _best(repeats, lambda c=changes: replay_osqp(qps, c))
            for label, changes in OSQP_VARIANTS.items()}
    piqp = rows["PIQP (sparse, update)"] = _best(repeats, lambda: replay_piqp(qps))
    rows["DAQP (dense, hot-started)"] = _best(repeats, lambda: replay_daqp(qps))
    for cap in HYBRID_CAPS:
        capped = _best(repeats, lambda c=cap: replay_osqp(qps, {"max_iter": c}))
        rows[f"OSQP capped at {cap} iterations, PIQP for the rest"] = hybrid(capped, piqp, cap)
    return rows


def hybrid(capped: Replay, fallback: Replay, cap: int) -> Replay:
    """OSQP stopped at ``cap`` iterations, the QPs it left solved by ``fallback``.

    The time of a QP OSQP left is its capped time plus the fallback's time on
    the same QP; accuracy is the fallback's where it took over.
    """
    failed = capped.iterations >= cap
    return Replay(capped.times + np.where(failed, fallback.times, 0.0),
                  np.where(failed, fallback.iterations, capped.iterations),
                  max(capped.error, fallback.error), max(capped.violation, fallback.violation),
                  fallback.failures)


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.qp_backends",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="30 s closed loops, print only")
    parser.add_argument("--repeats", type=int, default=3, help="replays per solver, best kept")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    sections: list[str] = []
    verdicts: list[str] = []
    for scenario, scheme in CASES:
        qps = capture(scenario, scheme, 30.0 if args.quick else None)
        n, m = qps[0].P.shape[0], qps[0].A.shape[0]
        rows = _replays(qps, args.repeats)
        table = ["| solver | median us | mean us | p99 us | mean iterations | "
                 "max abs(x - x_ref) | max violation | failures |",
                 "|---|---|---|---|---|---|---|---|"]
        table += [r.row(label) for label, r in rows.items()]
        sections.append(f"### {scenario}, {scheme} ({len(qps)} QPs, {n} variables, "
                        f"{m} rows)\n\n" + "\n".join(table))
        base = rows["OSQP, library settings"]
        tolerance = max(1e-4, 2.0 * base.violation)
        accurate = {k: r for k, r in rows.items()
                    if r.failures <= base.failures and r.violation <= tolerance}
        fastest = min(accurate, key=lambda k: float(accurate[k].times.mean()))
        gain = base.times.mean() / accurate[fastest].times.mean()
        verdicts.append(f"- {scenario} {scheme}: fastest mean time among the solvers as "
                        f"accurate as the library settings (violation <= {tolerance:.1e} m, "
                        f"no more failures than its {base.failures}): **{fastest}**, "
                        f"{gain:.2f} x faster than the library settings' mean "
                        f"({base.times.mean() * 1e6:.1f} us)")
        flattest = min(accurate, key=lambda k: float(np.percentile(accurate[k].times, 99)))
        t = accurate[flattest].times
        verdicts.append(f"  - smallest p99 among them: **{flattest}**, p99 "
                        f"{np.percentile(t, 99) * 1e6:.1f} us = "
                        f"{np.percentile(t, 99) / np.median(t):.1f} x its median (OSQP with "
                        f"the library settings: "
                        f"{np.percentile(base.times, 99) / np.median(base.times):.1f} x)")
    info = machine_info()
    report = f"""# QP backends on the QPs the controllers solve

Reproduce: `python -m benchmarks.qp_backends` (module docstring: what is replayed and how).

Machine: {info['CPU']}, {info['cores']}, Python {info['Python']}, OSQP {info['OSQP']};
{dt.datetime.now(dt.UTC):%Y-%m-%d %H:%M} UTC; wall time
{time.perf_counter() - t0:.0f} s; best of {args.repeats} replays.

Times are update + warm start + solve per QP; *max abs(x - x_ref)* against Clarabel's
high-accuracy solution (QPs whose slacks are not unique can differ there without being
less accurate); *max violation* is the largest constraint violation, m (the collision
rows carry a 1e-3 m margin, and every first input is verified on the true distance);
*failures* are QPs left unsolved (OSQP at its iteration cap: the library then solves them
again with Clarabel, which this replay does not).

## Verdicts (computed from the tables)

{chr(10).join(verdicts)}

## Tables

{chr(10).join(sections)}
"""
    publish(report, None if args.quick else DOC_PATH)
    return 0


if __name__ == "__main__":
    sys.exit(main())

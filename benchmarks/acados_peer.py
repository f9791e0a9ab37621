r"""acados (SQP-RTI with HPIPM) and sqpmpc on the same centralized OCPs, interleaved sample
by sample in one process, timed in CPU time.

Usage (from the repository root)::

    pip install --target /tmp/acados-deps comma-deps-acados   # acados, from the registry
    python -m benchmarks.acados_peer --acados-path /tmp/acados-deps   # docs/acados-peer.md
    python -m benchmarks.acados_peer --acados-path /tmp/acados-deps --quick --no-write
    python -m benchmarks.acados_peer --cases "paper-s2 decentralized" --no-write  # no acados

The wheel (acados 0.2 with HPIPM, BLASFEO, its Python template and ``t_renderer``)
also carries a CasADi of its own: installed into its own folder and appended to
``sys.path`` (``--acados-path``, or ``SQPMPC_ACADOS_PATH``), it leaves the
environment's CasADi first. Nothing of acados is kept in this repository: every
solver is generated and compiled (gcc) at benchmark time into a temporary folder,
removed at the end.

What is compared. The OCP of paper eq. 7 (centralized): unicycles with Euler
dynamics, :math:`\sum_{i=1}^N \|p_i - r_i\|_Q^2 + \sum_{i=0}^{N-1}\|u_i\|_R^2`,
input bounds, and the pairwise distances :math:`\|p_a - p_b\| \ge d_{ab} +`
``collision_margin`` on stages 1..N as acados's nonlinear constraints, softened
with the same L1 price (``slack_penalty``) as sqpmpc's rows on stages 2..N
(acados softens all stages: its stage-1 rows are not hard). acados runs SQP-RTI
(one Gauss-Newton QP per sample, ``PARTIAL_CONDENSING_HPIPM``); sqpmpc runs its
defaults (RTI, ``qp_solver="auto"``) unless ``--qp-solver`` says otherwise.

Interleaving. sqpmpc drives the closed loop; at every sample acados solves
from the same measured state and references, warm-started from its own
previous solution, and its first input is compared with sqpmpc's (reported:
the median and largest difference). The order of the two calls alternates
from sample to sample. The first sample (sqpmpc: up to 30 SQP iterations;
acados: 30 RTI iterations) is reported on its own and left out of the
medians.

Decentralized. The paper-s2 case also runs decentralized (sqpmpc alone: acados
has no counterpart of the robots' own QPs with the neighbours' exchanged plans):
each robot's thread CPU per sample, reported as the issue's per-robot median
(the median over robots of each robot's median over the samples after the
first) and the p99 over every robot and sample after the first.

Targets. The page ends with issue 34's verdicts computed from the run: sqpmpc's
median at most acados's C median at N = 8 and N = 40, its p99 at most acados's
(total) p99 at N = 40 and at 16 robots, and the decentralized per-robot median
at most :data:`PER_ROBOT_TARGET_MS`.

Times. ``time.thread_time`` around sqpmpc's ``controller.step`` (the whole
sample: references, linearization, QP, checks) and around acados's whole
Python call (state and references set, ``solve``, first input read): the
*total*; acados's own C time (``time_tot``) and its QP time (``time_qp``) beside
it. Nothing is hard-coded: every ratio is computed from the run.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sqpmpc.control.settings import SolverSettings
from sqpmpc.problem.fleets import antipodal_swap
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import ClosedLoopSimulation

from .compare_ipopt import machine_info
from .report import publish

__all__ = ["CASES", "DECENTRALIZED_CASE", "PER_ROBOT_TARGET_MS", "AcadosPeer", "CaseResult",
           "DecentralizedResult", "build_parser", "import_acados", "load_case", "main", "render",
           "run_case", "run_decentralized", "verdicts"]

DOC_PATH = Path(__file__).resolve().parent.parent / "docs" / "acados-peer.md"

#: ``(label, scenario, horizon, t_end)``: ``None`` keeps the scenario's own value.
CASES: tuple[tuple[str, str, int | None, float | None], ...] = (
    ("paper-s2 N 8", "paper-s2", None, 100.0),
    ("paper-s2 N 20", "paper-s2", 20, 100.0),
    ("paper-s2 N 40", "paper-s2", 40, 100.0),
    ("swap-4", "swap:4", None, None),
    ("swap-8", "swap:8", None, None),
    ("swap-16", "swap:16", None, None),
)
#: ``(label, scenario, t_end)`` of the decentralized case (sqpmpc alone).
DECENTRALIZED_CASE: tuple[str, str, float] = ("paper-s2 decentralized", "paper-s2", 100.0)
#: Issue 34's goal for the decentralized per-robot median, ms.
PER_ROBOT_TARGET_MS = 0.1
_FIRST_SAMPLE_ITERATIONS = 30


def import_acados(extra_path: str | None) -> tuple[object, object]:
    """``(acados, acados_template)`` from the ``comma-deps-acados`` wheel."""
    if extra_path:
        sys.path.append(str(Path(extra_path).resolve()))
    acados = importlib.import_module("acados")
    os.environ.setdefault("ACADOS_SOURCE_DIR", acados.DIR)
    os.environ.setdefault("TERA_PATH", acados.TERA_PATH)
    os.environ.setdefault("ACADOS_PYTHON_INTERFACE_PATH", acados.TEMPLATE_DIR)
    # the wheel's libraries find each other by soname only: load them first, global
    import ctypes

    for lib in ("libblasfeo.so", "libhpipm.so", "libqpOASES_e.so", "libacados.so"):
        ctypes.CDLL(os.path.join(acados.LIB_DIR, lib), mode=ctypes.RTLD_GLOBAL)
    template = importlib.import_module("acados.acados_template")
    return acados, template


def load_case(name: str, horizon: int | None, t_end: float | None) -> Scenario:
    """The scenario of a case (``swap:<n>``: :func:`antipodal_swap`)."""
    sc = antipodal_swap(int(name.split(":")[1])) if name.startswith("swap:") else (
        load_scenario(name))
    changes: dict[str, object] = {}
    if horizon is not None:
        changes["horizon"] = horizon
    if t_end is not None:
        changes["t_end"] = min(t_end, sc.t_end)
    return sc.with_changes(**changes) if changes else sc


class AcadosPeer:
    """The centralized OCP of ``scenario`` as an acados SQP-RTI solver, generated and
    compiled into ``folder``.

    Parameters
    ----------
    scenario
        The problem (no obstacles, no position bounds).
    settings
        sqpmpc's settings: the slack price and the collision margin are taken from them.
    folder
        Where the generated code and the shared library go.
    template
        The ``acados_template`` module.
    """

    def __init__(self, scenario: Scenario, settings: SolverSettings, folder: Path,
                 template: object) -> None:
        import casadi as ca

        sc = self.scenario = scenario
        n, N, h = sc.n_robots, sc.horizon, sc.sample_time
        if sc.obstacles or sc.polygons:
            raise ValueError("the acados peer has no obstacle rows")
        self.n, self.N = n, N
        x = ca.SX.sym("x", 3 * n)
        u = ca.SX.sym("u", 2 * n)
        rows = []
        for r in range(n):
            psi, v, om = x[3 * r + 2], u[2 * r], u[2 * r + 1]
            rows += [x[3 * r] + h * v * ca.cos(psi), x[3 * r + 1] + h * v * ca.sin(psi),
                     psi + h * om]
        model = template.AcadosModel()
        model.name = f"peer_{n}_{N}"
        model.x, model.u = x, u
        model.disc_dyn_expr = ca.vertcat(*rows)
        pairs = list(sc.pairs())
        dreq = sc.required_distances()
        if pairs:
            dist = [ca.sqrt(ca.sumsqr(x[3 * a:3 * a + 2] - x[3 * b:3 * b + 2]) + 1e-12)
                    for a, b in pairs]
            model.con_h_expr = ca.vertcat(*dist)
            model.con_h_expr_e = ca.vertcat(*dist)
        ocp = template.AcadosOcp()
        ocp.model = model
        ocp.code_export_directory = str(folder / "c_generated_code")
        ocp.dims.N = N
        ocp.solver_options.tf = N * h
        Q = np.asarray(sc.weights.Q, float)
        R = np.asarray(sc.weights.R, float)
        ny = 4 * n
        Vx = np.zeros((ny, 3 * n))
        Vu = np.zeros((ny, 2 * n))
        for r in range(n):
            Vx[2 * r, 3 * r] = Vx[2 * r + 1, 3 * r + 1] = 1.0
            Vu[2 * n + 2 * r, 2 * r] = Vu[2 * n + 2 * r + 1, 2 * r + 1] = 1.0
        ocp.cost.cost_type = ocp.cost.cost_type_e = "LINEAR_LS"
        # acados: 0.5 * h * ||y - y_ref||_W^2 per stage (scaled by the time step), 0.5 * ||.||_W
        # at the end; sqpmpc: ||p_i - r_i||_Q^2 + ||u_i||_R^2
        self.W = np.diag(np.r_[np.tile(2.0 * Q, n), np.tile(2.0 * R, n)]) / h
        self.W0 = np.diag(np.r_[np.zeros(2 * n), np.tile(2.0 * R, n)]) / h
        ocp.cost.W = self.W
        ocp.cost.Vx, ocp.cost.Vu = Vx, Vu
        ocp.cost.yref = np.zeros(ny)
        ocp.cost.W_e = np.diag(np.tile(2.0 * Q, n))
        ocp.cost.Vx_e = Vx[:2 * n]
        ocp.cost.yref_e = np.zeros(2 * n)
        ulo, uup = sc.bounds.input_lower(), sc.bounds.input_upper()
        ocp.constraints.lbu = np.tile(ulo, n)
        ocp.constraints.ubu = np.tile(uup, n)
        ocp.constraints.idxbu = np.arange(2 * n)
        ocp.constraints.x0 = sc.initial_states().ravel()
        if pairs:
            need = np.array([dreq[a, b] for a, b in pairs]) + settings.collision_margin
            big = 1e6
            for suffix in ("", "_e"):
                setattr(ocp.constraints, f"lh{suffix}", need)
                setattr(ocp.constraints, f"uh{suffix}", np.full(len(pairs), big))
                setattr(ocp.constraints, f"idxsh{suffix}", np.arange(len(pairs)))
                # the upper side is never near: priced as the lower one (a free slack would
                # leave the QP without a minimum in it)
                for name, value in (("zl", settings.slack_penalty),
                                    ("zu", settings.slack_penalty), ("Zl", 0.0), ("Zu", 0.0)):
                    # the L1 price per stage; acados scales stage terms by h as the cost
                    scale = 1.0 if suffix else 1.0 / h
                    setattr(ocp.cost, f"{name}{suffix}", np.full(len(pairs), value * scale))
        opts = ocp.solver_options
        opts.qp_solver = "PARTIAL_CONDENSING_HPIPM"
        opts.hessian_approx = "GAUSS_NEWTON"
        opts.integrator_type = "DISCRETE"
        opts.nlp_solver_type = "SQP_RTI"
        opts.qp_solver_iter_max = 100
        opts.print_level = 0
        with contextlib.chdir(folder), contextlib.redirect_stdout(sys.stderr):
            self.solver = template.AcadosOcpSolver(
                ocp, json_file=str(folder / f"{model.name}.json"), verbose=False)
        self._yref = np.zeros((N, ny))
        self.started = False

    def step(self, t: float, states: np.ndarray) -> tuple[np.ndarray, float, float, float, int]:
        """First inputs ``(n, 2)`` from ``states (n, 3)`` at ``t``; the thread CPU time of
        ``solve`` (acados's C code, s); acados's own ``time_tot`` and ``time_qp`` (wall
        clocks, s); QP iterations (summed over the RTI iterations of a first sample)."""
        sc, n, N, s = self.scenario, self.n, self.N, self.solver
        x0 = np.asarray(states, float).ravel()
        s.set(0, "lbx", x0)
        s.set(0, "ubx", x0)
        ref = sc.reference_positions(t + sc.sample_time * np.arange(1, N + 1))  # (N, n, 2)
        for i in range(1, N):
            self._yref[i, :2 * n] = ref[i - 1].ravel()
            s.set(i, "yref", self._yref[i])
        s.set(N, "yref", ref[N - 1].ravel())
        total = qp = cpu = 0.0
        qp_iter = 0
        for _ in range(1 if self.started else _FIRST_SAMPLE_ITERATIONS):
            if not self.started:  # the resting rollout, as sqpmpc starts
                for i in range(N + 1):
                    s.set(i, "x", x0)
            t0 = time.thread_time()
            s.solve()
            cpu += time.thread_time() - t0
            total += float(np.ravel(s.get_stats("time_tot"))[0])
            qp += float(np.ravel(s.get_stats("time_qp"))[0])
            qp_iter += int(np.sum(s.get_stats("qp_iter")))
            self.started = True
        return s.get(0, "u").reshape(n, 2), cpu, total, qp, qp_iter


@dataclass
class CaseResult:
    """The per-sample CPU times of one case (s), without the first sample."""

    label: str
    n_robots: int
    horizon: int
    sqpmpc: np.ndarray
    acados_total: np.ndarray
    acados_c: np.ndarray
    acados_qp: np.ndarray
    acados_wall: np.ndarray
    first: tuple[float, float]
    input_difference: tuple[float, float]
    qp_solver: str


@dataclass
class DecentralizedResult:
    """Each robot's CPU time per sample of a decentralized closed loop (s), ``(K, n)``,
    without the first sample, and the first sample's ``(n,)``."""

    label: str
    n_robots: int
    horizon: int
    cpu: np.ndarray
    first: np.ndarray
    qp_solver: str

    @property
    def per_robot_median(self) -> float:
        """The median over robots of each robot's median (s)."""
        return float(np.median(np.median(self.cpu, axis=0)))


def run_decentralized(label: str, scenario: Scenario, settings: SolverSettings
                      ) -> DecentralizedResult:
    """sqpmpc's decentralized closed loop on ``scenario``: each robot's CPU per sample."""
    sim = ClosedLoopSimulation(scenario, "decentralized", settings)
    sim.run()
    cpu = sim.cpu_times[:sim.k]
    return DecentralizedResult(label, scenario.n_robots, scenario.horizon, cpu[1:], cpu[0],
                               settings.qp_solver_for(scenario.n_robots, "decentralized"))


def _stats(x: np.ndarray) -> tuple[float, float]:
    return float(np.median(x)) * 1e3, float(np.percentile(x, 99)) * 1e3


def run_case(label: str, scenario: Scenario, settings: SolverSettings, template: object
             ) -> CaseResult:
    """One case: sqpmpc's closed loop, acados from the same state at every sample."""
    sim = ClosedLoopSimulation(scenario, "centralized", settings)
    ctrl = sim.controllers[0]
    step = ctrl.step
    cpu: list[float] = []

    def timed(*args: object, **kwargs: object) -> object:
        t0 = time.thread_time()
        out = step(*args, **kwargs)
        cpu.append(time.thread_time() - t0)
        return out

    ctrl.step = timed  # this benchmark's timing only
    with tempfile.TemporaryDirectory(prefix="acados-peer-") as tmp:
        peer = AcadosPeer(scenario, settings, Path(tmp), template)
        totals, cs, walls, qps, diffs = [], [], [], [], []
        for k in range(scenario.steps):
            x = sim.states[k].copy()
            t = float(sim.t[k])
            if k % 2:
                sim.step()
            t0 = time.thread_time()
            u_ac, c_time, wall_time, qp_time, _ = peer.step(t, x)
            totals.append(time.thread_time() - t0)
            if not k % 2:
                sim.step()
            cs.append(c_time)
            walls.append(wall_time)
            qps.append(qp_time)
            diffs.append(float(np.max(np.abs(u_ac - sim.inputs[k]))))
        del peer
    sq, tot = np.array(cpu), np.array(totals)
    d = np.array(diffs[1:])
    return CaseResult(label, scenario.n_robots, scenario.horizon, sq[1:], tot[1:],
                      np.array(cs[1:]), np.array(qps[1:]), np.array(walls[1:]), (sq[0], tot[0]),
                      (float(np.median(d)), float(d.max())),
                      settings.qp_solver_for(scenario.n_robots, "centralized",
                                             bool(scenario.robot_model().velocity_states)))


def verdicts(results: list[CaseResult], decentralized: DecentralizedResult | None) -> list[str]:
    """Issue 34's targets against acados and per robot, computed from the run (lines)."""
    by = {r.label: r for r in results}
    out = []

    def line(text: str, ok: bool) -> None:
        out.append(f"- {text}: {'met' if ok else 'NOT met'}")

    for label in ("paper-s2 N 8", "paper-s2 N 40"):
        if label in by:
            a, b = np.median(by[label].sqpmpc), np.median(by[label].acados_c)
            line(f"{label}: sqpmpc median {a * 1e3:.3f} ms <= acados C median {b * 1e3:.3f} ms",
                 a <= b)
    for label in ("paper-s2 N 40", "swap-16"):
        if label in by:
            a = np.percentile(by[label].sqpmpc, 99)
            b = np.percentile(by[label].acados_total, 99)
            line(f"{label}: sqpmpc p99 {a * 1e3:.3f} ms <= acados p99 {b * 1e3:.3f} ms", a <= b)
    if decentralized is not None:
        per = decentralized.per_robot_median * 1e3
        line(f"{decentralized.label}: per-robot median {per:.3f} ms <= {PER_ROBOT_TARGET_MS} ms",
             per <= PER_ROBOT_TARGET_MS)
    return out


def render(results: list[CaseResult], info: dict[str, str], command: str, wall: float,
           decentralized: DecentralizedResult | None = None) -> str:
    """The markdown page."""
    lines = [
        "# acados (SQP-RTI, HPIPM) and sqpmpc on the same OCPs",
        "",
        f"Reproduce: `{command}` (module docstring: what is compared and how).",
        "",
        "Machine: " + ", ".join(f"{k} {v}" for k, v in info.items()) + f"; run {wall:.0f} s; "
        f"load average at the end {os.getloadavg()[0]:.2f}.",
        "",
        "CPU time per sample (thread time), ms, medians and p99 over the samples after the "
        "first; *ratio* = sqpmpc / acados (< 1: sqpmpc faster). *acados C* is the thread "
        "CPU time of acados's `solve()` (its C code, no Python); acados's own `time_tot` "
        "and `time_qp` are wall clocks (they grow with the machine's load), given beside.",
        "",
        "| case | robots | N | sqpmpc QP | sqpmpc median / p99 | acados total median / p99 "
        "| acados C median / p99 | acados time_tot median (time_qp), wall | median ratio "
        "to total / to C | p99 ratio to total / to C | first sample sqpmpc / acados | "
        "first-input difference median / max |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        sm, sp = _stats(r.sqpmpc)
        tm, tp = _stats(r.acados_total)
        cm, cp = _stats(r.acados_c)
        qm, _ = _stats(r.acados_qp)
        wm, _ = _stats(r.acados_wall)
        lines.append(
            f"| {r.label} | {r.n_robots} | {r.horizon} | {r.qp_solver} | {sm:.3f} / {sp:.3f} | "
            f"{tm:.3f} / {tp:.3f} | {cm:.3f} / {cp:.3f} | {wm:.3f} ({qm:.3f}) | {sm / tm:.2f} / "
            f"{sm / cm:.2f} | {sp / tp:.2f} / {sp / cp:.2f} | {r.first[0] * 1e3:.1f} / "
            f"{r.first[1] * 1e3:.1f} | {r.input_difference[0]:.1e} / "
            f"{r.input_difference[1]:.1e} |")
    lines += ["", "The OCPs differ in one respect: acados softens the stage-1 distance rows "
              "too (sqpmpc keeps them hard and verifies the first input). The first-input "
              "differences say how close the two closed loops' decisions are from the same "
              "state.", ""]
    if decentralized is not None:
        d = decentralized
        lines += [f"## {d.label} (sqpmpc alone)", "",
                  "Each robot's thread CPU per sample, ms: the per-robot median (median over "
                  "robots of each robot's median) and the p99 over every robot and sample, "
                  "after the first sample.", "",
                  "| case | robots | N | sqpmpc QP | per-robot median | p99 | first sample, "
                  "largest robot |", "|---|---|---|---|---|---|---|",
                  f"| {d.label} | {d.n_robots} | {d.horizon} | {d.qp_solver} | "
                  f"{d.per_robot_median * 1e3:.4f} | {np.percentile(d.cpu, 99) * 1e3:.4f} | "
                  f"{d.first.max() * 1e3:.2f} |", ""]
    targets = verdicts(results, decentralized)
    if targets:
        lines += ["## Targets of issue 34", "", *targets, ""]
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    """Command-line options."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.acados_peer", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--acados-path", default=os.environ.get("SQPMPC_ACADOS_PATH"),
                   help="a folder to append to sys.path that holds the 'acados' package")
    p.add_argument("--quick", action="store_true", help="20 s of each case")
    p.add_argument("--cases", nargs="*", help="labels of CASES (and DECENTRALIZED_CASE) to run "
                   "(default: all)")
    p.add_argument("--qp-solver", default="auto", help="sqpmpc's qp_solver (default auto)")
    p.add_argument("--no-write", action="store_true", help="print only")
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the cases and write :data:`DOC_PATH`."""
    args = build_parser().parse_args(argv)
    cases = [case for case in CASES if not args.cases or case[0] in args.cases]
    # acados only for its cases: the decentralized case alone runs without it
    template = import_acados(args.acados_path)[1] if cases else None
    settings = SolverSettings(qp_solver=args.qp_solver)
    started = time.perf_counter()
    results = []
    for label, name, horizon, t_end in cases:
        sc = load_case(name, horizon, 20.0 if args.quick else t_end)
        results.append(run_case(label, sc, settings, template))
        r = results[-1]
        print(f"{label}: sqpmpc {_stats(r.sqpmpc)} acados total {_stats(r.acados_total)} "
              f"C {_stats(r.acados_c)} ms", file=sys.stderr, flush=True)
    label, name, t_end = DECENTRALIZED_CASE
    decentralized = None
    if not args.cases or label in args.cases:
        decentralized = run_decentralized(label, load_case(name, None, 20.0 if args.quick
                                                           else t_end), settings)
        print(f"{label}: per-robot median {decentralized.per_robot_median * 1e3:.4f} ms",
              file=sys.stderr, flush=True)
    command = "python -m benchmarks.acados_peer " + " ".join(argv if argv is not None
                                                              else sys.argv[1:])
    text = render(results, machine_info(), command.strip(), time.perf_counter() - started,
                  decentralized)
    publish(text, None if args.no_write else DOC_PATH)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

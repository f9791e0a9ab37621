"""Where the time of one controller sample goes, stage by stage of the pipeline.

Usage (from the repository root)::

    python -m benchmarks.stages                      # paper-s2 and swap-6, both schemes
    python -m benchmarks.stages --scenarios head-on

Each stage method of :class:`sqpmpc.control.pipeline.ControllerPipeline` is wrapped
(on the benchmark's controller instances only) with a wall-clock timer, and a
closed loop is run; the table gives the median and mean per controller sample
of each stage, the QP's update + solve inside the solve stage, and the rest
of ``run_sample`` (measurement, the sample view, the wrappers' own cost). The
first sample (a converged SQP start) is left out of the medians and means.
Prints only; `docs/engine.md` quotes a run.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from functools import wraps

import numpy as np

from sqpmpc.control.pipeline import ControllerPipeline
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import ClosedLoopSimulation

from .compare_ipopt import machine_info

__all__ = ["main", "stage_times"]

STAGES = ("predict_neighbours", "shape_references", "shift", "shape_guess", "solve",
          "after_solve", "verify", "count", "publish")
#: the rule hooks (:data:`sqpmpc.rules.base.HOOKS`) timed, by the method that implements them
HOOK_METHODS = {"references": "shape_references", "guess": "shape_guess",
                "after_solve": "after_solve"}


def _timed(fn: Callable[..., object], log: list[float]) -> Callable[..., object]:
    @wraps(fn)
    def wrapper(*args: object, **kwargs: object) -> object:
        t0 = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            log.append(time.perf_counter() - t0)
    return wrapper


def stage_times(scenario: str, scheme: str) -> dict[str, np.ndarray]:
    """Per-sample seconds of each stage of controller 0, summed over a sample's calls."""
    sim = ClosedLoopSimulation(load_scenario(scenario), scheme)
    ctrl: ControllerPipeline = sim.controllers[0]
    logs: dict[str, list[float]] = {name: [] for name in STAGES}
    for step in ("predict_neighbours", "verify", "count", "publish"):  # the pipeline's steps
        setattr(ctrl, step, _timed(getattr(ctrl, step), logs[step]))
    ctrl.engine.shift = _timed(ctrl.engine.shift, logs["shift"])
    qp_log: list[float] = []
    solve = ctrl.engine.solve

    def solve_and_log_qp(*args: object, **kwargs: object) -> object:
        report = solve(*args, **kwargs)
        qp_log.append(report.qp_time)
        return report

    ctrl.engine.solve = _timed(solve_and_log_qp, logs["solve"])
    for rule in ctrl.rules:
        for hook, method in HOOK_METHODS.items():
            if hook in rule.hooks:
                setattr(rule, method, _timed(getattr(rule, method), logs[method]))
    samples: dict[str, list[float]] = {name: [] for name in STAGES}
    samples.update({"QP update + solve": [], "whole sample": []})
    while sim.k < sim.scenario.steps:
        before = {name: len(log) for name, log in logs.items()}
        qp = len(qp_log)
        sim.step()
        for name, log in logs.items():
            samples[name].append(sum(log[before[name]:]))
        samples["QP update + solve"].append(sum(qp_log[qp:]))
        samples["whole sample"].append(sim.solve_times[sim.k - 1, 0])
    return {name: np.array(v[1:]) for name, v in samples.items()}


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit status."""
    parser = argparse.ArgumentParser(prog="python -m benchmarks.stages",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", nargs="+", default=["paper-s2", "swap-6"])
    args = parser.parse_args(argv)
    info = machine_info()
    print(f"Machine: {info['CPU']}, {info['cores']}, Python {info['Python']}, "
          f"OSQP {info['OSQP']}; {info['date']}\n")
    for name in args.scenarios:
        for scheme in ("centralized", "decentralized"):
            t = stage_times(name, scheme)
            whole = t["whole sample"]
            staged = sum(t[s] for s in STAGES)
            rows = [(s, t[s]) for s in STAGES]
            rows += [("  of which QP update + solve", t["QP update + solve"]),
                     ("rest of run_sample", whole - staged), ("whole sample", whole)]
            print(f"### {name}, {scheme} (controller 0, {whole.size} samples)\n")
            print("| stage | median us | mean us |\n|---|---|---|")
            for label, v in rows:
                print(f"| {label} | {np.median(v) * 1e6:.1f} | {v.mean() * 1e6:.1f} |")
            ratio = whole.sum() / t["QP update + solve"].sum()
            print(f"\nwhole / (QP update + solve): {ratio:.2f}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

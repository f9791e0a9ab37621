"""Small synthetic set-ups shared by the per-rule tests."""

from __future__ import annotations

import numpy as np

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.problem.scenario import Scenario
from sqpmpc.problem.scenario_file import parse_scenario
from sqpmpc.rules.base import Contribution, RuleInstance, SampleView

__all__ = ["fleet", "guess", "only", "shape", "view"]


def fleet(starts: list[list[float]], goals: list[list[float]], horizon: int = 8,
          sample_time: float = 0.5, t_end: float = 30.0) -> Scenario:
    """Robots at ``starts`` (x, y, psi) with point references at ``goals``, paper bounds."""
    return parse_scenario({
        "name": "synthetic", "t_end": t_end, "sample_time": sample_time, "horizon": horizon,
        "weights": {"Q": [1.0, 1.0], "R": [0.5, 0.5]},
        "bounds": {"v": [-0.6, 0.6], "omega": [-0.785, 0.785]},
        "robots": [{"id": i + 1, "initial_state": s, "diameter": 0.3,
                    "reference": {"type": "point", "position": g}}
                   for i, (s, g) in enumerate(zip(starts, goals, strict=True))],
    })


def view(ctrl: CentralizedController, states: np.ndarray, applied: np.ndarray | None = None,
         applied_before: np.ndarray | None = None, t: float = 0.0,
         sample: int = 5) -> SampleView:
    """The sample view the pipeline would build for ``states (n, 3)``."""
    m = ctrl.indices.size
    refs = ctrl.reference(t)
    zeros = np.zeros((m, 2))
    return SampleView(sample, t, np.ascontiguousarray(states[:, :2]), states[ctrl.indices],
                      refs, refs, zeros if applied is None else applied,
                      zeros if applied_before is None else applied_before,
                      np.ascontiguousarray(states[:, 2]))


def shape(ctrl: CentralizedController, inst: RuleInstance, v: SampleView) -> SampleView:
    """The view after ``inst``'s ``"references"`` hook, its contribution applied by ``ctrl``."""
    return ctrl.apply(inst.shape_references(v), v)


def guess(inst: RuleInstance, v: SampleView, speeds: np.ndarray) -> Contribution | None:
    """``inst``'s ``"guess"`` hook on ``speeds (m, N)``, which get its new speeds."""
    out = inst.shape_guess(v.but(guess_speeds=speeds.copy()))
    if out is not None and out.guess_speeds is not None:
        speeds[...] = out.guess_speeds
    return out


def only(*names: str) -> SolverSettings:
    """Settings with only the named rules."""
    from sqpmpc.rules.registry import select_rules

    return SolverSettings(rules=select_rules(list(names)))

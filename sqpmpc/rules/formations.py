r"""The ``yield`` rule: an arrived robot steps aside for those still travelling.

In dense goal sets (grid-to-grid, a warehouse's docks) the robots that arrive
first can wall in deeper goals. A robot within ``arrived`` metres of its goal
at rest *yields* when a travelling robot (one farther than ``travelling`` from
its own resting goal, so that a robot stepping aside is not one) within
``reach`` metres has it in its way: the arrived robot lies ahead of the
traveller and closer than their required distance plus ``clearance`` to the
traveller's straight way to its goal. Its reference then becomes its goal
moved sideways, perpendicular to the traveller's way on the side it already is
(the traveller's right when exactly on the way), far enough to leave the
required distance plus ``clearance``; it holds that point for ``hold`` samples
after the last such traveller and then returns to its goal. Every robot
applies the same rule to the same shared data (the scenario's goals, the
measured positions), so the decentralized robots agree.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from sqpmpc.errors import ProblemError
from sqpmpc.problem.references import PointReference
from sqpmpc.rules.base import (
    Contribution,
    Rule,
    RuleContext,
    RuleInstance,
    SampleView,
    check_positive,
)

__all__ = ["Yield"]


class _YieldInstance(RuleInstance):
    hooks = ("references",)
    rule: Yield
    counter_names = ("yield_samples", "yield_starts")

    def __init__(self, rule: Yield, context: RuleContext) -> None:
        super().__init__(rule, context)
        self.required = context.scenario.required_distances()
        self.hold = np.zeros(context.own.size, dtype=np.int64)
        self.targets = np.zeros((context.own.size, 2))
        self.references_changed()

    def references_changed(self) -> None:
        sc = self.context.scenario
        self.has_goal = np.array([isinstance(r.reference, PointReference) for r in sc.robots])
        self.goals = np.array([r.reference.goal if isinstance(r.reference, PointReference)
                               else (np.nan, np.nan) for r in sc.robots], dtype=float)
        self.active = bool(self.has_goal.sum() >= 2)
        self.idle = not self.active

    def shape_references(self, view: SampleView) -> Contribution | None:
        if not self.active:
            return None
        rule = self.rule
        pos = view.positions
        to_goal = np.hypot(*(self.goals - pos).T)
        travelling = self.has_goal & (to_goal > rule.travelling)
        out: np.ndarray | None = None
        for k, i in enumerate(self.context.own):
            i = int(i)
            if not self.has_goal[i] or to_goal[i] > rule.arrived and self.hold[k] == 0:
                continue
            if to_goal[i] <= rule.arrived:
                target = self._blocking(i, pos, travelling)
                if target is not None:
                    if self.hold[k] == 0:
                        self.counts["yield_starts"] += 1
                    self.targets[k] = target
                    self.hold[k] = rule.hold
            if self.hold[k] == 0:
                continue
            self.hold[k] -= 1
            if out is None:
                out = view.references.copy()
            out[k] = self.targets[k]
            self.counts["yield_samples"] += 1
        return None if out is None else Contribution(references=out)

    def _blocking(self, i: int, pos: np.ndarray, travelling: np.ndarray) -> np.ndarray | None:
        """The sideways goal of arrived robot ``i`` for the nearest traveller it blocks."""
        rule = self.rule
        p = pos[i]
        near = travelling.copy()
        near[i] = False
        gap = np.hypot(*(pos - p).T)
        near &= gap < rule.reach
        best, target = np.inf, None
        for j in np.flatnonzero(near):
            way = self.goals[j] - pos[j]
            length = float(np.hypot(*way))
            if length <= 1e-9:
                continue
            u = way / length
            rel = p - pos[j]
            along = float(rel @ u)
            if along <= 0.0 or along > length + self.required[i, j]:
                continue  # behind the traveller or beyond its goal
            lateral = float(u[0] * rel[1] - u[1] * rel[0])  # > 0: left of the way
            keep = self.required[i, j] + rule.clearance
            if abs(lateral) >= keep or gap[j] >= best:
                continue
            side = 1.0 if lateral > 1e-3 else -1.0  # on the way: the traveller's right
            normal = np.array([-u[1], u[0]]) * side
            best = gap[j]
            target = self.goals[i] + normal * (keep - abs(lateral))
        return target


@dataclass(frozen=True)
class Yield(Rule):
    r"""An arrived robot in a traveller's way steps aside, then returns to its goal.

    Parameters
    ----------
    arrived
        A robot within this distance of its resting goal has arrived, m.
    travelling
        A robot farther than this from its resting goal is travelling, m.
    reach
        Travellers nearer than this are considered, m.
    clearance
        Room left beyond the required distance to the traveller's way, m.
    hold
        Samples the sideways goal is held after the last blocking traveller.
    """

    name = "yield"
    summary = "an arrived robot in a traveller's way steps aside, then returns to its goal"
    instance = _YieldInstance
    arrived: float = 0.1
    travelling: float = 0.7
    reach: float = 1.5
    clearance: float = 0.25
    hold: int = 6

    def __post_init__(self) -> None:
        check_positive(self, "arrived", "travelling", "reach", "clearance", "hold")
        if not isinstance(self.hold, numbers.Integral):
            raise ProblemError(f"rule 'yield': hold must be an integer, got {self.hold!r}")

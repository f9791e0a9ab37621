r"""The ``coordination`` plug-in: robots with goals at rest follow the fleet's roadmap plan.

Every robot with a ``point`` reference gets its path of the fleet's conflict-free
roadmap plan (:func:`sqpmpc.coordination.fleet.fleet_plan`) and executes it in
the plan's order at every vertex (:class:`sqpmpc.coordination.schedule.Execution`):
at each sample the controller counts every robot's progress from the measured
positions, and its own robots' references of stages 1..N become the points at
arc length :math:`v_{\max} T_s i` along the polyline from the robot's position
through the path vertices it may head for now, held at the last of them (at its
own goal point once the whole path is open). A robot that may not move yet is
held at its progress vertex.

The plan is a function of the scenario and the margins, so every controller of a
run, in one process or in many, computes the same plan and counts the same
progress from the same measurements: no process coordinates the others, and no
process can make robots collide (the collision rows and the verified first input
are untouched: this plug-in only chooses where each robot heads). A goal changed
by :meth:`~sqpmpc.control.pipeline.ControllerPipeline.update_reference` re-plans
from every robot's progress vertex (a valid start: :mod:`sqpmpc.coordination.schedule`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sqpmpc.coordination.fleet import FleetPlan, fleet_plan, replan
from sqpmpc.coordination.schedule import Execution
from sqpmpc.problem.references import PointReference
from sqpmpc.rules.base import Contribution, Rule, RuleContext, RuleInstance, SampleView

__all__ = ["Coordination"]


class _Instance(RuleInstance):
    hooks = ("references", "guess")
    counter_names = ("coordination_holds", "coordination_replans", "coordination_linearized")

    def __init__(self, rule: Rule, context: RuleContext) -> None:
        super().__init__(rule, context)
        scenario = context.scenario
        radius = 0.5 * float(scenario.diameters().max())
        self.clearance = radius + context.wall_margin
        self.separation = float(scenario.required_distances().max(initial=0.0)) \
            + context.pair_margin if scenario.n_robots > 1 else 0.0
        self.plan: FleetPlan | None = fleet_plan(scenario, self.clearance, self.separation)
        self.idle = self.plan is None
        self._start(self.plan)

    def _start(self, plan: FleetPlan | None) -> None:
        if plan is None:
            self.execution = None
            self.rows = np.full(self.context.own.size, -1, dtype=np.int64)
            return
        c = self.context
        # vertices a robot can pass within the horizon, plus one
        window = math.ceil(c.max_speed * c.sample_time * c.horizon / plan.roadmap.spacing) + 1
        self.execution = Execution(plan.schedule, plan.roadmap, plan.robots, window)
        where = {int(r): k for k, r in enumerate(plan.robots)}
        self.rows = np.array([where.get(int(i), -1) for i in c.own], dtype=np.int64)
        self._stages = c.max_speed * c.sample_time * np.arange(1, c.horizon + 1)
        self._window = window
        # the fastest a robot at rest can go along its path at stages 0..N-1 (the
        # linearization speeds of a robot whose guess stands: v = 0 cannot steer)
        accel = c.scenario.bounds.acceleration
        ramp = np.full(c.horizon, c.max_speed) if accel is None else np.minimum(
            c.max_speed, min(-accel[0], accel[1]) * c.sample_time * np.arange(c.horizon))
        self._ramp = ramp
        self._moving = np.zeros(c.own.size, dtype=bool)
        self._speeds = np.zeros((c.own.size, c.horizon))

    def references_changed(self) -> None:
        plan, execution = self.plan, self.execution
        scenario = self.context.scenario
        if plan is None or execution is None:
            return
        configuration = execution.configuration()
        goals = []
        for k, i in enumerate(plan.robots):
            reference = scenario.robots[int(i)].reference
            goals.append(np.asarray(reference.position, dtype=float)
                         if isinstance(reference, PointReference)
                         else plan.roadmap.positions[configuration[k]])
        if all(np.allclose(g, old) for g, old in zip(goals, plan.goals, strict=True)):
            return
        self.plan = replan(plan, scenario, configuration, goals)
        self._start(self.plan)  # the new paths start at the progress vertices
        self.counts["coordination_replans"] += 1

    def shape_references(self, view: SampleView) -> Contribution | None:
        execution, plan = self.execution, self.plan
        if execution is None or plan is None:
            return None
        progress = execution.advance(view.positions)
        permitted = execution.permitted_all()
        out = np.array(view.references)
        self._moving[:] = False
        positions = view.positions
        for m, row in enumerate(self.rows):
            if row < 0:
                continue
            p = int(progress[row])
            last = int(plan.schedule.lengths[row]) - 1
            goal = plan.goals[row]
            if p >= last:
                out[m] = goal
                continue
            k = int(permitted[row])
            if k <= p:
                self.counts["coordination_holds"] += 1
                out[m] = execution.path_points(row, p, p)[0]
                continue
            here = positions[self.context.own[m]]
            back = max(p - 1, 0)  # from the segment into the progress vertex: no corner cut
            ahead = execution.path_points(row, back, k)
            first = back + _nearest_segment(here, ahead[:self._window + 2])
            pts = [here[None], execution.path_points(row, first, k)]
            if k >= last:
                pts.append(goal[None])
            out[m] = _along(np.concatenate(pts), self._stages)
            self._moving[m] = True
        return Contribution(references=out)

    def shape_guess(self, view: SampleView) -> Contribution | None:
        """A robot that may move along its path but whose linearization point stands (it
        would move less than the roadmap's reach over the horizon) is linearized at the
        fastest motion its bounds allow from rest, forwards when its path lies ahead of
        its heading, else backwards: at ``v = 0`` the linearized unicycle cannot turn."""
        if self.plan is None or view.guess_speeds is None or not self._moving.any():
            return None
        reach = self.plan.roadmap.reach
        guess = view.guess_speeds
        repaired = 0
        self._speeds[:] = guess
        for m in np.flatnonzero(self._moving):
            if np.abs(guess[m]).sum() * self.context.sample_time >= reach:
                continue
            pose = view.own_states[m]
            ahead = view.references[m, 0] - pose[:2]
            forward = ahead[0] * math.cos(pose[2]) + ahead[1] * math.sin(pose[2]) >= 0.0
            self._speeds[m] = self._ramp if forward else -self._ramp
            repaired += 1
        if not repaired:
            return None
        self.counts["coordination_linearized"] += repaired
        return Contribution(guess_speeds=self._speeds)


def _nearest_segment(point: np.ndarray, points: np.ndarray) -> int:
    """``s >= 1``: the segment ``points[s - 1] -> points[s]`` of the polyline ``points (K, 2)``
    nearest to ``point`` (the robot heads for its end: never back to a vertex it cut)."""
    a, b = points[:-1], points[1:]
    d = b - a
    dd = np.einsum("ij,ij->i", d, d)
    t = np.clip(np.einsum("ij,ij->i", point - a, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    gap = np.hypot(*(a + t[:, None] * d - point).T)
    return int(np.argmin(gap)) + 1


def _along(points: np.ndarray, distances: np.ndarray) -> np.ndarray:
    """Points at arc lengths ``distances`` along the polyline ``points (K, 2)``, held at
    its end."""
    steps = np.hypot(*np.diff(points, axis=0).T)
    arc = np.concatenate(([0.0], np.cumsum(steps)))
    s = np.minimum(distances, arc[-1])
    return np.column_stack((np.interp(s, arc, points[:, 0]), np.interp(s, arc, points[:, 1])))


@dataclass(frozen=True)
class Coordination(Rule):
    """Robots with goals at rest follow the fleet's roadmap plan in its vertex order.

    No parameters: the roadmap's spacing and reach follow from the robots' kept
    distance (:mod:`sqpmpc.coordination.roadmap`), the reference speed is the bound
    on :math:`|v|`.
    """

    name = "coordination"
    summary = ("robots with goals at rest follow a conflict-free roadmap plan (LaCAM), "
               "entering each vertex in the plan's order")
    instance = _Instance

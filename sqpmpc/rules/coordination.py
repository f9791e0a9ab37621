r"""The ``coordination`` plug-in: robots with goals at rest follow the fleet's roadmap plan.

Every robot with a ``point`` reference gets its path of the fleet's conflict-free
roadmap plan (:func:`sqpmpc.coordination.fleet.fleet_plan`) and executes it in
the plan's order at every vertex (:class:`sqpmpc.coordination.schedule.Execution`):
at each sample the controller counts every robot's progress from the measured
positions, and each of its own robots tracks the motion along the open part of
its path (:func:`sqpmpc.coordination.motion.path_motion`): from the vertex behind
it to the last vertex it may enter now (its goal once the whole path is open),
stopping there. The motion's positions are the references of stages 1..N and its
velocities the references of the inputs (and velocity states): the cost is
:math:`\|u - u^{\mathrm{ref}}\|_R`, so a robot at rest that must turn is asked to
turn (at :math:`v = 0` the linearized unicycle's position does not depend on its
heading: a cost on positions alone gave it no reason to), and the QP linearizes its
dynamics along the motion, so that it sees what the turn is for
(:meth:`~sqpmpc.ocp.iteration.Iteration.update_motion`). The motion starts at the
robot's velocities (for a model with velocity states; the last command when they are
not measured). At the end of its open path a robot waits within the roadmap's reach of
its vertex, turned (in place) to face the edge it leaves by next; one pushed farther
heads straight back to it, facing it first (a unicycle does not close a sideways gap by
itself), backwards when the vertex is behind it and its bounds allow; at its goal it
closes to half the reach, where the NMPC's own final approach takes over.

The plan is a function of the scenario and the margins, so every controller of a
run, in one process or in many, computes the same plan and counts the same
progress from the same measurements: no process coordinates the others, and no
process can make robots collide (the collision rows and the verified first input
are untouched: this plug-in only chooses where each robot heads). A goal changed
by :meth:`~sqpmpc.control.pipeline.ControllerPipeline.update_reference` re-plans
from every robot's progress vertex (a valid start: :mod:`sqpmpc.coordination.schedule`).
A controller that joins a run under way (started late, or restarted after a crash)
has no earlier positions: at its first sample it counts the progress from that one
measurement (:meth:`~sqpmpc.coordination.schedule.Execution.resume`).

**Progress stops: a new plan from where the robots are.** The execution cannot
deadlock while robots stay near their paths (:mod:`sqpmpc.coordination.schedule`):
the robot whose next vertex comes first in the plan is free, and it reaches that
vertex within the time a free robot needs from rest, :math:`T = \pi/\omega_{\max} +
(h + 2\rho)/v_{\max} + 2 v_{\max}/a_{\max} + N T_s` (a half-turn in place, the edge
and the reach, speeding up and slowing down, and the horizon to see it). The collision
rows may push a robot off its path, into the way of a robot that waits for it
(a 256-robot swap: a robot counted at its vertex stood 0.74 m from it, beyond the robot
waiting for it to go on). So when no robot's progress has grown for :math:`T` (in
samples) while robots are not at their paths' ends, every controller plans again from the
measured positions (:func:`~sqpmpc.coordination.fleet.replan_from_positions`: each
robot from the distinct vertex nearest to it, same goals) and executes the new plan:
it counts the same progress from the same measurements, so it re-plans at the same
sample to the same plan (in one process, computed once). A controller restarted after
such a re-plan does not know of it and executes the first plan; the collision rows keep
it safe. (Re-planning also when a single robot free to go on has not reached its next
vertex for :math:`T` re-planned a 256-robot swap every :math:`T` from 45 s on: in a crowd
a free robot is often slowed that long by its neighbours, and every new plan restarts
the progress.)

**A robot leaves: a new plan around it.** When the controller is told that robots left
the run for good (:meth:`~sqpmpc.control.pipeline.ControllerPipeline.update_departed`,
every controller at the same sample: in the services, the plant's states message says
so), it plans again from the measured positions with those robots standing on the
vertices nearest to them (the plan's robots parked on their goals): the robots the old
plan had waiting for them are planned around them, or, where no way around is left (a
one-lane aisle), the plan is kept and they wait (logged). Counted in
``coordination_departures``; a robot taking part again is planned to its goal again.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from sqpmpc.coordination.fleet import FleetPlan, fleet_plan, replan, replan_from_positions
from sqpmpc.coordination.mapf import PlanningError
from sqpmpc.coordination.motion import path_motion
from sqpmpc.coordination.schedule import Execution
from sqpmpc.problem.goals import ARRIVAL_TOLERANCE
from sqpmpc.problem.references import PointReference
from sqpmpc.rules.base import Contribution, Rule, RuleContext, RuleInstance, SampleView

__all__ = ["Coordination"]

_LOG = logging.getLogger(__name__)


class _Instance(RuleInstance):
    hooks = ("references",)
    counter_names = ("coordination_departures", "coordination_holds",
                     "coordination_replans", "coordination_stalls", "coordination_tracked")

    def __init__(self, rule: Rule, context: RuleContext) -> None:
        super().__init__(rule, context)
        scenario = context.scenario
        radius = 0.5 * float(scenario.diameters().max())
        self.clearance = radius + context.wall_margin
        self.separation = float(scenario.required_distances().max(initial=0.0)) \
            + context.pair_margin if scenario.n_robots > 1 else 0.0
        self.plan: FleetPlan | None = fleet_plan(scenario, self.clearance, self.separation)
        self._joined = False  # whether this controller counted progress at an earlier sample
        self._departed: frozenset[int] = frozenset()  # the robots the plan has standing
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
        # the scheduled ones among them, and each one's place there (clear: its decision only)
        self._scheduled = self.rows[self.rows >= 0]
        self._slot = np.cumsum(self.rows >= 0) - 1
        bounds = c.scenario.bounds
        self._speed = float(bounds.v[1])
        self._reverse = float(bounds.v[0]) < 0.0
        self._back = min(-float(bounds.v[0]), self._speed)  # the speed bound backwards
        self._turn = float(min(-bounds.omega[0], bounds.omega[1]))
        self._accel = None if bounds.acceleration is None else float(
            min(-bounds.acceleration[0], bounds.acceleration[1]))
        self._window = window
        # the distance to its goal within which a robot's own NMPC finishes its approach
        self._arrive = min(0.5 * plan.roadmap.reach, 0.5 * ARRIVAL_TOLERANCE)
        # a stall: no robot's progress for the time the slowest free robot takes to reach
        # its next vertex from rest within the reach of its own: a half-turn in place, the
        # edge and the reach at v_max, speeding up and slowing down, and the horizon the
        # NMPC needs to see the vertex (module docstring)
        speed_up = 0.0 if self._accel is None else 2.0 * self._speed / self._accel
        patience = (math.pi / self._turn + (plan.roadmap.spacing + 2.0 * plan.roadmap.reach)
                    / self._speed + speed_up + c.horizon * c.sample_time)
        #: samples without progress after which the fleet is planned again (read it)
        self.patience = math.ceil(patience / c.sample_time)
        self._total = -1  # the sum of the robots' progress when it last grew
        self._grew = 0  # the sample it did
        m, N = c.own.size, c.horizon
        self._tracked = np.zeros(m, dtype=bool)
        self._poses = np.zeros((m, N + 1, 3))
        self._velocities = np.zeros((m, N + 1, 2))

    def references_changed(self) -> None:
        plan, execution = self.plan, self.execution
        scenario = self.context.scenario
        if plan is None or execution is None:
            return
        configuration = execution.configuration()
        goals = []
        for k, i in enumerate(plan.robots):
            reference = scenario.robots[int(i)].reference
            goals.append(np.asarray(reference.goal, dtype=float)
                         if isinstance(reference, PointReference)
                         else plan.roadmap.positions[configuration[k]])
        if all(np.allclose(g, old) for g, old in zip(goals, plan.goals, strict=True)):
            return
        self.plan = replan(plan, scenario, configuration, goals)
        self._start(self.plan)  # the new paths start at the progress vertices
        self.counts["coordination_replans"] += 1

    def _stalled(self, execution: Execution, progress: np.ndarray, sample: int) -> bool:
        """Whether no robot's progress has grown for the patience, robots not at their
        paths' ends (in samples, so that controllers that skipped one agree)."""
        total = int(progress.sum())
        if total > self._total or execution.all_finished():
            self._total, self._grew = max(total, self._total), sample
            return False
        return sample - self._grew >= self.patience

    def _replan_from(self, plan: FleetPlan, execution: Execution, view: SampleView,
                     why: str) -> tuple[Execution, FleetPlan]:
        """A new plan from the measured states (:func:`replan_from_positions`), the same in
        every controller that counted the same progress and was told the same departed
        robots, those standing; kept as it was when there is none (logged)."""
        departed = self.context.departed & frozenset(plan.robots.tolist())
        self._departed = self.context.departed
        try:
            plan = replan_from_positions(plan, self.context.scenario, view.positions,
                                         standing=departed)
        except PlanningError as error:
            _LOG.warning("coordination: %s and no new plan from the robots' positions "
                         "(%s): the plan is kept", why, error)
            self._grew = view.sample  # tried again after another patience, not every sample
            return execution, plan
        self.plan = plan
        self._start(plan)
        return self.execution or execution, plan

    def shape_references(self, view: SampleView) -> Contribution | None:
        execution, plan = self.execution, self.plan
        if execution is None or plan is None:
            return None
        if self._joined or view.sample == 0:
            progress = execution.advance(view.positions)
        else:  # a controller started (or restarted) mid-run: no history of the positions
            progress = execution.resume(view.positions)
        self._joined = True
        if self.context.departed != self._departed:
            self.counts["coordination_departures"] += 1
            execution, plan = self._replan_from(plan, execution, view,
                                                "the robots taking part changed")
            progress = execution.advance(view.positions)
            self._total, self._grew = int(progress.sum()), view.sample
        elif self._stalled(execution, progress, view.sample):
            self.counts["coordination_stalls"] += 1
            execution, plan = self._replan_from(plan, execution, view, "progress stopped")
            progress = execution.advance(view.positions)
        permitted = execution.clear(view.positions, self._scheduled)
        out = np.array(view.references)
        self._tracked[:] = False
        reach = plan.roadmap.reach
        c = self.context
        for m, row in enumerate(self.rows):
            if row < 0:
                continue
            p = int(progress[row])
            last = int(plan.schedule.lengths[row]) - 1
            k = min(int(permitted[self._slot[m]]), last)
            if k <= p and p < last:
                self.counts["coordination_holds"] += 1
            here = view.own_states[m]
            reverse = False
            if k <= p:  # at the end of its open path: its progress vertex, or its goal
                end = plan.goals[row] if p >= last else execution.path_points(row, p, p)[0]
                gap = math.hypot(end[0] - here[0], end[1] - here[1])
                # at a vertex it waits within the reach; its goal it closes to half the
                # reach or half the arrival tolerance, the nearer, where the NMPC's own
                # final approach takes over (from farther, a goal beside the robot left
                # it standing: a point reference at v = 0 asks for no turn; warehouse
                # family, 4 robots, seed 22: 0.054 m from its goal from 20 s to the end)
                if gap <= (self._arrive if p >= last else reach):
                    out[m] = end
                    if p >= last:
                        continue
                    # waiting at a vertex: it faces the edge it will leave by, so that it
                    # starts along it once free instead of turning in place then
                    ahead = execution.path_points(row, p, p + 1)
                    way = ahead[1] - ahead[0]
                    facing = math.atan2(way[1], way[0])
                    if abs(math.remainder(facing - float(here[2]), 2.0 * math.pi)) <= 1e-3:
                        continue
                    points = np.stack((here[:2], here[:2] + 1e-6 * way))
                    halt, within = True, 1
                else:
                    # straight at it, facing it first (a unicycle does not close a sideways
                    # gap by itself), backwards when it is behind and the bounds allow
                    points, halt, within = np.stack((here[:2], end)), True, 1
                    bearing = math.atan2(end[1] - here[1], end[0] - here[0])
                    reverse = self._reverse and math.cos(bearing - here[2]) < 0.0  # behind it
            else:
                back = max(p - 1, 0)  # from the segment into the progress vertex
                stop = min(k, back + self._window + 1)  # beyond the horizon's reach: open
                points = execution.path_points(row, back, stop)
                if stop == last:
                    points = np.concatenate((points, plan.goals[row][None]))
                halt, within = stop == k, p + 1 - back  # projected up to the next vertex
            # the robot's velocities (the command it was last sent, as the model takes them
            # when none are measured); a model without velocity states starts its motion
            # at the motion's own rate (its inputs are the sample's velocities)
            speed, rate = (here[3], here[4]) if here.size >= 5 else view.applied[m]
            if self._accel is None:
                rate = None
            motion = path_motion(points, here, float(speed), reach,
                                 c.sample_time, c.horizon, self._back if reverse else self._speed,
                                 self._turn, self._accel,
                                 stop=halt, within=within, reverse=reverse,
                                 turn_rate=None if rate is None else float(rate),
                                 out=(self._poses[m], self._velocities[m]))
            out[m] = motion.poses[1:, :2]
            self._tracked[m] = True
        if not self._tracked.any():
            return Contribution(references=out)
        rows = np.flatnonzero(self._tracked)
        self.counts["coordination_tracked"] += rows.size
        return Contribution(references=out,
                            motions=(rows, self._poses[rows], self._velocities[rows]))

@dataclass(frozen=True)
class Coordination(Rule):
    """Robots with goals at rest follow the fleet's roadmap plan in its vertex order.

    No parameters: the roadmap's spacing and reach follow from the robots' kept
    distance (:mod:`sqpmpc.coordination.roadmap`), the reference speed is the bound
    on :math:`|v|`.
    """

    name = "coordination"
    summary = ("robots with goals at rest follow a conflict-free roadmap plan, entering "
               "each vertex in the plan's order, along a motion a unicycle can make")
    instance = _Instance

r"""The fleet's plan: the roadmap, the conflict-free plan and its schedule, for a scenario.

:func:`fleet_plan` is what every controller of a run calls with the same
scenario and margins, and gets the same plan (a function of its inputs: the
planner's tie-breaking is seeded); in one process the plan is computed once and
shared. The robots planned are those with a goal at rest (``point``
references); robots that follow a trajectory in time are left to their
references and to the collision rows.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from sqpmpc.coordination.mapf import PlanningError, plan_paths
from sqpmpc.coordination.roadmap import Roadmap, build_roadmap, drawn_grid
from sqpmpc.coordination.schedule import Schedule
from sqpmpc.problem.references import PointReference
from sqpmpc.problem.routes import scenario_box
from sqpmpc.problem.scenario import Scenario

__all__ = ["FleetPlan", "clear_cache", "fleet_plan", "replan", "replan_from_positions",
           "turn_per_step"]


@dataclass(frozen=True, eq=False)
class FleetPlan:
    """A scenario's roadmap, plan and schedule.

    Attributes
    ----------
    roadmap
        The graph.
    robots
        ``(n,)`` scenario indices of the planned robots (schedule order).
    goals
        ``(n, 2)`` their goal points.
    configs
        ``(T + 1, n)`` the plan.
    schedule
        The plan's schedule.
    seconds
        CPU time spent planning (roadmap, plan and schedule), s.
    base
        The roadmap before the vertices of departed robots were cut off
        (:func:`replan_from_positions`; ``None``: :attr:`roadmap` itself), where later
        plans start from.
    """

    roadmap: Roadmap
    robots: np.ndarray
    goals: np.ndarray
    configs: np.ndarray
    schedule: Schedule
    seconds: float
    base: Roadmap | None = None

    @property
    def makespan_steps(self) -> int:
        """``T``: steps of the plan."""
        return int(self.configs.shape[0] - 1)

    def path_length(self, robot: int) -> float:
        """Length of robot ``robot``'s (schedule order) path on the roadmap, m."""
        s = self.schedule
        pts = self.roadmap.positions[s.paths[robot, :s.lengths[robot]]]
        return float(np.hypot(*np.diff(pts, axis=0).T).sum()) if pts.shape[0] > 1 else 0.0


def turn_per_step(scenario: Scenario, spacing: float) -> float:
    r"""The largest turn in place of the scenario's robots in one step of a plan on a
    roadmap of ``spacing`` :math:`h`: :math:`\omega_{\max} h / v_{\max}` rad (a step is
    an edge at :math:`v_{\max}`), so a plan gives every turn the steps it takes
    (:func:`sqpmpc.coordination.mapf.plan_paths`)."""
    speed, rate = _speeds(scenario)
    return rate * float(spacing) / speed


def planned_robots(scenario: Scenario) -> np.ndarray:
    """Scenario indices of the robots with a goal at rest."""
    return np.array([i for i, r in enumerate(scenario.robots)
                     if isinstance(r.reference, PointReference)], dtype=np.int64)


def fleet_plan(scenario: Scenario, clearance: float, separation: float) -> FleetPlan | None:
    """The plan of ``scenario``'s robots with goals at rest (cached per process), or
    ``None`` when no robot has one.

    Parameters
    ----------
    scenario
        The problem (its static map, ``[bounds]``, ``[roadmap]``, robots).
    clearance
        Distance the robots' centres keep from the static map, m (largest radius plus
        the obstacle rows' margin).
    separation
        Largest distance the collision rows keep between two robots, m.

    Raises
    ------
    sqpmpc.coordination.mapf.PlanningError
        No plan (a goal cut off, two goals on one vertex, the search's budget).
    sqpmpc.errors.ProblemError
        A declared grid too fine for the robots.
    """
    return _cached(scenario, round(float(clearance), 12), round(float(separation), 12))


def clear_cache() -> None:
    """Forget the plans this process has cached (:func:`fleet_plan`,
    :func:`replan_from_positions`): the next call plans afresh (benchmarks time it)."""
    _cached.cache_clear()
    _replanned.cache_clear()


@functools.lru_cache(maxsize=8)
def _cached(scenario: Scenario, clearance: float, separation: float) -> FleetPlan | None:
    robots = planned_robots(scenario)
    if robots.size == 0:
        return None
    n = scenario.n_robots
    starts = scenario.initial_states()[:, :2]
    goals = scenario.reference_positions(0.0)
    has_goal = np.zeros(n, dtype=bool)
    has_goal[robots] = True
    return _plan(scenario, robots, starts, goals, has_goal, clearance, separation, None)


def _plan(scenario: Scenario, robots: np.ndarray, starts: np.ndarray, goals: np.ndarray,
          has_goal: np.ndarray, clearance: float, separation: float,
          start_vertices: np.ndarray | None, roadmap: Roadmap | None = None,
          headings: np.ndarray | None = None, method: str = "auto") -> FleetPlan:
    t0 = time.process_time()
    if roadmap is None:
        diameter = float(scenario.diameters().max())
        # the declared grid, else the one the walls were drawn on (roadmap.drawn_grid)
        grid = scenario.roadmap or drawn_grid(scenario.polygons, separation, diameter)
        arguments = (scenario.polygons, scenario.obstacles, scenario_box(scenario), starts,
                     goals, has_goal, clearance, separation, diameter, grid)
        roadmap = build_roadmap(*arguments, diagonal=grid is None)
        if grid is None:  # the tube's roadmap where prioritized planning solves it
            try:
                plan = _plan(scenario, robots, starts, goals, has_goal, clearance, separation,
                             start_vertices, roadmap, headings, method="prioritized")
                return replace(plan, seconds=time.process_time() - t0)
            except PlanningError:
                roadmap = build_roadmap(*arguments, diagonal=True, tube=False)
    s = roadmap.starts[robots] if start_vertices is None else start_vertices
    g = roadmap.goals[robots]
    names = [f"robot {scenario.robots[i].id}" for i in robots]
    turn_step = turn_per_step(scenario, roadmap.spacing)
    if headings is None and start_vertices is None:
        headings = scenario.initial_states()[robots, 2]
    # two plans, with the turns' steps and without them; of the two, the one whose
    # execution by unicycles at their bounds ends first (Schedule.predicted_arrivals)
    speed, rate = _speeds(scenario)
    facing = np.full(robots.size, np.nan) if headings is None else np.asarray(headings)
    candidates = []
    # the plan without the turns' steps on the 4-connected grid only: its pass over the
    # diagonals doubled the planning of a 256-robot swap (12.8 s against 6.5 s), and
    # where it is kept (dense formations) its diagonals did not shorten it
    for step in ((turn_step, 0.0) if turn_step > 0.0 else (0.0,)):
        used, configs = _plan_on(roadmap if step == turn_step else replace(
            roadmap, diagonals=np.zeros((0, 4), dtype=np.int64)), s, g, names, step, headings,
            method)
        schedule = Schedule.from_plan(configs, used.corners())
        end = float(schedule.predicted_arrivals(used.positions, facing, speed, rate).max())
        candidates.append((end, len(candidates), used, configs, schedule))
    _, _, roadmap, configs, schedule = min(candidates, key=lambda c: c[:2])
    return FleetPlan(roadmap, robots, goals[robots], configs, schedule,
                     time.process_time() - t0)


def _speeds(scenario: Scenario) -> tuple[float, float]:
    """``v_max`` (m/s) and ``omega_max`` (rad/s) as :func:`turn_per_step` takes them."""
    bounds = scenario.bounds
    return (float(max(bounds.v[1], -bounds.v[0])),
            float(min(-bounds.omega[0], bounds.omega[1])))


def _plan_on(roadmap: Roadmap, starts: np.ndarray, goals: np.ndarray, names: list[str],
             turn_step: float, headings: np.ndarray | None, method: str = "auto"
             ) -> tuple[Roadmap, np.ndarray]:
    """The plan on ``roadmap`` and the roadmap it uses: with and without the diagonals, the
    plan of fewer steps (its dependency chains are shorter; diagonals shorten crossings
    and lengthen dense formations). The 4-connected plan first (prioritized, else
    LaCAM's; ``method`` as :func:`~sqpmpc.coordination.mapf.plan_paths` takes it); over the
    diagonals prioritized planning then seeks only a plan of fewer steps."""
    square = replace(roadmap, diagonals=np.zeros((0, 4), dtype=np.int64))
    configs = plan_paths(square, starts, goals, seed=0, names=names, turn_step=turn_step,
                         headings=headings, method=method)
    if roadmap.diagonals.size:
        try:
            return roadmap, plan_paths(
                roadmap, starts, goals, seed=0, names=names, method="prioritized",
                shorter_than=configs.shape[0] - 1, turn_step=turn_step, headings=headings)
        except PlanningError:
            pass
    return square, configs


def replan(previous: FleetPlan, scenario: Scenario, configuration: np.ndarray,
           goals: Sequence[np.ndarray]) -> FleetPlan:
    """A new plan on ``previous``'s roadmap from the robots' progress vertices
    ``configuration (n,)`` to ``goals`` (``(2,)`` each, schedule order): each goal's
    vertex is the free vertex nearest to it (the robot ends on its own point)."""
    roadmap = previous.roadmap
    points = np.asarray(goals, dtype=float).reshape(-1, 2)
    goal_v = roadmap.goals.copy()
    goal_v[previous.robots] = _nearest_vertices(roadmap, points)
    moved = replace(roadmap, goals=goal_v)
    n = scenario.n_robots
    has_goal = np.zeros(n, dtype=bool)
    has_goal[previous.robots] = True
    all_goals = scenario.reference_positions(0.0)
    all_goals[previous.robots] = points
    return _plan(scenario, previous.robots, scenario.initial_states()[:, :2], all_goals,
                 has_goal, 0.0, 0.0, np.asarray(configuration), roadmap=moved)


def replan_from_positions(previous: FleetPlan, scenario: Scenario, positions: np.ndarray,
                          standing: frozenset[int] = frozenset()) -> FleetPlan:
    r"""A new plan on ``previous``'s roadmap to its goals from where the robots *are*:
    the measured ``positions (N, 2)`` of all robots (scenario order).

    Each planned robot starts at a distinct vertex: the assignment of least total
    distance between the robots and their nearest vertices (each robot's
    :math:`k` nearest, :math:`k` grown until an assignment exists), so a robot pushed
    off its path starts from the vertex it stands nearest to, not from the one its
    progress counted. The robots' first turns take no steps in the plan (every
    controller measures every robot's position, its own robots' headings only).
    Cached per process: every controller of a run that re-plans at the same sample
    from the same measurements gets the same plan, computed once.

    The robots ``standing`` (scenario indices: robots whose controllers left the run,
    :attr:`sqpmpc.rules.base.RuleContext.departed`) stand on their start vertices, which
    are cut off the roadmap (:meth:`~sqpmpc.coordination.roadmap.Roadmap.isolated`): the
    others are planned around them. The other robots' goals are their scenario
    references' (a point at rest), else ``previous``'s; a goal a departed robot stands on
    is moved to the nearest vertex that is no other robot's (the robot comes as near as
    it can, and is planned to its own goal again once that robot takes part again).

    Raises
    ------
    sqpmpc.coordination.mapf.PlanningError
        No plan from there.
    """
    positions = np.asarray(positions, dtype=float)
    key = np.ascontiguousarray(positions[previous.robots, :2]).tobytes()
    return _replanned(previous, scenario, key, frozenset(int(i) for i in standing))


@functools.lru_cache(maxsize=4)
def _replanned(previous: FleetPlan, scenario: Scenario, key: bytes,
               standing: frozenset[int]) -> FleetPlan:
    # imported here: scipy.optimize is ~0.2 s of every process's start (each service
    # imports this module through the rules' registry) and only a re-plan needs it
    from scipy.optimize import linear_sum_assignment

    poses = np.frombuffer(key, dtype=float).reshape(-1, 2)
    roadmap = previous.base or previous.roadmap
    n, size = poses.shape[0], roadmap.size
    tree = cKDTree(roadmap.positions)
    k = min(9, size)
    while True:
        _, near = tree.query(poses[:, :2], k=k)
        near = np.asarray(near).reshape(n, -1)
        columns = np.unique(near)
        if columns.size >= n:
            cost = np.hypot(poses[:, None, 0] - roadmap.positions[columns][None, :, 0],
                            poses[:, None, 1] - roadmap.positions[columns][None, :, 1])
            # only each robot's own nearest vertices: the others priced out
            allowed = np.zeros_like(cost, dtype=bool)
            allowed[np.repeat(np.arange(n), near.shape[1]),
                    np.searchsorted(columns, near.ravel())] = True
            cost = np.where(allowed, cost, cost.max(initial=0.0) * n + 1.0)
            rows, cols = linear_sum_assignment(cost)
            if allowed[rows, cols].all() or k >= size:
                break
        k = min(2 * k, size)
    starts = np.empty(n, dtype=np.int64)
    starts[rows] = columns[cols]
    has_goal = np.zeros(scenario.n_robots, dtype=bool)
    has_goal[previous.robots] = True
    goals = previous.goals.copy()
    goal_v = roadmap.goals.copy()
    cut = []  # the vertices the departed robots stand on
    for r, i in enumerate(previous.robots.tolist()):
        reference = scenario.robots[i].reference
        if i in standing:
            goals[r] = roadmap.positions[starts[r]]
            goal_v[i] = starts[r]
            cut.append(starts[r])
        elif isinstance(reference, PointReference):
            goals[r] = np.asarray(reference.goal, dtype=float)
            goal_v[i] = _nearest_vertices(roadmap, goals[r][None])[0]
    if cut:  # a goal a departed robot stands on: the nearest vertex no one else has
        taken = set(cut) | {int(goal_v[i]) for i in previous.robots.tolist() if i not in standing}
        for r, i in enumerate(previous.robots.tolist()):
            if i not in standing and int(goal_v[i]) in cut:
                gap = np.hypot(*(roadmap.positions - roadmap.positions[goal_v[i]]).T)
                gap[list(taken)] = np.inf
                goal_v[i] = int(np.argmin(gap))
                taken.add(int(goal_v[i]))
                goals[r] = roadmap.positions[goal_v[i]]
    all_goals = scenario.reference_positions(0.0)
    all_goals[previous.robots] = goals
    planned = replace(roadmap, goals=goal_v)
    plan = _plan(scenario, previous.robots, scenario.initial_states()[:, :2], all_goals,
                 has_goal, 0.0, 0.0, starts,
                 roadmap=planned.isolated(np.asarray(cut, dtype=np.int64)) if cut else planned)
    return replace(plan, base=planned) if cut else plan


def _nearest_vertices(roadmap: Roadmap, points: np.ndarray) -> np.ndarray:
    """``(k,)`` the roadmap vertex nearest to each of ``points (k, 2)``."""
    return np.argmin(np.hypot(roadmap.positions[None, :, 0] - points[:, None, 0],
                              roadmap.positions[None, :, 1] - points[:, None, 1]), axis=1)

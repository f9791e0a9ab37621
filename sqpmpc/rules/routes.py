r"""The ``route`` rule: a robot whose goal lies behind static obstacles tracks a route.

A robot with a goal at rest (a ``point`` reference) whose straight way to it
crosses the static map inflated by its radius plus ``margin`` gets the
shortest route around it (:class:`sqpmpc.problem.routes.RoadMap`: a visibility
graph of the inflated walls, shelves and resting circles, inside the scenario's
``[bounds]`` box). The route is
time-parametrized at ``speed`` times the robot's top speed from the moment it
is planned, but never runs more than ``lead`` metres of arc ahead of the
robot's progress (its projection on the route), so a robot held up by others
is not pulled across a corner; stages 1..N of the reference are the route's
points at that arc length plus ``speed`` times the stage's time, each held at
the last one the robot can reach in a straight line keeping what the rows
against the static map keep for the plant: its radius plus
:attr:`~sqpmpc.rules.base.RuleContext.obstacle_margin`, or its clearance now if
it stands nearer (when stage 1 is out of reach already: the route's next vertex).
A unicycle tracking a point beyond a corner cuts it and can end up pinned
against it: the rows hold it off the corner while the cost pulls it on (with
acceleration limits the rows keep 0.125 m more than the radius; room-door
decentralized on the exact plant left robot 5 4.70 m from its goal against the
door jamb when reach was judged by the radius alone). The routes keep
``margin`` beyond the radius whatever the rows keep: widening them to 5 cm beyond
what the rows keep (0.30 m with acceleration bounds [-2, 2] m/s^2) had routes
planned where the straight way is free, and a robot of corridor centralized
(``benchmarks.physical``'s bounds, exact plant) ended 3.34 m short. The route is
re-planned from the robot's position when the robot has not progressed by
``progress`` metres for ``patience`` seconds or has been pushed more than
``deviation`` metres off it, and dropped once the straight way to the goal
is free. A robot pressed against a wall (within ``pressed`` of what the rows
keep), facing it, stopped with no neighbour
near and far from its goal for a few samples backs away from it first (facing a wall, a unicycle's
linearization has no way out). Safety is the collision rows' business, as for every rule: the
route only chooses where the robot heads.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass

import numpy as np

from sqpmpc.problem.references import PointReference
from sqpmpc.problem.routes import RoadMap, Route, scenario_box
from sqpmpc.rules.base import (
    Contribution,
    Rule,
    RuleContext,
    RuleInstance,
    SampleView,
    check_positive,
)

__all__ = ["RouteFollowing", "road_map"]

_LOG = logging.getLogger(__name__)


@functools.lru_cache(maxsize=16)
def _road_map(polygons: tuple, circles: tuple, radius: float, margin: float,
              bounds: tuple | None) -> RoadMap:
    """One road map per map, box and clearance, shared by the controllers of a run."""
    return RoadMap(polygons, circles, radius, margin, bounds)


def road_map(scenario: object, radius: float, margin: float) -> RoadMap:
    """The (cached) road map of a scenario's static map and ``[bounds]`` box for a robot
    of ``radius`` keeping ``margin``."""
    frame = scenario_box(scenario)
    key = None if frame is None else (tuple(map(float, frame[0])), tuple(map(float, frame[1])))
    return _road_map(tuple(scenario.polygons), tuple(scenario.obstacles),  # type: ignore
                     float(radius), float(margin), key)


@dataclass
class _Tracking:
    route: Route
    t0: float
    progress: float = 0.0
    best: float = 0.0
    t_best: float = 0.0


class _RouteInstance(RuleInstance):
    hooks = ("references",)
    rule: RouteFollowing
    counter_names = ("route_plans", "route_replans", "route_samples", "routes_missing",
                     "wall_escapes")

    def __init__(self, rule: RouteFollowing, context: RuleContext) -> None:
        super().__init__(rule, context)
        self.maps: list[RoadMap | None] = []
        self.goals: list[np.ndarray | None] = []
        self.tracking: list[_Tracking | None] = []
        self.speed = rule.speed * context.max_speed
        #: what the rows against the static map keep beyond the radius, m
        self.keep = float(context.obstacle_margin)
        m = context.own.size
        self.pinned = np.zeros(m, dtype=np.int64)  # samples pressed against a wall
        self.escape = np.zeros(m, dtype=np.int64)  # samples of escape left
        self.escape_to = np.zeros((m, 2))
        self.references_changed()

    def references_changed(self) -> None:
        sc = self.context.scenario
        static = bool(sc.polygons) or any(not o.moving for o in sc.obstacles)
        self.maps, self.goals, self.tracking = [], [], []
        for i in self.context.own:
            robot = sc.robots[int(i)]
            ref = robot.reference
            if not static or not isinstance(ref, PointReference):
                self.maps.append(None)
                self.goals.append(None)
            else:
                self.maps.append(road_map(sc, 0.5 * robot.diameter, self.rule.margin))
                self.goals.append(np.asarray(ref.goal, dtype=float))
            self.tracking.append(None)
        self._told: set[int] = set()  # robots whose missing route was logged
        #: whether some own robot has a map and a goal (else the hook has nothing to do)
        self.routed = any(road is not None for road in self.maps)
        self.idle = not self.routed

    def _plan(self, k: int, p: np.ndarray, t: float) -> None:
        road, goal = self.maps[k], self.goals[k]
        route = None if road is None or goal is None else road.route(p, goal)
        if route is None:
            self.counts["routes_missing"] += 1
            self.tracking[k] = None
            robot = int(self.context.own[k])
            if robot not in self._told:  # once per robot: what would plan its way
                self._told.add(robot)
                _LOG.warning(
                    "route: robot id %s has no route to its goal keeping %.3g m beyond its "
                    "radius from the static map (a corridor narrower than %.3g m is closed "
                    "to it); the roadmap coordination (--rules coordination) plans through "
                    "corridors down to the diameter plus the rows' margins",
                    self.context.scenario.robots[robot].id, self.rule.margin,
                    float(self.context.scenario.robots[robot].diameter) + 2 * self.rule.margin)
            return
        self.tracking[k] = _Tracking(route, t, 0.0, 0.0, t)

    def _escaping(self, k: int, p: np.ndarray, goal: np.ndarray, view: SampleView) -> bool:
        """Whether robot ``k`` backs away from a wall it is pressed against, stopped, far
        from its goal (a unicycle facing a wall has no linearized way out)."""
        rule = self.rule
        if self.escape[k] > 0:
            self.escape[k] -= 1
            return True
        road = self.maps[k]
        if road is None or np.hypot(*(goal - p)) < rule.escape_distance:
            self.pinned[k] = 0
            return False
        gap, away = road.away_from_walls(p)
        stopped = abs(float(view.applied[k, 0])) < rule.stopped_speed
        psi = float(view.own_states[k, 2])
        facing = -(np.cos(psi) * away[0] + np.sin(psi) * away[1]) > rule.facing
        # a robot held up by a neighbour waits for it, it is not trapped by the wall
        others = np.delete(view.positions, self.context.own[k], axis=0)
        crowded = others.size and float(np.hypot(*(others - p).T).min()) < rule.neighbour
        self.pinned[k] = (self.pinned[k] + 1 if stopped and facing and not crowded
                          and gap < self.keep + rule.pressed else 0)
        if self.pinned[k] < rule.pinned_samples:
            return False
        self.pinned[k] = 0
        self.escape[k] = rule.escape_samples - 1
        self.escape_to[k] = p + rule.escape_distance * away
        self.tracking[k] = None  # re-planned from where the escape ends
        self.counts["wall_escapes"] += 1
        return True

    def shape_references(self, view: SampleView) -> Contribution | None:
        if not self.routed:  # no map or no goal: nothing to route
            return None
        rule = self.rule
        out: np.ndarray | None = None
        N = view.references.shape[1]
        stage_s = self.speed * self.context.sample_time * np.arange(1, N + 1)
        for k, road in enumerate(self.maps):
            goal = self.goals[k]
            if road is None or goal is None:
                continue
            p = view.own_states[k, :2]
            if self._escaping(k, p, goal, view):
                if out is None:
                    out = view.references.copy()
                out[k] = self.escape_to[k]
                continue
            track = self.tracking[k]
            if track is None:
                if view.sample % rule.check_every or road.free(p, goal):
                    continue
                self.counts["route_plans"] += 1
                self._plan(k, p, view.t)
                track = self.tracking[k]
                if track is None:
                    continue
            elif road.free(p, goal):
                self.tracking[k] = None  # the way is clear: the goal itself
                continue
            s, off = track.route.project(p, lower=track.progress - rule.lead)
            track.progress = max(track.progress, s)
            if track.progress > track.best + rule.progress:
                track.best, track.t_best = track.progress, view.t
            stalled = view.t - track.t_best > rule.patience
            if stalled or off > rule.deviation:
                self.counts["route_replans"] += 1
                self._plan(k, p, view.t)
                track = self.tracking[k]
                if track is None:
                    continue
            base = min(self.speed * (view.t - track.t0), track.progress + rule.lead)
            if out is None:
                out = view.references.copy()
            pts = track.route.position_at(base + stage_s)
            seen = road.sees(p, pts, self.keep)
            if not seen.all():  # never past a corner not yet in sight: the next vertex
                first = int(np.argmin(seen))
                if first == 0:
                    cum = track.route.cumulative
                    ahead = cum[cum > track.progress + 1e-6]
                    pts[:] = track.route.position_at(ahead[0] if ahead.size else cum[-1])
                else:
                    pts[first:] = pts[first - 1]
            out[k] = pts
            self.counts["route_samples"] += 1
        return None if out is None else Contribution(references=out)


@dataclass(frozen=True)
class RouteFollowing(Rule):
    r"""Track the shortest route around the static map when the goal is behind it.

    Parameters
    ----------
    margin
        Clearance kept beyond the robot's radius by the route, m.
    speed
        The route's speed as a fraction of the robot's top speed.
    lead
        Largest arc length the route's reference runs ahead of the robot's
        progress, m.
    progress, patience
        Re-plan when the progress grew by less than ``progress`` m in
        ``patience`` s.
    deviation
        Re-plan when the robot is farther than this from its route, m.
    check_every
        Samples between the checks of a robot without a route (is its way blocked?).
    pressed, stopped_speed, pinned_samples, facing, neighbour
        A robot nearer than ``pressed`` m beyond what the rows keep (its radius plus
        :attr:`~sqpmpc.rules.base.RuleContext.obstacle_margin`) to a wall, heading into it
        (the cosine between its heading and the wall's direction above ``facing``),
        no other robot within ``neighbour`` m, whose applied speed stayed below
        ``stopped_speed`` m/s for ``pinned_samples`` samples, is pinned (facing the
        wall, a unicycle's linearization has no way out) ...
    escape_distance, escape_samples
        ... and heads for the point ``escape_distance`` m straight away from the wall
        for ``escape_samples`` samples, then goes on (its goal, or a new route).
    """

    name = "route"
    summary = "a goal behind walls or pillars: follow the shortest route around the static map"
    instance = _RouteInstance
    margin: float = 0.2
    speed: float = 0.9
    lead: float = 0.6
    progress: float = 0.25
    patience: float = 8.0
    deviation: float = 1.0
    check_every: int = 1
    pressed: float = 0.03
    stopped_speed: float = 0.05
    pinned_samples: int = 4
    facing: float = 0.5
    neighbour: float = 0.8
    escape_distance: float = 0.4
    escape_samples: int = 4

    def __post_init__(self) -> None:
        check_positive(self, "margin", "speed", "lead", "progress", "patience", "deviation",
                       "check_every", "pressed", "stopped_speed", "pinned_samples", "facing",
                       "neighbour",
                       "escape_distance", "escape_samples")

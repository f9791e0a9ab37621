"""Prioritized planning's per-robot search (sqpmpc.kernels.mapf.safe_interval_search):
exact in arrival time against a brute-force search over (vertex, step, heading, steps
standing) on small roadmaps, with and without the turns' steps and the diagonals, and
the plans it makes conflict-free (tests/test_coordination.py's checker)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sqpmpc.coordination import mapf
from sqpmpc.coordination.mapf import distance_tables, plan_paths
from sqpmpc.coordination.roadmap import Roadmap, build_roadmap
from sqpmpc.kernels.mapf import (
    FIELDS,
    FOUND,
    SCRATCH,
    UNBOUNDED,
    reserve_path,
    safe_interval_search,
)
from sqpmpc.problem.fleets import antipodal_swap
from sqpmpc.problem.grid import GridSpec
from sqpmpc.problem.polygons import PolygonObstacle
from tests.test_coordination import _edges, check_plan

OCC, ENTER = 1, 2
ROWS = 40


def _holed_grid(diagonal: bool) -> Roadmap:
    """A 5 x 4 grid of 1 m with a wall over two cells of its middle column: 18 vertices,
    with the diagonals of the squares whose corners are all vertices."""
    ends = np.array([[0.0, 0.0], [4.0, 3.0]])
    wall = PolygonObstacle(((1.6, 0.6), (2.4, 0.6), (2.4, 2.4), (1.6, 2.4)))
    roadmap = build_roadmap((wall,), (), (np.array([-0.4, -0.4]), np.array([4.4, 3.4])), ends,
                            ends[::-1], np.array([True, True]), 0.1, 0.5, 0.3,
                            GridSpec(1.0, (0.0, 0.0)), diagonal=True)
    assert roadmap.size == 18 and roadmap.diagonals.shape[0] > 0
    return roadmap if diagonal else replace(roadmap, diagonals=np.zeros((0, 4), dtype=np.int64))


def _waits(bend: float, turn_step: float) -> int:
    return int(np.ceil(bend / turn_step - 1e-9)) if turn_step > 0.0 else 0


def _bend(a: float, b: float) -> float:
    return abs((a - b + np.pi) % (2.0 * np.pi) - np.pi)


class _Rules:
    """The rules of a robot's moves around the reservations (the kernels' module
    docstring), written out step by step."""

    def __init__(self, moves, res: np.ndarray, parked: np.ndarray, others: np.ndarray,
                 hold: int) -> None:
        self.moves, self.res, self.parked, self.others, self.hold = (moves, res, parked,
                                                                   others, hold)

    def _row(self, s: int) -> np.ndarray:
        return self.res[min(s, self.res.shape[0] - 1)]

    def free(self, x: int, s: int) -> bool:
        """Whether the robot may stand on ``x`` at step ``s >= 1``."""
        return (not self._row(s)[x] & OCC and self.parked[x] > s
                and not self._row(s + 1)[x] & ENTER and not (self.others[x] and s <= self.hold))

    def corner(self, x: int, t: int) -> bool:
        """Whether corner ``x`` of a diagonal move from ``t`` to ``t + 1`` is free."""
        if any(self._row(s)[x] & OCC for s in range(max(t - 1, 0), t + 2)):
            return False
        if self._row(t + 2)[x] & ENTER or self.parked[x] <= t + 1:
            return False
        return not (t < self.hold and self.others[x])

    def move(self, e: int, v: int, t: int) -> bool:
        """Whether move ``e`` out of ``v`` from ``t`` to ``t + 1`` is allowed (its end
        free, no robot coming the other way, a diagonal's corners free)."""
        mv = self.moves
        u = int(mv.targets[e])
        if not self.free(u, t + 1) or (self._row(t + 1)[v] >> 2) == u + 1:
            return False
        return mv.b[e] < 0 or (self.corner(int(mv.b[e]), t) and self.corner(int(mv.c[e]), t))


def _brute_force(rules: _Rules, turn_step: float, heading: float, start: int, goal: int
                 ) -> int | None:
    """The earliest step the robot reaches ``goal`` to stay there for good: a breadth-first
    search over (vertex, last move, steps standing) at every step, until the layers repeat
    past the reservations (then no step ever reaches it)."""
    mv = rules.moves
    blocked = [s for s in range(ROWS + 3) if not rules.free(goal, s)]
    after = blocked[-1] if blocked else -1
    layer = {(start, -1, 0)}
    seen_after: set[frozenset] = set()
    for t in range(100_000):
        if any(v == goal and t > after for v, _, _ in layer):
            return t
        if t > ROWS + 3:
            key = frozenset(layer)
            if key in seen_after or not layer:
                return None
            seen_after.add(key)
        nxt = set()
        for v, came, standing in layer:
            if rules.free(v, t + 1):
                nxt.add((v, came, min(standing + 1, rules.hold)))
            facing = heading if came < 0 else mv.angle[came]
            for e in range(mv.ptr[v], mv.ptr[v + 1]):
                if mv.targets[e] == v:
                    continue
                need = 0 if np.isnan(facing) else _waits(_bend(mv.angle[e], facing), turn_step)
                if standing >= need and rules.move(e, v, t):
                    nxt.add((int(mv.targets[e]), e, 0))
        layer = nxt
    return None


def _check_path(path: np.ndarray, rules: _Rules, turn_step: float, heading: float) -> None:
    """Every step of ``path`` obeys the rules, a turn after its steps standing."""
    mv = rules.moves
    facing, since = heading, 0
    for t in range(1, path.size):
        v, u = int(path[t - 1]), int(path[t])
        assert rules.free(u, t), f"step {t} on vertex {u}"
        if u == v:
            continue
        e = next(e for e in range(mv.ptr[v], mv.ptr[v + 1]) if mv.targets[e] == u)
        assert rules.move(e, v, t - 1), f"move at step {t}"
        if not np.isnan(facing):
            assert t - 1 - since >= _waits(_bend(mv.angle[e], facing), turn_step), "turn"
        facing, since = mv.angle[e], t


class _Planner:
    """One robot's search after another on the same reservations."""

    def __init__(self, roadmap: Roadmap, turn_step: float) -> None:
        self.roadmap = roadmap
        self.moves = mapf.plan_moves(roadmap)
        self.moves.turning(turn_step)
        self.turn_step = turn_step
        self.hold = 1 + (int(np.ceil(np.pi / turn_step)) if turn_step > 0.0 else 0)
        size = roadmap.size
        self.res = np.zeros((ROWS, size), dtype=np.int64)
        self.runs = np.zeros((size, ROWS // 2 + 1, 2), dtype=np.int64)
        self.count = np.zeros(size, dtype=np.int64)
        self.parked = np.full(size, UNBOUNDED, dtype=np.int64)
        self.last_use = np.full(size, -1, dtype=np.int64)
        self.others = np.zeros(size, dtype=np.uint8)
        self.states = np.zeros((8, FIELDS), dtype=np.int32)
        self.heap = np.zeros((2, 3), dtype=np.int64)
        self.search = 0

    def rules(self) -> _Rules:
        return _Rules(self.moves, self.res, self.parked, self.others, self.hold)

    def reserve(self, path: np.ndarray) -> None:
        mv = self.moves
        reserve_path(path, path.size, mv.ptr, mv.targets, mv.b, mv.c, self.res, self.parked,
                     self.last_use, self.runs, self.count, ROWS - 1)

    def plan(self, start: int, goal: int, heading: float) -> np.ndarray | None:
        mv = self.moves
        dist = distance_tables(self.roadmap, np.array([goal]),
                               diagonal=self.roadmap.diagonals.size > 0)[0]
        while True:
            self.search += 1
            status, length, _, path = safe_interval_search(
                mv.ptr, mv.targets, mv.b, mv.c, mv.straight, mv.angle, mv.back, mv.offsets,
                mv.depart, mv.turn, self.turn_step, heading, self.hold, dist, mv.x, mv.y,
                start, goal, int(self.last_use[goal]) + 1, -1, 10**9, self.runs, self.count,
                self.parked, self.others, self.search, self.states, self.heap)
            if status != SCRATCH:
                break
            if length < 0:  # the scratch arrays start small: grown as the kernel asks
                self.heap = np.zeros((-length, 3), dtype=np.int64)
            else:
                self.states = np.zeros((length, FIELDS), dtype=np.int32)
        if status != FOUND:
            return None
        assert path.size == length and path[0] == start and path[-1] == goal
        return path


CASES = [(False, 0.0), (False, np.pi / 4), (True, 0.0), (True, np.pi / 4), (True, 1.0),
         (False, np.pi / 2)]


@pytest.mark.parametrize(("diagonal", "turn_step"), CASES)
def test_each_search_arrives_as_early_as_a_brute_force_on_random_reservations(
        diagonal: bool, turn_step: float) -> None:
    """Reservations of random walks (waits, diagonals, robots parked where they end), starts
    of robots not planned yet, a random start heading: the search's path obeys every rule
    and arrives when the brute force does (none where it finds none). A robot that must
    wait or detour is among them, and one with no path."""
    rng = np.random.default_rng(int(10 * turn_step) + 7 * diagonal)
    roadmap = _holed_grid(diagonal)
    outcomes = {"late": 0, "none": 0}
    for _ in range(40):
        planner = _Planner(roadmap, turn_step)
        mv = planner.moves
        for _ in range(int(rng.integers(0, 8))):
            walk = [int(rng.integers(roadmap.size))]
            for _ in range(int(rng.integers(2, 24))):
                walk.append(int(rng.choice(mv.targets[mv.ptr[walk[-1]]:mv.ptr[walk[-1] + 1]])))
            planner.reserve(np.array(walk, dtype=np.int64))
        planner.others[rng.choice(roadmap.size, 2, replace=False)] = 1
        res = planner.res
        free = [x for x in range(roadmap.size) if not res[0, x] and not res[1, x] & ENTER
                and not planner.others[x] and planner.parked[x] >= UNBOUNDED]
        if len(free) < 2:
            continue
        start, goal = (int(x) for x in rng.choice(free, 2, replace=False))
        heading = float(rng.choice([np.nan, rng.uniform(-np.pi, np.pi)]))
        path = planner.plan(start, goal, heading)
        expected = _brute_force(planner.rules(), turn_step, heading, start, goal)
        assert (None if path is None else path.size - 1) == expected
        if path is not None:
            _check_path(path, planner.rules(), turn_step, heading)
            hops = distance_tables(roadmap, np.array([goal]), diagonal=diagonal)[0, start]
            outcomes["late"] += path.size - 1 > hops
        else:
            outcomes["none"] += 1
    assert outcomes["late"] > 0 and outcomes["none"] > 0


@pytest.mark.parametrize(("diagonal", "turn_step"), CASES)
def test_robots_planned_one_after_another_arrive_as_early_as_a_brute_force(
        diagonal: bool, turn_step: float) -> None:
    """Prioritized planning's sequence on the small grid: each robot searched around the
    paths of the robots before it (reserved as planned), its arrival the brute force's
    on the same reservations: no plan of the old space-time search arrives earlier."""
    rng = np.random.default_rng(3 + int(4 * turn_step) + diagonal)
    roadmap = _holed_grid(diagonal)
    planned = 0
    for _ in range(12):
        planner = _Planner(roadmap, turn_step)
        k = int(rng.integers(2, 6))
        starts = rng.choice(roadmap.size, k, replace=False)
        goals = rng.choice(roadmap.size, k, replace=False)
        planner.others[starts] = 1
        for i in range(k):
            planner.others[starts[i]] = 0
            heading = float(rng.uniform(-np.pi, np.pi))
            path = planner.plan(int(starts[i]), int(goals[i]), heading)
            expected = _brute_force(planner.rules(), turn_step, heading, int(starts[i]),
                                    int(goals[i]))
            assert (None if path is None else path.size - 1) == expected
            if path is None:
                break
            _check_path(path, planner.rules(), turn_step, heading)
            planner.reserve(path)
            planned += 1
    assert planned > 12


def test_a_lone_robot_turns_standing_and_turns_while_it_waits() -> None:
    """A robot at (0, 0) heading east whose goal is (0, 3): it stands two steps (a
    quarter-turn at pi/4 per step) before its first move. With another robot on (0, 1) up to
    step 3 (then it leaves east, not followed) it leaves at step 3 for step 4: its turn
    made while it waits adds no step."""
    roadmap = _holed_grid(False)

    def at(x: float, y: float) -> int:
        return int(np.argmin(np.hypot(*(roadmap.positions - [x, y]).T)))

    start, goal, step = at(0, 0), at(0, 3), np.pi / 4
    alone = _Planner(roadmap, step).plan(start, goal, 0.0)
    assert alone is not None
    assert alone.tolist() == [start, start, start, at(0, 1), at(0, 2), goal]
    crossing = _Planner(roadmap, step)
    crossing.reserve(np.array([at(0, 1)] * 4 + [at(1, 1), at(1, 2), at(1, 3)], dtype=np.int64))
    waited = crossing.plan(start, goal, 0.0)
    assert waited is not None
    _check_path(waited, crossing.rules(), step, 0.0)
    assert waited.tolist() == [start] * 4 + [at(0, 1), at(0, 2), goal]
    assert waited.size - 1 == _brute_force(crossing.rules(), step, 0.0, start, goal)


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("turns", [False, True])
def test_plans_over_diagonals_and_with_turns_are_conflict_free(seed: int, turns: bool) -> None:
    """Random instances in open space over the grid squares' diagonals, with and without the
    turns' steps (random start headings): valid plans, corners of the diagonals free."""
    rng = np.random.default_rng(seed)
    sc = antipodal_swap(12)
    roadmap = build_roadmap((), (), None, sc.initial_states()[:, :2],
                            sc.reference_positions(0.0), np.ones(12, dtype=bool), 0.151,
                            0.302, 0.3, diagonal=True)
    k = int(rng.integers(8, 30))
    starts = rng.choice(roadmap.size, k, replace=False)
    goals = rng.choice(roadmap.size, k, replace=False)
    headings = rng.uniform(-np.pi, np.pi, k)
    step = np.pi / 4 if turns else 0.0
    configs = plan_paths(roadmap, starts, goals, turn_step=step, headings=headings)
    check_plan(_edges(roadmap), configs, starts, goals, roadmap.corners())


def test_the_moves_are_the_roadmap_edges_in_order_with_the_move_back_and_straight_on() -> None:
    """The compiled planners' moves (built with arrays) against the roadmap's lists: out of
    every vertex its neighbours in order, the wait, its diagonals in order with their
    corners; the move back of each; the vertex straight on (``straight_on``)."""
    sc = antipodal_swap(12)
    roadmap = build_roadmap((), (), None, sc.initial_states()[:, :2],
                            sc.reference_positions(0.0), np.ones(12, dtype=bool), 0.151,
                            0.302, 0.3, diagonal=True)
    for graph in (roadmap, replace(roadmap, diagonals=np.zeros((0, 4), dtype=np.int64))):
        mv = mapf.plan_moves(graph)
        straight = mapf.straight_on(graph, diagonal=True)
        rows = []
        for v, (grid, diag) in enumerate(zip(graph.neighbour_lists(), graph.diagonal_lists(),
                                             strict=True)):
            rows += [(v, u, b, c) for u, b, c in (*((w, -1, -1) for w in grid), (v, -1, -1),
                                                  *diag)]
        tail = np.repeat(np.arange(graph.size), np.diff(mv.ptr))
        assert list(zip(tail.tolist(), mv.targets.tolist(), mv.b.tolist(), mv.c.tolist(),
                        strict=True)) == rows
        assert mv.straight.tolist() == [-1 if v == u else straight.get((v, u), -1)
                                        for v, u, _, _ in rows]
        assert np.array_equal(tail[mv.back], mv.targets)
        assert np.array_equal(mv.targets[mv.back], tail)

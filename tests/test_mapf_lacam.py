"""LaCAM with PIBT (compiled, sqpmpc.kernels.lacam): complete against an exhaustive search
over the configurations on small grids, valid where prioritized planning fails, and
bounded by its node budget (tests/test_coordination.py's checker)."""

from __future__ import annotations

import itertools
from collections import deque

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components

from sqpmpc.coordination.mapf import PlanningError, plan_paths
from sqpmpc.coordination.roadmap import Roadmap
from tests.test_coordination import _edges, _maze_plan, check_plan


def _grid(free: np.ndarray) -> Roadmap:
    """The 4-connected roadmap of the free cells of ``free`` (rows x columns), 1 m apart."""
    rows, cols = free.shape
    cells = [(r, c) for r in range(rows) for c in range(cols) if free[r, c]]
    index = {cell: k for k, cell in enumerate(cells)}
    indptr, indices = [0], []
    for r, c in cells:
        for cell in ((r - 1, c), (r, c - 1), (r, c + 1), (r + 1, c)):
            if cell in index:
                indices.append(index[cell])
        indptr.append(len(indices))
    positions = np.array([[c, r] for r, c in cells], dtype=float)
    none = np.zeros(0, dtype=np.int64)
    return Roadmap(positions, np.array(indptr), np.array(indices, dtype=np.int64), 1.0, 0.25,
                   none, none)


def _step_ok(a: tuple[int, ...], b: tuple[int, ...]) -> bool:
    """A step of the plans LaCAM makes: no vertex or swap conflict, no rotation."""
    if len(set(b)) < len(b):
        return False
    moves = {(u, v) for u, v in zip(a, b, strict=True) if u != v}
    if any((v, u) in moves for u, v in moves):
        return False
    at = {v: r for r, v in enumerate(a)}
    for r in range(len(a)):
        seen, j = {r}, r
        while b[j] != a[j] and b[j] in at and at[b[j]] != j:
            j = at[b[j]]
            if j in seen:
                return False
            seen.add(j)
    return True


def _reachable(roadmap: Roadmap, starts: tuple[int, ...], goals: tuple[int, ...]) -> bool:
    """Whether ``goals`` is reachable from ``starts`` by such steps (breadth-first over
    every configuration)."""
    moves = [[v, *map(int, roadmap.neighbours(v))] for v in range(roadmap.size)]
    seen, queue = {starts}, deque([starts])
    while queue:
        a = queue.popleft()
        if a == goals:
            return True
        for b in itertools.product(*(moves[v] for v in a)):
            if b not in seen and _step_ok(a, b):
                seen.add(b)
                queue.append(b)
    return False


def _small_instances() -> list[tuple[np.ndarray, int, int]]:
    """Grids of 5 to 12 cells, some blocked, with 2 to 4 robots: (free cells, robots,
    seed); each configuration space at most a few thousand configurations."""
    out = []
    rng = np.random.default_rng(11)
    shapes = ((1, 5), (2, 3), (2, 4), (3, 3), (3, 4))
    while len(out) < 40:
        rows, cols = shapes[len(out) % len(shapes)]
        free = rng.random((rows, cols)) > 0.2
        roadmap = _grid(free)
        if roadmap.size < 4:
            continue
        if connected_components(roadmap.adjacency(), directed=False)[0] > 1:
            continue
        robots = int(rng.integers(2, min(4, roadmap.size - 1) + 1))
        out.append((free, robots, int(rng.integers(1 << 30))))
    return out


@pytest.mark.parametrize("free,robots,seed", _small_instances())
def test_lacam_plans_exactly_the_reachable_goals(free: np.ndarray, robots: int,
                                                 seed: int) -> None:
    """On every small instance LaCAM finds a valid plan when the goal configuration can be
    reached (without rotations) and reports none otherwise: it is complete."""
    roadmap = _grid(free)
    rng = np.random.default_rng(seed)
    starts = rng.choice(roadmap.size, robots, replace=False)
    goals = rng.choice(roadmap.size, robots, replace=False)
    reachable = _reachable(roadmap, tuple(starts.tolist()), tuple(goals.tolist()))
    if reachable:
        configs = plan_paths(roadmap, starts, goals, seed=seed, method="lacam")
        check_plan(_edges(roadmap), configs, starts, goals)
    else:
        with pytest.raises(PlanningError, match="cannot be reached together"):
            plan_paths(roadmap, starts, goals, seed=seed, method="lacam")


def test_lacam_plans_dense_instances_where_prioritized_planning_fails() -> None:
    """A sixth of the maze's vertices as robots (tests/test_coordination.py's dense
    instances) and the random instances of 2 to 9 robots of LaCAM's seeds 0-29 (seed 5 took
    60,000 search nodes in pure Python): every plan valid, and LaCAM plans at least one
    instance prioritized planning cannot."""
    sc, plan = _maze_plan()
    roadmap = plan.roadmap
    refused = 0
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        k = roadmap.size // 6
        starts = rng.choice(roadmap.size, k, replace=False)
        goals = rng.choice(roadmap.size, k, replace=False)
        try:
            plan_paths(roadmap, starts, goals, method="prioritized")
        except PlanningError:
            refused += 1
        configs = plan_paths(roadmap, starts, goals, seed=seed, method="lacam")
        check_plan(_edges(roadmap), configs, starts, goals)
    assert refused > 0
    for seed in range(30):
        rng = np.random.default_rng(seed)
        k = int(rng.integers(2, 10))
        starts = rng.choice(roadmap.size, k, replace=False)
        goals = rng.choice(roadmap.size, k, replace=False)
        configs = plan_paths(roadmap, starts, goals, seed=seed, method="lacam")
        check_plan(_edges(roadmap), configs, starts, goals)


def test_lacam_over_its_node_budget_is_refused_never_partial() -> None:
    """Two robots swapping the ends of a corridor with one pocket need a search of a few
    nodes: with a budget of one node the planner refuses by the budget."""
    free = np.array([[False, False, True, False, False], [True, True, True, True, True]])
    roadmap = _grid(free)
    starts, goals = np.array([1, 5]), np.array([5, 1])
    configs = plan_paths(roadmap, starts, goals, method="lacam")
    check_plan(_edges(roadmap), configs, starts, goals)
    with pytest.raises(PlanningError, match="within 1 search nodes"):
        plan_paths(roadmap, starts, goals, method="lacam", max_nodes=1)


def test_lacam_goes_straight_on_among_equally_near_vertices() -> None:
    """On an open 5 x 5 grid a lone robot from a corner to the far corner has many shortest
    paths; PIBT keeps going straight where a turn is as near: one turn, whatever the
    seed."""
    roadmap = _grid(np.ones((5, 5), dtype=bool))
    for seed in range(10):
        configs = plan_paths(roadmap, np.array([0]), np.array([24]), seed=seed,
                             method="lacam")
        way = np.diff(roadmap.positions[configs[:, 0]], axis=0)
        assert configs.shape[0] - 1 == 8
        turns = np.count_nonzero(np.any(way[1:] != way[:-1], axis=1))
        assert turns == 1

"""The coordination layer: roadmap, conflict-free plans, their delay-tolerant execution,
and the MovingAI reader (no closed loop here: tests/test_coordination_loop.py)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components, shortest_path
from shapely.geometry import LineString, Point

from sqpmpc.coordination.fleet import fleet_plan, replan_from_positions, turn_per_step
from sqpmpc.coordination.mapf import PlanningError, distance_tables, plan_paths
from sqpmpc.coordination.roadmap import build_roadmap, drawn_grid
from sqpmpc.coordination.schedule import Execution, Schedule
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.problem.fleets import antipodal_swap, grid_to_grid
from sqpmpc.problem.grid import GridSpec
from sqpmpc.problem.movingai import blocked_rectangles, mapf_scenario, read_map, read_scen
from sqpmpc.problem.polygons import PolygonObstacle
from sqpmpc.problem.scenario_file import parse_scenario_text
from tests.map_helpers import turned_maze

DATA = Path(__file__).parent / "data"
MAP, SCEN = DATA / "maze-12-8.map", DATA / "maze-12-8.scen"


def check_plan(adjacency: set[tuple[int, int]], configs: np.ndarray, starts: np.ndarray,
               goals: np.ndarray,
               corners: dict[tuple[int, int], tuple[int, int]] | None = None) -> None:
    """A plan is valid: from the starts to the goals, one edge (or diagonal, ``corners``) or a
    wait per step, no two robots on a vertex, no two robots swapping along an edge, no
    other robot on a diagonal move's corners at either end of the move."""
    corners = corners or {}
    assert np.array_equal(configs[0], starts)
    assert np.array_equal(configs[-1], goals)
    for a, b in zip(configs[:-1], configs[1:], strict=True):
        assert len(set(b.tolist())) == b.size, "vertex conflict"
        for r, (u, v) in enumerate(zip(a, b, strict=True)):
            move = (int(u), int(v))
            assert u == v or move in adjacency or move in corners, "not an edge"
            for x in corners.get(move, ()):
                others = np.delete(np.arange(a.size), r)
                assert x not in a[others] and x not in b[others], "a diagonal's corner held"
        moves = {(int(u), int(v)) for u, v in zip(a, b, strict=True) if u != v}
        assert not any((v, u) in moves for u, v in moves), "swap conflict"
        # no rotation: following the robots onto the vertices others leave never closes
        at = {int(v): r for r, v in enumerate(a)}
        for r in range(a.size):
            seen, j = {r}, r
            while b[j] != a[j] and int(b[j]) in at and at[int(b[j])] != j:
                j = at[int(b[j])]
                assert j not in seen, "rotation"
                seen.add(j)


def _edges(roadmap) -> set[tuple[int, int]]:
    return {(v, int(u)) for v in range(roadmap.size) for u in roadmap.neighbours(v)}


def _maze_plan(cell: float = 0.5):
    sc = mapf_scenario(MAP, 6, scen_path=SCEN, cell=cell, diameter=0.3)
    return sc, fleet_plan(sc, 0.15 + 0.01, 0.3 + 0.01)


def test_movingai_map_and_scen_are_read() -> None:
    blocked = read_map(MAP)
    assert blocked.shape == (8, 12) and int(blocked.sum()) == 40
    agents = read_scen(SCEN)
    assert agents[0] == ((0, 0), (11, 6)) and len(agents) == 6
    rects = blocked_rectangles(blocked)
    covered = np.zeros_like(blocked)
    for r0, c0, r1, c1 in rects:
        assert not covered[r0:r1, c0:c1].any(), "rectangles overlap"
        covered[r0:r1, c0:c1] = True
    assert np.array_equal(covered, blocked)


@pytest.mark.parametrize("text, message", [
    ("type octile\nheight 2\nwidth 3\nmap\n...\n.x.\n", "line 6"),
    ("height 2\nwidth 3\n", "not a MovingAI map"),
    ("type octile\nheight 3\nwidth 3\nmap\n...\n...\n", "expected 3 map rows"),
])
def test_bad_maps_are_refused_by_name(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "bad.map"
    path.write_text(text)
    with pytest.raises(ProblemError, match=message):
        read_map(path)


def test_mapf_scenario_declares_its_grid_and_round_trips() -> None:
    sc = mapf_scenario(MAP, 6, scen_path=SCEN, cell=0.5, diameter=0.3, acceleration=2.0,
                       angular_acceleration=10.0)
    assert sc.roadmap == GridSpec(0.5, (0.25, 0.25))
    assert np.allclose(sc.initial_states()[0, :2], (0.25, 3.75))  # row 0 is the top
    again = parse_scenario_text(sc.to_toml().encode(), "again")
    assert again == sc
    with pytest.raises(ProblemError, match="does not fit a cell"):
        mapf_scenario(MAP, 2, cell=0.3, diameter=0.3)
    with pytest.raises(ProblemError, match="the file has 6 agents"):
        mapf_scenario(MAP, 7, scen_path=SCEN)


def test_roadmap_section_is_validated() -> None:
    text = mapf_scenario(MAP, 2, cell=0.5).to_toml().replace("cell = 0.5", "cell = -1.0")
    with pytest.raises(ScenarioError, match=r"roadmap\.cell"):
        parse_scenario_text(text.encode(), "bad")


def test_every_free_cell_is_a_vertex_and_only_neighbours_are_joined() -> None:
    sc, plan = _maze_plan()
    roadmap = plan.roadmap
    blocked = read_map(MAP)
    assert roadmap.size == int((~blocked).sum())
    for v, u in _edges(roadmap):
        assert np.isclose(np.hypot(*(roadmap.positions[v] - roadmap.positions[u])), 0.5)
    assert np.allclose(roadmap.positions[roadmap.starts], sc.initial_states()[:, :2])


@pytest.mark.parametrize("offset", [(0.5, 0.5), (0.3, 0.7), (0.0, 0.5)])
def test_a_point_anywhere_in_a_cell_is_joined_to_the_grid(offset: tuple[float, float]) -> None:
    """A start or goal at a cell's centre removes the cell's corners: it is joined to the
    ring beyond (the 5 x 5 grid formation's robot 15 was cut off with a 1.5 h radius)."""
    h = 1.0
    point = np.array([[2.0 + offset[0] * h, 2.0 + offset[1] * h]])
    goal = np.array([[0.0, 0.0]])
    roadmap = build_roadmap((), (), (np.array([0.0, 0.0]), np.array([5.0, 5.0])), point, goal,
                            np.array([True]), 0.0, 0.5, 0.3, GridSpec(h, (0.0, 0.0)))
    start = int(roadmap.starts[0])
    assert roadmap.neighbours(start).size >= 1
    configs = plan_paths(roadmap, roadmap.starts, roadmap.goals)
    check_plan(_edges(roadmap), configs, roadmap.starts, roadmap.goals)


def test_a_grid_formation_is_one_connected_roadmap() -> None:
    sc = grid_to_grid(5, 5)
    plan = fleet_plan(sc, 0.151, 0.301)
    assert connected_components(plan.roadmap.adjacency(), directed=False)[0] == 1
    check_plan(_edges(plan.roadmap), plan.configs, plan.roadmap.starts, plan.roadmap.goals,
               plan.roadmap.corners())


def test_a_formation_gets_a_grid_through_its_points_and_a_circle_the_finest() -> None:
    """A 4 x 4 formation 1 m apart (h = 0.45 m at least): the fitted grid of 0.5 m has every
    start and goal on a vertex; an antipodal swap's points fit no lattice: the finest grid."""
    sc = grid_to_grid(4, 4)
    plan = fleet_plan(sc, 0.15 + 0.001, 0.3 + 0.001)
    roadmap = plan.roadmap
    assert roadmap.spacing == pytest.approx(0.5)
    ends = np.concatenate((sc.initial_states()[:, :2], sc.reference_positions(0.0)))
    vertices = roadmap.positions[np.concatenate((roadmap.starts, roadmap.goals))]
    assert np.hypot(*(vertices - ends).T).max() <= roadmap.reach
    # each vertex of the lattice is 0.5 m from its grid neighbours: no point was added
    step = np.hypot(*(roadmap.positions[roadmap.indices]
                      - np.repeat(roadmap.positions, np.diff(roadmap.indptr), axis=0)).T)
    np.testing.assert_allclose(step, 0.5, atol=1e-9)
    swap = fleet_plan(antipodal_swap(8), 0.15 + 0.001, 0.3 + 0.001)
    assert swap.roadmap.spacing == pytest.approx(0.301 + 2 * 0.3 / 4)


def _aisle(goal_gap: float, rows: tuple[float, ...] = (2.4,)
           ) -> tuple[list[PolygonObstacle], np.ndarray, np.ndarray]:
    """Two 8 m shelves 1.6 m apart (the aisle's middle at y = 2.4); eight goals ``goal_gap``
    apart on each of ``rows`` (every other row shifted by half a gap); the robots start in
    a column 2 m beyond the shelves' end."""
    shelves = [PolygonObstacle(((-4.0, y0), (4.0, y0), (4.0, y0 + 0.8), (-4.0, y0 + 0.8)))
               for y0 in (0.8, 3.2)]
    goals = np.concatenate([np.column_stack((goal_gap * (np.arange(8) - 3.5 + 0.5 * (k % 2)),
                                             np.full(8, y))) for k, y in enumerate(rows)])
    starts = np.column_stack((np.full(len(goals), 6.0), 0.5 * np.arange(len(goals)) - 2.0))
    return shelves, starts, goals


def test_an_open_space_roadmap_keeps_the_tube_around_its_grid_clear() -> None:
    """Without a declared grid, every grid vertex and grid edge is farther than the clearance
    plus the reach from the obstacles: a robot within the reach of its way keeps the
    clearance (the warehouse family's robot pinned at a shelf's corner, stuck for 80 s)."""
    shelves, starts, goals = _aisle(0.8)
    clearance = 0.151
    roadmap = build_roadmap(shelves, (), None, starts, goals, np.ones(len(goals), dtype=bool),
                            clearance, 0.302, 0.3, diagonal=True)
    ends = set(roadmap.starts.tolist()) | set(roadmap.goals.tolist())
    grid = [v for v in range(roadmap.size) if v not in ends]
    assert len(grid) > 100
    shapes = [shelf.shape for shelf in shelves]
    room = clearance + roadmap.reach - 1e-9
    for v in grid:
        assert min(s.distance(Point(roadmap.positions[v])) for s in shapes) >= room
        for u in roadmap.neighbours(v):
            if int(u) in ends:
                continue
            line = LineString([roadmap.positions[v], roadmap.positions[u]])
            assert min(s.distance(line) for s in shapes) >= room


def test_goals_crowding_an_aisle_are_bridged_to_the_rest_of_the_roadmap() -> None:
    """Goals off the grid remove the grid vertices nearer than h around them: two rows of
    goals in an aisle leave parts of it no grid vertex, and their rings do not reach each
    other (without the bridges 6 robots here were cut off from their goals on every grid
    tried, with the tube or without). The roadmap joins the parts by their shortest free
    segments: every robot's start is joined to its goal, and the fleet is planned."""
    shelves, starts, goals = _aisle(1.2, (2.1, 2.7))
    roadmap = build_roadmap(shelves, (), None, starts, goals, np.ones(len(goals), dtype=bool),
                            0.151, 0.302, 0.3, diagonal=True)
    _, label = connected_components(roadmap.adjacency(), directed=False)
    assert np.array_equal(label[roadmap.starts], label[roadmap.goals])
    configs = plan_paths(roadmap, roadmap.starts, roadmap.goals)
    check_plan(_edges(roadmap), configs, roadmap.starts, roadmap.goals, roadmap.corners())
    # one more robot whose goal is walled in: passed over, the others still bridged
    box = [PolygonObstacle(((x0, y0), (x0 + w, y0), (x0 + w, y0 + t), (x0, y0 + t)))
           for x0, y0, w, t in ((8.0, -4.0, 2.0, 0.2), (8.0, -2.2, 2.0, 0.2),
                                (8.0, -3.8, 0.2, 1.6), (9.8, -3.8, 0.2, 1.6))]
    roadmap = build_roadmap(shelves + box, (), None, np.vstack(([[9.0, 5.0]], starts)),
                            np.vstack(([[9.0, -3.0]], goals)), np.ones(len(goals) + 1, dtype=bool),
                            0.151, 0.302, 0.3, diagonal=True)
    _, label = connected_components(roadmap.adjacency(), directed=False)
    joined = label[roadmap.starts] == label[roadmap.goals]
    assert not joined[0] and joined[1:].all()


NARROW = """
name = "narrow"
t_end = 60.0
sample_time = 0.5
horizon = 8
[weights]
Q = [1.0, 1.0]
R = [0.5, 0.5]
[bounds]
v = [-0.6, 0.6]
omega = [-0.7853981633974483, 0.7853981633974483]
x = [-3.5, 3.5]
y = [-2.0, 2.0]
[[robots]]
id = 1
initial_state = [-3.0, 0.0, 0.0]
diameter = 0.3
reference = { type = "point", position = [3.0, 0.0] }
[[robots]]
id = 2
initial_state = [3.0, 0.7, 3.14]
diameter = 0.3
reference = { type = "point", position = [-3.0, 0.7] }
[[obstacles]]
points = [[-1.0, 0.2], [1.0, 0.2], [1.0, 3.0], [-1.0, 3.0]]
[[obstacles]]
points = [[-1.0, -0.2], [1.0, -0.2], [1.0, -3.0], [-1.0, -3.0]]
"""


def test_a_corridor_too_narrow_for_the_tube_is_passed_keeping_the_clearance() -> None:
    """A 0.4 m corridor for robots of 0.3 m (clearance 0.151 m): wider than 2 c, narrower than
    2 (c + rho) = 0.452 m. No grid vertex of the tube's roadmap is in it, yet the robots
    swap sides through it (bridged or on the thinner roadmap), and every edge of the
    roadmap keeps the clearance from the walls."""
    sc = parse_scenario_text(NARROW.encode(), "narrow.toml")
    clearance, separation = 0.151, 0.302
    plan = fleet_plan(sc, clearance, separation)
    roadmap = plan.roadmap
    check_plan(_edges(roadmap), plan.configs, roadmap.starts, roadmap.goals, roadmap.corners())
    walls = [polygon.shape for polygon in sc.polygons]
    for v, u in _edges(roadmap):
        line = LineString([roadmap.positions[v], roadmap.positions[u]])
        assert min(wall.distance(line) for wall in walls) >= clearance - 1e-9
    x = roadmap.positions[plan.configs, 0]  # (steps, robots)
    assert np.all(np.sign(x[0]) == -np.sign(x[-1]))
    tube = build_roadmap(sc.polygons, (), (np.array([-3.5, -2.0]), np.array([3.5, 2.0])),
                         sc.initial_states()[:, :2], sc.reference_positions(0.0),
                         np.ones(2, dtype=bool), clearance, separation, 0.3, diagonal=True)
    starts_goals = set(tube.starts.tolist()) | set(tube.goals.tolist())
    assert not any(abs(tube.positions[v, 0]) < 1.0 for v in range(tube.size)
                   if v not in starts_goals)


@pytest.mark.parametrize("degrees", [17.0, 30.0, 45.0])
def test_corridors_in_any_direction_get_lanes_along_their_middle(degrees: float) -> None:
    """A maze of 0.5 m corridors turned off the axes: no grid line runs along them, yet
    the roadmap joins every robot's start to its goal through them (lanes on the medial
    axis), its vertices keep the grid's spacing, its edges the clearance, and every edge
    but a robot's own point's keeps the spacing from every third vertex."""
    sc = turned_maze("maze-12-8", 6, degrees)
    clearance, separation = 0.191, 0.321  # what the rule passes for these robots
    plan = fleet_plan(sc, clearance, separation)
    roadmap = plan.roadmap
    check_plan(_edges(roadmap), plan.configs, roadmap.starts, roadmap.goals, roadmap.corners())
    p = roadmap.positions
    gaps = np.hypot(*(p[:, None] - p[None]).transpose(2, 0, 1))
    np.fill_diagonal(gaps, np.inf)
    assert gaps.min() >= roadmap.spacing - 1e-9
    walls = [polygon.shape for polygon in sc.polygons]
    own = set(roadmap.starts.tolist()) | set(roadmap.goals.tolist())
    for v, u in _edges(roadmap):
        line = LineString([p[v], p[u]])
        assert min(wall.distance(line) for wall in walls) >= clearance - 1e-9
        if v in own or u in own:
            continue
        others = [w for w in range(roadmap.size) if w not in (v, u)]
        assert min(line.distance(Point(p[w])) for w in others) >= roadmap.spacing - 1e-9


def test_a_cell_no_wider_than_the_kept_distance_is_refused() -> None:
    sc = mapf_scenario(MAP, 2, cell=0.5, diameter=0.3)
    with pytest.raises(ProblemError, match="not wider than the distance the robots keep"):
        fleet_plan(sc, 0.16, 0.5)


def test_the_maze_plan_is_conflict_free() -> None:
    sc, plan = _maze_plan()
    check_plan(_edges(plan.roadmap), plan.configs, plan.roadmap.starts, plan.roadmap.goals)


# six random instances per method, LaCAM's seed 10 too: in the pure-Python search without
# the swap technique seed 5's instance (7 robots) took ~60,000 search nodes (a minute) and
# seeds 0, 4 and 10 hundreds; compiled, with the swap technique, 20-42 nodes each (the
# search's backtracking: tests/test_mapf_lacam.py), each plan checked
RANDOM_INSTANCES = [*((seed, "auto") for seed in range(6)),
                    *((seed, "lacam") for seed in (0, 1, 2, 3, 4, 5, 10))]


@pytest.mark.parametrize("seed,method", RANDOM_INSTANCES)
def test_random_instances_are_planned_conflict_free(seed: int, method: str) -> None:
    rng = np.random.default_rng(seed)
    sc, plan = _maze_plan()
    roadmap = plan.roadmap
    k = int(rng.integers(2, 10))
    starts = rng.choice(roadmap.size, k, replace=False)
    goals = rng.choice(roadmap.size, k, replace=False)
    configs = plan_paths(roadmap, starts, goals, seed=seed, method=method)
    check_plan(_edges(roadmap), configs, starts, goals)


def test_prioritized_plans_are_conflict_free_and_no_shorter_than_the_lower_bound() -> None:
    """Dense instances (a sixth of the maze's vertices) where the first order of
    prioritized planning can fail: what it returns is a valid plan, and what it cannot
    plan is refused by name (LaCAM then plans it, in ``auto``)."""
    sc, plan = _maze_plan()
    roadmap = plan.roadmap
    solved = 0
    for seed in range(12):
        rng = np.random.default_rng(100 + seed)
        k = roadmap.size // 6
        starts = rng.choice(roadmap.size, k, replace=False)
        goals = rng.choice(roadmap.size, k, replace=False)
        table = distance_tables(roadmap, goals)
        bound = int(table[np.arange(k), starts].max())
        try:
            configs = plan_paths(roadmap, starts, goals, method="prioritized")
        except PlanningError as error:
            assert "prioritized planning found no plan" in str(error)
            continue
        solved += 1
        check_plan(_edges(roadmap), configs, starts, goals)
        assert configs.shape[0] - 1 >= bound
    assert solved > 0
    with pytest.raises(PlanningError, match="unknown planning method"):
        plan_paths(roadmap, roadmap.starts, roadmap.goals, method="cbs")


def test_distance_tables_are_the_graph_distances() -> None:
    sc, plan = _maze_plan()
    roadmap = plan.roadmap
    goals = np.array([0, roadmap.size // 2, roadmap.size - 1, 0])
    expected = shortest_path(roadmap.adjacency(), directed=False, unweighted=True,
                             indices=goals)
    assert np.array_equal(distance_tables(roadmap, goals), expected)


def test_prioritized_planning_seeks_only_shorter_plans() -> None:
    """``shorter_than``: a plan found is valid and shorter; none below the lower bound
    (the prioritized planner says so, ``auto`` falls back to LaCAM's plan)."""
    sc, plan = _maze_plan()
    roadmap = plan.roadmap
    rng = np.random.default_rng(3)
    k = 8
    starts = rng.choice(roadmap.size, k, replace=False)
    goals = rng.choice(roadmap.size, k, replace=False)
    free = plan_paths(roadmap, starts, goals, method="prioritized")
    steps = free.shape[0] - 1
    bounded = plan_paths(roadmap, starts, goals, method="prioritized", shorter_than=steps + 1)
    check_plan(_edges(roadmap), bounded, starts, goals)
    assert bounded.shape[0] - 1 <= steps
    lower = int(distance_tables(roadmap, goals)[np.arange(k), starts].max())
    with pytest.raises(PlanningError, match=f"of fewer than {lower} steps"):
        plan_paths(roadmap, starts, goals, method="prioritized", shorter_than=lower)
    check_plan(_edges(roadmap), plan_paths(roadmap, starts, goals, shorter_than=lower),
               starts, goals)


def test_a_swap_in_a_corridor_without_a_pocket_ends_every_prioritized_search() -> None:
    """Two robots to swap the ends of a corridor: no plan exists. Each search ends when its
    space-time graph is exhausted (past the last reservation one node per vertex), and the
    prioritized planner refuses the instance in its last order."""
    ends = np.array([[0.0, 0.0], [4.0, 0.0]])
    roadmap = build_roadmap((), (), (np.array([-0.5, -0.5]), np.array([4.5, 0.5])), ends,
                            ends[::-1], np.array([True, True]), 0.0, 0.5, 0.3,
                            GridSpec(1.0, (0.0, 0.0)))
    assert roadmap.size == 5
    with pytest.raises(PlanningError, match="prioritized planning found no plan"):
        plan_paths(roadmap, roadmap.starts, roadmap.goals, method="prioritized")


def test_a_goal_cut_off_or_shared_is_refused_by_name() -> None:
    positions = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]])
    wall = PolygonObstacle(((1.55, -0.5), (2.45, -0.5), (2.45, 0.5), (1.55, 0.5)))
    roadmap = build_roadmap((wall,), (), (np.array([-0.5, -0.5]), np.array([3.5, 0.5])),
                            positions[:2], positions[[1, 0]], np.array([True, True]), 0.1, 0.5,
                            0.3, GridSpec(1.0, (0.0, 0.0)))
    isolated = np.flatnonzero(np.all(np.isclose(roadmap.positions, [3.0, 0.0]), axis=1))
    with pytest.raises(PlanningError, match="robot index 0 cannot reach its goal"):
        plan_paths(roadmap, np.array([roadmap.starts[0]]), isolated)
    with pytest.raises(PlanningError, match="share the goal vertex"):
        plan_paths(roadmap, roadmap.starts, roadmap.starts[[0, 0]])


def test_a_full_ring_is_not_rotated() -> None:
    """Four robots on the four vertices of a ring, each to go to the next: the only plan
    rotates them all at once, which executed in order would deadlock: no plan."""
    ends = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    roadmap = build_roadmap((), (), (np.array([-0.2, -0.2]), np.array([1.2, 1.2])), ends,
                            ends[[1, 2, 3, 0]], np.ones(4, dtype=bool), 0.0, 0.5, 0.3,
                            GridSpec(1.0, (0.0, 0.0)))
    assert roadmap.size == 4
    with pytest.raises(PlanningError, match="cannot be reached together"):
        plan_paths(roadmap, roadmap.starts, roadmap.goals)


def test_a_two_robot_swap_in_a_corridor_with_one_pocket_is_solved() -> None:
    """A line of 5 cells with a pocket above the middle: the robots at both ends swap
    (PIBT alone cannot, nor prioritized planning: LaCAM's search does)."""
    walls = [PolygonObstacle(((x - 0.45, 0.55), (x + 0.45, 0.55), (x + 0.45, 1.45),
                              (x - 0.45, 1.45))) for x in (0.0, 1.0, 3.0, 4.0)]
    ends = np.array([[0.0, 0.0], [4.0, 0.0]])
    roadmap = build_roadmap(walls, (), (np.array([-0.5, -0.5]), np.array([4.5, 1.5])),
                            ends, ends[::-1], np.array([True, True]), 0.0, 0.5, 0.3,
                            GridSpec(1.0, (0.0, 0.0)))
    assert roadmap.size == 6
    configs = plan_paths(roadmap, roadmap.starts, roadmap.goals)
    check_plan(_edges(roadmap), configs, roadmap.starts, roadmap.goals)


def _execute(schedule: Schedule, roadmap, rng: np.random.Generator, slow: float) -> int:
    """Discrete execution with random delays: each round every robot that may head for
    its next vertex moves there with probability 1 - slow. Returns the rounds taken;
    checks that no two robots share a vertex and that the execution never stalls."""
    n = schedule.size
    execution = Execution(schedule, roadmap, np.arange(n), window=1)
    corners = roadmap.corners()
    rounds = 0
    while not all(execution.finished(i) for i in range(n)):
        rounds += 1
        may = execution.permitted_all()
        waiting = [i for i in range(n) if not execution.finished(i)]
        assert any(may[i] > execution.progress[i] for i in waiting), "deadlock"
        positions = roadmap.positions[execution.configuration()].copy()
        for i in range(n):
            p = int(execution.progress[i])
            if may[i] > p and rng.random() > slow:
                positions[i] = roadmap.positions[schedule.paths[i, p + 1]]
        before = execution.progress.copy()
        held = execution.configuration()
        execution.advance(positions)
        assert np.all(execution.progress - before <= 1)
        occupied = execution.configuration()
        assert len(set(occupied.tolist())) == n, "two robots on one vertex"
        for i in np.flatnonzero(occupied != held):  # a diagonal passes free corners
            for x in corners.get((int(held[i]), int(occupied[i])), ()):
                others = np.delete(np.arange(n), i)
                assert x not in held[others] and x not in occupied[others], "corner held"
    return rounds


@pytest.mark.parametrize("slow", [0.0, 0.5, 0.9])
def test_execution_with_delays_keeps_vertices_apart_and_never_deadlocks(slow: float) -> None:
    rng = np.random.default_rng(7)
    sc, plan = _maze_plan()
    rounds = _execute(plan.schedule, plan.roadmap, rng, slow)
    if slow == 0.0:  # undelayed, the execution is as fast as the plan
        assert rounds <= plan.makespan_steps


def test_execution_of_a_large_random_plan_with_delays() -> None:
    rng = np.random.default_rng(3)
    sc, plan = _maze_plan()
    roadmap = plan.roadmap
    starts = rng.choice(roadmap.size, 10, replace=False)
    goals = rng.choice(roadmap.size, 10, replace=False)
    schedule = Schedule.from_plan(plan_paths(roadmap, starts, goals))
    _execute(schedule, roadmap, rng, 0.6)


@pytest.mark.parametrize("slow", [0.0, 0.7])
def test_plans_over_diagonals_keep_corners_free_when_executed_with_delays(slow: float) -> None:
    """Open space with the grid squares' diagonals: random instances are planned by
    prioritized planning over them (a diagonal move keeps the square's other corners free)
    and executed with delays without a deadlock, a shared vertex or a held corner."""
    rng = np.random.default_rng(11)
    sc = antipodal_swap(12)
    roadmap = build_roadmap((), (), None, sc.initial_states()[:, :2],
                            sc.reference_positions(0.0), np.ones(12, dtype=bool), 0.151,
                            0.302, 0.3, diagonal=True)
    assert roadmap.diagonals.shape[0] > 0
    used = 0
    for _ in range(4):
        starts = rng.choice(roadmap.size, 24, replace=False)
        goals = rng.choice(roadmap.size, 24, replace=False)
        configs = plan_paths(roadmap, starts, goals, method="prioritized")
        corners = roadmap.corners()
        check_plan(_edges(roadmap), configs, starts, goals, corners)
        steps = zip(configs[:-1], configs[1:], strict=True)
        used += sum((int(a), int(b)) in corners for row in steps
                    for a, b in zip(*row, strict=True))
        _execute(Schedule.from_plan(configs, corners), roadmap, rng, slow)
    assert used > 0


def test_fleet_plan_of_a_swap_is_conflict_free_and_open_space_gets_a_grid() -> None:
    sc = antipodal_swap(16)
    plan = fleet_plan(sc, 0.16, 0.31)
    assert plan is not None and plan.robots.size == 16
    assert np.isclose(plan.roadmap.spacing, 0.31 + 2 * plan.roadmap.reach)
    check_plan(_edges(plan.roadmap), plan.configs, plan.roadmap.starts, plan.roadmap.goals,
               plan.roadmap.corners())
    # the robots' own points are vertices: they start and end exactly there
    assert np.allclose(plan.roadmap.positions[plan.roadmap.starts], sc.initial_states()[:, :2])
    # over the diagonals only a plan of fewer steps than the 4-connected one is kept
    square = replace(plan.roadmap, diagonals=np.zeros((0, 4), dtype=np.int64))
    steps = plan_paths(square, square.starts, square.goals,
                       turn_step=turn_per_step(sc, square.spacing),
                       headings=sc.initial_states()[:, 2]).shape[0] - 1
    assert plan.makespan_steps < steps if plan.roadmap.diagonals.size else \
        plan.makespan_steps == steps


def test_a_plan_from_measured_positions_starts_each_robot_at_a_distinct_nearest_vertex(
) -> None:
    """Progress stopped: the new plan starts where the robots are. Robots near their plan's
    vertices start there; a robot pushed onto another robot's vertex and that robot get
    two distinct vertices, the nearest assignment; the plan is valid to the same goals
    and computed once for the same measurements."""
    sc = antipodal_swap(16)
    plan = fleet_plan(sc, 0.16, 0.31)
    assert plan is not None
    rng = np.random.default_rng(3)
    middle = plan.configs[plan.makespan_steps // 2]
    positions = plan.roadmap.positions[middle] + rng.uniform(-0.05, 0.05, (16, 2))
    moved = positions.copy()
    moved[3] = plan.roadmap.positions[middle[4]] + np.array([0.02, 0.0])  # onto robot 4's
    for where, pushed in ((positions, False), (moved, True)):
        new = replan_from_positions(plan, sc, where)
        starts = new.configs[0]
        assert np.unique(starts).size == 16
        check_plan(_edges(new.roadmap), new.configs, starts, plan.configs[-1],
                   new.roadmap.corners())
        gap = np.hypot(*(new.roadmap.positions[starts] - where).T)
        if not pushed:
            assert np.array_equal(starts, middle)
        else:
            assert starts[3] == middle[4] and starts[4] != middle[4]
            assert gap[4] <= plan.roadmap.spacing * np.sqrt(2) + 0.06
        assert replan_from_positions(plan, sc, where.copy()) is new


def test_a_robot_holds_while_another_stands_on_its_next_vertex() -> None:
    """Robot 0 goes from x = 1 to x = 4 along a one-cell corridor and robot 1 follows it from
    x = 0: the order lets robot 1 head for x = 1 once robot 0 is counted at x = 2, but it
    holds while any robot stands within half the spacing of x = 1: robot 0 pushed back
    there (its progress does not go back), or a robot the plan does not know."""
    walls = [PolygonObstacle(((-0.5, 0.5), (4.5, 0.5), (4.5, 1.5), (-0.5, 1.5)))]
    starts = np.array([[1.0, 0.0], [0.0, 0.0]])
    goals = np.array([[4.0, 0.0], [3.0, 0.0]])
    roadmap = build_roadmap(walls, (), (np.array([-0.5, -0.5]), np.array([4.5, 0.5])),
                            starts, goals, np.array([True, True]), 0.0, 0.5, 0.3,
                            GridSpec(1.0, (0.0, 0.0)))
    schedule = Schedule.from_plan(plan_paths(roadmap, roadmap.starts, roadmap.goals))
    execution = Execution(schedule, roadmap, np.arange(2), window=2)
    x = roadmap.positions[schedule.paths, 0]
    assert x[0, :4].tolist() == [1.0, 2.0, 3.0, 4.0] and x[1, :4].tolist() == [0.0, 1.0, 2.0, 3.0]

    def at(a: float, b: float, outsider: tuple[float, float] = (9.0, 9.0)) -> np.ndarray:
        return np.array([[a, 0.0], [b, 0.0], outsider])

    execution.advance(at(1.0, 0.0))
    assert execution.clear_all(at(1.0, 0.0))[1] == 0  # the order holds it
    execution.advance(at(1.6, 0.0))
    assert execution.progress[0] == 1 and execution.clear_all(at(1.6, 0.0))[1] == 1
    assert execution.clear_all(at(1.3, 0.0))[1] == 0  # robot 0 pushed back near x = 1
    assert execution.progress[0] == 1 and execution.permitted_all()[1] == 1
    assert execution.clear_all(at(1.6, 0.0, (1.1, 0.2)))[1] == 0  # another robot there
    assert execution.clear_all(at(1.6, 0.0, (1.0, 0.6)))[1] == 1  # beside it: not there


def test_a_free_robot_gives_way_to_one_standing_on_its_way() -> None:
    """Open space, 1 m cells, kept distance 0.5 m: robot 0 heads east from (0, 0), robot 1
    north from (1, 1), neither waiting for the other in the plan. Robot 1 pushed off its
    path to (0.3, 0.2), on robot 0's way (robot 0 pushed to (-0.25, -0.3)), its own way
    clear of robot 0: robot 0 holds, robot 1 stays free. Each on the other's way (robot 1
    heading for (-1, -1) from (0, -1)): neither holds (no cycle of waiting); a third robot
    on no way changes nothing. Robot 1 back on its path: nobody holds."""
    points = np.array([[0.0, 0.0], [1.0, 1.0], [0.0, -1.0]])
    roadmap = build_roadmap((), (), (np.array([-2.0, -2.0]), np.array([3.0, 3.0])), points,
                            points, np.ones(3, dtype=bool), 0.0, 0.5, 0.3,
                            GridSpec(1.0, (0.0, 0.0)))
    assert np.isclose(roadmap.spacing - 2 * roadmap.reach, 0.5)

    def vertex(x: float, y: float) -> int:
        return int(np.argmin(np.hypot(*(roadmap.positions - (x, y)).T)))

    east = [vertex(0, 0), vertex(1, 0), vertex(2, 0)]
    for way, holds in (([vertex(1, 1), vertex(1, 2)], [0]),
                       ([vertex(0, -1), vertex(-1, -1)], [])):
        configs = np.array([east, way + way[-1:], [vertex(2, -2)] * 3]).T
        schedule = Schedule.from_plan(configs)
        execution = Execution(schedule, roadmap, np.arange(3), window=1)
        assert execution.permitted_all().tolist() == [2, 1, 0]  # nobody waits for anybody
        here = np.array([[-0.25, -0.3], [0.3, 0.2], [2.0, -2.0]])
        permitted = execution.clear_all(here)
        assert np.flatnonzero(permitted == execution.progress).tolist() == holds + [2]
        # robot 1 on its path: nobody on robot 0's way that the plan did not put there
        here[1] = (1.0, 1.2) if holds else (0.0, -1.2)
        assert execution.clear_all(here).tolist() == [2, 1, 0]


def _turn_waits(path: np.ndarray, positions: np.ndarray, turn_step: float) -> list[int]:
    """For every bend of a robot's plan, how many more steps it stood at the bend's vertex
    than the turn needs (``ceil(angle / turn_step)``)."""
    change = np.flatnonzero(path[1:] != path[:-1])  # the steps moving off path[k]
    slack = []
    for a, b in zip(change[:-1], change[1:], strict=True):
        d0 = positions[path[a + 1]] - positions[path[a]]
        d1 = positions[path[b + 1]] - positions[path[b]]
        bend = abs(np.remainder(np.arctan2(d1[1], d1[0]) - np.arctan2(d0[1], d0[0]) + np.pi,
                                2 * np.pi) - np.pi)
        need = int(np.ceil(bend / turn_step - 1e-9))
        if need:
            slack.append(int(b - a - 1) - need)
    return slack


def test_a_turn_takes_its_steps_in_a_prioritized_plan() -> None:
    """A robot alone on the test maze: each bend of its path is preceded by the steps a
    turn in place takes (a quarter-turn per two steps here), and its plan is as long as its
    moves plus those steps; with ``turn_step = 0`` it is its distance."""
    sc, plan = _maze_plan()
    roadmap = replace(plan.roadmap, diagonals=np.zeros((0, 4), dtype=np.int64))
    table = distance_tables(roadmap, roadmap.goals)
    far = int(np.argmax(table[np.arange(table.shape[0]), roadmap.starts]))
    start, goal = roadmap.starts[far:far + 1], roadmap.goals[far:far + 1]
    fast = plan_paths(roadmap, start, goal)
    assert fast.shape[0] - 1 == int(table[far, start[0]])
    step = np.pi / 4
    slow = plan_paths(roadmap, start, goal, turn_step=step)
    check_plan(_edges(roadmap), slow, start, goal)
    slack = _turn_waits(slow[:, 0], roadmap.positions, step)
    assert slack and min(slack) == 0 and max(slack) == 0  # every bend: its turn, no more
    bends = len(slack)
    assert slow.shape[0] - 1 == int(table[far, start[0]]) + 2 * bends  # all quarter-turns


@pytest.mark.parametrize("seed", range(6))
def test_plans_with_turns_are_conflict_free(seed: int) -> None:
    """Random instances on the test maze with turns taking steps: valid plans (where the
    robots cannot all be given their turns' steps, prioritized planning leaves them out,
    for a robot or for the fleet, and the plan is still conflict-free)."""
    rng = np.random.default_rng(seed)
    sc, plan = _maze_plan()
    roadmap = replace(plan.roadmap, diagonals=np.zeros((0, 4), dtype=np.int64))
    k = int(rng.integers(2, 10))
    starts = rng.choice(roadmap.size, k, replace=False)
    goals = rng.choice(roadmap.size, k, replace=False)
    headings = rng.uniform(-np.pi, np.pi, k)
    configs = plan_paths(roadmap, starts, goals, turn_step=np.pi / 4, headings=headings)
    check_plan(_edges(roadmap), configs, starts, goals)


def _arrivals_by_recursion(schedule: Schedule, positions: np.ndarray, headings: np.ndarray,
                           speed: float, rate: float) -> np.ndarray:
    """The reference of ``Schedule.predicted_arrivals``: its recursion evaluated event by
    event, each arrival from the arrivals it needs (memoized depth-first)."""
    needs: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for o, k, j, m in zip(schedule.dep_owner, schedule.dep_index, schedule.dep_robot,
                          schedule.dep_need, strict=True):
        needs.setdefault((int(o), int(k)), []).append((int(j), int(m)))
    memo: dict[tuple[int, int], float] = {}

    def arrival(i: int, k: int) -> float:
        if k == 0:
            return 0.0
        if (i, k) not in memo:
            a, b = positions[schedule.paths[i, k - 1]], positions[schedule.paths[i, k]]
            way = b - a
            facing = headings[i] if k == 1 else np.arctan2(
                *(a - positions[schedule.paths[i, k - 2]])[::-1])
            bend = abs((np.arctan2(way[1], way[0]) - facing + np.pi) % (2 * np.pi) - np.pi)
            turn = 0.0 if np.isnan(bend) else bend / rate
            ready = max([arrival(j, m) for j, m in needs.get((i, k), [])], default=0.0)
            memo[i, k] = max(arrival(i, k - 1) + turn, ready) + np.hypot(*way) / speed
        return memo[i, k]

    return np.array([arrival(i, int(schedule.lengths[i]) - 1) for i in range(schedule.size)])


def test_predicted_arrivals_of_one_robot_are_its_moves_and_turns() -> None:
    """One robot on a straight line of three vertices 0.5 m apart at 1 m/s and pi/2 rad/s:
    1 s facing the way, 1 s more for a quarter-turn first, 2 s more for a half-turn;
    unknown heading: the first turn is free."""
    positions = np.array([[0.0, 0.0], [0.5, 0.0], [1.0, 0.0]])
    schedule = Schedule.from_plan(np.array([[0], [1], [2]]))
    for heading, expected in ((0.0, 1.0), (np.pi / 2, 2.0), (np.pi, 3.0), (np.nan, 1.0)):
        got = schedule.predicted_arrivals(positions, np.array([heading]), 1.0, np.pi / 2)
        assert np.allclose(got, [expected]), (heading, got)


@pytest.mark.parametrize("seed", range(3))
def test_predicted_arrivals_are_the_recursion_over_the_dependencies(seed: int) -> None:
    """Random plans on the test maze (4-connected, turns in the plan) and in open space
    over the diagonals (corner passes are dependencies too): the vectorized fixed point
    equals the recursion evaluated event by event; every robot is predicted no earlier
    than its path at full speed, and a robot that waits for others no earlier than them."""
    rng = np.random.default_rng(seed)
    sc, plan = _maze_plan()
    open_space = build_roadmap((), (), None, antipodal_swap(12).initial_states()[:, :2],
                               antipodal_swap(12).reference_positions(0.0),
                               np.ones(12, dtype=bool), 0.151, 0.302, 0.3, diagonal=True)
    for roadmap, k in ((replace(plan.roadmap, diagonals=np.zeros((0, 4), dtype=np.int64)), 8),
                       (open_space, 24)):
        starts = rng.choice(roadmap.size, k, replace=False)
        goals = rng.choice(roadmap.size, k, replace=False)
        headings = rng.uniform(-np.pi, np.pi, k)
        configs = plan_paths(roadmap, starts, goals, turn_step=np.pi / 4, headings=headings)
        schedule = Schedule.from_plan(configs, roadmap.corners())
        assert schedule.dep_owner.size > 0
        got = schedule.predicted_arrivals(roadmap.positions, headings, 0.7, 1.3)
        want = _arrivals_by_recursion(schedule, roadmap.positions, headings, 0.7, 1.3)
        assert np.allclose(got, want, rtol=0.0, atol=1e-9)
        lengths = [np.hypot(*np.diff(roadmap.positions[schedule.paths[i, :schedule.lengths[i]]],
                                     axis=0).T).sum() for i in range(k)]
        assert np.all(got >= np.array(lengths) / 0.7 - 1e-9)


def test_the_fleet_plan_is_the_one_predicted_to_end_first() -> None:
    """A grid formation: of the plans with the turns' steps and without them (on the
    4-connected grid), the fleet plan is the one whose predicted execution ends first;
    every candidate is valid."""
    sc = grid_to_grid(4, 4)
    plan = fleet_plan(sc, 0.16, 0.31)
    assert plan is not None
    headings = sc.initial_states()[plan.robots, 2]
    v = float(sc.bounds.v[1])
    w = float(sc.bounds.omega[1])
    chosen = plan.schedule.predicted_arrivals(plan.roadmap.positions, headings, v, w).max()
    full = build_roadmap((), (), None, sc.initial_states()[:, :2], sc.reference_positions(0.0),
                         np.ones(sc.n_robots, dtype=bool), 0.16, 0.31, 0.3, diagonal=True)
    assert full.size == plan.roadmap.size
    square = replace(full, diagonals=np.zeros((0, 4), dtype=np.int64))
    ends = []
    for step in (turn_per_step(sc, full.spacing), 0.0):
        # each candidate as the fleet makes it: the 4-connected plan, then (with the turns'
        # steps) over the diagonals a plan of fewer steps if there is one
        roadmap = square
        configs = plan_paths(square, square.starts, square.goals, turn_step=step,
                             headings=headings)
        try:
            if step > 0.0:
                configs = plan_paths(full, full.starts, full.goals, turn_step=step,
                                     headings=headings, method="prioritized",
                                     shorter_than=configs.shape[0] - 1)
                roadmap = full
        except PlanningError:
            pass
        check_plan(_edges(roadmap), configs, roadmap.starts, roadmap.goals, roadmap.corners())
        ends.append(Schedule.from_plan(configs, roadmap.corners()).predicted_arrivals(
            roadmap.positions, headings, v, w).max())
    assert np.isclose(chosen, min(ends), rtol=0.0, atol=1e-9)


def test_a_departed_robot_is_planned_standing_and_a_goal_it_holds_moves_next_to_it() -> None:
    """An antipodal swap of 8 planned from where the robots start with robot index 0
    standing (its controller left): its vertex is cut off the roadmap (no edge, no
    diagonal), its path is that vertex, no other robot's plan enters it, the plan is valid
    on the cut roadmap; robot index 4, whose goal is robot 0's start, is sent to the
    nearest vertex no one else has; the others keep their goals. Planned with nobody
    standing again, robot 4's goal is its own again."""
    sc = antipodal_swap(8)
    plan = fleet_plan(sc, 0.16, 0.31)
    assert plan is not None
    where = sc.initial_states()[:, :2]
    new = replan_from_positions(plan, sc, where, standing=frozenset({0}))
    row0, row4 = (int(np.flatnonzero(new.robots == i)[0]) for i in (0, 4))
    vertex = new.configs[0, row0]
    assert (new.configs[:, row0] == vertex).all()
    assert not (np.delete(new.configs, row0, axis=1) == vertex).any()
    assert new.roadmap.neighbours(vertex).size == 0
    assert not np.isin(new.roadmap.diagonals, [vertex]).any()
    check_plan(_edges(new.roadmap), new.configs, new.configs[0], new.configs[-1],
               new.roadmap.corners())
    goals = sc.reference_positions(0.0)
    assert np.allclose(goals[4], where[0])  # robot 4's goal is where robot 0 stands
    moved = new.roadmap.positions[new.configs[-1, row4]]
    assert 0.0 < np.hypot(*(moved - goals[4])) <= np.sqrt(2) * new.roadmap.spacing + 1e-9
    assert np.allclose(new.goals[row4], moved)  # the point it closes on at its path's end
    others = [k for k in range(new.robots.size) if k not in (row0, row4)]
    assert np.allclose(new.roadmap.positions[new.configs[-1, others]],
                       goals[new.robots[others]])
    back = replan_from_positions(new, sc, where)
    assert back.base is None and back.roadmap.neighbours(vertex).size > 0
    assert np.allclose(back.roadmap.positions[back.configs[-1, row4]], goals[4])


def _permitted_everywhere(execution: Execution) -> np.ndarray:
    """:meth:`Execution.permitted_all` as its docstring states it, every dependency
    applied one by one."""
    s = execution.schedule
    out = s.lengths - 1
    for e in range(s.dep_owner.size):
        owner = s.dep_owner[e]
        if s.dep_index[e] > execution.progress[owner] and \
                execution.progress[s.dep_robot[e]] < s.dep_need[e]:
            out[owner] = min(out[owner], s.dep_index[e] - 1)
    return out


def _clear_by_all_pairs(execution: Execution, now: np.ndarray) -> np.ndarray:
    """:meth:`Execution.clear_all` as its docstring states it, every robot against every
    other (the dense form it had)."""
    s, roadmap = execution.schedule, execution.roadmap
    points = roadmap.positions[s.paths]
    out = _permitted_everywhere(execution)
    rows = np.flatnonzero(out > execution.progress)
    nxt = points[rows, execution.progress[rows] + 1]
    gap = np.hypot(*(now[None, :, :] - nxt[:, None, :]).transpose(2, 0, 1))
    gap[np.arange(rows.size), execution.robots[rows]] = np.inf
    held = rows[gap.min(axis=1) < 0.5 * roadmap.spacing]
    out[held] = execution.progress[held]
    free = np.setdiff1d(rows, held)
    if free.size < 2:
        return out
    sep = roadmap.spacing - 2.0 * roadmap.reach
    a = now[execution.robots[free]]
    d = points[free, execution.progress[free] + 1] - a
    v0 = points[free, execution.progress[free]]
    inway = np.zeros((free.size, free.size), dtype=bool)
    for r in range(free.size):
        for j in range(free.size):
            if r == j:
                continue
            f = np.clip((a[j] - a[r]) @ d[r] / max(d[r] @ d[r], 1e-12), 0.0, 1.0)
            edge = d[j] + a[j] - v0[j]
            g = np.clip((a[j] - v0[j]) @ edge / max(edge @ edge, 1e-12), 0.0, 1.0)
            off = np.hypot(*(a[j] - v0[j] - g * edge)) > roadmap.reach
            inway[r, j] = off and np.hypot(*(a[j] - a[r] - f * d[r])) < sep
    for e in range(s.dep_owner.size):  # the robot it follows onto its next vertex
        o, t = s.dep_owner[e], s.dep_robot[e]
        if o in free and t in free and s.dep_index[e] == execution.progress[o] + 1:
            inway[np.flatnonzero(free == o)[0], np.flatnonzero(free == t)[0]] = False
    waits = inway & ~inway.T
    _, label = connected_components(waits, directed=True, connection="strong")
    wait = free[waits.any(axis=1) & ~(np.bincount(label)[label] > 1)]
    out[wait] = execution.progress[wait]
    return out


@pytest.mark.parametrize("seed", range(6))
def test_holds_and_waits_are_those_of_checking_every_pair(seed: int) -> None:
    """The holds and waits of a swap's execution, found near each robot (a k-d tree),
    are those of checking every pair of robots, with robots scattered around their
    paths (some pushed off, some on another's next vertex)."""
    rng = np.random.default_rng(seed)
    sc = antipodal_swap(16)
    plan = fleet_plan(sc, 0.2, 0.321)
    n = plan.schedule.size
    execution = Execution(plan.schedule, plan.roadmap, plan.robots, window=3)
    waits_seen = holds_seen = 0
    for _ in range(30):
        top = plan.schedule.lengths - 1
        execution.progress[:] = np.minimum(execution.progress + rng.integers(0, 2, n), top)
        at = plan.roadmap.positions[plan.schedule.paths[np.arange(n), execution.progress]]
        now = at + rng.normal(0.0, plan.roadmap.spacing * 0.4, (n, 2))
        want = _clear_by_all_pairs(execution, now)
        np.testing.assert_array_equal(execution.permitted_all(),
                                      _permitted_everywhere(execution))
        np.testing.assert_array_equal(execution.clear_all(now), want)
        free = want > execution.progress
        held = (execution.permitted_all() > execution.progress) & ~free
        holds_seen += int(held.sum())
        waits_seen += int(free.sum())
    assert holds_seen > 0 and waits_seen > 0  # robots held or waiting, and robots free


def test_the_grid_a_map_was_drawn_on_is_read_from_its_walls() -> None:
    """Axis-aligned walls with their corners on one lattice: the coarsest subdivision of
    it that holds the robots (cell >= s + d/2), centred in the cells; none for slanted
    walls or a drawing finer than the robots."""
    sc = mapf_scenario(MAP, 6, scen_path=SCEN, cell=0.5, diameter=0.3)
    grid = drawn_grid(sc.polygons, 0.321, 0.3)
    assert grid is not None and grid.cell == 0.5
    offset = (np.asarray(grid.origin) - np.asarray(sc.roadmap.origin)) / 0.5
    np.testing.assert_allclose(offset, np.round(offset), atol=1e-9)
    box = PolygonObstacle(((0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (0.0, 1.0)))
    one = drawn_grid([box], 0.3, 0.3)  # lattice 1 m: cells of 0.5 m (>= 0.45)
    assert one is not None and one.cell == 0.5 and one.origin == (0.25, 0.25)
    assert drawn_grid([box], 0.6, 0.6) is not None and drawn_grid([box], 0.6, 0.6).cell == 1.0
    assert drawn_grid([box], 0.8, 0.6) is None  # 1 m cannot be cut into cells >= 1.1 m
    slanted = PolygonObstacle(((0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (0.5, 1.0)))
    assert drawn_grid([box, slanted], 0.3, 0.3) is None
    fine = PolygonObstacle(((0.0, 0.0), (0.05, 0.0), (0.05, 1.0), (0.0, 1.0)))
    assert drawn_grid([box, fine], 0.3, 0.3) is None  # a 5 cm drawing: no cell holds them
    assert drawn_grid([], 0.3, 0.3) is None

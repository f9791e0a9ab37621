"""Maps: polygon obstacles (CONTRACT 1d), routes through the static map, the yield rule."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ScenarioError
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.kernels.polygons import path_keeps_pieces, polygon_rows
from sqpmpc.problem.polygons import PolygonObstacle, pack_pieces
from sqpmpc.problem.routes import RoadMap
from sqpmpc.problem.scenario_file import load_scenario, parse_scenario
from sqpmpc.rules.registry import rule_names, select_rules
from sqpmpc.sim.simulation import simulate

WALL = """
name = "wall"
t_end = 30.0
sample_time = 0.5
horizon = 8
[weights]
Q = [1.0, 1.0]
R = [0.5, 0.5]
[bounds]
v = [-0.6, 0.6]
omega = [-0.7853981633974483, 0.7853981633974483]
[[robots]]
id = 1
initial_state = [-2.0, 0.3, 0.0]
diameter = 0.3
reference = { type = "point", position = [2.0, 0.0] }
[[robots]]
id = 2
initial_state = [2.0, 2.2, 3.14]
diameter = 0.3
reference = { type = "point", position = [-2.0, 2.2] }
[[obstacles]]
points = [[-0.2, -1.0], [0.2, -1.0], [0.2, 1.0], [-0.2, 1.0]]
[[obstacles]]
position = [0.0, 3.2]
diameter = 0.4
"""

C_SHAPE = [[3, 0], [3, 3], [0, 3], [0, 0.5], [0.5, 0.5], [0.5, 2.5], [2.5, 2.5], [2.5, 0]]


def _wall(extra: str = "", **replace: str) -> dict:
    text = WALL + extra
    for old, new in replace.items():
        text = text.replace(old.replace("_", " "), new)
    return tomllib.loads(text)


def test_polygons_are_read_written_and_either_orientation_is_the_same_obstacle() -> None:
    sc = parse_scenario(_wall(), "wall.toml")
    assert len(sc.polygons) == 1 and len(sc.obstacles) == 1 and sc.obstacle_slots == 2
    assert parse_scenario(tomllib.loads(sc.to_toml())) == sc
    cw = PolygonObstacle([[0, 0], [0, 3], [3, 3], [3, 0]])
    ccw = PolygonObstacle([[0, 0], [3, 0], [3, 3], [0, 3]])
    assert [p.tolist() for p in cw.pieces] == [p.tolist() for p in ccw.pieces]
    c = PolygonObstacle(C_SHAPE)
    assert len(c.pieces) > 1  # non-convex: convex pieces that cover it exactly
    union = shapely.union_all([shapely.Polygon(p) for p in c.pieces])
    assert abs(union.area - c.shape.area) < 1e-9 and union.symmetric_difference(
        c.shape).area < 1e-9


@pytest.mark.parametrize(("points", "needle"), [
    ("[[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]",
     "obstacles[2].points: expected a simple polygon .* self-intersecting one near (0.5, 0.5)"),
    ("[[0.0, 0.0], [1.0, 1.0]]", "obstacles[2].points: expected an array of 3 to 128"),
    ("[[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]]", "obstacles[2].points: expected a simple "),
    ("[[-2.1, 0.0], [-1.9, 0.0], [-1.9, 1.0]]", "obstacles[2].points: polygon obstacle "
                                                "overlaps robot id 1"),
])
def test_bad_polygons_are_refused_naming_the_obstacle(points: str, needle: str) -> None:
    data = _wall(f"[[obstacles]]\npoints = {points}\n")
    with pytest.raises(ScenarioError, match=needle.replace("(", r"\(").replace(")", r"\)")
                       .replace("[", r"\[")):
        parse_scenario(data, "wall.toml")


def test_path_check_matches_the_true_distance() -> None:
    poly = PolygonObstacle(C_SHAPE)
    vertices, counts, _ = pack_pieces([poly])
    rng = np.random.default_rng(1)
    checked = 0
    for _ in range(400):
        a, b = rng.uniform(-1.0, 4.0, size=(2, 2))
        keep = 0.15
        if poly.signed_distance(a) < keep:
            continue
        checked += 1
        true = shapely.distance(poly.shape, shapely.LineString([a, b]))
        ok = path_keeps_pieces(a[0], a[1], b[0], b[1], vertices, counts,
                               np.full(counts.size, keep), 0.0)
        if ok:
            assert true >= keep - 1e-9
        elif true >= keep + 1e-6:
            # a false alarm only where a piece edge inside the polygon is near
            pieces_d = min(shapely.distance(shapely.Polygon(p), shapely.LineString([a, b]))
                           for p in poly.pieces)
            assert pieces_d < keep + 1e-6
    assert checked > 50


def test_rows_separate_the_whole_piece_and_stage_one_keeps_standing_still_feasible() -> None:
    poly = PolygonObstacle(C_SHAPE)
    vertices, counts, _ = pack_pieces([poly])
    rng = np.random.default_rng(2)
    N = 4
    rot = np.tile([1.0, 0.0], (N, 1))
    for _ in range(100):
        me = rng.uniform(-1.0, 4.0, size=2)
        if poly.signed_distance(me) < 0.2:
            continue
        own = np.column_stack((me + rng.normal(scale=0.5, size=(N, 2)), np.zeros(N)))
        A = np.empty((counts.size, N, 2))
        lo = np.empty((counts.size, N))
        polygon_rows(me, own, vertices, counts, np.full(counts.size, 0.2), rot, A, lo)
        assert np.allclose(np.hypot(A[..., 0], A[..., 1]), 1.0)
        for e in range(counts.size):
            piece = vertices[e, :counts[e]]
            # every point on a row's line is at least d from the piece: support + d
            assert np.all(lo[e, 1:] >= (A[e, 1:] @ piece.T).max(axis=1) + 0.2 - 1e-9)
            assert A[e, 0] @ me >= lo[e, 0] - 1e-9  # standing still satisfies stage 1


def test_route_goes_around_the_wall_and_a_walled_off_goal_has_none() -> None:
    sc = parse_scenario(_wall())
    road = RoadMap(sc.polygons, sc.obstacles, 0.15, 0.1)
    route = road.route(np.array([-2.0, 0.3]), np.array([2.0, 0.0]))
    assert route is not None and route.length > 4.0
    line = shapely.LineString(route.points)
    assert shapely.distance(sc.polygons[0].shape, line) >= 0.25 - 1e-6
    box = PolygonObstacle(C_SHAPE[:3] + [[0, 0]])  # the C closed: a solid square
    assert RoadMap([box], [], 0.15, 0.1).route(np.array([-1.0, -1.0]),
                                               np.array([1.5, 1.5])) is None


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_a_goal_behind_a_wall_is_reached_without_touching_it(scheme: str) -> None:
    sc = parse_scenario(_wall())
    m = compute_metrics(simulate(sc, scheme))
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0 and m["min_obstacle_clearance"] >= 0.0
    assert m["input_bound_violations"] == 0 and m["no_route"] == []
    assert m["max_final_position_error"] <= 0.05
    assert m["counters"]["route_plans"] >= 1
    without = compute_metrics(simulate(sc.with_changes(t_end=10.0), scheme,
                                       SolverSettings().without("route")))
    assert without["obstacle_collisions"] == 0 and "route_plans" not in without["counters"]


def test_a_walled_off_goal_is_reported() -> None:
    box = "[[obstacles]]\npoints = [[1.5, -0.5], [2.5, -0.5], [2.5, 0.5], [1.5, 0.5]]\n"
    data = _wall(box)
    data["robots"][0]["reference"]["position"] = [2.0, 0.0]  # inside the box
    sc = parse_scenario(data).with_changes(t_end=2.0)
    m = compute_metrics(simulate(sc, "decentralized"))
    assert m["no_route"] == [1] and m["obstacle_collisions"] == 0


def test_yield_and_route_are_rules_like_the_others() -> None:
    assert {"route", "yield"} <= set(rule_names())
    names = [r.name for r in select_rules(None, without=["yield", "route"])]
    assert "yield" not in names and "route" not in names


def test_built_in_maps() -> None:
    for name, robots in (("warehouse", 8), ("room-door", 2)):
        sc = load_scenario(name)
        assert sc.polygons and sc.n_robots >= robots
        road = RoadMap(sc.polygons, sc.obstacles, 0.15, 0.0)
        goals = sc.reference_positions(sc.t_end)
        blocked = [not road.free(p, g) for p, g in zip(sc.initial_states()[:, :2], goals,
                                                       strict=True)]
        assert any(blocked)  # some goal lies behind a wall
        assert all(road.route(p, g) is not None for p, g in
                   zip(sc.initial_states()[:, :2], goals, strict=True))
    assert math.isfinite(load_scenario("warehouse").t_end)


def test_every_view_draws_the_polygons(tmp_path) -> None:
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    from sqpmpc.io.animate import load_run, render_frames
    from sqpmpc.io.files import write_run

    sc = parse_scenario(_wall()).with_changes(t_end=2.0)
    metrics = write_run(tmp_path, simulate(sc, "decentralized"))
    assert metrics["obstacle_collisions"] == 0
    assert {"trajectories.png", "recording.mcap"} <= {p.name for p in tmp_path.iterdir()}
    run = load_run(tmp_path)  # from trajectory.npz alone
    assert len(run.polygons) == 1
    np.testing.assert_allclose(run.polygons[0], np.asarray(sc.polygons[0].points))
    assert next(render_frames(run, step=4)).ndim == 3
    factory = DecoderFactory()
    entities = set()
    with open(tmp_path / "recording.mcap", "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            if channel.topic == "/scene":
                scene = factory.decoder_for("protobuf", schema)(message.data)
                for e in scene.entities:
                    if e.id.startswith("polygon_"):
                        entities.add(e.id)
                        assert len(e.triangles[0].points) % 3 == 0 and e.lines
    assert entities == {"polygon_0"}


@settings(max_examples=150, deadline=None)
@given(st.lists(st.one_of(st.lists(st.floats(-1e6, 1e6) | st.floats(), min_size=0,
                                   max_size=3), st.integers(), st.text(max_size=3)),
                max_size=8))
def test_any_points_value_is_a_polygon_or_one_scenario_error(points: list) -> None:
    data = _wall()
    data["obstacles"].append({"points": points})
    try:
        sc = parse_scenario(data, "fuzz.toml")
    except ScenarioError as exc:
        assert exc.key.startswith("obstacles[2]")
    else:
        assert len(sc.polygons) == 2 and all(len(p) >= 3 for p in sc.polygons[1].pieces)


def test_a_many_sided_non_convex_polygon_is_split_quickly() -> None:
    angles = np.linspace(0.0, 2.0 * np.pi, 128, endpoint=False)
    radius = np.where(np.arange(128) % 2, 1.0, 2.0)  # a star
    star = PolygonObstacle(np.column_stack((radius * np.cos(angles),
                                            radius * np.sin(angles))).tolist())
    union = shapely.union_all([shapely.Polygon(p) for p in star.pieces])
    assert union.symmetric_difference(star.shape).area < 1e-9


def _shaped(rule, v) -> np.ndarray:
    """The references after a rule's ``references`` hook (its contribution, if any)."""
    c = rule.shape_references(v)
    return v.references if c is None or c.references is None else c.references


def test_a_robot_pressed_against_a_wall_backs_away_then_goes_on() -> None:
    from sqpmpc.control.centralized import CentralizedController
    from tests.rule_helpers import only, view

    data = _wall()
    data["robots"][0]["initial_state"] = [-0.36, 0.0, 0.0]  # 0.01 m off the wall, facing it
    sc = parse_scenario(data)
    ctrl = CentralizedController(sc, only("route"))
    (rule,) = ctrl.rules
    states = sc.initial_states()
    for sample in range(rule.rule.pinned_samples):
        refs = _shaped(rule, view(ctrl, states, sample=sample))
    # pinned: heads straight away from the wall (-x) for escape_samples samples
    np.testing.assert_allclose(refs[0], [[-0.36 - rule.rule.escape_distance, 0.0]]
                               * sc.horizon, atol=1e-9)
    assert rule.counters()["wall_escapes"] == 1
    for sample in range(rule.rule.escape_samples):
        refs = _shaped(rule, view(ctrl, states, sample=10 + sample))
    assert not np.allclose(refs[0, -1], [-0.76, 0.0])  # then its route again
    moving = view(ctrl, states, applied=np.array([[0.3, 0.0], [0.0, 0.0]]), sample=20)
    for _ in range(2 * rule.rule.pinned_samples):  # a moving robot is never pinned
        rule.shape_references(moving)
    assert rule.counters()["wall_escapes"] == 1


def test_an_arrived_robot_steps_aside_for_a_traveller_and_returns() -> None:
    from sqpmpc.control.centralized import CentralizedController
    from tests.rule_helpers import fleet, only, view

    sc = fleet([[2.0, 0.05, 0.0], [1.0, 0.0, 0.0]], [[2.0, 0.05], [4.0, 0.0]])
    ctrl = CentralizedController(sc, only("yield"))
    (rule,) = ctrl.rules
    refs = _shaped(rule, view(ctrl, sc.initial_states()))
    keep = 0.3 + rule.rule.clearance
    # robot 1 sits 0.05 m left of robot 2's way: it moves to keep left of it
    np.testing.assert_allclose(refs[0], [[2.0, keep]] * sc.horizon, atol=1e-9)
    np.testing.assert_allclose(refs[1], [[4.0, 0.0]] * sc.horizon)
    far = sc.initial_states()
    far[1, :2] = [4.0, 0.0]  # the traveller arrived too: nobody in the way any more
    for _ in range(rule.rule.hold + 1):
        refs = _shaped(rule, view(ctrl, far))
    np.testing.assert_allclose(refs[0], [[2.0, 0.05]] * sc.horizon)
    assert rule.counters()["yield_starts"] == 1


def test_assign_slots_keeps_chosen_obstacles_in_their_slots_nearest_first() -> None:
    from sqpmpc.ocp.obstacle_rows import assign_slots

    gaps = np.array([0.5, -0.1, -0.3, -0.2, -0.05])  # 1..4 within reach
    first = assign_slots(gaps, np.full(3, -1))
    np.testing.assert_array_equal(first, [2, 3, 1])  # the 3 nearest, nearest first
    gaps = np.array([-0.4, -0.1, 0.2, -0.2, -0.05])  # 2 out of reach, 0 the nearest now
    again = assign_slots(gaps, first)
    np.testing.assert_array_equal(again, [0, 3, 1])  # 3 and 1 keep their slots
    np.testing.assert_array_equal(assign_slots(np.ones(5), again), [-1, -1, -1])


def test_rows_by_reach_equal_every_row_when_the_nearby_pieces_fit(monkeypatch) -> None:
    """A robot among 36 boxes, 8 slots: the same first input as with a row per box (the
    far boxes' rows are never active), and the QP has 8 obstacle slots instead of 36."""
    import sqpmpc.ocp.obstacle_rows as rows
    from sqpmpc.qp.backend import OSQPSettings
    from sqpmpc.sim.simulation import ClosedLoopSimulation

    boxes = [[[x - 0.2, y - 0.2], [x + 0.2, y - 0.2], [x + 0.2, y + 0.2], [x - 0.2, y + 0.2]]
             for x in np.arange(6) * 1.5 + 0.75 for y in np.arange(6) * 1.5 + 0.75]
    sc = parse_scenario({
        "name": "boxes", "t_end": 0.5, "sample_time": 0.5, "horizon": 6,
        "weights": {"Q": [1.0, 1.0], "R": [0.5, 0.5]}, "bounds": {"v": [-0.6, 0.6],
                                                               "omega": [-0.785, 0.785]},
        "robots": [{"id": 1, "initial_state": [0.0, 1.3, 0.0], "diameter": 0.3,
                    "reference": {"type": "point", "position": [9.0, 1.5]}}],
        "obstacles": [{"points": b} for b in boxes]}, "boxes.toml")
    runs = {}
    tight = SolverSettings(qp_solver="piqp", osqp=OSQPSettings(eps_abs=1e-9, eps_rel=1e-9))
    for slots in (8, None):
        monkeypatch.setattr(rows, "OBSTACLE_SLOTS", slots)
        sim = ClosedLoopSimulation(sc, "centralized", tight)
        runs[slots] = (sim.run(), sim.controllers[0].engine.qp.layout.n_external)
        if slots:  # the premise: every box within reach had a slot (some stayed empty)
            assert np.any(sim.controllers[0].obstacle_rows.polygons.slot_pieces < 0)
    assert runs[8][1] == 8 and runs[None][1] == 36
    # the first sample's converged SQP (30 iterations at most) to the QPs' tolerance
    np.testing.assert_allclose(runs[8][0].inputs, runs[None][0].inputs, atol=1e-5)

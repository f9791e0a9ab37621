"""Obstacle rows by reach (issue 34): polygon pieces selected per stage by what the
horizon can reach, behind-a-row pieces shadowed, none dropped.

Three kinds of test: a property test on random maps and poses (every piece within
reach is kept by the stage's rows, checked against shapely's distances), the QP
updated in place against its rebuild with the selection on, and closed loops
through a field of boxes (no collision at or between samples, arrival).
"""

from __future__ import annotations

import numpy as np
import pytest
import qpsolvers
import scipy.sparse as sp
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

import sqpmpc.ocp.obstacle_rows as obstacle_rows
import sqpmpc.ocp.polygon_rows as polygon_rows
from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.kernels.polygons import support
from sqpmpc.ocp.geometry import RowGeometry
from sqpmpc.ocp.polygon_rows import PolygonRows
from sqpmpc.problem.polygons import PolygonObstacle
from sqpmpc.problem.scenario_file import parse_scenario
from sqpmpc.qp.backend import OSQPSettings
from sqpmpc.sim.simulation import ClosedLoopSimulation

N = 6
RADIUS, MARGIN = 0.15, 0.02


def _random_map(rng: np.random.Generator, n: int) -> list[PolygonObstacle]:
    """``n`` random convex polygons (hulls of random points) in a 6 m square."""
    out = []
    for _ in range(n):
        centre = rng.uniform(-3.0, 3.0, 2)
        points = centre + rng.uniform(-0.4, 0.4, (rng.integers(3, 7), 2))
        hull = shapely.convex_hull(shapely.MultiPoint(points))
        if hull.geom_type != "Polygon" or hull.area < 1e-3:
            hull = shapely.box(*(centre - 0.1), *(centre + 0.1))
        out.append(PolygonObstacle(np.asarray(hull.exterior.coords)[:-1]))
    return out


def _rows(polygons: list[PolygonObstacle], slots: int | None, reach: float) -> PolygonRows:
    return PolygonRows(polygons, np.array([2 * RADIUS]), N, RowGeometry.plain(N), MARGIN,
                       slots, reach)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 40), slots=st.integers(1, 6),
       reach=st.floats(0.05, 0.6))
def test_every_piece_within_reach_is_kept_by_the_stage_rows(seed: int, n: int, slots: int,
                                                            reach: float) -> None:
    """Random maps, poses and iterates: at every stage, every point that keeps the
    slots' rows keeps its distance from every piece within reach (shapely's distance,
    independent of the kernels), whether the piece has a slot, lies behind a chosen
    row or was covered by a raised row (overflow)."""
    rng = np.random.default_rng(seed)
    polygons = _random_map(rng, n)
    pieces = [shapely.Polygon(p) for poly in polygons for p in poly.pieces]
    rows = _rows(polygons, slots, reach)
    if not rows.selecting:
        return
    p0 = rng.uniform(-3.0, 3.0, 2)
    if min(piece.distance(shapely.Point(p0)) for piece in pieces) < RADIUS + MARGIN:
        p0 = np.array([5.0, 5.0])  # outside every piece
    states = np.zeros((1, N + 1, 3))
    states[0, 0, :2] = p0
    steps = rng.normal(0.0, reach, (N, 2))  # an iterate, at times beyond the reach
    states[0, 1:, :2] = p0 + np.cumsum(steps, axis=0)
    rows.set_sample(0.0, states[:, 0])
    K = rows.n_obstacles
    A = np.zeros((1, K, N, 2))
    lower = np.zeros((1, K, N))
    rows.write_rows(states, A, lower)
    required = RADIUS + MARGIN
    start = np.array([piece.distance(shapely.Point(p0)) for piece in pieces])
    # the candidates: every piece within the horizon's reach, and no other
    gap = start - required - rows.stage_reach[-1]
    cand = set(rows.candidates[0].tolist())
    assert set(np.flatnonzero(gap <= -1e-9).tolist()) <= cand
    assert cand <= set(np.flatnonzero(gap <= 1e-9).tolist())
    box = rng.uniform(-1.0, 1.0, (3000, 2)) * (reach * (N + 2) + 1.0) + p0
    for i in range(N):
        on = np.isfinite(lower[0, :, i])
        # each slot's row is its piece's (or a raised one): it keeps every slot piece
        for s in np.flatnonzero(on):
            e = rows.slot_pieces[0, s, i]
            verts = rows.vertices[e, :rows.counts[e]]
            assert support(A[0, s, i, 0], A[0, s, i, 1], verts, verts.shape[0]) + required \
                <= lower[0, s, i] + 1e-9 or i == 0  # stage 1 is capped at standing still
        if i == 0:
            continue
        keeps = np.all(box @ A[0, on, i].T >= lower[0, on, i] - 1e-12, axis=1)
        within = np.flatnonzero(start - required <= rows.stage_reach[i] - 1e-9)
        for e in within:
            d = shapely.distance(pieces[e], shapely.points(box[keeps]))
            assert d.size == 0 or d.min() >= required - 1e-7, (i, e)
            verts = rows.vertices[e, :rows.counts[e]]
            implied = [support(A[0, s, i, 0], A[0, s, i, 1], verts, verts.shape[0]) + required
                       <= lower[0, s, i] + 1e-9 for s in np.flatnonzero(on)]
            assert any(implied), f"stage {i + 1}: piece {e} within reach left without a row"


def test_the_k_d_tree_finds_the_same_candidates(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(3)
    polygons = _random_map(rng, 60)
    scan = _rows(polygons, 4, 0.3)
    monkeypatch.setattr(polygon_rows, "TREE_PIECES", 10)
    tree = _rows(polygons, 4, 0.3)
    assert tree.indexed and not scan.indexed
    for _ in range(50):
        pose = np.array([[*rng.uniform(-4.0, 4.0, 2), 0.0]])
        scan.set_sample(0.0, pose)
        tree.set_sample(0.0, pose)
        np.testing.assert_array_equal(np.sort(tree.candidates[0]), np.sort(scan.candidates[0]))


def test_first_input_check_by_candidates_equals_the_check_of_every_piece() -> None:
    """Exact: a path within the reach needs the candidates only; beyond it, every piece."""
    rng = np.random.default_rng(5)
    polygons = _random_map(rng, 40)
    selecting, every = _rows(polygons, 3, 0.2), _rows(polygons, None, 0.2)
    assert selecting.selecting and not every.selecting
    verdicts = set()
    for _ in range(400):
        p0 = rng.uniform(-3.0, 3.0, 2)
        pose = np.array([[*p0, 0.0]])
        selecting.set_sample(0.0, pose)
        every.set_sample(0.0, pose)
        nxt = p0 + rng.normal(0.0, rng.choice([0.1, 0.5, 2.0]), 2)
        growth = np.array([rng.uniform(0.0, 0.3)])
        got = selecting.first_input_safe(p0[None], nxt[None], growth)
        assert got == every.first_input_safe(p0[None], nxt[None], growth)
        verdicts.add(got)
    assert verdicts == {True, False}


def test_slots_below_one_are_refused() -> None:
    with pytest.raises(ProblemError, match="slots"):
        _rows(_random_map(np.random.default_rng(0), 3), 0, 0.3)


# ---------------------------------------------------------------- scenarios: a box field
def _field(robots: list[dict], boxes: int = 6, t_end: float = 30.0) -> object:
    """``boxes x boxes`` boxes of 0.5 m, 1 m apart (0.5 m corridors)."""
    h = 0.25
    walls = [{"points": [[x - h, y - h], [x + h, y - h], [x + h, y + h], [x - h, y + h]]}
             for x in np.arange(boxes) + 0.5 for y in np.arange(boxes) + 0.5]
    return parse_scenario({
        "name": "box field", "t_end": t_end, "sample_time": 0.5, "horizon": N,
        "weights": {"Q": [1.0, 1.0], "R": [0.5, 0.5]},
        "bounds": {"v": [-0.6, 0.6], "omega": [-0.7853981633974483, 0.7853981633974483]},
        "robots": robots, "obstacles": walls}, "box-field.toml")


def _crossing(boxes: int = 6) -> list[dict]:
    end = boxes + 0.6
    robots = []
    for lane in (1.0, 3.0):
        for start, goal in (([-0.6, lane, 0.0], [end, lane]),
                            ([lane, -0.6, np.pi / 2], [lane, end])):
            robots.append({"id": len(robots) + 1, "initial_state": start, "diameter": 0.3,
                           "reference": {"type": "point", "position": goal}})
    return robots


def test_qp_updated_in_place_equals_its_rebuild_with_the_selection_on(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """A robot through the field with 3 slots per stage (36 pieces): every sample the QP's
    obstacle rows are the rows the selection wrote (slots filled, emptied, refilled), the
    backend is set up once, and its in-place solve equals an interior-point solve of the
    QP rebuilt from the matrices."""
    monkeypatch.setattr(obstacle_rows, "OBSTACLE_SLOTS", 3)
    sc = _field([{"id": 1, "initial_state": [-0.6, 1.0, 0.0], "diameter": 0.3,
                  "reference": {"type": "point", "position": [6.6, 3.0]}}], t_end=8.0)
    tight = SolverSettings(qp_solver="osqp", osqp=OSQPSettings(
        eps_abs=1e-9, eps_rel=1e-9, max_iter=100000, polishing=True, rescue_solver=None))
    sim = ClosedLoopSimulation(sc, "decentralized", tight)
    ctrl = sim.controllers[0]
    engine, layout = ctrl.engine, ctrl.engine.qp.layout
    rows = ctrl.obstacle_rows.polygons
    assert rows.selecting and rows.n_obstacles == 3
    first = layout.n_external - 3  # the neighbour slots come first
    seen = set()
    for _ in range(sc.steps):
        sim.step()
        seen.add(tuple(np.unique(rows.slot_pieces[0])))
        P, q, A, lo, up = engine.qp.matrices()
        written_A, written_lower = engine.collision_blocks()["external"]
        A = A.toarray()
        pos = layout.state_index[0, 1:, :2]  # (N, 2)
        for s in range(3):
            for i in range(N):
                r = layout.external_rows[0, first + s, i]
                np.testing.assert_array_equal(A[r, pos[i]], written_A[0, first + s, i])
                assert lo[r] == written_lower[0, first + s, i] or (
                    lo[r] <= -1e20 and np.isinf(written_lower[0, first + s, i]))
        assert engine.qp.backend.setup_count == 1
    assert len(seen) > 3  # the slots changed hands along the way
    res = engine.qp.solve()
    assert res.success
    G = sp.vstack((-sp.csc_matrix(A), sp.csc_matrix(A))).tocsc()
    h = np.concatenate((-lo, up))
    keep = np.isfinite(h) & (np.abs(h) < 1e20)
    ref = qpsolvers.solve_problem(qpsolvers.Problem(
        (P + sp.triu(P, 1).T).tocsc(), q, G=G[keep], h=h[keep]), solver="clarabel")
    assert ref.found
    np.testing.assert_allclose(res.x, ref.x, atol=2e-5)


@pytest.mark.parametrize("scheme", ["decentralized", "centralized"])
def test_closed_loop_through_the_field_keeps_every_box_and_arrives(
        monkeypatch: pytest.MonkeyPatch, scheme: str) -> None:
    """Four robots across 36 boxes with 3 slots per stage: no collision with a box or a
    robot at or between samples, no overflow, every robot home."""
    monkeypatch.setattr(obstacle_rows, "OBSTACLE_SLOTS", 3)
    sc = _field(_crossing(), t_end=35.0)
    sim = ClosedLoopSimulation(sc, scheme)
    record = sim.run()
    m = compute_metrics(record)
    polys = [c.obstacle_rows.polygons for c in sim.controllers]
    assert all(p.selecting and p.n_obstacles == 3 for p in polys)
    assert m["obstacle_collisions"] == 0 and m["collisions"] == 0
    assert m["min_obstacle_clearance"] > 0.0
    assert m["all_arrived"], m["final_position_error"]

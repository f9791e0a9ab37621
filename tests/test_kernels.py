"""The compiled kernels (model, QP and collision) against the NumPy reference implementations
of the same maths."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from sqpmpc.kernels import collision as collision_kernels
from sqpmpc.kernels import ocp as kernels
from sqpmpc.kernels.rules import inside_pairs
from sqpmpc.models.unicycle import discrete_dynamics, discrete_jacobians, rollout
from sqpmpc.problem.paths import segment_distances
from sqpmpc.qp.layout import A_PATTERN, B_PATTERN, QPLayout

RNG = np.random.default_rng(7)


def _states_inputs(m: int, N: int) -> tuple[np.ndarray, np.ndarray]:
    x = RNG.normal(size=(m, N + 1, 3))
    u = RNG.normal(size=(m, N, 2))
    return x, u


def test_euler_step_and_rollout_match_the_model() -> None:
    x, u = _states_inputs(3, 7)
    out = np.empty((3, 3))
    kernels.euler_step(x[:, 0], u[:, 0], 0.3, out)
    np.testing.assert_allclose(out, discrete_dynamics(x[:, 0], u[:, 0], 0.3), rtol=0,
                               atol=1e-14)
    traj = np.empty((3, 8, 3))
    kernels.euler_rollout(np.ascontiguousarray(x[:, 0]), u, 0.3, traj)
    ref = np.swapaxes(rollout(x[:, 0], np.swapaxes(u, 0, 1), 0.3), 0, 1)
    np.testing.assert_allclose(traj, ref, rtol=0, atol=1e-12)
    # stage 1 of a rollout is exactly one step (what the plant applies)
    np.testing.assert_array_equal(traj[:, 1], out)


def test_euler_linearization_writes_the_jacobians_of_the_model() -> None:
    m, N, h = 2, 5, 0.4
    layout = QPLayout(m, N)
    x, u = _states_inputs(m, N)
    z = layout.join_primal(x, u)
    dyn_A, dyn_B = np.empty(m * N * 5), np.empty(m * N * 5)
    lo, up = np.empty(m * N * 3), np.empty(m * N * 3)
    kernels.euler_linearize(z, m, N, layout.block_size, h, dyn_A, dyn_B, lo, up)
    nxt, A_k, B_k = discrete_jacobians(x[:, :N], u, h)
    np.testing.assert_allclose(-dyn_A.reshape(m, N, 5), A_k[:, :, A_PATTERN[0], A_PATTERN[1]],
                               rtol=0, atol=1e-14)
    np.testing.assert_allclose(-dyn_B.reshape(m, N, 5), B_k[:, :, B_PATTERN[0], B_PATTERN[1]],
                               rtol=0, atol=1e-14)
    c = (nxt - np.einsum("mnij,mnj->mni", A_k, x[:, :N]) - np.einsum("mnij,mnj->mni", B_k, u))
    np.testing.assert_allclose(lo.reshape(m, N, 3), c, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(lo, up)


def test_pair_rows_are_unit_normals_and_keep_stopping_feasible() -> None:
    m, N = 4, 6
    states = RNG.normal(scale=2.0, size=(m, N + 1, 3))
    now = np.ascontiguousarray(states[:, 0, :2])
    pairs = np.array([[0, 1], [0, 2], [1, 3], [2, 3]], dtype=np.int64)
    required = np.full(4, 0.5)
    rotation = np.tile([np.cos(0.3), np.sin(0.3)], (N, 1))
    A, lo = np.empty((4, N, 4)), np.empty((4, N))
    collision_kernels.pair_rows(pairs, now, states, required, rotation, 0.6, A, lo,
                                np.empty((N, 2)), np.full(pairs.shape[0], N, dtype=np.int64))
    np.testing.assert_allclose(np.hypot(A[..., 0], A[..., 1]), 1.0, atol=1e-12)
    np.testing.assert_array_equal(A[..., 2:], -A[..., :2])
    # standing still satisfies stage 1 (the stage-one-override safety row)
    gap = now[pairs[:, 0]] - now[pairs[:, 1]]
    assert np.all(np.einsum("pi,pi->p", A[:, 0, :2], gap) >= lo[:, 0] - 1e-12)


def test_pairs_keep_distance_is_the_segment_distance() -> None:
    now = RNG.normal(size=(5, 2))
    nxt = now + RNG.normal(scale=0.5, size=(5, 2))
    pairs = np.array([[i, j] for i in range(5) for j in range(i + 1, 5)], dtype=np.int64)
    d = segment_distances(now[pairs[:, 0]] - now[pairs[:, 1]],
                          nxt[pairs[:, 0]] - nxt[pairs[:, 1]])
    zero = np.zeros(5)
    assert collision_kernels.pairs_keep_distance(pairs, now, nxt, d - 1e-9, zero)
    worst = int(np.argmin(d))
    assert not collision_kernels.pairs_keep_distance(pairs[worst:worst + 1], now, nxt,
                                                     d[worst:worst + 1] + 1e-9, zero)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kkt_residual_kernel_matches_the_formula(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n, k, nnz = 6, 5, 12
    rows, cols = rng.integers(0, k, nnz), rng.integers(0, n, nnz)
    vals = rng.normal(size=nnz)
    z, y = rng.normal(size=n), rng.normal(size=k)
    lo, up = rng.normal(size=k) - 1.0, rng.normal(size=k) + 1.0
    lo[0], up[1] = -np.inf, np.inf
    P, q = rng.uniform(0.1, 1, size=n), rng.normal(size=n)
    Az = np.bincount(rows, vals * z[cols], minlength=k)
    ATy = np.bincount(cols, vals * y[rows], minlength=n)
    stat = np.abs(P * z + q + ATy).max()
    prim = np.maximum(np.maximum(lo - Az, Az - up), 0.0).max()
    comp = max(np.where((y < 0) & np.isfinite(lo), np.abs(y * (Az - lo)), 0).max(),
               np.where((y > 0) & np.isfinite(up), np.abs(y * (up - Az)), 0).max())
    wrong = max(np.where((y < 0) & ~np.isfinite(lo), -y, 0).max(),
                np.where((y > 0) & ~np.isfinite(up), y, 0).max())
    got = kernels.kkt_residual(vals, rows.astype(np.int64), cols.astype(np.int64), z, y, lo,
                               up, P, q, np.empty(k), np.empty(n))
    assert got == pytest.approx(max(stat, prim, comp, wrong), rel=1e-12)  # |y| small: s = 1
    # multipliers of mean size 1000 (s = 10): stationarity and complementarity over s only
    big = y * (1000.0 * k / np.abs(y).sum())
    ATy = np.bincount(cols, vals * big[rows], minlength=n)
    stat = np.abs(P * z + q + ATy).max()
    comp = max(np.where((big < 0) & np.isfinite(lo), np.abs(big * (Az - lo)), 0).max(),
               np.where((big > 0) & np.isfinite(up), np.abs(big * (up - Az)), 0).max())
    wrong = max(np.where((big < 0) & ~np.isfinite(lo), -big, 0).max(),
                np.where((big > 0) & ~np.isfinite(up), big, 0).max())
    got = kernels.kkt_residual(vals, rows.astype(np.int64), cols.astype(np.int64), z, big, lo,
                               up, P, q, np.empty(k), np.empty(n))
    scale = 1000.0 / kernels.MULTIPLIER_SCALE
    assert got == pytest.approx(max(stat / scale, prim, comp / scale, wrong), rel=1e-12)


def test_kkt_residual_never_scales_the_primal_violation() -> None:
    # z0 >= 0.5 active with a multiplier of 1e6 (s = 5000), z1 >= 0.5 violated by 0.5
    vals, rows, cols = np.ones(2), np.arange(2), np.arange(2)
    z, y = np.array([0.5, 0.0]), np.array([-1e6, 0.0])
    lo, up = np.full(2, 0.5), np.full(2, np.inf)
    q = np.array([1e6, 0.0])  # stationary: q + A^T y = 0
    got = kernels.kkt_residual(vals, rows, cols, z, y, lo, up, np.zeros(2), q, np.empty(2),
                               np.empty(2))
    assert got == 0.5


def test_euler_defect_is_zero_on_a_rollout_and_counts_the_initial_state() -> None:
    m, N, h = 2, 4, 0.2
    layout = QPLayout(m, N)
    x, u = _states_inputs(m, N)
    x = np.swapaxes(rollout(x[:, 0], np.swapaxes(u, 0, 1), h), 0, 1)
    z = layout.join_primal(x, u)
    x0 = np.ascontiguousarray(x[:, 0])
    assert kernels.euler_defect_l1(z, x0, m, N, layout.block_size, h) == pytest.approx(
        0.0, abs=1e-12)
    shifted = x0 + 0.1
    assert kernels.euler_defect_l1(z, shifted, m, N, layout.block_size, h) == pytest.approx(
        0.6, abs=1e-12)


def test_all_finite() -> None:
    assert kernels.all_finite(np.zeros(4))
    assert not kernels.all_finite(np.array([0.0, np.nan]))
    assert not kernels.all_finite(np.array([np.inf, 0.0]))


@pytest.mark.parametrize("seed", range(5))
def test_nearest_within_matches_a_stable_sort_of_the_distances(seed: int) -> None:
    rng = np.random.default_rng(seed)
    positions = rng.uniform(-5.0, 5.0, (30, 2))
    positions[7] = positions[3]  # a tie: the stable order keeps 3 before 7
    others = np.array([i for i in range(30) if i != 0])
    radius = rng.uniform(2.0, 6.0, others.size)
    dist = np.hypot(*(positions[others] - positions[0]).T)
    near = np.flatnonzero(dist <= radius)
    expected = near[np.argsort(dist[near], kind="stable")]
    for slots in (0, 3, 8, 40):
        chosen = np.full(min(slots, others.size), -1, dtype=np.int64)
        rest = np.full(others.size, -1, dtype=np.int64)
        used, extra = collision_kernels.nearest_within(positions[0], positions, others, radius,
                                                       chosen, rest)
        assert used + extra == expected.size
        np.testing.assert_array_equal(np.concatenate([chosen[:used], rest[:extra]]), expected)


def _select_pairs_reference(pairs: np.ndarray, positions: np.ndarray, radius: np.ndarray,
                            slots: int, horizon: int) -> np.ndarray:
    dist = np.hypot(*(positions[pairs[:, 0]] - positions[pairs[:, 1]]).T)
    stages = np.where(dist <= radius, 1, 0)
    for r in range(positions.shape[0]):
        mine = np.flatnonzero(((pairs == r).any(axis=1)) & (dist <= radius))
        stages[mine[np.argsort(dist[mine], kind="stable")][:slots]] = horizon
    return stages


@pytest.mark.parametrize("seed", range(4))
def test_select_pairs_gives_each_robot_its_nearest_pairs_and_stage_one_to_the_rest(
        seed: int) -> None:
    rng = np.random.default_rng(seed)
    m, N = 12, 6
    positions = rng.uniform(-4.0, 4.0, (m, 2))
    pairs = np.array([(a, b) for a in range(m) for b in range(a + 1, m)], dtype=np.int64)
    radius = rng.uniform(2.0, 5.0, pairs.shape[0])
    for slots in (1, 3, 20):
        stages = np.full(pairs.shape[0], -1, dtype=np.int64)
        full, first = collision_kernels.select_pairs(pairs, positions, radius, slots, N, stages)
        np.testing.assert_array_equal(
            stages, _select_pairs_reference(pairs, positions, radius, slots, N))
        assert (full, first) == (np.count_nonzero(stages == N), np.count_nonzero(stages == 1))


def test_pair_rows_beyond_their_stages_are_off() -> None:
    m, N = 3, 5
    states = RNG.normal(scale=2.0, size=(m, N + 1, 3))
    now = np.ascontiguousarray(states[:, 0, :2])
    pairs = np.array([[0, 1], [0, 2], [1, 2]], dtype=np.int64)
    rotation = np.tile([1.0, 0.0], (N, 1))
    A, lo = np.full((3, N, 4), 7.0), np.full((3, N), 7.0)
    collision_kernels.pair_rows(pairs, now, states, np.full(3, 0.5), rotation, -1.0, A, lo,
                      np.empty((N, 2)), np.array([N, 1, 0], dtype=np.int64))
    assert np.all(np.isfinite(lo[0])) and np.all(A[0, :, :2] != 0.0)
    assert np.isfinite(lo[1, 0]) and np.all(A[1, 0] != 0.0)
    np.testing.assert_array_equal(A[1, 1:], 0.0)
    np.testing.assert_array_equal(A[2], 0.0)
    assert np.all(lo[1, 1:] == -np.inf) and np.all(lo[2] == -np.inf)


@pytest.mark.parametrize("seed", range(3))
def test_segment_keeps_distance_is_the_segment_distance_test(seed: int) -> None:
    rng = np.random.default_rng(seed)
    points = rng.uniform(-2.0, 2.0, (40, 2))
    for _ in range(20):
        a, b = rng.uniform(-2.0, 2.0, 2), rng.uniform(-2.0, 2.0, 2)
        if _ % 5 == 0:
            b = a.copy()  # standing still: the point distance
        keep = rng.uniform(0.1, 1.0, points.shape[0])
        expected = bool(np.all(segment_distances(a - points, b - points) >= keep - 1e-12))
        assert collision_kernels.segment_keeps_distance(a[0], a[1], b[0], b[1], points, keep,
                                                        1e-12, 0.0) == expected


def test_split_rows_gives_piqp_equalities_inequalities_and_off_rows() -> None:
    rng = np.random.default_rng(3)
    n_rows = 6
    A = sp.random(n_rows, 5, density=0.6, random_state=4, format="csr")
    A.data[:] = rng.normal(size=A.nnz)
    lower = np.array([1.0, -np.inf, -2.0, -np.inf, 0.5, -3.0])
    upper = np.array([1.0, np.inf, 4.0, 7.0, 0.5, 1e25])
    eq_rows, ineq_rows = np.array([0, 4]), np.array([1, 2, 3, 5])
    ids = sp.csr_matrix((np.arange(1, A.nnz + 1, dtype=float), A.nonzero()), shape=A.shape)
    A_eq_ids, G_ids = ids[eq_rows].tocsc(), ids[ineq_rows].tocsc()
    eq_entries = A_eq_ids.data.astype(np.int64) - 1
    g_entries = G_ids.data.astype(np.int64) - 1
    values = A.tocoo()
    entry_values = np.zeros(A.nnz)
    order = np.lexsort((values.col, values.row))  # ids were numbered in this order
    entry_values[:] = values.data[order]
    A_eq_data, G_data = np.zeros(eq_entries.size), np.zeros(g_entries.size)
    b, h_l, h_u = np.zeros(2), np.zeros(4), np.zeros(4)
    kernels.split_rows(entry_values, lower, upper, eq_entries, g_entries,
                       G_ids.indices.astype(np.int64), eq_rows, ineq_rows, 1e20, 1e30,
                       A_eq_data, G_data, b, h_l, h_u)
    np.testing.assert_array_equal(b, [1.0, 0.5])
    np.testing.assert_array_equal(h_l, [-1.0, -2.0, -1e30, -3.0])
    np.testing.assert_array_equal(h_u, [1.0, 4.0, 7.0, 1e25])
    np.testing.assert_array_equal(A_eq_data, entry_values[eq_entries])
    off = G_ids.indices == 0  # row 1 of the QP: free on both sides
    np.testing.assert_array_equal(G_data[off], 0.0)
    np.testing.assert_array_equal(G_data[~off], entry_values[g_entries][~off])


@pytest.mark.parametrize("seed", range(4))
def test_growing_segment_distance_is_the_brute_force_minimum(seed: int) -> None:
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, 20001)
    for case in range(200):
        r0 = rng.normal(size=2) * rng.uniform(0.01, 2.0)
        d = rng.normal(size=2) * rng.uniform(0.0, 2.0)
        if case % 7 == 0:
            d = -r0 * rng.uniform(0.5, 2.0)  # through (or towards) the origin
        growth = [0.0, rng.uniform(0.0, 0.2), rng.uniform(0.0, 3.0)][case % 3]
        brute = (np.hypot(*(r0[:, None] + s * d[:, None])) - growth * s).min()
        got = collision_kernels.growing_segment_distance(r0[0], r0[1], d[0], d[1], growth)
        assert got <= brute + 1e-12  # never optimistic
        assert got >= brute - 2e-4   # and exact up to the grid (kinks at the origin)


@pytest.mark.parametrize("seed", range(3))
def test_halfplanes_hold_path_is_the_brute_force_test(seed: int) -> None:
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, 4001)
    for _ in range(300):
        n = rng.normal(size=(3, 2))
        n /= np.hypot(n[:, 0], n[:, 1])[:, None]
        p0, p1 = rng.normal(size=2), rng.normal(size=2)
        rhs = n @ p0 - rng.uniform(0.0, 0.5, 3)  # p0 inside every half-plane
        alpha = rng.uniform(-0.2, 0.3)
        beta = rng.uniform(-0.3, 0.3)
        if alpha < 0 or alpha + beta < 0:  # the bound must be >= 0 on [0, 1]
            alpha = abs(alpha) + abs(beta)
        bound = alpha * s + beta * s * (1 - s)
        path = (1 - s)[:, None] * p0 + s[:, None] * p1  # (S, 2)
        margin = (path @ n.T - rhs) - bound[:, None]  # worst case: strays against n
        expected = bool(margin[1:].min() >= -1e-9)
        got = collision_kernels.halfplanes_hold_path(n, rhs, p0[0], p0[1], p1[0], p1[1],
                                                     alpha, beta, 1e-9)
        if got != expected:  # only a grid point away from the boundary may differ
            assert abs(margin[1:].min()) < 1e-6


@pytest.mark.parametrize("seed", range(3))
def test_box_heading_and_overlap_kernels_match_their_numpy_expressions(seed: int) -> None:
    rng = np.random.default_rng(seed)
    low, high = np.array([-1.0, -2.0]), np.array([1.0, 2.0])
    for _ in range(50):
        points = rng.uniform(-1.3, 1.3, size=(3, 2)) * [1.0, 2.0]
        if rng.random() < 0.1:
            points[rng.integers(3), rng.integers(2)] = np.nan
        expected = bool(((points >= low) & (points <= high)).all())
        assert kernels.within_box(points, low, high) is expected
        plan = np.zeros((3, 4, 3))
        plan[:, 1, :2] = points
        assert kernels.within_box(plan[:, 1, :2], low, high) is expected  # strided
        psi, last = rng.uniform(-4.0, 4.0, size=4), rng.uniform(-4.0, 4.0, size=4)
        assert kernels.headings_jump(psi, last) is bool((np.abs(psi - last) > np.pi).any())
        me, others = rng.normal(size=2), rng.normal(size=(4, 2))
        shared, distance = rng.random(4) < 0.7, rng.uniform(0.0, 2.0, size=4)
        out = np.zeros(4, dtype=np.bool_)
        count = inside_pairs(me, others, shared, distance, out)
        gap = np.hypot(others[:, 0] - me[0], others[:, 1] - me[1])
        np.testing.assert_array_equal(out, shared & (gap < distance))
        assert count == int(out.sum())

"""The second robot model (velocity states, acceleration inputs): Jacobians, QP, plant, loop."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import qpsolvers
import scipy.sparse as sp

import sqpmpc
from sqpmpc.errors import ProblemError, ScenarioError
from sqpmpc.kernels.acceleration import bulging_segment_distance
from sqpmpc.models.acceleration import AccelerationUnicycle
from sqpmpc.models.paper import UnicycleModel
from sqpmpc.models.unicycle import discrete_dynamics as paper_step
from sqpmpc.problem.paths import plant_paths
from sqpmpc.problem.plant import (
    Plant,
    PlantSpec,
    acceleration_path_deviation,
    largest_deviation,
    model_margin,
)
from sqpmpc.problem.scenario_file import parse_scenario
from sqpmpc.qp.backend import OSQPSettings
from sqpmpc.qp.layout import QPLayout
from sqpmpc.qp.sparse import SparseQP
from tests import HANG

EPS = 1e-6
MODEL = AccelerationUnicycle(np.array([-0.6, -0.8]), np.array([0.6, 0.8]),
                             np.array([-1.0, -3.0]), np.array([1.0, 3.0]))


def _random(rng: np.random.Generator, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    x = rng.normal(size=shape + (5,)) * [2.0, 2.0, 3.0, 0.5, 0.7]
    u = rng.normal(size=shape + (2,)) * [1.0, 2.0]
    return x, u


@pytest.mark.parametrize("method", ["euler", "rk4", "exact"])
def test_jacobians_match_finite_differences(method: str) -> None:
    rng = np.random.default_rng(3)
    x, u = _random(rng, (4, 6))
    nxt, A, B = MODEL.discrete_jacobians(x, u, 0.5, method)
    np.testing.assert_allclose(nxt, MODEL.discrete_dynamics(x, u, 0.5, method), rtol=0, atol=0)
    for i in range(5):
        d = np.zeros(5)
        d[i] = EPS
        fd = (MODEL.discrete_dynamics(x + d, u, 0.5, method)
              - MODEL.discrete_dynamics(x - d, u, 0.5, method)) / (2 * EPS)
        np.testing.assert_allclose(A[..., :, i], fd, atol=1e-8)
    for i in range(2):
        d = np.zeros(2)
        d[i] = EPS
        fd = (MODEL.discrete_dynamics(x, u + d, 0.5, method)
              - MODEL.discrete_dynamics(x, u - d, 0.5, method)) / (2 * EPS)
        np.testing.assert_allclose(B[..., :, i], fd, atol=1e-8)
    # every non-zero lies in the model's pattern (the QP's fixed sparsity)
    off_a = np.ones((5, 5), dtype=bool)
    off_a[MODEL.a_pattern] = False
    off_b = np.ones((5, 2), dtype=bool)
    off_b[MODEL.b_pattern] = False
    assert not A[..., off_a].any() and not B[..., off_b].any()


def test_weighted_hessian_matches_finite_differences() -> None:
    rng = np.random.default_rng(4)
    x, u = _random(rng, (3,))
    lam = rng.normal(size=(3, 5))
    H = MODEL.weighted_dynamics_hessian(x, u, lam, 0.5, "rk4")

    def value(xx: np.ndarray, uu: np.ndarray) -> np.ndarray:
        return np.einsum("ni,ni->n", lam, MODEL.discrete_dynamics(xx, uu, 0.5, "rk4"))

    def var(k: int) -> tuple[np.ndarray, np.ndarray]:
        dx, du = np.zeros(5), np.zeros(2)
        (dx.__setitem__(2 + k, 1e-4) if k < 3 else du.__setitem__(k - 3, 1e-4))
        return dx, du

    for a in range(5):
        for b in range(5):
            (xa, ua), (xb, ub) = var(a), var(b)
            fd = (value(x + xa + xb, u + ua + ub) - value(x + xa - xb, u + ua - ub)
                  - value(x - xa + xb, u - ua + ub) + value(x - xa - xb, u - ua - ub)) / 4e-8
            np.testing.assert_allclose(H[:, a, b], fd, atol=2e-6)


def test_euler_plan_is_the_paper_plan_of_its_mean_velocities_and_exact_is_the_limit() -> None:
    rng = np.random.default_rng(5)
    x0, _ = _random(rng, (3,))
    u = rng.normal(size=(3, 6, 2)) * 0.4
    plan = MODEL.rollout(x0, u, 0.5)
    poses = np.empty((3, 7, 3))
    poses[:, 0] = x0[:, :3]
    mean = MODEL.velocity_plan(plan, u)
    for i in range(6):
        poses[:, i + 1] = paper_step(poses[:, i], mean[:, i], 0.5)
    np.testing.assert_allclose(MODEL.poses(plan), poses, atol=1e-12)
    # the exact quadrature against 64 tiny RK4 steps
    fine = x0.copy()
    for _ in range(64):
        fine = MODEL.discrete_dynamics(fine, u[:, 0], 0.5 / 64, "rk4")
    np.testing.assert_allclose(MODEL.discrete_dynamics(x0, u[:, 0], 0.5, "exact"), fine,
                               atol=1e-10)


def test_unicycle_model_is_the_paper_unicycle() -> None:
    model = UnicycleModel(np.array([-0.6, -0.8]), np.array([0.6, 0.8]))
    rng = np.random.default_rng(6)
    x = rng.normal(size=(2, 3))
    u = rng.normal(size=(2, 4, 2)) * 0.3
    for method in ("euler", "rk4", "exact"):
        rolled = model.rollout(x, u, 0.5, method)
        step = x
        for i in range(4):
            step = paper_step(step, u[:, i], 0.5, method)
            np.testing.assert_allclose(rolled[:, i + 1], step, atol=1e-14)
    assert model.kernels("euler") is not None and model.kernels("rk4") is None
    np.testing.assert_array_equal(model.braking_inputs(x, 3, 0.5), np.zeros((2, 3, 2)))


def test_model_refuses_bad_bounds() -> None:
    with pytest.raises(ProblemError, match="lower <= 0 <= upper"):
        AccelerationUnicycle(np.array([-1.0, -1.0]), np.array([1.0, 1.0]),
                             np.array([0.5, -1.0]), np.array([1.0, 1.0]))
    with pytest.raises(ProblemError, match="shape"):
        UnicycleModel(np.zeros(3), np.ones(3))


def test_braking_respects_the_limits_and_stops() -> None:
    x = np.array([[0.0, 0.0, 0.0, 0.6, -0.8], [1.0, 0.0, 1.0, -0.3, 0.2]])
    u = MODEL.braking_inputs(x, 5, 0.5)
    assert (u >= MODEL.input_lower - 1e-12).all() and (u <= MODEL.input_upper + 1e-12).all()
    path = MODEL.rollout(x, u, 0.5)
    np.testing.assert_allclose(path[:, 2:, 3:5], 0.0, atol=1e-12)  # 0.6 m/s at 1 m/s^2: 2 samples


def test_kernels_match_the_numpy_model() -> None:
    """The compiled Euler kernels (the model's, chosen through it) equal its NumPy functions."""
    kernels = MODEL.kernels("euler")
    assert kernels is not None and MODEL.kernels("rk4") is None
    rng = np.random.default_rng(10)
    m, n_stages, h = 2, 3, 0.4
    x0, _ = _random(rng, (m,))
    u = rng.normal(size=(m, n_stages, 2)) * 0.5
    out = np.empty((m, n_stages + 1, 5))
    kernels.rollout(np.ascontiguousarray(x0), u, h, out)
    step = x0
    for i in range(n_stages):
        step = MODEL.discrete_dynamics(step, u[:, i], h)
        np.testing.assert_allclose(out[:, i + 1], step, atol=1e-13)
    layout = QPLayout(m, n_stages, model=MODEL)
    z = layout.join_primal(out + rng.normal(size=out.shape) * 0.1, u)
    qp = SparseQP(layout)
    sl = layout.A_slices
    dyn = layout.dyn_rows.ravel()
    lower, upper = np.zeros(dyn.size), np.zeros(dyn.size)
    kernels.linearize(z, m, n_stages, layout.block_size, h, qp.A_values[sl["dyn_A"]],
                      qp.A_values[sl["dyn_B"]], lower, upper)
    states, inputs = layout.split_primal(z)
    nxt, A, B = MODEL.discrete_jacobians(states[:, :-1], inputs, h)
    c = nxt - np.einsum("mnij,mnj->mni", A, states[:, :-1]) - np.einsum("mnij,mnj->mni", B,
                                                                        inputs)
    ref = SparseQP(layout)
    ref.update_dynamics(A, B, c)
    np.testing.assert_allclose(qp.A_values[sl["dyn_A"]], ref.A_values[sl["dyn_A"]], atol=1e-15)
    np.testing.assert_allclose(qp.A_values[sl["dyn_B"]], ref.A_values[sl["dyn_B"]], atol=1e-15)
    np.testing.assert_allclose(lower, ref.lower[dyn], atol=1e-13)
    np.testing.assert_array_equal(lower, upper)
    defect = np.abs(states[:, 1:] - nxt).sum() + np.abs(states[:, 0] - x0).sum()
    assert kernels.defect_l1(z, x0, m, n_stages, layout.block_size, h) == pytest.approx(defect)
    z_out, y_out = np.empty_like(z), np.empty(3)
    order = np.arange(z.size)
    kernels.shift(z, np.zeros(3), order, np.arange(3), m, n_stages, layout.block_size, h,
                  z_out, y_out)
    np.testing.assert_allclose(z_out[layout.state_index[:, -1]],
                               MODEL.discrete_dynamics(states[:, -1], inputs[:, -1], h),
                               atol=1e-13)


# ---------------------------------------------------------------- the QP: update vs rebuild
N = 4


def _dense(m: int, E: int, d: dict) -> tuple[np.ndarray, ...]:
    """(P, q, A, l, u) of the accelerated model's QP by explicit loops (independent)."""
    nb = 7 * N + 5
    n = m * nb + m * E * (N - 1)

    def xi(r: int, i: int) -> int:
        return r * nb + 7 * i

    def ui(r: int, i: int) -> int:
        return xi(r, i) + 5

    P, q = np.zeros((n, n)), np.zeros(n)
    rows, lo, up = [], [], []

    def row(coeffs: list[tuple[int, float]], lower: float, upper: float) -> None:
        a = np.zeros(n)
        for j, c in coeffs:
            a[j] += c
        rows.append(a)
        lo.append(lower)
        up.append(upper)

    for r in range(m):
        for i in range(1, N + 1):
            for c in range(2):
                P[xi(r, i) + c, xi(r, i) + c] = 2 * d["Q"][c]
                q[xi(r, i) + c] = -2 * d["Q"][c] * d["ref"][r, i - 1, c]
                P[xi(r, i) + 3 + c, xi(r, i) + 3 + c] = 2 * d["Rv"][c]
        for i in range(N):
            for c in range(2):
                P[ui(r, i) + c, ui(r, i) + c] = 2 * d["R"][c]
            idx = [xi(r, i) + 2, xi(r, i) + 3, xi(r, i) + 4, ui(r, i), ui(r, i) + 1]
            P[np.ix_(idx, idx)] += d["curv"][r, i]
            q[idx] -= d["curv"][r, i] @ d["zbar"][idx]
    q[m * nb:] = d["rho"]
    for r in range(m):
        for c in range(5):
            row([(xi(r, 0) + c, 1.0)], d["x0"][r, c], d["x0"][r, c])
    for r in range(m):
        for i in range(N):
            for c in range(5):
                coeffs = [(xi(r, i + 1) + c, 1.0)]
                coeffs += [(xi(r, i) + k, -d["A"][r, i, c, k]) for k in range(5)]
                coeffs += [(ui(r, i) + k, -d["B"][r, i, c, k]) for k in range(2)]
                row(coeffs, d["c"][r, i, c], d["c"][r, i, c])
    for r in range(m):
        for i in range(N):
            for c in range(2):
                row([(ui(r, i) + c, 1.0)], d["ulo"][c], d["uup"][c])
    for r in range(m):
        for i in range(1, N + 1):
            for c in range(2):
                row([(xi(r, i) + 3 + c, 1.0)], d["vlo"][r, i - 1, c], d["vup"][r, i - 1, c])
    s = m * nb
    for r in range(m):
        for e in range(E):
            for i in range(N):
                nv = d["n_ext"][r, e, i]
                coeffs = [(xi(r, i + 1), nv[0]), (xi(r, i + 1) + 1, nv[1])]
                if i > 0:
                    coeffs.append((s + (r * E + e) * (N - 1) + i - 1, 1.0))
                row(coeffs, d["b_ext"][r, e, i], np.inf)
    for k in range(m * E * (N - 1)):
        row([(s + k, 1.0)], 0.0, np.inf)
    return P, q, np.array(rows), np.array(lo), np.array(up)


def _data(rng: np.random.Generator, m: int, E: int, n_var: int) -> dict:
    A = np.zeros((m, N, 5, 5))
    A[..., MODEL.a_pattern[0], MODEL.a_pattern[1]] = rng.normal(size=(m, N, 12))
    A[..., np.arange(5), np.arange(5)] = 1.0
    B = np.zeros((m, N, 5, 2))
    B[..., MODEL.b_pattern[0], MODEL.b_pattern[1]] = rng.normal(size=(m, N, 7))
    curv = rng.normal(size=(m, N, 5, 5))
    n_ext = rng.normal(size=(m, E, N, 2))
    n_ext /= np.linalg.norm(n_ext, axis=-1, keepdims=True)
    x0 = rng.normal(size=(m, 5)) * 0.3
    vlo, vup = MODEL.velocity_bounds(x0, N, 0.5)
    return {"Q": np.array([1.0, 2.0]), "R": np.array([0.2, 0.1]), "Rv": np.array([0.5, 0.3]),
            "rho": 100.0, "x0": x0, "ref": rng.normal(size=(m, N, 2)), "A": A, "B": B,
            "c": rng.normal(size=(m, N, 5)) * 0.1,
            "curv": np.einsum("...ij,...kj->...ik", curv, curv),
            "zbar": rng.normal(size=n_var), "n_ext": n_ext,
            "b_ext": rng.uniform(-3, -1, size=(m, E, N)),
            "ulo": MODEL.input_lower, "uup": MODEL.input_upper, "vlo": vlo, "vup": vup}


def _apply(qp: SparseQP, d: dict) -> None:
    qp.update_cost_weights(d["Q"], d["R"], d["rho"], d["Rv"])
    qp.update_reference(d["ref"])
    qp.update_initial_state(d["x0"])
    qp.update_dynamics(d["A"], d["B"], d["c"])
    qp.update_input_bounds(d["ulo"], d["uup"])
    qp.update_velocity_bounds(d["vlo"], d["vup"])
    qp.update_external_collisions(d["n_ext"], d["b_ext"])
    qp.update_curvature(d["curv"], d["zbar"])


@pytest.mark.parametrize(("m", "E"), [(1, 2), (2, 1)])
def test_update_in_place_equals_rebuild(m: int, E: int) -> None:
    layout = QPLayout(m, N, np.zeros((0, 2), dtype=np.int64), E, False, MODEL)
    qp = SparseQP(layout, OSQPSettings(eps_abs=1e-9, eps_rel=1e-9, max_iter=100000,
                                       polishing=True, rescue_solver=None))
    rng = np.random.default_rng(8)
    _apply(qp, _data(rng, m, E, layout.n_var))
    qp.solve()
    second = _data(rng, m, E, layout.n_var)
    _apply(qp, second)
    res = qp.solve()
    assert qp.setup_count == 1
    P_ref, q_ref, A_ref, l_ref, u_ref = _dense(m, E, second)
    P, q, A, lo, up = qp.matrices()
    np.testing.assert_allclose(P.toarray(), np.triu(P_ref), atol=1e-14)
    np.testing.assert_allclose(q, q_ref, atol=1e-13)
    np.testing.assert_allclose(A.toarray(), A_ref, atol=1e-14)
    np.testing.assert_array_equal(lo, l_ref)
    np.testing.assert_array_equal(up, u_ref)
    assert res.success, res.status
    G = np.vstack((-A_ref, A_ref))
    h = np.concatenate((-l_ref, u_ref))
    keep = np.isfinite(h)
    ref = qpsolvers.solve_problem(qpsolvers.Problem(sp.csc_matrix(P_ref), q_ref,
                                                    G=sp.csc_matrix(G[keep]), h=h[keep]),
                                  solver="clarabel")
    assert ref.found
    np.testing.assert_allclose(res.x, ref.x, atol=2e-6)


# ---------------------------------------------------------------- scenario, plant, margins
def _with_limits(name: str = "paper-s2", **extra: object) -> sqpmpc.Scenario:
    sc = sqpmpc.load_scenario(name)
    bounds = replace(sc.bounds, acceleration=(-1.0, 1.0), angular_acceleration=(-3.0, 3.0))
    return sc.with_changes(bounds=bounds, **extra)


def test_scenario_keys_select_the_model_and_round_trip(tmp_path) -> None:
    sc = _with_limits()
    assert isinstance(sc.robot_model(), AccelerationUnicycle)
    assert isinstance(sqpmpc.load_scenario("paper-s2").robot_model(), UnicycleModel)
    path = tmp_path / "s.toml"
    path.write_text(sc.to_toml())
    assert sqpmpc.load_scenario(str(path)) == sc
    text = sqpmpc.load_scenario("paper-s2").to_toml().replace(
        "[bounds]", "[bounds]\nacceleration = [-1.0, 1.0]")
    with pytest.raises(ScenarioError, match="angular_acceleration"):
        parse_scenario(tomllib.loads(text), "t.toml")
    text = text.replace("acceleration = [-1.0, 1.0]",
                        "acceleration = [0.5, 1.0]\nangular_acceleration = [-1.0, 1.0]")
    with pytest.raises(ScenarioError, match=r"bounds.*acceleration.*lower <= 0 <= upper"):
        parse_scenario(tomllib.loads(text), "t.toml")


def test_plant_changes_velocities_within_the_limits() -> None:
    plant = Plant(PlantSpec("exact"), 0.5, 2, (np.array([-1.0, -3.0]), np.array([1.0, 3.0])))
    x = np.zeros((2, 3))
    assert plant.measure(x).shape == (2, 5)
    commands = np.array([[0.6, 0.8], [-0.6, -0.8]])
    reached = []
    for _ in range(3):
        x, applied = plant.step(x, commands)
        reached.append(applied)
    steps = np.diff(np.concatenate((np.zeros((1, 2, 2)), reached)), axis=0)
    assert (np.abs(steps[..., 0]) <= 0.5 + 1e-12).all()  # |a| <= 1 m/s^2 over 0.5 s
    np.testing.assert_allclose(reached[-1], commands)      # 0.6 m/s in 2 samples, 0.8 in 1


@pytest.mark.parametrize(("prediction", "plant"), [("euler", "euler"), ("euler", "exact"),
                                                   ("exact", "exact"), ("exact", "euler")])
def test_path_deviation_bounds_the_true_path(prediction: str, plant: str) -> None:
    """The true path of a robot accelerating within the limits stays within
    alpha s + beta s (1 - s) of the predicted segment (random samples)."""
    rng = np.random.default_rng(9)
    h = 0.5
    x0 = np.concatenate((rng.normal(size=(200, 3)), rng.uniform(-0.6, 0.6, (200, 1)),
                         rng.uniform(-0.8, 0.8, (200, 1))), axis=1)
    acc = rng.uniform([-1.0, -3.0], [1.0, 3.0], (200, 2))
    predicted = MODEL.discrete_dynamics(x0, acc, h, prediction)
    alpha, beta = acceleration_path_deviation(x0[:, 3:5], acc, h, prediction, plant)
    for s in np.linspace(0.0, 1.0, 21):
        true = MODEL.discrete_dynamics(x0, acc, s * h, plant)[:, :2] if s > 0 else x0[:, :2]
        if plant == "euler":  # the Euler plant moves along its own chord
            end = MODEL.discrete_dynamics(x0, acc, h, "euler")[:, :2]
            along = (x0[:, 3] * s * h + acc[:, 0] * (s * h) ** 2 / 2) / (
                h * (x0[:, 3] + acc[:, 0] * h / 2) + 1e-300)
            true = x0[:, :2] + along[:, None] * (end - x0[:, :2])
        line = (1 - s) * x0[:, :2] + s * predicted[:, :2]
        gap = np.linalg.norm(true - line, axis=1)
        assert (gap <= alpha * s + beta * s * (1 - s) + 1e-9).all()
    lo, hi = np.array([-0.6, -0.8]), np.array([0.6, 0.8])
    limits = (np.array([-1.0, -3.0]), np.array([1.0, 3.0]))
    # twice the linear majorant |a| Ts^2 / 2 of the Euler plant's bulge
    assert model_margin(lo, hi, h, "euler", PlantSpec("euler"), limits) == pytest.approx(0.25)


def test_bulging_distance_is_the_smallest_over_the_segment() -> None:
    """The checks' distance under the bound alpha s + beta s (1 - s), against a fine grid."""
    rng = np.random.default_rng(11)
    s = np.linspace(0.0, 1.0, 20001)
    for _ in range(300):
        r0, d = rng.normal(size=2), rng.normal(size=2)
        alpha, beta = abs(rng.normal()) * 0.2, rng.normal() * 0.3
        bound = alpha * s + max(beta, 0.0) * s * (1 - s)
        grid = (np.hypot(r0[0] + s * d[0], r0[1] + s * d[1]) - bound).min()
        got = bulging_segment_distance(r0[0], r0[1], d[0], d[1], alpha, beta)
        assert grid - 1e-6 <= got <= grid + 1e-12
        assert largest_deviation(alpha, beta) >= (alpha * s + beta * s * (1 - s)).max() - 1e-12


# ---------------------------------------------------------------- the controllers and the loop
def test_controllers_take_poses_or_poses_and_velocities() -> None:
    sc = _with_limits()
    a = sqpmpc.CentralizedController(sc)
    b = sqpmpc.CentralizedController(sc)
    x = sc.initial_states()
    first = a.step(0.0, x)
    assert first.model_states.shape == (4, sc.horizon + 1, 5)
    b.step(0.0, np.concatenate((x, np.zeros((4, 2))), axis=1))
    x1 = first.predicted_states[:, 1]
    # poses alone: the robot is taken to move at what it was last commanded
    out_a = a.step(0.5, x1)
    out_b = b.step(0.5, np.concatenate((x1, first.inputs), axis=1))
    np.testing.assert_allclose(out_a.inputs, out_b.inputs, atol=1e-12)
    with pytest.raises(ProblemError, match=r"\(4, 3\).*\(4, 5\)"):
        a.step(1.0, np.zeros((4, 4)))


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_closed_loop_on_paper_s2_with_acceleration_limits(scheme: str) -> None:
    """0 collisions at and between samples, bounds held (inputs and velocity changes), every
    robot ends within the tracking band of the ideal (paper-unicycle) run."""
    sc = _with_limits()
    rec = sqpmpc.ClosedLoopSimulation(sc, scheme).run()
    m = sqpmpc.compute_metrics(rec)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["input_bound_violations"] == 0
    v = rec.plant_inputs  # the velocities reached
    change = np.diff(np.concatenate((np.zeros((1,) + v.shape[1:]), v)), axis=0) / sc.sample_time
    assert (change >= sc.bounds.acceleration_lower() - 1e-9).all()
    assert (change <= sc.bounds.acceleration_upper() + 1e-9).all()
    assert (v >= sc.bounds.input_lower() - 1e-9).all() and (v <= sc.bounds.input_upper()
                                                             + 1e-9).all()
    # the metrics measure between samples along the ramping paths (not uniform chords)
    _, path = plant_paths(rec.states, rec.plant_inputs, sc.sample_time, "euler", True)
    pairs = np.asarray(sc.pairs()).reshape(-1, 2)
    need = sc.required_distances()[pairs[:, 0], pairs[:, 1]]
    along = np.linalg.norm(path[:, pairs[:, 0]] - path[:, pairs[:, 1]], axis=-1) - need
    measured = min(m["min_clearance"], m["intersample_min_clearance"])
    assert along.min() - 2e-3 <= measured <= along.min() + 1e-12
    ideal = sqpmpc.ClosedLoopSimulation(sqpmpc.load_scenario("paper-s2"), scheme).run()
    err = np.linalg.norm(ideal.positions - ideal.references(), axis=-1)
    band = max(0.05, float(err[-(err.shape[0] // 10):].max()))
    assert m["max_final_position_error"] <= band


def test_braking_robots_keep_clear_of_obstacles() -> None:
    """corridor (pillars) with acceleration limits, decentralized: braking takes several
    samples, and the braking check keeps the obstacles too (146 obstacle collisions
    without it)."""
    sc = _with_limits("corridor")
    m = sqpmpc.compute_metrics(sqpmpc.ClosedLoopSimulation(sc, "decentralized").run())
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["obstacle_collisions"] == 0 and m["input_bound_violations"] == 0


def test_services_plant_respects_the_limits(tmp_path: Path) -> None:
    """The distributed run (plant and robot processes, poses only over the wire: each
    controller takes its robot to move at what it last commanded): the plant changes the
    velocities within the limits, no collision, no bound violated."""
    sc = _with_limits(t_end=8.0)
    path = tmp_path / "s2-acc.toml"
    path.write_text(sc.to_toml())
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "services.launch", "--scenario", str(path), "--scheme",
           "decentralized", "--out", str(out), "--no-plots"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=HANG,
                         cwd=Path(__file__).resolve().parent.parent)
    assert res.returncode == 0, res.stderr
    traj = np.load(out / "trajectory.npz")
    v = traj["plant_inputs"]
    change = np.diff(np.concatenate((np.zeros((1,) + v.shape[1:]), v)), axis=0) / sc.sample_time
    assert (change >= sc.bounds.acceleration_lower() - 1e-9).all()
    assert (change <= sc.bounds.acceleration_upper() + 1e-9).all()
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["collisions"] == 0 and metrics["intersample_collisions"] == 0
    assert metrics["input_bound_violations"] == 0

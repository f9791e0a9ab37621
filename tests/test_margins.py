"""The shared rows' margin of robots with acceleration limits (sqpmpc.problem.margins)."""

from __future__ import annotations

import numpy as np
import pytest

import sqpmpc
from sqpmpc.models.acceleration import AccelerationUnicycle
from sqpmpc.problem.margins import RowMargins, required_height, row_deviation
from sqpmpc.problem.plant import PlantSpec, largest_deviation
from sqpmpc.problem.scenario_file import parse_scenario

H = 0.5
V_LO, V_HI = np.array([-0.6, -0.8]), np.array([0.6, 0.8])
A_LO, A_HI = np.array([-2.0, -7.1]), np.array([2.0, 7.1])
MODEL = AccelerationUnicycle(V_LO, V_HI, A_LO, A_HI)


def test_required_height_is_the_smallest_passing_height() -> None:
    """m(h0) against a fine grid of s: the smallest h1 with (1-s) h0 + s h1 >= alpha s +
    beta s (1-s) on (0, 1]; and L (the largest deviation) is its fixed point."""
    rng = np.random.default_rng(3)
    s = np.concatenate((np.geomspace(1e-6, 1e-2, 20001), np.linspace(1e-2, 1.0, 20001)))
    for _ in range(300):
        alpha, beta = abs(rng.normal()) * 0.1, rng.normal() * 0.3
        h0 = abs(rng.normal()) * 0.2 * (rng.random() < 0.9)
        b = max(beta, 0.0)
        grid = (alpha + (1 - s) * (b - h0 / s)).max()
        got = float(required_height(h0, alpha, beta))
        assert grid - 1e-12 <= got <= grid + 1e-6
        steady = float(largest_deviation(alpha, beta))
        assert float(required_height(steady, alpha, beta)) <= steady + 1e-12
    assert float(required_height(0.0, 0.1, 0.25)) == pytest.approx(0.35)  # the old margin


@pytest.mark.parametrize("plant", ["euler", "exact"])
def test_rows_margin_covers_the_true_path(plant: str) -> None:
    """Sampled robots accelerating within the limits (box corners included), lines at
    random heights h0: whenever the predicted next position is at least max(L, m(h0))
    above the line (what the rows ask), the true path stays above it over the sample."""
    rng = np.random.default_rng(17)
    n = 40000
    alpha, beta = row_deviation(V_LO, V_HI, H, "euler", PlantSpec(plant), (A_LO, A_HI))
    steady = float(largest_deviation(alpha, beta))
    x0 = np.concatenate((rng.normal(size=(n, 3)), rng.uniform(V_LO, V_HI, (n, 2))), axis=1)
    acc = rng.uniform(A_LO, A_HI, (n, 2))
    corner = rng.random((n, 2)) < 0.5                      # half the samples at the corners
    acc = np.where(corner, np.where(acc > 0, A_HI, A_LO), acc)
    end = x0[:, 3:5] + H * acc                              # keep the end velocities in the box
    acc = (np.clip(end, V_LO, V_HI) - x0[:, 3:5]) / H
    predicted = MODEL.discrete_dynamics(x0, acc, H, "euler")[:, :2]
    angle = rng.uniform(0, 2 * np.pi, n)
    normal = np.stack((np.cos(angle), np.sin(angle)), axis=1)
    h0 = rng.uniform(0.0, 0.4, n) * (rng.random(n) < 0.9)
    h1 = h0 + np.einsum("ij,ij->i", normal, predicted - x0[:, :2])
    rows = h1 >= np.maximum(steady, required_height(h0, alpha, beta))
    assert rows.sum() > n // 4
    lowest = np.full(n, np.inf)
    for s in np.linspace(0.0, 1.0, 41)[1:]:
        if plant == "euler":  # the Euler plant: its chord, travelled as v0 t + a t^2 / 2
            along = (x0[:, 3] * s * H + acc[:, 0] * (s * H) ** 2 / 2) / (
                H * (x0[:, 3] + acc[:, 0] * H / 2) + 1e-300)
            true = x0[:, :2] + along[:, None] * (predicted - x0[:, :2])
        else:
            true = MODEL.discrete_dynamics(x0, acc, s * H, plant)[:, :2]
        height = h0 + np.einsum("ij,ij->i", normal, true - x0[:, :2])
        lowest = np.minimum(lowest, height)
    assert (lowest[rows] >= -1e-9).all()
    if plant == "euler":  # the bound is tight there: accepted paths come within 1 mm
        assert (lowest[rows] < 1e-3).any()


def _beside_a_parked_robot() -> sqpmpc.Scenario:
    robot = {"diameter": 0.3}
    return parse_scenario({
        "name": "beside-parked", "t_end": 15.0, "sample_time": H, "horizon": 8,
        "weights": {"Q": [1.0, 1.0], "R": [0.5, 0.5]},
        "bounds": {"v": [-0.6, 0.6], "omega": [-0.785, 0.785],
                   "acceleration": [-2.0, 2.0], "angular_acceleration": [-7.1, 7.1]},
        "robots": [
            {"id": 1, "initial_state": [0.0, -0.4, 0.0], **robot,
             "reference": {"type": "point", "position": [0.0, -0.4]}},
            {"id": 2, "initial_state": [-3.0, 0.4, 0.0], **robot,
             "reference": {"type": "point", "position": [0.0, 0.4]}},
        ]}, source="<test>")


@pytest.mark.parametrize("scheme", ["decentralized", "centralized"])
def test_robot_reaches_a_goal_beside_a_parked_robot(scheme: str) -> None:
    """corridor's ending: a goal 0.80 m beside a parked robot, under the declared bounds,
    in the library loop (default rules with keep-right): the old margin kept 0.801 m, the
    pair rows of either scheme now 0.3 + 2 L; 0 collisions at and between samples."""
    sc = _beside_a_parked_robot()
    sim = sqpmpc.ClosedLoopSimulation(sc, scheme)
    margins: RowMargins = sim.controllers[0].margins
    assert 0.3 + sim.controllers[0].pair_margin > 0.8      # the old rows: unreachable
    assert margins.kept == pytest.approx(2 * 2.0 * H * H / 8)  # 2 L, L = |a| Ts^2 / 8
    rec = sim.run()
    m = sqpmpc.compute_metrics(rec)
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["input_bound_violations"] == 0
    # the old rows held robot 2 0.038 m off its goal and pushed robot 1 by 3 mm
    assert m["max_final_position_error"] <= 0.005
    d = np.linalg.norm(rec.positions[:, 0] - rec.positions[:, 1], axis=-1)
    assert d.min() >= 0.3 - 1e-9

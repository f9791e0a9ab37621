"""The plant: model mismatch bounds, noise, obstacles, and closed loops on real plants."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.models.unicycle import DISCRETIZATIONS, discrete_dynamics
from sqpmpc.problem.plant import (
    NOISE_TRUNCATION,
    Plant,
    PlantSpec,
    linear_growth,
    model_margin,
    path_deviation,
)
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import SimulationOptions, simulate

S = np.linspace(0.0, 1.0, 201)


def _true_path(x0: np.ndarray, u: np.ndarray, h: float, plant: str) -> np.ndarray:
    """Positions ``(S, n, 2)`` of the plant's path over one sample."""
    if plant == "exact":  # the arc itself
        return np.stack([discrete_dynamics(x0, u, s * h, "exact")[..., :2] for s in S])
    end = discrete_dynamics(x0, u, h, plant)[..., :2]  # a chord
    return (1 - S)[:, None, None] * x0[..., :2] + S[:, None, None] * end


@pytest.mark.parametrize("prediction", DISCRETIZATIONS)
@pytest.mark.parametrize("plant", DISCRETIZATIONS)
@pytest.mark.parametrize("noisy", [False, True])
def test_path_deviation_bounds_the_true_path(prediction: str, plant: str, noisy: bool) -> None:
    rng = np.random.default_rng(hash((prediction, plant, noisy)) % 2**32)
    n, h = 400, 0.7
    x0 = np.column_stack((rng.normal(size=(n, 2)), rng.uniform(-np.pi, np.pi, n)))
    u = np.column_stack((rng.uniform(-0.6, 0.6, n), rng.uniform(-0.8, 0.8, n)))
    W = np.array([0.1, 0.12]) if noisy else np.zeros(2)
    applied = u + rng.uniform(-1.0, 1.0, (n, 2)) * W  # any noise within the bound
    applied[::7] = u[::7] + W * np.sign(rng.normal(size=(u[::7].shape)))  # at the bound
    predicted_end = discrete_dynamics(x0, u, h, prediction)[:, :2]
    segment = (1 - S)[:, None, None] * x0[:, :2] + S[:, None, None] * predicted_end
    deviation = np.hypot(*np.moveaxis(_true_path(x0, applied, h, plant) - segment, -1, 0))
    alpha, beta = path_deviation(u, h, prediction, plant, W)
    bound = alpha * S[:, None] + beta * (S * (1 - S))[:, None]
    assert np.all(deviation <= bound + 1e-12)
    assert np.all(bound >= -1e-15)  # a valid bound is never negative
    assert np.all(linear_growth(alpha, beta) * S[:, None] >= bound - 1e-15)


def test_model_margin_is_zero_for_a_matching_plant_and_derived_otherwise() -> None:
    lo, hi = np.array([-0.6, -0.8]), np.array([0.6, 0.8])
    for model in ("euler", "rk4"):
        assert model_margin(lo, hi, 0.5, model, PlantSpec(model)) == 0.0
    # Euler on exact, exact on exact: v_max omega_max Ts^2
    assert model_margin(lo, hi, 0.5, "euler", PlantSpec("exact")) == pytest.approx(0.12)
    assert model_margin(lo, hi, 0.5, "exact", PlantSpec("exact")) == pytest.approx(0.12)
    noisy = model_margin(lo, hi, 0.5, "exact", PlantSpec("exact", (0.03, 0.04)))
    assert noisy > 0.12 + 2 * NOISE_TRUNCATION * 0.03 * 0.5 - 1e-12


def test_plant_noise_is_seeded_and_truncated() -> None:
    spec = PlantSpec("euler", (0.05, 0.1), seed=7)
    u = np.zeros((3, 2))
    a = [Plant(spec, 0.5, 3).applied_inputs(u) for _ in range(2)]
    np.testing.assert_array_equal(a[0], a[1])
    draws = Plant(spec, 0.5, 3)
    noise = np.concatenate([draws.applied_inputs(u) for _ in range(20000)])
    assert np.all(np.abs(noise) <= NOISE_TRUNCATION * np.array([0.05, 0.1]) + 1e-15)
    np.testing.assert_allclose(noise.std(axis=0), [0.05, 0.1], rtol=0.03)
    assert not np.array_equal(Plant(PlantSpec("euler", (0.05, 0.1), seed=8), 0.5, 3)
                              .applied_inputs(u), a[0])


def test_plant_spec_refuses_bad_values_naming_the_field() -> None:
    with pytest.raises(ProblemError, match="^model: "):
        PlantSpec("midpoint")
    with pytest.raises(ProblemError, match="^input_noise: "):
        PlantSpec("euler", (0.1, float("nan")))
    with pytest.raises(ProblemError, match="^seed: "):
        PlantSpec("euler", seed=-1)


def _arrived(metrics: dict, tolerance: float = 0.05) -> bool:
    return metrics["max_final_position_error"] <= tolerance


def _check_safe(metrics: dict) -> None:
    assert metrics["collisions"] == 0 and metrics["intersample_collisions"] == 0
    assert metrics["obstacle_collisions"] == 0
    assert metrics["input_bound_violations"] == 0
    assert metrics["completed"]


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
@pytest.mark.parametrize("discretization", ["euler", "exact"])
def test_head_on_on_an_exact_plant_is_safe_and_arrives(scheme: str, discretization: str) -> None:
    from sqpmpc.io.metrics import compute_metrics

    scenario = load_scenario("head-on")
    record = simulate(scenario, scheme, SolverSettings(discretization=discretization),
                      SimulationOptions(plant_discretization="exact"))
    metrics = compute_metrics(record)
    _check_safe(metrics)
    assert _arrived(metrics)
    assert metrics["plant_discretization"] == "exact"
    assert metrics["model_margin"] == pytest.approx(
        model_margin(scenario.bounds.input_lower(), scenario.bounds.input_upper(),
                     scenario.sample_time, discretization, PlantSpec("exact")))


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_corridor_is_crossed_both_ways_without_touching_a_pillar(scheme: str) -> None:
    from sqpmpc.io.metrics import compute_metrics

    scenario = load_scenario("corridor")
    assert len(scenario.obstacles) == 18
    metrics = compute_metrics(simulate(scenario, scheme))
    _check_safe(metrics)
    assert metrics["min_obstacle_clearance"] >= 0.0
    assert _arrived(metrics)
    # both ways: two robots start on each side of the corridor and end on the other
    start = scenario.initial_states()[:, 0]
    assert sorted(np.sign(start)) == [-1, -1, 1, 1]


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_input_noise_is_recorded_and_stays_safe(scheme: str) -> None:
    from sqpmpc.io.metrics import compute_metrics

    scenario = load_scenario("head-on")
    scenario = scenario.with_changes(plant=PlantSpec("exact", (0.03, 0.04), seed=3))
    record = simulate(scenario, scheme)
    metrics = compute_metrics(record)
    _check_safe(metrics)
    noise = record.plant_inputs - record.inputs
    assert np.abs(noise).max() > 0
    assert np.all(np.abs(noise) <= NOISE_TRUNCATION * np.array([0.03, 0.04]) + 1e-12)
    assert metrics["plant"]["input_noise"] == [0.03, 0.04]


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
@pytest.mark.parametrize("velocity", [(0.0, -0.3), (-0.1, 0.0)], ids=["crossing", "head-on"])
def test_a_moving_obstacle_on_the_path_is_avoided(scheme: str,
                                                  velocity: tuple[float, float]) -> None:
    from sqpmpc.io.metrics import compute_metrics
    from sqpmpc.problem.obstacles import Obstacle

    scenario = load_scenario("head-on")
    robot = scenario.robots[0]
    # an obstacle across (or along, against) the robot's straight path, there when it is
    start, goal = np.array(robot.initial_state[:2]), np.array(robot.reference.position(0.0))
    middle = 0.5 * (start + goal) - 5.0 * np.asarray(velocity)
    crossing = Obstacle(position=(float(middle[0]), float(middle[1])), diameter=0.4,
                        velocity=velocity)
    # head-on, the robot backs away before it goes round: time to arrive
    scenario = scenario.with_changes(robots=(robot,), obstacles=(crossing,), t_end=45.0)
    metrics = compute_metrics(simulate(scenario, scheme))
    _check_safe(metrics)
    assert metrics["min_obstacle_clearance"] >= 0.0
    assert _arrived(metrics)

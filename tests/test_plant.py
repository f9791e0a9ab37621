"""The plant: model mismatch bounds, noise, obstacles, and closed loops on real plants."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError, ScenarioError
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


LAG = (0.03, 4.0)  # [plant] response: a 30 ms delay, then at least 4 m/s^2


def _lagging_path(x0: np.ndarray, previous: np.ndarray, u: np.ndarray, h: float,
                  response: tuple[float, float], steps: int = 2000) -> np.ndarray:
    """Positions ``(S, n, 2)`` over one sample of a plant whose speed holds ``previous`` for
    the delay and then moves at the acceleration to ``u``, its yaw rate at ``u`` (fine Euler
    steps of the exact motion), at the fractions of :data:`S`."""
    delay, accel = response
    dt = h / steps
    x = x0.copy()
    v = previous[:, 0].copy()
    out = [x[:, :2].copy()]
    for j in range(1, steps + 1):
        t = (j - 0.5) * dt
        if t > delay:
            v = v + np.clip(u[:, 0] - v, -accel * dt, accel * dt)
        psi = x[:, 2] + 0.5 * dt * u[:, 1]
        x = np.column_stack((x[:, 0] + dt * v * np.cos(psi), x[:, 1] + dt * v * np.sin(psi),
                             x[:, 2] + dt * u[:, 1]))
        out.append(x[:, :2].copy())
    path = np.array(out)
    return path[np.round(S * steps).astype(int)]


@pytest.mark.parametrize("prediction", DISCRETIZATIONS)
def test_path_deviation_of_a_lagging_plant_bounds_its_path_and_the_brake_after(
        prediction: str) -> None:
    rng = np.random.default_rng(17)
    n, h = 300, 0.5
    spec = PlantSpec("exact", response=LAG)
    x0 = np.column_stack((rng.normal(size=(n, 2)), rng.uniform(-np.pi, np.pi, n)))
    previous = np.column_stack((rng.choice([-0.6, 0.0, 0.6], n), rng.uniform(-0.8, 0.8, n)))
    u = np.column_stack((rng.uniform(-0.6, 0.6, n), rng.uniform(-0.8, 0.8, n)))
    u[::5, 0] = -previous[::5, 0]  # full reversals
    path = _lagging_path(x0, previous, u, h, LAG)
    end = discrete_dynamics(x0, u, h, prediction)[:, :2]
    segment = (1 - S)[:, None, None] * x0[:, :2] + S[:, None, None] * end
    deviation = np.hypot(*np.moveaxis(path - segment, -1, 0))
    alpha, beta = path_deviation(u, h, prediction, "exact", None, spec, previous)
    bound = alpha * S[:, None] + beta * (S * (1 - S))[:, None]
    assert np.all(deviation <= bound + 1e-9)
    # without the lag (the previous commands taken as the speed) the bound fails: the lag
    # is what it covers
    alpha0, beta0 = path_deviation(u, h, prediction, "exact", None, spec, u)
    assert np.any(deviation > alpha0 * S[:, None] + beta0 * (S * (1 - S))[:, None] + 1e-3)
    # the brake after the sample (the unchecked fallback) stays within the coast, which
    # the bound's end already holds: the robot stops within c(|v|) of where it was
    here = path[-1]
    brake = _lagging_path(np.column_stack((here, x0[:, 2])), u, np.zeros_like(u), h, LAG)
    travelled = np.hypot(*np.moveaxis(brake - here, -1, 0)).max(axis=0)
    coast = spec.speed_lag(u[:, 0])
    assert np.all(travelled <= coast + 1e-9)
    assert np.all(alpha >= coast)
    assert travelled.max() == pytest.approx(spec.speed_lag(0.6), rel=0.01)  # the worst case


def test_a_lagging_plant_keeps_the_coast_in_the_rows_and_moves_with_the_slowest_response(
        ) -> None:
    lo, hi = np.array([-0.6, -0.8]), np.array([0.6, 0.8])
    spec = PlantSpec("exact", response=LAG)
    coast = 0.6 * 0.03 + 0.6**2 / (2 * 4.0)
    assert spec.speed_lag(-0.6) == pytest.approx(coast)
    assert spec.settling_time(1.2) == pytest.approx(0.03 + 0.3)
    assert model_margin(lo, hi, 0.5, "euler", spec) == pytest.approx(0.12 + 2 * coast)
    # the plant: full speed, then a stop command: it coasts c(0.6) past the stop
    plant = Plant(spec, 0.5, 1)
    x, _ = plant.step(np.zeros((1, 3)), np.array([[0.6, 0.0]]))
    assert x[0, 0] == pytest.approx(0.3 - 0.6 * 0.03 - 0.6**2 / (2 * 4.0), abs=1e-6)
    assert plant.speeds[0] == pytest.approx(0.6)
    y, _ = plant.step(x, np.zeros((1, 2)))
    assert y[0, 0] - x[0, 0] == pytest.approx(coast, abs=1e-6)
    assert plant.speeds[0] == 0.0


def test_a_response_is_refused_where_it_does_not_hold() -> None:
    with pytest.raises(ProblemError, match="^response: expected"):
        PlantSpec("exact", response=(0.02, 0.0))
    with pytest.raises(ProblemError, match="^response: expected"):
        PlantSpec("exact", response=(-0.1, 4.0))
    with pytest.raises(ProblemError, match='^response: .*model = "exact"'):
        PlantSpec("euler", response=LAG)
    sc = load_scenario("head-on")
    with pytest.raises(ScenarioError, match="plant.response: the speed settles in up to"):
        sc.with_changes(plant=PlantSpec("exact", response=(0.1, 2.0)))  # 0.7 s > 0.5 s
    from dataclasses import replace

    with pytest.raises(ScenarioError, match="plant.response: for the paper's robot only"):
        sc.with_changes(plant=PlantSpec("exact", response=LAG), bounds=replace(
            sc.bounds, acceleration=(-2.0, 2.0), angular_acceleration=(-7.0, 7.0)))
    # declared in a file: read, written and read back
    from sqpmpc.problem.scenario_file import parse_scenario

    declared = sc.with_changes(plant=PlantSpec("exact", response=LAG))
    import tomllib

    assert parse_scenario(tomllib.loads(declared.to_toml())).plant == declared.plant


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_head_on_on_a_lagging_plant_is_safe_and_arrives(scheme: str) -> None:
    """The paper's robots head-on on a plant that coasts and lags: every sample's check
    takes the lag and the coast of the brake after it, so no robot ends a sample inside
    another's distance, and they arrive."""
    from sqpmpc.io.metrics import compute_metrics

    scenario = load_scenario("head-on").with_changes(plant=PlantSpec("exact", response=LAG))
    record = simulate(scenario, scheme)
    metrics = compute_metrics(record)
    assert metrics["collisions"] == 0 and metrics["completed"]
    assert metrics["min_clearance"] > 0.0
    assert _arrived(metrics)


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

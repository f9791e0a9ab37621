"""Closed loops of both schemes: safety, bounds, tracking, fallbacks."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.plans import PlanMessage
from sqpmpc.control.settings import SolverSettings
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.qp.backend import OSQPSettings
from sqpmpc.sim.simulation import ClosedLoopSimulation, SimulationOptions, simulate


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_paper_s2_closed_loop_is_safe_and_tracks(scheme: str) -> None:
    m = compute_metrics(simulate(load_scenario("paper-s2"), scheme))
    assert m["steps"] == 800 and m["completed"]
    assert m["collisions"] == 0
    assert m["min_clearance"] >= 0.0
    assert m["intersample_collisions"] == 0  # nobody passes through anybody between samples
    assert m["input_bound_violations"] == 0
    assert m["solver_failures"] == 0
    assert m["max_final_position_error"] <= 0.05


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_symmetric_head_on_pair_does_not_deadlock(scheme: str) -> None:
    # exactly symmetric: without the symmetry-breaking rules both robots stop nose to nose
    m = compute_metrics(simulate(load_scenario("head-on"), scheme))
    assert m["collisions"] == 0 and m["min_clearance"] >= 0.0
    assert m["max_final_position_error"] <= 0.05


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
@pytest.mark.parametrize("name", ["crossing-4", "swap-6"])
def test_symmetry_breaking_rules_resolve_the_hard_encounters(name: str, scheme: str) -> None:
    sc = load_scenario(name)
    m = compute_metrics(simulate(sc, scheme))
    assert m["collisions"] == 0 and m["min_clearance"] >= 0.0
    assert m["intersample_collisions"] == 0
    assert m["max_final_position_error"] <= 0.05
    _assert_counters_consistent(m, sc, scheme)


def _assert_counters_consistent(m: dict, sc, scheme: str) -> None:
    """The engine's counters agree with each other and with the run."""
    c = m["counters"]
    controllers = 1 if scheme == "centralized" else sc.n_robots
    assert c["samples"] == m["steps"] * controllers
    assert c["fallbacks"] == c["shifted_plan_fallbacks"] + c["brake_fallbacks"]
    assert c["fallbacks"] == m["solver_failures"]
    # the gear-cycle rule is the only rule that asks for converged samples
    assert c.get("converged_samples", 0) == c.get("gear_cycle_samples", 0)
    assert all(isinstance(v, int) and v >= 0 for v in c.values())


def test_failed_qp_applies_a_safe_fallback_and_counts_it() -> None:
    sc = load_scenario("paper-s2").with_changes(t_end=20.0)
    settings = SolverSettings(qp_solver="osqp",  # no hand-over: OSQP alone fails
                              osqp=OSQPSettings(max_iter=1, accept_inaccurate=False,
                                                rescue_solver=None))
    sim = ClosedLoopSimulation(sc, "centralized", settings)
    record = sim.run()
    m = compute_metrics(record)
    assert m["solver_failures"] == sc.steps  # every QP stops at max_iter: all fall back
    assert m["input_bound_violations"] == 0
    assert m["collisions"] == 0
    lo, up = sc.bounds.input_lower(), sc.bounds.input_upper()
    assert np.all(record.inputs >= lo) and np.all(record.inputs <= up)


def test_paper_mode_runs_and_reports_honestly() -> None:
    sc = load_scenario("paper-s1").with_changes(t_end=120.0)
    options = SimulationOptions(decentralized_mode="paper")
    record = simulate(sc, "decentralized", options=options)
    m = compute_metrics(record)
    assert m["completed"] and m["decentralized_mode"] == "paper"
    assert m["input_bound_violations"] == 0
    assert isinstance(m["collisions"], int)


def test_lost_plans_use_the_paper_fallback_and_stay_within_bounds() -> None:
    sc = load_scenario("paper-s2").with_changes(t_end=150.0)
    options = SimulationOptions(message_drop_probability=0.3, seed=3)
    sim = ClosedLoopSimulation(sc, "decentralized", options=options)
    m = compute_metrics(sim.run())
    assert sim.dropped_messages > 0
    assert m["input_bound_violations"] == 0
    assert m["collisions"] == 0


def test_shared_hyperplanes_of_a_pair_are_the_same_line() -> None:
    sc = load_scenario("paper-s2")
    a, b = DecentralizedController(sc, 1), DecentralizedController(sc, 3)
    rng = np.random.default_rng(0)
    N = sc.horizon
    states = sc.initial_states()
    plans = {}
    for rid in (1, 2, 3, 4):
        x = np.cumsum(rng.normal(scale=0.05, size=(N + 1, 3)), axis=0)
        x[0] = states[rid - 1]
        x[1:] += states[rid - 1]
        plans[rid] = PlanMessage(rid, 0, x, np.zeros((N, 2)))
    a.published, b.published = plans[1], plans[3]
    a.step(1, 0.5, states, plans, states)
    b.step(1, 0.5, states, plans, states)
    e_a = list(a.other_ids).index(3)
    e_b = list(b.other_ids).index(1)
    n_a, r_a = a.collisions.fixed_normals[e_a], a.collisions.fixed_rhs[e_a]
    n_b, r_b = b.collisions.fixed_normals[e_b], b.collisions.fixed_rhs[e_b]
    np.testing.assert_allclose(n_a, -n_b, atol=1e-12)
    # n'p_a >= r_a and -n'p_b >= r_b imply n'(p_a - p_b) >= r_a + r_b = required + margin
    req = sc.required_distances()[0, 2] + a.settings.collision_margin
    np.testing.assert_allclose(r_a + r_b, req, atol=1e-12)


@pytest.mark.parametrize("without", [("detour",), ("detour", "keep-right")])
def test_decentralized_stays_safe_without_the_detour_rule(without: tuple[str, ...]) -> None:
    # robots pressed together for hundreds of samples: solver tolerances accepted by the
    # first-stage check used to accumulate into collisions (146 samples, -0.7 mm)
    settings = SolverSettings().without(*without)
    m = compute_metrics(simulate(load_scenario("paper-s2"), "decentralized", settings))
    assert m["collisions"] == 0 and m["min_clearance"] >= 0.0
    assert m["input_bound_violations"] == 0


@pytest.mark.parametrize("gap_in_margins", [0.3, 0.9, 2.5])
def test_first_stage_checks_of_a_pair_together_keep_the_true_distance(
    gap_in_margins: float,
) -> None:
    """Any two next positions the two robots' checks accept are at least ``D`` apart."""
    sc = load_scenario("head-on")
    a, b = DecentralizedController(sc, 1), DecentralizedController(sc, 2)
    D = sc.required_distances()[0, 1]
    margin = a.settings.collision_margin
    half = 0.5 * (D + gap_in_margins * margin)
    states = np.array([[-half, 0.01, 0.0], [half, -0.01, np.pi]])
    N = sc.horizon
    plans = {
        rid: PlanMessage(rid, 0, np.tile(states[rid - 1], (N + 1, 1)), np.zeros((N, 2)))
        for rid in (1, 2)
    }
    a.published, b.published = plans[1], plans[2]
    a.step(1, 0.5, states, plans, states)
    b.step(1, 0.5, states, plans, states)
    rng = np.random.default_rng(1)
    steps = rng.uniform(-2.0 * margin, 2.0 * margin, size=(4000, 2))
    ok_a = np.array([a.collisions.first_stage_safe(states[0, :2] + s) for s in steps])
    ok_b = np.array([b.collisions.first_stage_safe(states[1, :2] + s) for s in steps])
    assert a.collisions.first_stage_safe(states[0, :2])  # standing still is always accepted
    assert b.collisions.first_stage_safe(states[1, :2])
    assert 0 < ok_a.sum() < steps.shape[0] and 0 < ok_b.sum() < steps.shape[0]
    pa = states[0, :2] + steps[ok_a]
    pb = states[1, :2] + steps[ok_b]
    # worst pair: the accepted positions closest along the line of centres
    n = (states[0, :2] - states[1, :2]) / np.linalg.norm(states[0, :2] - states[1, :2])
    worst = (pa @ n).min() - (pb @ n).max()
    assert worst >= min(D, 2 * half) - 1e-12
    dist = np.linalg.norm(pa[:, None] - pb[None], axis=-1)
    assert dist.min() >= min(D, 2 * half) - 1e-12


@pytest.mark.parametrize("seed", [1, 2])
def test_perturbed_crossing_arrives_safely_with_consistent_counters(seed: int) -> None:
    """crossing-4 with initial states off by 1 mm: invariants only (the path is chaotic)."""
    import dataclasses

    sc = load_scenario("crossing-4")
    x0 = sc.initial_states() + np.random.default_rng(seed).normal(scale=1e-3, size=(4, 3))
    robots = tuple(dataclasses.replace(r, initial_state=tuple(map(float, x0[i])))
                   for i, r in enumerate(sc.robots))
    sc = sc.with_changes(robots=robots)
    m = compute_metrics(simulate(sc, "decentralized"))
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["input_bound_violations"] == 0
    assert m["max_final_position_error"] <= 0.05
    _assert_counters_consistent(m, sc, "decentralized")


def test_spent_time_budget_stops_iterating_after_one_qp() -> None:
    """SQP iterations start no new QP once the sample's time budget is spent."""
    sc = load_scenario("head-on").with_changes(t_end=3.0)
    free = simulate(sc, "centralized", SolverSettings(iteration_scheme="sqp"))
    assert free.extra["sqp_iterations_total"] > free.k  # several QPs in some sample
    spent = simulate(sc, "centralized", SolverSettings(iteration_scheme="sqp", time_budget=1e-12))
    assert spent.extra["sqp_iterations_total"] == spent.k  # exactly one QP per sample
    assert compute_metrics(spent)["collisions"] == 0


def test_engaged_robots_are_those_with_an_active_collision_row() -> None:
    sc = load_scenario("crossing-4")
    engine = CentralizedController(sc).engine
    L = engine.layout
    y = np.zeros(L.n_con)
    y[L.dyn_rows] = 5.0  # dynamics multipliers do not count
    assert not engine.engaged_robots(y).any()
    pair = 4  # pairs are (0,1), (0,2), (0,3), (1,2), (1,3), (2,3)
    y[L.internal_rows[pair, 3]] = -0.01
    np.testing.assert_array_equal(engine.engaged_robots(y), [False, True, False, True])
    ctrl = DecentralizedController(sc, robot_id=1)
    L = ctrl.engine.layout
    y = np.zeros(L.n_con)
    y[L.external_rows[0, 2, 0]] = -0.01
    assert ctrl.engine.engaged_robots(y).tolist() == [True]


def test_centralized_check_refuses_passing_through_between_samples() -> None:
    sc = load_scenario("head-on")
    ctrl = CentralizedController(sc)
    D = sc.required_distances()[0, 1]
    now = np.array([[-0.2, 0.0, 0.0], [0.2, 0.0, np.pi]])
    swapped = np.array([[0.2, 0.0, 0.0], [-0.2, 0.0, np.pi]])  # both ends 0.4 m > D apart
    assert np.linalg.norm(swapped[0, :2] - swapped[1, :2]) > D
    inputs = np.array([[0.4, 0.0], [0.4, 0.0]])  # the Euler plant: no path deviation
    assert not ctrl.first_input_safe(now, swapped, inputs)
    sidestep = np.array([[-0.2, 0.0, 0.0], [0.2, 0.5, np.pi]])
    assert ctrl.first_input_safe(now, sidestep, inputs)


def test_centralized_controller_refuses_bad_state_shapes() -> None:
    from sqpmpc.errors import ProblemError

    ctrl = CentralizedController(load_scenario("paper-s1"))
    with pytest.raises(ProblemError, match=r"shape \(4, 3\)"):
        ctrl.step(0.0, np.zeros((3, 3)))
    with pytest.raises(ProblemError, match="finite"):
        ctrl.step(0.0, np.full((4, 3), np.nan))


@pytest.mark.parametrize("solver", ["piqp", "daqp"])
@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
def test_other_qp_backends_closed_loops_are_safe_and_arrive(scheme: str, solver: str) -> None:
    sc = load_scenario("swap-6")
    m = compute_metrics(simulate(sc, scheme, SolverSettings(qp_solver=solver)))
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["input_bound_violations"] == 0
    assert m["max_final_position_error"] <= 0.05
    _assert_counters_consistent(m, sc, scheme)


@pytest.mark.parametrize("scheme", ["decentralized", "centralized"])
def test_rti_one_qp_path_gives_the_loops_closed_loop(scheme) -> None:
    """RTI's usual sample (one QP, no KKT check) takes a shorter path through
    :meth:`~sqpmpc.ocp.iteration.MultipleShootingSQP.solve`; with a KKT threshold that
    every sample meets, the general loop runs the same QP and keeps the same iterate
    (it only relinearizes once more to measure the residual): the closed loops are equal
    bitwise."""
    scenario = load_scenario("paper-s2").with_changes(t_end=4.0)
    short = simulate(scenario, scheme, SolverSettings())
    loop = simulate(scenario, scheme, SolverSettings(rti_kkt_threshold=1e300))
    np.testing.assert_array_equal(short.states, loop.states)
    np.testing.assert_array_equal(short.inputs, loop.inputs)

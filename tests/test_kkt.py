"""SQP mode converges to a KKT point of the NLP (checked with finite differences)."""

from __future__ import annotations

import numpy as np

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.models.unicycle import discrete_dynamics
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.qp.backend import OSQPSettings
from sqpmpc.sim.simulation import ClosedLoopSimulation


def _nlp_functions(ctrl: CentralizedController, x_meas: np.ndarray, t: float):
    """The NLP of paper eq. 7 (+ L1 slacks) written directly, independent of the QP code."""
    sc, L = ctrl.scenario, ctrl.engine.layout
    Q, R = np.asarray(sc.weights.Q), np.asarray(sc.weights.R)
    ref = ctrl.reference(t)
    rho = ctrl.settings.slack_penalty
    req = ctrl.required + ctrl.settings.collision_margin
    pairs = ctrl.pairs

    def split(z):
        X = z[L.state_index]
        U = z[L.input_index]
        S = np.zeros((len(pairs), sc.horizon))
        S[:, 1:] = z[L.slack_internal_index]
        return X, U, S

    def f(z):
        X, U, S = split(z)
        e = X[:, 1:, :2] - ref
        return float(np.sum(Q * e**2) + np.sum(R * U**2) + rho * S[:, 1:].sum())

    def eq(z):  # equality rows in the layout's order (initial, dynamics)
        X, U, _ = split(z)
        dyn = X[:, 1:] - discrete_dynamics(X[:, :-1], U, sc.sample_time)
        return np.concatenate(((X[:, 0] - x_meas).ravel(), dyn.ravel()))

    def coll(z):  # distance rows: ||p_a - p_b|| + s - req >= 0, stages 1..N
        X, _, S = split(z)
        d = X[pairs[:, 0], 1:, :2] - X[pairs[:, 1], 1:, :2]
        return (np.hypot(d[..., 0], d[..., 1]) + S - req[:, None]).ravel()

    return f, eq, coll


def _fd_gradient(fun, z, h=1e-6):
    out = []
    for i in range(z.size):
        e = np.zeros_like(z)
        e[i] = h
        out.append((np.asarray(fun(z + e)) - np.asarray(fun(z - e))) / (2 * h))
    return np.array(out)  # (n, m) or (n,)


def test_sqp_solution_satisfies_nlp_kkt_conditions() -> None:
    sc = load_scenario("paper-s2")
    # drive the closed loop to the first encounter with RTI (defaults)
    sim = ClosedLoopSimulation(sc, "centralized")
    pairs = sc.pairs()
    req = sc.required_distances()[pairs[:, 0], pairs[:, 1]]
    while True:
        sim.step()
        p = sim.states[sim.k, :, :2]
        d = np.linalg.norm(p[pairs[:, 0]] - p[pairs[:, 1]], axis=1)
        if np.any(d < req + 0.05):
            break
        assert sim.k < sc.steps
    x_meas = sim.states[sim.k]
    t = sim.t[sim.k]
    settings = SolverSettings(
        iteration_scheme="sqp", kkt_tolerance=1e-9, max_sqp_iterations=200,
        first_sample_iterations=200,
        osqp=OSQPSettings(eps_abs=1e-11, eps_rel=1e-11, max_iter=200000, polishing=True,
                          accept_inaccurate=False),
    ).without("keep-right", "stall-repair", "detour")
    ctrl = CentralizedController(sc, settings)
    out = ctrl.step(t, x_meas)
    assert out.fallback is None
    assert out.report.converged, out.report.kkt_residual
    assert ctrl.collisions.stage_one_overrides == 0
    z, y = ctrl.engine.z, ctrl.engine.y
    L = ctrl.engine.layout
    f, eq, coll = _nlp_functions(ctrl, x_meas, t)
    # stationarity of the Lagrangian in OSQP's convention: grad f + sum_rows y_row grad(row) = 0
    y_eq = np.concatenate((y[L.init_rows].ravel(), y[L.dyn_rows].ravel()))
    y_coll = y[L.internal_rows].ravel()
    grad = _fd_gradient(f, z) + _fd_gradient(eq, z) @ y_eq + _fd_gradient(coll, z) @ y_coll
    # linear rows (input bounds, slack >= 0) have identity gradients
    np.add.at(grad, L.input_index.ravel(), y[L.input_rows].ravel())
    np.add.at(grad, L.n_var - L.n_slack + np.arange(L.n_slack), y[L.slack_rows])
    assert np.abs(grad).max() < 1e-6
    # primal feasibility
    assert np.abs(eq(z)).max() < 1e-6
    assert coll(z).min() > -1e-6
    # dual feasibility (>= rows carry y <= 0) and complementarity
    assert y_coll.max() < 1e-6
    assert np.abs(y_coll * coll(z)).max() < 1e-6
    active = y_coll < -1e-4
    assert active.any(), "the sample must have an active collision constraint"
    u = z[L.input_index]
    lo, up = sc.bounds.input_lower(), sc.bounds.input_upper()
    y_u = y[L.input_rows]
    assert np.all(u >= lo - 1e-6) and np.all(u <= up + 1e-6)
    assert np.abs(np.where(y_u > 0, y_u * (up - u), y_u * (u - lo))).max() < 1e-6


def test_merit_weight_follows_each_sample_not_the_past() -> None:
    """The L1 merit weight is set from the current sample's multipliers.

    A weight kept from an encounter (multipliers in the hundreds) made later line
    searches backtrack on every step; after the encounter it must come down again.
    """
    sc = load_scenario("head-on")
    sim = ClosedLoopSimulation(sc, "centralized", SolverSettings(iteration_scheme="sqp"))
    engine = sim.controllers[0].engine
    weights = []
    while sim.k < sc.steps:
        sim.step()
        weights.append(engine.merit_weight)
    weights = np.array(weights)
    assert weights.max() > 100.0  # the encounter has large multipliers
    assert weights[-5:].max() < 0.1 * weights.max()  # and they do not linger


def test_first_sample_of_a_dense_circle_ends_at_the_qps_resolution() -> None:
    """Robots 0.48 m apart on the circle of swap-256, no plans yet: the stage-1 rows of the
    two missing neighbours (``missing-neighbour-reach``, nearly parallel to the motion they
    stop) carry multipliers of tens of thousands, so the KKT residual of steps at the QP's
    resolution (1e-9 m and less) stayed above 1e-5 and these robots iterated to the cap of
    30. Robot 53 now converges at once by the KKT test scaled by the multipliers (by the
    step test alone it ended after 3 QPs); robot 71's third step is too small for the merit
    function's line search and is taken whole, ending the SQP. The first-input check still
    brakes both: a missing neighbour is nearer than its distance plus its reach."""
    from sqpmpc.control.decentralized import DecentralizedController
    from sqpmpc.problem.fleets import antipodal_swap
    from sqpmpc.rules.registry import select_rules

    sc = antipodal_swap(256)
    settings = SolverSettings(rules=select_rules(["none"]))
    for index, most in ((53, 2), (71, 3)):
        ctrl = DecentralizedController(sc, int(sc.ids[index]), settings)
        out = ctrl.step(0, 0.0, sc.initial_states(), {})
        assert out.report.success and out.report.iterations <= most
        assert np.abs(out.report.last_qp.y).max() > 1e4  # the multipliers scaled for
        assert out.fallback == "brake"
        assert np.array_equal(out.inputs, np.zeros((1, 2)))

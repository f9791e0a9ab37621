"""The three always-on safety rows (sqpmpc.ocp.collision_rows): inner approximation, stage-one
override, missing-neighbour reach."""

from __future__ import annotations

import numpy as np

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.plans import PlanMessage
from sqpmpc.control.settings import SolverSettings
from sqpmpc.ocp.collision_rows import MISSING, SHARED
from sqpmpc.problem.scenario_file import load_scenario


def test_inner_approximation_satisfied_rows_imply_the_distance() -> None:
    """Every internal row the centralized controller writes, at random positions."""
    sc = load_scenario("paper-s2")
    ctrl = CentralizedController(sc)
    ctrl.step(0.0, sc.initial_states())
    A, lo = ctrl.engine.collision_blocks()["internal"]  # (P, N, 4), (P, N)
    pairs = ctrl.pairs
    rng = np.random.default_rng(4)
    p = rng.uniform(-3, 3, size=(20000, sc.n_robots, 2))
    for k, (a, b) in enumerate(pairs):
        gap = p[:, a] - p[:, b]
        for i in range(sc.horizon):
            satisfied = gap @ A[k, i, :2] >= lo[k, i]
            assert np.all(np.hypot(gap[satisfied, 0], gap[satisfied, 1]) >= lo[k, i] - 1e-12)


def test_stage_one_override_keeps_standing_still_feasible() -> None:
    """Predictions that crossed each other must not make the current configuration
    infeasible."""
    sc = load_scenario("head-on")
    ctrl = DecentralizedController(sc, 1)
    states = np.array([[-0.151, 0.0, 0.0], [0.151, 0.0, np.pi]])
    N = sc.horizon
    # robot 2 claims it will be on robot 1's left side of the line: its normals would flip
    crossing = PlanMessage(2, 0, np.tile([-0.5, 0.0, np.pi], (N + 1, 1)), np.zeros((N, 2)))
    before = ctrl.counters()["stage_one_overrides"]
    out = ctrl.step(1, 0.5, states, {2: crossing}, states)
    c = ctrl.collisions
    assert c.fixed_normals[0, 0] @ states[0, :2] >= c.fixed_rhs[0, 0] - 1e-12
    assert out.fallback is None or out.fallback == "brake"
    assert out.counters["stage_one_overrides"] > before
    # the same holds without any liveness rule (the override is not a rule)
    bare = DecentralizedController(sc, 1, SolverSettings(rules=()))
    bare.step(1, 0.5, states, {2: crossing}, states)
    c = bare.collisions
    assert c.fixed_normals[0, 0] @ states[0, :2] >= c.fixed_rhs[0, 0] - 1e-12


def test_missing_neighbour_keeps_its_reach_or_stands_still() -> None:
    sc = load_scenario("head-on")
    ctrl = DecentralizedController(sc, 1)
    D = sc.required_distances()[0, 1]
    reach = ctrl.collisions.reach
    assert reach == sc.sample_time * 0.6  # what the neighbour can travel in one sample
    for gap in (D + reach + 0.5, D + 0.5 * reach):  # room to move, and not
        states = np.array([[-gap / 2, 0.0, 0.0], [gap / 2, 0.0, np.pi]])
        ctrl.predict_neighbours(3, states, {}, states)  # no plan from robot 2
        c = ctrl.collisions
        assert c.kind.tolist() == [MISSING]
        me, other = states[0, :2], states[1, :2]
        assert c.first_stage_safe(me)  # standing still is always accepted
        rng = np.random.default_rng(1)
        for step in rng.uniform(-0.4, 0.4, size=(2000, 2)):
            nxt = me + step
            if c.first_stage_safe(nxt):
                # the whole segment keeps d + reach from the neighbour's current position
                s = np.linspace(0.0, 1.0, 51)[:, None]
                seg = me + s * step
                assert np.hypot(*(seg - other).T).min() >= D + reach - 1e-9
        away = c.first_stage_safe(me + np.array([-0.05, 0.0]))
        closer = c.first_stage_safe(me + np.array([0.05, 0.0]))
        if gap >= D + reach:  # room: moving away is fine, closer only while keeping d + r
            assert away and closer == (gap - 0.05 >= D + reach)
        else:  # inside the neighbour's reach: only standing still is accepted
            assert not away and not closer


def test_shared_slot_with_a_fresh_plan_is_shared() -> None:
    sc = load_scenario("head-on")
    ctrl = DecentralizedController(sc, 1)
    states = sc.initial_states()
    N = sc.horizon
    plan = PlanMessage(2, 2, np.tile(states[1], (N + 1, 1)), np.zeros((N, 2)))
    ctrl.step(2, 2 * sc.sample_time, states)  # its own plan of sample 2
    ctrl.predict_neighbours(3, states, {2: plan}, states)
    assert ctrl.collisions.kind.tolist() == [SHARED]
    ctrl.predict_neighbours(4, states, {2: plan}, states)  # one sample too old: missing
    assert ctrl.collisions.kind.tolist() == [MISSING]
    # unless robot 2 reported (relayed by the plant) that its newest plan of robot 1 was
    # 2 samples old: then both build the pair's row from their plans of sample 2
    ctrl.step(4, 4 * sc.sample_time, states, {2: plan}, states, plan_ages={2: {1: 2}})
    assert ctrl.collisions.kind.tolist() == [SHARED]
    assert ctrl.counters()["older_shared_neighbours"] == 1
    # its own report: robot 2's newest plan is 2 samples old, late at one step only (it
    # may have been lost): not reported
    assert ctrl.plan_ages == {}

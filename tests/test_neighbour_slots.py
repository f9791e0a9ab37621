"""Neighbour selection: a fixed budget of collision slots filled with the nearest robots
that can come within their distance over the horizon."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.decentralized import DecentralizedController
from sqpmpc.control.plans import PlanMessage
from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.ocp.collision_rows import OFF, SHARED
from sqpmpc.problem.fleets import antipodal_swap
from sqpmpc.sim.simulation import simulate
from tests.rule_helpers import fleet


def _line_fleet() -> tuple[DecentralizedController, np.ndarray]:
    """Robot 1 at the origin, others at 0.5, 1, 1.5, 20 and 40 m on the x axis."""
    xs = [0.0, 0.5, 1.0, 1.5, 20.0, 40.0]
    sc = fleet([[x, 0.0, 0.0] for x in xs], [[x, 5.0] for x in xs])
    ctrl = DecentralizedController(sc, 1, SolverSettings(neighbour_slots=2))
    return ctrl, sc.initial_states()


def test_slots_hold_the_nearest_neighbours_within_the_interaction_radius() -> None:
    ctrl, states = _line_fleet()
    radius = ctrl.interaction_radius
    # 0.3 m + margin + 2 x 0.6 m/s x 8 x 0.5 s = 5.101 m: robots at 20 m and 40 m are out
    np.testing.assert_allclose(radius, 0.3 + 0.001 + 4.8)
    ctrl.predict_neighbours(0, states, {}, None)
    assert ctrl.slots == 2 and ctrl.engine.layout.n_external == 2
    np.testing.assert_array_equal(ctrl.slot_data.index, [1, 2])  # the two nearest
    # the third robot within reach is left to the first-input check
    np.testing.assert_allclose(ctrl.collisions.unslotted, [[1.5, 0.0]])
    assert ctrl.counters()["unslotted_neighbours"] == 1


def test_free_slots_are_off_and_plans_fill_the_used_ones() -> None:
    sc = fleet([[0, 0, 0], [0.5, 0, 0], [30, 0, 0]], [[0, 5], [0.5, 5], [30, 5]])
    ctrl = DecentralizedController(sc, 1, SolverSettings(neighbour_slots=2))
    N = sc.horizon
    states = sc.initial_states()
    plan = PlanMessage(2, 0, np.tile(states[1], (N + 1, 1)), np.zeros((N, 2)))
    ctrl.step(0, 0.0, states)  # a shared row needs both plans of sample 0: its own too
    ctrl.predict_neighbours(1, states, {2: plan}, states)
    assert ctrl.collisions.kind.tolist() == [SHARED, OFF]
    assert np.all(np.isneginf(ctrl.collisions.fixed_rhs[1]))  # no row for the free slot


def test_the_unslotted_check_keeps_distance_plus_reach_or_stands_still() -> None:
    # the two slots go to the robots above and below; the one ahead at 1.2 m gets none
    starts = [[0, 0, 0], [0, 1.0, 0], [0, -1.0, 0], [1.2, 0, 0]]
    sc = fleet(starts, [[s[0], s[1] + 5] for s in starts])
    ctrl = DecentralizedController(sc, 1, SolverSettings(neighbour_slots=2))
    states = sc.initial_states()
    ctrl.predict_neighbours(0, states, {}, None)
    c = ctrl.collisions
    np.testing.assert_allclose(c.unslotted, [[1.2, 0.0]])
    keep = 0.3 + c.reach  # its distance plus what it can travel in one sample: 0.6 m
    assert c.first_stage_safe(np.zeros(2))  # standing still
    assert c.first_stage_safe(np.array([1.2 - keep - 0.01, 0.0]))
    assert not c.first_stage_safe(np.array([1.2 - keep + 0.01, 0.0]))
    assert c.first_stage_safe(np.array([-0.3, 0.0]))  # away


def test_without_slots_every_other_robot_has_its_slot() -> None:
    sc = antipodal_swap(6)
    ctrl = DecentralizedController(sc, 1)
    assert ctrl.slots == 5 and not ctrl.selecting
    np.testing.assert_array_equal(ctrl.slot_data.index, ctrl.others)


@pytest.mark.parametrize("slots", [2, 4])
def test_a_dense_swap_with_few_slots_stays_safe(slots: int) -> None:
    sc = antipodal_swap(16)
    m = compute_metrics(simulate(sc, "decentralized", SolverSettings(neighbour_slots=slots)))
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["input_bound_violations"] == 0
    assert m["counters"]["unslotted_neighbours"] > 0  # the budget was exceeded


def test_centralized_pair_rows_use_the_same_selection() -> None:
    xs = [0.0, 0.5, 1.0, 1.5, 20.0]
    sc = fleet([[x, 0.0, 0.0] for x in xs], [[x, 5.0] for x in xs])
    ctrl = CentralizedController(sc, SolverSettings(neighbour_slots=1))
    layout_rows = ctrl.engine.layout.n_con
    ctrl.predict_neighbours(0, sc.initial_states(), {}, None)
    stages = dict(zip(map(tuple, ctrl.pairs.tolist()), ctrl.collisions.stages.tolist(),
                      strict=True))
    N = sc.horizon
    # each robot's nearest pair gets every stage
    assert stages[(0, 1)] == stages[(1, 2)] == stages[(2, 3)] == N
    # within reach but nobody's nearest: stage 1 only; beyond reach (20 m): no row
    assert stages[(0, 2)] == stages[(0, 3)] == stages[(1, 3)] == 1
    assert all(stages[(a, 4)] == 0 for a in range(4))
    assert ctrl.counters()["stage_one_pairs"] == 3
    assert ctrl.engine.layout.n_con == layout_rows  # the pattern holds every pair


@pytest.mark.parametrize("slots", [1, 3])
def test_a_centralized_swap_with_few_pair_slots_stays_safe(slots: int) -> None:
    sc = antipodal_swap(12)
    m = compute_metrics(simulate(sc, "centralized", SolverSettings(neighbour_slots=slots)))
    assert m["collisions"] == 0 and m["intersample_collisions"] == 0
    assert m["input_bound_violations"] == 0
    assert m["counters"]["stage_one_pairs"] > 0  # the budget was exceeded


@pytest.mark.parametrize("value", [0, -1, 2.5, True])
def test_bad_slot_budget_is_refused(value: object) -> None:
    with pytest.raises(ProblemError, match="neighbour_slots"):
        SolverSettings(neighbour_slots=value)


def test_auto_settings_pick_the_fleet_path_above_the_fleet_size() -> None:
    from sqpmpc.control.settings import (
        BOUNDED_QP_SOLVER,
        FLEET_NEIGHBOUR_SLOTS,
        FLEET_QP_SOLVER,
        FLEET_ROBOTS,
    )

    auto = SolverSettings()
    small = auto.resolved(FLEET_ROBOTS)
    large = auto.resolved(FLEET_ROBOTS + 1)
    assert (small.qp_solver, small.neighbour_slots) == (BOUNDED_QP_SOLVER, None)
    assert (large.qp_solver, large.neighbour_slots) == (FLEET_QP_SOLVER, FLEET_NEIGHBOUR_SLOTS)
    explicit = SolverSettings(qp_solver="daqp", neighbour_slots=None).resolved(64)
    assert (explicit.qp_solver, explicit.neighbour_slots) == ("daqp", None)
    ctrl = DecentralizedController(antipodal_swap(16), 1)
    assert ctrl.slots == FLEET_NEIGHBOUR_SLOTS and ctrl.settings.qp_solver == FLEET_QP_SOLVER
    central = CentralizedController(antipodal_swap(16))
    assert central.slots == FLEET_NEIGHBOUR_SLOTS
    assert central.settings.qp_solver == BOUNDED_QP_SOLVER

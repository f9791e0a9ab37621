"""Rule ``gear-cycle``: a free robot reversing gear twice in a row is iterated to convergence."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.control.settings import SolverSettings
from sqpmpc.errors import ProblemError
from sqpmpc.rules.liveness import GearCycle
from tests.rule_helpers import fleet, only, view


def _asks(plan_speed: float, last: float, before: float, iteration: str = "rti",
          engaged: bool = False) -> tuple[bool, int]:
    sc = fleet([[0, 0, 0], [3, 3, 0]], [[2, 0], [5, 3]])
    settings = only("gear-cycle")
    if iteration == "sqp":
        settings = SolverSettings(iteration_scheme="sqp", rules=settings.rules)
    ctrl = CentralizedController(sc, settings)
    applied = np.array([[last, 0.0], [0.0, 0.0]])
    before = np.array([[before, 0.0], [0.0, 0.0]])
    # the solution: robot 1 plans plan_speed first, robot 2 stands; a row holds both or none
    v = view(ctrl, sc.initial_states(), applied, before).but(
        first_speeds=np.array([plan_speed, 0.0]),
        holding=lambda: np.array([engaged, engaged]))
    out = ctrl.rule("gear-cycle").after_solve(v)
    return out is not None and out.iterate, ctrl.counters()["gear_cycle_samples"]


@pytest.mark.parametrize(("plan", "last", "before"), [(0.3, -0.3, 0.3), (-0.2, 0.2, -0.1)])
def test_a_second_reversal_in_a_row_asks_for_convergence(plan: float, last: float,
                                                         before: float) -> None:
    assert _asks(plan, last, before) == (True, 1)


@pytest.mark.parametrize(("plan", "last", "before"), [
    (0.3, -0.3, -0.3),  # one gear change only
    (0.3, 0.3, 0.3),  # no change
    (0.3, -0.003, 0.3),  # a reversal through rest (below min_speed)
    (0.001, -0.3, 0.3),  # the plan is at rest
])
def test_other_speed_histories_do_not(plan: float, last: float, before: float) -> None:
    assert _asks(plan, last, before) == (False, 0)


def test_a_robot_held_by_a_collision_row_is_left_to_rti() -> None:
    assert _asks(0.3, -0.3, 0.3, engaged=True) == (False, 0)


def test_sqp_iteration_never_asks() -> None:
    assert _asks(0.3, -0.3, 0.3, iteration="sqp") == (False, 0)


def test_bad_threshold_is_refused() -> None:
    with pytest.raises(ProblemError, match="gear-cycle"):
        GearCycle(min_speed=0.0)

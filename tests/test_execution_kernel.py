"""The compiled execution of a schedule (:mod:`sqpmpc.kernels.execution`) counts the
same progress and takes the same holds and waits as the numpy form it replaced
(``tests/execution_reference.py``): swaps whose robots are scattered around their paths
(some pushed off, some on another's next vertex, some each on the other's way), all
robots at once and a controller's own robots alone (:meth:`Execution.clear`)."""

from __future__ import annotations

import numpy as np
import pytest

from sqpmpc.coordination.fleet import fleet_plan
from sqpmpc.coordination.schedule import Execution
from sqpmpc.problem.fleets import antipodal_swap
from tests import execution_reference as reference


class _Counting:
    """The reference's waits (:func:`reference.yield_way`), counted."""

    def __init__(self) -> None:
        self.waits = 0
        self.inner = reference.yield_way

    def __call__(self, execution: Execution, now: np.ndarray, free: np.ndarray) -> np.ndarray:
        mask = self.inner(execution, now, free)
        self.waits += int(mask.sum())
        return mask


@pytest.mark.parametrize(("robots", "seeds"), [(16, range(8)), (48, range(2))])
def test_the_compiled_execution_is_the_numpy_one(robots: int, seeds: range,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    counting = _Counting()
    monkeypatch.setattr(reference, "yield_way", counting)
    plan = fleet_plan(antipodal_swap(robots), 0.2, 0.321)
    n = plan.schedule.size
    top = plan.schedule.lengths - 1
    holds = 0
    for seed in seeds:
        rng = np.random.default_rng(seed)
        want = Execution(plan.schedule, plan.roadmap, plan.robots, window=3)
        got = Execution(plan.schedule, plan.roadmap, plan.robots, window=3)
        for _ in range(40):
            ahead = np.minimum(want.progress + rng.integers(0, 3, n), top)
            at = plan.roadmap.positions[plan.schedule.paths[np.arange(n), ahead]]
            spread = plan.roadmap.spacing * rng.choice([0.1, 0.3, 0.6])
            now = at + rng.normal(0.0, spread, (n, 2))
            np.testing.assert_array_equal(got.advance(now), reference.advance(want, now))
            cleared = reference.clear_all(want, now)
            np.testing.assert_array_equal(got.clear_all(now), cleared)
            rows = rng.permutation(n)[:rng.integers(1, n + 1)]
            np.testing.assert_array_equal(got.clear(now, rows), cleared[rows])
            permitted = got.permitted_all()
            holds += int(((permitted > got.progress) & (cleared == got.progress)).sum())
    assert holds > 0 and counting.waits > 0  # both held robots and robots giving way


def test_with_one_robot_measured_none_is_held_nor_waits() -> None:
    plan = fleet_plan(antipodal_swap(2), 0.2, 0.321)
    execution = Execution(plan.schedule, plan.roadmap, plan.robots, window=3)
    one = plan.roadmap.positions[plan.schedule.paths[:1, 0]]
    execution.robots = np.zeros(1, dtype=np.int64)  # both scheduled robots read robot 0
    np.testing.assert_array_equal(execution.clear(one, np.array([0])),
                                  reference.clear_all(execution, one)[:1])

"""Measured headings wrapped as odometry reports them (MuJoCo, ROS: to an interval of one
turn) give the controllers the same inputs as continuous ones: a robot driving along
:math:`\\pm\\pi` is not asked to turn a full circle."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sqpmpc.control.centralized import CentralizedController
from sqpmpc.models.base import continuous_headings
from sqpmpc.problem.references import PointReference
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.simulation import ClosedLoopSimulation


def _wrap(psi: np.ndarray) -> np.ndarray:
    """To [-pi, pi)."""
    return np.remainder(psi + np.pi, 2.0 * np.pi) - np.pi


def test_continuous_headings_moves_only_jumps() -> None:
    last = np.array([3.1, -3.1, 0.5])
    psi = np.array([-3.1, 3.1, 0.6])
    out = continuous_headings(psi, last)
    assert out == pytest.approx([2 * np.pi - 3.1, 3.1 - 2 * np.pi, 0.6])
    assert out[2] == psi[2]                                  # unchanged, bit for bit
    assert continuous_headings(psi, None).tolist() == psi.tolist()


@pytest.mark.parametrize("accelerations", [False, True], ids=["paper-robot", "accelerations"])
def test_wrapped_headings_give_the_same_inputs(accelerations: bool) -> None:
    # one robot heading 3.0 rad for a goal at -2.82 rad (3.46 continuous): it turns
    # through pi, where the wrapped heading jumps by a turn
    sc = load_scenario("head-on")
    robot = dataclasses.replace(sc.robots[0], initial_state=(0.0, 0.0, 3.0),
                                reference=PointReference(position=(-3.0, -1.0)))
    sc = sc.with_changes(robots=(robot,), t_end=8.0)
    if accelerations:
        sc = sc.with_changes(bounds=dataclasses.replace(
            sc.bounds, acceleration=(-2.0, 2.0), angular_acceleration=(-7.0, 7.0)))
    sim = ClosedLoopSimulation(sc, "centralized")
    wrapped = CentralizedController(sim.scenario)
    jumps = 0
    while sim.k < sc.steps:
        k = sim.k
        measured = np.array(sim.plant.measure(sim.states[k]), dtype=float)
        measured[:, 2] = _wrap(measured[:, 2])
        jumps += int(np.count_nonzero(np.abs(measured[:, 2] - sim.states[k, :, 2]) > 1.0))
        out = wrapped.step(sim.t[k], measured, k)
        sim.step()
        assert out.inputs == pytest.approx(sim.inputs[k], abs=1e-6)
    assert jumps > 0  # the wrapped headings did differ by a turn

"""The MuJoCo physics plant (``physics`` extra): the driver, the measurements and a short
closed loop of both schemes on rigid-body robots (skipped only without MuJoCo)."""

from __future__ import annotations

import dataclasses
import sys

import numpy as np
import pytest

from sqpmpc.errors import DependencyError, ProblemError
from sqpmpc.io.metrics import compute_metrics
from sqpmpc.problem.scenario_file import load_scenario
from sqpmpc.sim.physics import (
    OVERLAP_TOLERANCE,
    PhysicalRobot,
    PhysicalSimulation,
    PhysicsFleet,
    load_mujoco,
)


def test_a_missing_mujoco_is_one_error_naming_the_extra(monkeypatch: pytest.MonkeyPatch
                                                        ) -> None:
    monkeypatch.setitem(sys.modules, "mujoco", None)  # import mujoco then fails
    with pytest.raises(DependencyError, match=r"'physics' extra"):
        load_mujoco()


@pytest.mark.parametrize("field, value", [("mass", 0.0), ("wheel_torque", -1.0),
                                          ("friction", float("nan")), ("track_fraction", 1.2),
                                          ("physics_step", True)])
def test_robot_model_refuses_bad_values(field: str, value: object) -> None:
    with pytest.raises(ProblemError, match=field):
        PhysicalRobot(**{field: value})


def test_sample_time_must_be_a_multiple_of_the_physics_step() -> None:
    with pytest.raises(ProblemError, match="multiple"):
        PhysicalRobot().substeps(0.0503)


def _one_robot():
    sc = load_scenario("head-on")
    return sc.with_changes(robots=sc.robots[:1])


def test_driver_and_measurements_follow_a_held_command() -> None:
    pytest.importorskip("mujoco")
    fleet = PhysicsFleet(_one_robot())
    start = fleet.poses()
    assert np.allclose(start, [[-3.0, 0.0, 0.0]], atol=1e-9)  # settled where declared
    u = np.array([[0.4, 0.3]])
    wheels = fleet.wheel_speeds(u)
    r, b = fleet.robot.wheel_radius, fleet.robot.track_fraction * 0.3
    assert wheels[0, 1] - wheels[0, 0] == pytest.approx(0.3 * b / r)
    assert wheels.mean() == pytest.approx(0.4 / r)
    for _ in range(4):
        poses, applied = fleet.step(start, u)
    np.testing.assert_array_equal(applied, u)
    v, w = fleet.velocities()[0]
    assert v == pytest.approx(0.4, rel=0.05) and w == pytest.approx(0.3, rel=0.05)
    # a robot that lags behind its command: short of the ideal distance, never beyond it
    assert 0.0 < np.linalg.norm(poses[0, :2] - start[0, :2]) < 4 * 0.5 * 0.4
    assert len(fleet.pair_clearance) == 4 * fleet.substeps


@pytest.mark.parametrize("scheme", ["centralized", "decentralized"])
@pytest.mark.parametrize("accelerations", [False, True], ids=["paper-robot", "accelerations"])
def test_short_closed_loop_on_the_physics_plant(scheme: str, accelerations: bool) -> None:
    pytest.importorskip("mujoco")
    sc = load_scenario("head-on")
    if accelerations:  # what the nominal robot reaches, halved (docs/physical-robots.md)
        sc = sc.with_changes(bounds=dataclasses.replace(
            sc.bounds, acceleration=(-2.0, 2.0), angular_acceleration=(-7.0, 7.0)))
    sim = PhysicalSimulation(sc, scheme)
    # the controllers get the measured velocities exactly when the robots have them
    assert sim.fleet.measure(sim.states[0]).shape == (2, 5 if accelerations else 3)
    rec = sim.run()
    assert rec.completed
    assert rec.extra["physics_steps"] == sc.steps * sim.fleet.substeps
    assert rec.extra["plant_discretization"] == "mujoco"
    # every physics step: no overlap beyond the QP's 1 mm margin
    assert rec.extra["overlap_steps"] == 0
    assert rec.extra["physics_min_clearance"] >= -OVERLAP_TOLERANCE
    assert min(sim.fleet.pair_clearance) == rec.extra["physics_min_clearance"]
    assert compute_metrics(rec)["max_final_position_error"] <= 0.05
    # measured velocities: within the input bounds (a little overshoot of the servos)
    lo, hi = sc.bounds.input_lower(), sc.bounds.input_upper()
    assert (sim.velocities >= lo - 0.05).all() and (sim.velocities <= hi + 0.05).all()

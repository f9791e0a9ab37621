"""The public API: top-level names, names that match the file format, per-tick setters."""

from __future__ import annotations

import dataclasses
import inspect
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

import sqpmpc
from sqpmpc.models.unicycle import discrete_dynamics
from sqpmpc.problem.scenario_file import (
    OBSTACLE_KEYS,
    OPTIONAL_TOP_KEYS,
    PLANT_KEYS,
    POLYGON_KEYS,
    ROBOT_KEYS,
    TOP_KEYS,
)

ROOT = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------- names


def test_every_public_name_resolves_to_the_defining_module() -> None:
    exported = [n for n in sqpmpc.__all__ if n != "__version__"]
    assert len(set(sqpmpc.__all__)) == len(sqpmpc.__all__)
    for name in exported:
        value = getattr(sqpmpc, name)
        defining = [m for key, m in list(sys.modules.items()) if key.startswith("sqpmpc.")
                    and name in getattr(m, "__all__", ()) and getattr(m, name, None) is value]
        assert defining, f"{name} is public but in no sqpmpc module's __all__"
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        _ = sqpmpc.nope


def test_importing_the_package_loads_no_solver_or_compiler() -> None:
    code = ("import sys, sqpmpc; heavy = [m for m in ('numba', 'osqp', 'scipy', 'matplotlib') "
            "if m in sys.modules]; print(heavy); sqpmpc.Scenario; print('numba' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, env={"PYTHONPATH": str(ROOT), "PATH": ""}, check=True)
    assert out.stdout.split("\n")[:2] == ["[]", "True"]


def test_constructor_keywords_are_the_scenario_file_keys() -> None:
    def keywords(cls: type) -> set[str]:
        return set(inspect.signature(cls).parameters)

    # polygons are the file's [[obstacles]] tables with points (CONTRACT 1d)
    assert keywords(sqpmpc.Scenario) - {"source", "polygons"} == set(
        TOP_KEYS + OPTIONAL_TOP_KEYS)
    assert keywords(sqpmpc.Obstacle) == set(OBSTACLE_KEYS)
    assert keywords(sqpmpc.PolygonObstacle) == set(POLYGON_KEYS)
    assert keywords(sqpmpc.PlantSpec) == set(PLANT_KEYS)
    assert keywords(sqpmpc.RobotSpec) == set(ROBOT_KEYS)
    assert keywords(sqpmpc.Weights) == {"Q", "R"}
    assert keywords(sqpmpc.Bounds) == {"v", "omega", "x", "y", "acceleration",
                                       "angular_acceleration"}
    examples = [sqpmpc.HarmonicReference(omega=0.1, x=(0, 1, 2), y=(3, 4, 5)),
                sqpmpc.PointReference(position=(1.5, -2.0)),
                sqpmpc.WaypointReference(times=(0.0, 4.0), points=((0, 0), (2, 1)))]
    for ref in examples:
        table = ref.to_dict()
        assert keywords(type(ref)) == set(table) - {"type"}
        # the inline table is the constructor's keywords, both ways
        assert type(ref)(**{k: v for k, v in table.items() if k != "type"}) == ref
        assert sqpmpc.reference_from_dict(table, "t", "reference") == ref


def test_point_reference_goal_repr_and_deprecated_alias() -> None:
    ref = sqpmpc.PointReference(position=[3, 4])
    assert ref.goal == (3.0, 4.0) and ref == sqpmpc.PointReference((3.0, 4.0))
    assert eval(repr(ref), {"PointReference": sqpmpc.PointReference}) == ref
    np.testing.assert_array_equal(ref.position(np.zeros(2)), [[3.0, 4.0], [3.0, 4.0]])
    with pytest.warns(DeprecationWarning, match="goal"):
        assert ref.position_xy == (3.0, 4.0)


def test_problem_data_built_in_code_raise_the_library_errors() -> None:
    with pytest.raises(sqpmpc.ProblemError, match=r"position: expected an array of 2"):
        sqpmpc.PointReference(position=(1.0,))
    with pytest.raises(sqpmpc.ProblemError, match=r"diameter: expected a finite number > 0"):
        sqpmpc.RobotSpec(id=1, initial_state=(0, 0, 0), diameter=-1.0,
                         reference=sqpmpc.PointReference((0, 0)))
    with pytest.raises(ValueError):  # still a ValueError for existing callers
        sqpmpc.Weights(Q=(1.0, 1.0), R=(0.0, 1.0))


# ----------------------------------------------------------------------------- setters


def _with_reference(sc: sqpmpc.Scenario, robot_id: int, ref: sqpmpc.Reference):
    robots = tuple(dataclasses.replace(r, reference=ref) if r.id == robot_id else r
                   for r in sc.robots)
    return sc.with_changes(robots=robots)


def _assert_same(a: sqpmpc.ControlOutput, b: sqpmpc.ControlOutput) -> None:
    np.testing.assert_allclose(a.inputs, b.inputs, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.predicted_states, b.predicted_states, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.predicted_inputs, b.predicted_inputs, rtol=0, atol=1e-9)
    assert a.fallback == b.fallback


def test_update_reference_equals_a_controller_built_with_it_centralized() -> None:
    sc = sqpmpc.load_scenario("paper-s2")
    new = sqpmpc.PointReference(position=(1.0, -1.0))  # a goal at rest: the roundabout's too
    rebuilt = sqpmpc.CentralizedController(_with_reference(sc, 2, new))
    updated = sqpmpc.CentralizedController(sc)
    updated.update_reference(2, new)
    assert updated.scenario.robots[1].reference == new
    np.testing.assert_array_equal(updated.rule("roundabout").rest_goals,
                                  rebuilt.rule("roundabout").rest_goals)
    x = sc.initial_states()
    for k in range(4):
        t = k * sc.sample_time
        a, b = updated.step(t, x), rebuilt.step(t, x)
        _assert_same(a, b)
        assert a.plan is None
        x = discrete_dynamics(x, b.inputs, sc.sample_time, "euler")
    assert updated.counters() == rebuilt.counters()


def test_update_reference_equals_a_controller_built_with_it_decentralized() -> None:
    sc = sqpmpc.load_scenario("crossing-4")
    new = sqpmpc.WaypointReference(times=(0.0, 20.0), points=((0.0, 0.0), (2.0, 2.0)))
    changed = _with_reference(sc, 1, new)
    fleet = {int(i): sqpmpc.DecentralizedController(changed, int(i)) for i in sc.ids}
    updated = sqpmpc.DecentralizedController(sc, 1)
    updated.update_reference(1, new)
    x, prev, plans = changed.initial_states(), None, {}
    for k in range(4):
        t = k * sc.sample_time
        mine = updated.step(k, t, x, plans, prev)
        outs = {i: c.step(k, t, x, plans, prev) for i, c in fleet.items()}
        _assert_same(mine, outs[1])
        plans = {i: o.plan for i, o in outs.items()}
        u = np.concatenate([outs[int(i)].inputs for i in sc.ids])
        prev, x = x, discrete_dynamics(x, u, sc.sample_time, "euler")


def test_update_reference_mid_run_is_tracked_from_the_next_step() -> None:
    sc = sqpmpc.load_scenario("head-on")
    ctrl = sqpmpc.CentralizedController(sc)
    ctrl.step(0.0, sc.initial_states())
    goal = (0.5, 2.0)
    ctrl.update_reference(1, sqpmpc.PointReference(position=goal))
    np.testing.assert_array_equal(ctrl.reference(sc.sample_time)[0],
                                  np.tile(goal, (sc.horizon, 1)))
    np.testing.assert_array_equal(ctrl.reference(0.0)[1],
                                  sc.robots[1].reference.position(
                                      sc.sample_time * np.arange(1, sc.horizon + 1)))


def test_update_reference_refuses_bad_input_naming_the_robot() -> None:
    sc = sqpmpc.load_scenario("head-on")
    ctrl = sqpmpc.CentralizedController(sc)
    with pytest.raises(sqpmpc.ProblemError, match=r"update_reference: no robot with id 9"):
        ctrl.update_reference(9, sqpmpc.PointReference((0, 0)))
    with pytest.raises(sqpmpc.ProblemError,
                       match=r"update_reference: robot 2: expected a HarmonicReference.*tuple"):
        ctrl.update_reference(2, (1.0, 2.0))
    with pytest.raises(sqpmpc.ProblemError, match=r"robot_id must be an integer"):
        ctrl.update_reference("2", sqpmpc.PointReference((0, 0)))
    assert ctrl.scenario is sc  # nothing changed


def test_update_neighbour_plan_equals_passing_the_plans() -> None:
    sc = sqpmpc.load_scenario("crossing-4")
    fleet = {int(i): sqpmpc.DecentralizedController(sc, int(i)) for i in sc.ids}
    held = sqpmpc.DecentralizedController(sc, 2)
    x, prev, plans = sc.initial_states(), None, {}
    for k in range(4):
        t = k * sc.sample_time
        outs = {i: c.step(k, t, x, plans, prev) for i, c in fleet.items()}
        mine = held.step(k, t, x, previous_states=prev)  # the plans it was given
        _assert_same(mine, outs[2])
        assert mine.plan is held.published and mine.plan.sample == k
        plans = {i: o.plan for i, o in outs.items()}
        for i, plan in plans.items():
            if i != 2:
                held.update_neighbour_plan(plan)
        assert set(held.neighbour_plans) == {1, 3, 4}
        u = np.concatenate([outs[int(i)].inputs for i in sc.ids])
        prev, x = x, discrete_dynamics(x, u, sc.sample_time, "euler")
    # a late (older) plan does not replace the newer one
    newest = held.neighbour_plans[1]
    old = sqpmpc.PlanMessage(1, newest.sample - 1, newest.states, newest.inputs)
    held.update_neighbour_plan(old)
    assert held.neighbour_plans[1] is newest


def test_update_neighbour_plan_refuses_bad_plans_naming_the_robot() -> None:
    sc = sqpmpc.load_scenario("crossing-4")
    ctrl = sqpmpc.DecentralizedController(sc, 2)
    N = sc.horizon
    good = {"states": np.zeros((N + 1, 3)), "inputs": np.zeros((N, 2))}
    cases = [
        (sqpmpc.PlanMessage(2, 0, **good), r"robot 2: plan of robot 2: not a neighbour"),
        (sqpmpc.PlanMessage(9, 0, **good), r"plan of robot 9: not a neighbour; neighbours: "
                                           r"1, 3, 4"),
        (sqpmpc.PlanMessage(1, -1, **good), r"plan of robot 1: sample must be an integer"),
        (sqpmpc.PlanMessage(1, 0, np.zeros((N, 3)), good["inputs"]),
         rf"plan of robot 1: states must be finite with shape \({N + 1}, 3\)"),
        (sqpmpc.PlanMessage(1, 0, good["states"], np.full((N, 2), np.nan)),
         r"plan of robot 1: inputs must be finite .* non-finite"),
    ]
    for plan, message in cases:
        with pytest.raises(sqpmpc.ProblemError, match=message):
            ctrl.update_neighbour_plan(plan)
    with pytest.raises(sqpmpc.ProblemError, match="expects a PlanMessage"):
        ctrl.update_neighbour_plan({"robot_id": 1})
    assert not ctrl.neighbour_plans


def test_no_warnings_on_the_documented_path() -> None:
    sc = sqpmpc.load_scenario("head-on")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ctrl = sqpmpc.DecentralizedController(sc, 1)
        ctrl.update_reference(1, sqpmpc.PointReference(position=(0.0, 1.0)))
        out = ctrl.step(0, 0.0, sc.initial_states())
    assert out.plan.robot_id == 1
